"""Photo mode's fine detail against its held-out score on a capture of many photos (a room): blend, balanced, sharp.

    python bench/bench_detail.py MESH CAMERAS                      # every tenth photo from the fifth held out
    python bench/bench_detail.py MESH CAMERAS --app-style 4096 --override photos__temperature=0.5
    python bench/bench_detail.py MESH CAMERAS --app-style 4096 --repeat 4 --no-variants --override photos__keyframes=off

MESH is the capture's mesh with its texture (a capture app's input), or, with ``--app-style SIZE``, a mesh whose
UV layout an app-style input is baked on from the given photos (:func:`bench.baselines.app_style_bake`: per texel
the photo that sees it best, as it is). CAMERAS is anything ``--photos`` reads. The held-out photos (every
``--every``-th from ``--first``) are given to nothing; scantex gets the others (``photos.holdout`` 0) and the
input, once a run: the default (``photos.detail`` auto: balanced from 50 photos, blend below), the other two of
``photos.detail`` blend, balanced and sharp, and each ``--override``. Input and results are rendered through the
held-out photos' cameras and scored colour-matched (:func:`scantex.photos.training.score_photos`), with each
render's fine detail (mean |Laplacian of a Gaussian of 1 px| of its grey, the photos' own beside it). Prints a
Markdown table; bench/RESULTS.md "sharp detail" holds the real apartment's (the G2LTex ``apt0`` capture, kept
outside the repository: its mesh fused from the depth maps). ``--repeat N`` gives scantex each given photo N times
over (a stand-in for a video's repeated views: ``photos.keyframes``, "photo memory" in bench/RESULTS.md), the
app-style input still baked from them once; ``--no-variants`` runs the default and the overrides alone.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
from bench._results import parse_override  # noqa: E402


def main() -> None:
    from bench.baselines import app_style_bake
    from scantex.io import load_scan
    from scantex.photos import load_photos
    from scantex.photos.training import VisibilitySettings, prepare_photos, score_photos
    from scantex.pipeline.config import preset
    from scantex.pipeline.enhance import detail_mode, enhance
    from scantex.views.raycast import RayCaster

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("mesh", type=Path)
    parser.add_argument("cameras", type=Path)
    parser.add_argument("--every", type=int, default=10, help="hold out every N-th photo (default 10)")
    parser.add_argument("--first", type=int, default=5, help="... from this one (default 5)")
    parser.add_argument("--app-style", type=int, default=0, metavar="SIZE",
                        help="bake an app-style input of SIZE² from the given photos on MESH's UV layout")
    parser.add_argument("--override", action="append", default=[], metavar="SECTION__NAME=VALUE",
                        help="one more run with this config override (JSON value or a string); repeat for more")
    parser.add_argument("--repeat", type=int, default=1, metavar="N",
                        help="give scantex each given photo N times over (default 1)")
    parser.add_argument("--no-variants", action="store_true",
                        help="run the default and the overrides only, not the other photos.detail modes")
    args = parser.parse_args()

    everything = load_photos(args.cameras)
    held = list(range(args.first, len(everything), args.every))
    given = everything.subset([i for i in range(len(everything)) if i not in held])
    scan = load_scan(args.mesh)
    caster = RayCaster(scan.positions, scan.faces)
    if args.app_style:
        scan = app_style_bake(scan, given, prepare_photos(scan, given, range(len(given)), caster, 640),
                              size=args.app_style)
    auto = detail_mode("auto", len(given))  # the default run's: not run twice
    runs = [{}] + [{"photos__detail": mode} for mode in ("blend", "balanced", "sharp")
                   if mode != auto and not args.no_variants]
    runs += [parse_override(item) for item in args.override]
    if args.repeat > 1:
        given = given.subset(list(range(len(given))) * args.repeat)
    results, seconds = {"input": scan}, {}
    for k, override in enumerate(runs):
        name = ", ".join(f"{key.replace('__', '.')} {value}" for key, value in override.items()) or "default"
        t = time.perf_counter()
        results[name] = enhance(scan, preset("default").override(photos__holdout=0, **override), photos=given).scan
        seconds[name] = time.perf_counter() - t
        print(f"{name}: {seconds[name]:.0f} s", file=sys.stderr, flush=True)
    views = prepare_photos(scan, everything, held, caster, 640, VisibilitySettings(supersample=2))
    scores = score_photos(results, views, caster)
    i = scores["input"]
    times = f" ({len(given) // args.repeat} x {args.repeat})" if args.repeat > 1 else ""
    print(f"{len(given)} photos given{times}, {len(held)} held out; the photos' own detail {i['photo_detail']:.4f}\n")
    print(f"| run | colour-matched PSNR (input -> output) | SSIM | detail (input {i['detail']:.4f}) | enhance s |")
    print("|---|---|---|---|---|")
    for name in results:
        if name == "input":
            continue
        o = scores[name]
        print(f"| {name} | {i['psnr_matched']:.2f} -> **{o['psnr_matched']:.2f}** "
              f"({o['psnr_matched'] - i['psnr_matched']:+.2f}) | {i['ssim_matched']:.3f} -> {o['ssim_matched']:.3f} | "
              f"{o['detail']:.4f} | {seconds[name]:.0f} |")


if __name__ == "__main__":
    main()
