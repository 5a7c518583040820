"""Photo mode at room scale: a synthetic room captured from inside with a hundred photos, by the held-out
protocol of the real captures.

    python bench/bench_room_photos.py                   # 110 photos, 11 held out; ~10 min on 2 cores
    python bench/bench_room_photos.py --photos 40 --override photos__consistency=0.1 --no-write

The room (``scantex.synth.make_room``: 4 x 3 x 2.5 m, furniture boxes, about 4,600 faces) is photographed
from inside (``scantex.synth.photos``: 640x480, each photo's own exposure and white balance, blur, noise,
JPEG, recorded poses off by 0.2 degrees and 6 mm per axis), as the apartment capture that the project is
scored on was (110 photos given, 640x480). The app-style input is what a capture app exports:
:func:`bench.baselines.app_style_bake`, a best-view blend of the training photos as they are, on the scan's
UV layout at 2048². Then, as in ``bench/bench_real_photos.py`` (its worker): ``scantex enhance`` gets only
the training photos; the input and the result are rendered through the held-out photos' recorded cameras
and scored against the held-out photos, colour-matched. The capture is kept in ``/tmp/scantex_room_capture``
(taking it costs minutes) and made again when the photo count changes.
Writes the 'room photos' section of bench/RESULTS.md.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
from bench._results import parse_override, run_worker, update_section  # noqa: E402
from bench.bench_real_photos import WORKER  # noqa: E402

CAPTURE = Path("/tmp/scantex_room_capture")
OUT = Path("/tmp/scantex_room_photos")


def held_out(n: int) -> list[int]:
    """Every tenth photo, from the fifth: 10 % held out, spread over the capture."""
    return list(range(5, n, 10))


def take_capture(n_photos: int) -> tuple[Path, Path]:
    """``(cameras.json, app-style OBJ)`` of the synthetic room, made once per photo count."""
    folder = CAPTURE / f"{n_photos}"
    cameras, app = folder / "photos" / "cameras.json", folder / "app" / "room_app.obj"
    if cameras.exists() and app.exists():
        return cameras, app
    from bench.baselines import app_style_bake
    from scantex.io import save_scan
    from scantex.photos import load_photos
    from scantex.photos.training import prepare_photos
    from scantex.synth import make_room
    from scantex.synth.photos import PhotoCapture, capture_photos
    from scantex.views.raycast import RayCaster

    demo = make_room(seed=0)
    print(f"photographing the room ({n_photos} photos) ...", flush=True)
    capture_photos(demo, folder / "photos", PhotoCapture(n_photos=n_photos, distance=None), seed=0)
    photos = load_photos(cameras)
    train = [i for i in range(len(photos)) if i not in held_out(len(photos))]
    scan = demo.scan
    views = prepare_photos(scan, photos, train, RayCaster(scan.positions, scan.faces), 640)
    print("baking the app-style input ...", flush=True)
    save_scan(app_style_bake(scan, photos, views, size=2048), app)
    return cameras, app


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--photos", type=int, default=110, help="photos taken (10 %% held out)")
    parser.add_argument("--preset", default="default")
    parser.add_argument("--override", action="append", default=[], metavar="SECTION__NAME=VALUE",
                        help="a config override for the scantex run (JSON value or a string); repeat for more runs")
    parser.add_argument("--no-write", action="store_true", help="print only, leave RESULTS.md alone")
    args = parser.parse_args()
    cameras, app = take_capture(args.photos)
    n = len(json.loads(cameras.read_text())["frames"])
    held = held_out(n)
    runs = [{}]
    runs += [parse_override(item) for item in args.override]
    lines = ["## Photo mode at room scale (synthetic room, held-out protocol)", "",
             "| run | held-out colour-matched PSNR (input -> output) | SSIM | pose-aligned PSNR | time s | "
             "peak GiB |", "|---|---|---|---|---|---|"]
    for k, override in enumerate(runs):
        spec = {"name": "room", "cameras": str(cameras), "mesh": str(app), "held": held, "method": "scantex",
                "preset": args.preset, "override": override, "png": str(OUT), "tag": f"_{k}" if k else ""}
        r = run_worker(WORKER, spec)
        i, o = r["scores"]["input"], r["scores"]["output"]
        label = f"`{args.preset}`" + (f" {override}" if override else "")
        lines.append(f"| {label} | {i['psnr_matched']:.2f} -> **{o['psnr_matched']:.2f}** "
                     f"({o['psnr_matched'] - i['psnr_matched']:+.2f}) | {i['ssim_matched']:.3f} -> "
                     f"{o['ssim_matched']:.3f} | {i['psnr_aligned']:.2f} -> {o['psnr_aligned']:.2f} | "
                     f"{r['seconds']:.0f} | {r['peak_mb'] / 1024:.2f} |")
        print(lines[-1], json.dumps(r.get("timings")), flush=True)
    lines += ["", f"{n} photos of 640x480 taken from inside the room, {len(held)} held out ({held}); scantex gets "
              f"the other {n - len(held)} (`photos.holdout` 0) and the app-style input (a best-view blend of the "
              "same photos as they are, 2048²). Scored at the held-out photos' recorded poses, colour-matched (a "
              f"gain and offset per channel and photo). Images (photo | input | result) in {OUT}/. Time: the enhance call; "
              "peak memory: its process, the scoring included. Command: `python bench/bench_room_photos.py`"]
    if not args.no_write:
        update_section("room photos", "\n".join(lines))


if __name__ == "__main__":
    main()
