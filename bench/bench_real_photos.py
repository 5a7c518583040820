"""Photo mode on the real captures in ../shared/data, by their held-out protocol (skips without them).

    python bench/bench_real_photos.py                 # bolster and façade, default settings
    python bench/bench_real_photos.py --only bolster --override photos__texturing=field

For each capture (``../shared/data/README.md``): ``--photos`` gets ONLY the training photos (a filtered
``cameras.json`` written to a temporary folder outside the repository, ``photos.holdout`` 0); the
app-style input is enhanced; then the input, the result and the classical baseline
(:func:`bench.baselines.best_view_projective` on the same training photos) are rendered through the
held-out photos' cameras and scored on the pixels that pass the visibility test, raw and colour-matched
(a per-photo gain and offset per channel). Each run is its own process (time and peak memory its own).
Every method is also scored after aligning the held-out photo's pose to its own texture (the
``psnr_aligned`` of :func:`scantex.photos.training.score_photos`): the held-out poses are a few pixels
off, which penalises sharp texels more than blurred ones. Comparison images (photo | input | result)
go to ``/tmp/scantex_real_photos/``.
Writes the 'real photos' section of bench/RESULTS.md.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
from bench._results import parse_override, run_worker, update_section  # noqa: E402

DATA = ROOT.parent / "shared" / "data"
CAPTURES = {
    "bolster": ("bolster_rgbd_posed/cameras.json", "bolster_rgbd_posed/app_style_input/bolster_app_style.obj", [4, 11]),
    "facade": ("facade_openmvs/cameras.json", "facade_openmvs/app_style_input/scene_mesh_baked.obj", [2, 7]),
    # the Kinect capture as it was fused, untextured: textured from the photos alone (texrecon's case)
    "bolster_bare": ("bolster_rgbd_posed/cameras.json", "bolster_rgbd_posed/bloster.ply", [4, 11]),
}
UNTEXTURED = {"bolster_bare"}


def capture_files(name: str) -> tuple[Path, Path, list[int]] | None:
    """``(cameras.json, mesh, held-out photos)`` of ``CAPTURES[name]`` in ``../shared/data``, or ``None`` (and a
    line saying so) where the data is absent."""
    cams, mesh, held = CAPTURES[name]
    if not (DATA / cams).exists():
        print(f"skipped: {DATA / cams} not found")
        return None
    return DATA / cams, DATA / mesh, held


def training_frames(cameras: Path, held) -> list[dict]:
    """The frames of ``cameras`` (a ``cameras.json``) but those at ``held``, their image and depth paths made
    absolute: a ``cameras.json`` of the training photos alone, to write anywhere."""
    frames = json.loads(cameras.read_text())["frames"]
    train = [dict(f) for i, f in enumerate(frames) if i not in held]
    for f in train:
        for key in ("image", "depth"):
            if f.get(key):
                f[key] = str((cameras.parent / f[key]).resolve())
    return train
OUT = Path("/tmp/scantex_real_photos")

WORKER = r"""
import json, resource, sys, tempfile, time
from pathlib import Path
import numpy as np
from PIL import Image
sys.path.insert(0, ".")
from scantex.io import load_scan
from scantex.photos import load_photos
from scantex.photos.training import VisibilitySettings, prepare_photos, score_photos
from scantex.pipeline.config import preset
from scantex.pipeline.enhance import enhance
from scantex.views.raycast import RayCaster
from scantex.views.render import to_uint8
spec = json.loads(sys.argv[1])
cameras = Path(spec["cameras"])
frames = json.loads(cameras.read_text())["frames"]
held = spec["held"]
train = [i for i in range(len(frames)) if i not in held]
scan = load_scan(spec["mesh"])
everything = load_photos(cameras)
with tempfile.TemporaryDirectory() as tmp:
    subset = []
    for i in train:
        f = dict(frames[i])
        for key in ("image", "depth"):
            if f.get(key):
                f[key] = str((cameras.parent / f[key]).resolve())
        subset.append(f)
    (Path(tmp) / "cameras.json").write_text(json.dumps({"frames": subset}))
    given = load_photos(Path(tmp) / "cameras.json")
    t = time.perf_counter()
    if spec["method"] == "scantex":
        cfg = preset(spec["preset"]).override(**{"photos__holdout": 0, **spec.get("override", {})})
        result = enhance(scan, cfg, photos=given)
        out, extra = result.scan, {"timings": result.metrics["timings_s"],
                                   "alignment": result.metrics["photos"]["alignment"]}
    else:
        from bench.baselines import best_view_projective
        caster = RayCaster(scan.positions, scan.faces)
        views = prepare_photos(scan, given, range(len(given)), caster, 640, VisibilitySettings(supersample=2))
        out, extra = best_view_projective(scan, given, views), {}
    seconds = time.perf_counter() - t
caster = RayCaster(scan.positions, scan.faces)
held_views = prepare_photos(scan, everything, held, caster, 640, VisibilitySettings(supersample=2))
sheets = {}
scores = score_photos({"input": scan, "output": out}, held_views, caster, images=sheets, align=True)
folder = Path(spec["png"]); folder.mkdir(parents=True, exist_ok=True)
for i, im in sheets.items():
    Image.fromarray(to_uint8(im)).save(folder / f"{spec['name']}_{spec['method']}{spec.get('tag', '')}_held_out_{i:02d}.png")
print(json.dumps({"seconds": seconds, "peak_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
                  "scores": scores, **extra}))
"""


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--only", choices=sorted(CAPTURES), action="append")
    parser.add_argument("--preset", default="default")
    parser.add_argument("--override", action="append", default=[], metavar="SECTION__NAME=VALUE",
                        help="a config override for the scantex runs (JSON value or a string)")
    parser.add_argument("--no-write", action="store_true", help="print only, leave RESULTS.md alone")
    parser.add_argument("--no-variants", action="store_true", help="the preset and the baseline only")
    parser.add_argument("--final", action="store_true",
                        help="only the held-out share: 10 %% of the given photos held out for the run's own score, "
                             "the texture written from the training photos or from all (photos.final); own section")
    args = parser.parse_args()
    if not DATA.exists():
        print(f"{DATA} not present: nothing to do")
        return
    override = {k: v for item in args.override for k, v in parse_override(item).items()}
    lines = ["## Photo mode on real captures (held-out protocol of ../shared/data)", "",
             "| capture | method | held-out PSNR dB (input -> output) | colour-matched PSNR | colour-matched SSIM | "
             "pose-aligned PSNR (SSIM) | time s | peak GiB |", "|---|---|---|---|---|---|---|---|"]
    runs = [("scantex", override, f"scantex `{args.preset}`" + (f" {override}" if override else ""))]
    if args.final:
        runs = [("scantex", {"photos__holdout": 0.1, "photos__final": final},
                 f"scantex `{args.preset}`, 10 % of the given photos held out, texture from {what} (`photos.final` {final})")
                for final, what in (("training", "the others"), ("all", "all of them once scored"))]
    elif not override and not args.no_variants:
        runs += [("scantex", {"photos__refine_poses": "off"}, "scantex, poses as recorded (`photos.refine_poses` off)"),
                 ("scantex", {"photos__refine_poses": "consensus", "photos__refine_iterations": 2},
                  "scantex, poses refined to the other photos' consensus, 2 rounds (`photos.refine_poses` consensus)"),
                 ("scantex", {"photos__temperature": 0.15}, "scantex, best view dominates (`photos.temperature` 0.15)"),
                 ("scantex", {"photos__texturing": "field"}, "scantex, the field's colour (`photos.texturing` field)")]
    if not args.final:
        runs.append(("baseline", {}, "best-view baseline"))
    for name in args.only or sorted(CAPTURES):
        cams, mesh, held = CAPTURES[name]
        for k, (method, changes, label) in enumerate(runs):
            if method == "baseline" and name in UNTEXTURED:
                continue  # it levels each photo to the input texture, which an untextured mesh has not
            spec = {"name": name, "cameras": str(DATA / cams), "mesh": str(DATA / mesh), "held": held,
                    "method": method, "preset": args.preset, "override": changes, "png": str(OUT),
                    "tag": f"_{k}" if k else ""}
            r = run_worker(WORKER, spec)
            i, o = r["scores"]["input"], r["scores"]["output"]
            lines.append(f"| {name} | {label} | {i['psnr']:.2f} -> {o['psnr']:.2f} | "
                         f"{i['psnr_matched']:.2f} -> **{o['psnr_matched']:.2f}** "
                         f"({o['psnr_matched'] - i['psnr_matched']:+.2f}) | {i['ssim_matched']:.3f} -> "
                         f"{o['ssim_matched']:.3f} | {i['psnr_aligned']:.2f} -> {o['psnr_aligned']:.2f} "
                         f"({i['ssim_aligned']:.3f} -> {o['ssim_aligned']:.3f}) | {r['seconds']:.0f} | "
                         f"{r['peak_mb'] / 1024:.2f} |")
            print(lines[-1], json.dumps({k: v for k, v in r.items() if k not in ("scores",)}), flush=True)
    lines += ["", f"Held-out photos: bolster {CAPTURES['bolster'][2]} (`bolster_bare`: its untextured Kinect mesh, "
              f"whose input scores a flat grey), façade {CAPTURES['facade'][2]}, scored at "
              "640 px. Colour-matched: a gain and offset per channel and photo. Pose-aligned: the same after the "
              "held-out photo's pose is aligned (rotation, translation, focal) to each texture on its own, as "
              "pose-refining NeRFs are evaluated. Comparison images (photo | input | result) in "
              f"{OUT}/. Command: `python bench/bench_real_photos.py{' --final' if args.final else ''}`"]
    if args.final:
        lines[0] = "## Photo mode on real captures: the held-out share and the texture written (`photos.final`)"
        lines[-1] += (" The given photos are the training photos of the protocol; the run holds 10 % of them out "
                      "for its own score (as a user's run does) and the table scores the written texture on the "
                      "protocol's held-out photos, which neither texture saw.")
    if not args.no_write:
        update_section("real photos final" if args.final else "real photos", "\n".join(lines))


if __name__ == "__main__":
    main()
