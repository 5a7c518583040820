"""Photo mode's peak memory and time with many large photos: 100 photos of 12 megapixels.

    python bench/bench_photo_memory.py                  # 100 photos of 4032x3024 (504x378 x 8)
    python bench/bench_photo_memory.py --photos 24 --base-width 1008 --scale 2
    python bench/bench_photo_memory.py --photos 300 --base-width 480 --scale 4 --texture-size 8192 \
        --override photos__sample_memory_mb=0     # phone frames on a fine atlas, the samples unbounded

The demo wall (``make_wall(seed=0)``) is photographed by ``scantex.synth.photos.capture_photos`` at
``--base-width`` (4:3; pose errors, exposure, blur, noise as in ``bench/bench_photos.py``), and every photo is
written again ``--scale`` times larger (bicubic, JPEG quality 90) with its intrinsics scaled to match: the
pixel counts of a phone's 12 MP photos, with the detail of far smaller ones (the bench measures memory and
time, not what the extra pixels show; rendering the photos at full size would take most of an hour).
Then ``scantex enhance scan.obj --photos cameras.json`` runs as a user would run it, in its own process:
its wall time and peak resident memory, and from its ``metrics.json`` the size the photos were sampled at
and the memory their samples held. Prints one Markdown row; the numbers go into bench/RESULTS.md by hand.
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def take_large_photos(folder: Path, n_photos: int, width: int, scale: int) -> Path:
    """``folder/large/cameras.json`` of ``n_photos`` photos of the demo wall, ``width`` x 3/4 ``width`` times
    ``scale``."""
    from PIL import Image

    from scantex.photos.cameras_json import write_cameras_json
    from scantex.photos.photoset import PhotoSet
    from scantex.synth import make_wall
    from scantex.synth.photos import PhotoCapture, capture_photos

    small = capture_photos(make_wall(seed=0), folder / "small", PhotoCapture(n_photos=n_photos, width=width,
                                                                            height=width * 3 // 4), seed=0)
    large = folder / "large"
    large.mkdir()
    paths = []
    for i, cam in enumerate(small.cameras):
        with Image.open(small.images[i]) as im:
            big = im.resize((cam.width * scale, cam.height * scale), Image.Resampling.BICUBIC)
        paths.append(large / f"{i:03d}.jpg")
        big.save(paths[-1], quality=90)
    photos = PhotoSet(cameras=tuple(c.scaled(scale) for c in small.cameras), images=tuple(paths), source=large,
                      format="synthetic")
    return write_cameras_json(photos, large, copy_images=False)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--photos", type=int, default=100, help="photos to take (default: 100)")
    parser.add_argument("--base-width", type=int, default=504, help="the photos are rendered this wide (default: 504)")
    parser.add_argument("--scale", type=int, default=8, help="and written this many times larger (default: 8)")
    parser.add_argument("--texture-size", type=int, default=0,
                        help="the output atlas's size (default: the run's own, 2048 on the demo wall): a finer atlas "
                             "wants the photos sampled finer")
    parser.add_argument("--override", action="append", default=[], metavar="SECTION__NAME=VALUE",
                        help="a config setting for the run, e.g. photos__sample_memory_mb=0 (repeatable)")
    args = parser.parse_args()
    from scantex.synth import make_wall

    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        t = time.perf_counter()
        cameras = take_large_photos(folder, args.photos, args.base_width, args.scale)
        print(f"{args.photos} photos taken in {time.perf_counter() - t:.0f} s", flush=True)
        demo = make_wall(seed=0)
        from scantex.io import save_scan

        save_scan(demo.scan, folder / "scan" / "scan.obj")
        out = folder / "out"
        command = [sys.executable, "-m", "scantex", "enhance", str(folder / "scan" / "scan.obj"), "--photos",
                   str(cameras), "-o", str(out)]
        if args.texture_size:
            command += ["--texture-size", str(args.texture_size)]
        if args.override:
            from bench._results import parse_override
            from scantex.pipeline.config import preset, save_config

            overrides = {k: v for item in args.override for k, v in parse_override(item).items()}
            save_config(preset("default").override(**overrides), folder / "config.json")
            command += ["--config", str(folder / "config.json")]
        t = time.perf_counter()
        subprocess.run(command, check=True, cwd=ROOT)
        seconds = time.perf_counter() - t
        peak = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 2**20
        m = json.loads((out / "metrics.json").read_text())
        texturing = m["photos"]["texturing"]
        held = m.get("held_out_photos", {})
        sampled = sorted(tuple(s) for s in texturing.get("sampled_at", []))
        print(f"| {args.photos} photos of {args.base_width * args.scale}x{args.base_width * 3 // 4 * args.scale} | "
              f"sampled at {'x'.join(map(str, sampled[0]))} to {'x'.join(map(str, sampled[-1]))} | "
              f"{texturing.get('photo_memory_mb')} MB of samples | {seconds:.0f} s | {peak:.2f} GiB | "
              f"held-out photos {held.get('input', {}).get('psnr_matched', float('nan')):.2f} -> "
              f"{held.get('enhanced', {}).get('psnr_matched', float('nan')):.2f} dB |")


if __name__ == "__main__":
    main()
