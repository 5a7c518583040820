"""Projective texturing's per-texel blend, compiled (numba) against its numpy twin, on the bolster's own bake.

    python bench/bench_blend.py              # the bolster (../shared/data), 3 repeats
    python bench/bench_blend.py --no-write

The bolster's app-style input is enhanced with its 12 training photos (``photos.holdout`` 0) twice, the
compiled blend switched on and off (``scantex.photos.compiled.available``); the first run's bake hands over
its chunks of texel points. Both colour functions then colour the same chunks, one after another on one
thread (as each of the bake's workers does), and the colours are compared. Times are the median of the
repeats, in this process. Skips without ``../shared/data``. Writes the 'blend' section of bench/RESULTS.md.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
from bench._results import update_section  # noqa: E402
from bench.bench_real_photos import CAPTURES, DATA, training_frames  # noqa: E402


def baked_colours(scan, photos, compiles: bool) -> tuple:
    """``(colour, chunks, report)`` of one photo-mode run: the bake's colour function, the chunks of texel
    points it coloured (``(points, normals, face_ids, bary)``), and the run's projective texturing report."""
    import scantex.pipeline.enhance as pipeline
    from scantex.photos import compiled
    from scantex.pipeline.config import preset

    seen: dict = {}
    bake = pipeline.bake

    def capturing(target, colour, **kwargs):
        chunks = []

        def recorded(points, normals, face_ids, bary, **more):
            chunks.append((points, normals, face_ids, bary))
            return colour(points, normals, face_ids, bary, **more)

        seen.update(colour=colour, chunks=chunks)
        return bake(target, recorded, **kwargs)

    available = compiled.available
    pipeline.bake = capturing
    if not compiles:
        compiled.available = lambda: False
    try:
        result = pipeline.enhance(scan, preset("default").override(photos__holdout=0), photos=photos)
    finally:
        pipeline.bake, compiled.available = bake, available
    return seen["colour"], seen["chunks"], result.metrics["photos"]["texturing"]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--no-write", action="store_true", help="print only, leave RESULTS.md alone")
    args = parser.parse_args()
    if not DATA.exists():
        print(f"{DATA} not present: nothing to do")
        return
    import json
    import tempfile

    from scantex.io import load_scan
    from scantex.photos import compiled, load_photos

    if not compiled.available():
        print("numba is not installed: nothing to compare")
        return
    cameras, mesh, held = CAPTURES["bolster"]
    scan = load_scan(DATA / mesh)
    with tempfile.TemporaryDirectory() as tmp:
        (Path(tmp) / "cameras.json").write_text(json.dumps({"frames": training_frames(DATA / cameras, held)}))
        photos = load_photos(Path(tmp) / "cameras.json")
        fast, chunks, report = baked_colours(scan, photos, True)
        slow, _, slow_report = baked_colours(scan, photos, False)
    assert report["compiled"] and not slow_report["compiled"]
    fast(*chunks[0])  # the kernel loaded (from numba's cache, or compiled) before the clock starts
    before = report["clipped"]["samples"]  # the report counts the samples of every call
    times, colours = {}, {}
    for name, colour in (("compiled", fast), ("numpy", slow)):
        runs = []
        for _ in range(args.repeats):
            t = time.perf_counter()
            colours[name] = np.concatenate([colour(*chunk) for chunk in chunks])
            runs.append(time.perf_counter() - t)
        times[name] = statistics.median(runs)
    samples = (report["clipped"]["samples"] - before) // args.repeats
    difference = np.abs(colours["compiled"] - colours["numpy"]).max(axis=1)
    points = len(colours["numpy"])
    lines = ["## Projective texturing's blend: compiled against numpy (`bench/bench_blend.py`)", "",
             f"The bolster's bake ({points:,} texel points in {len(chunks)} chunks, {len(photos)} training photos, "
             f"{samples:,} samples), each colour function on one thread, median of "
             f"{args.repeats}:", "",
             "| blend | seconds | points per second |", "|---|---|---|"]
    for name in ("numpy", "compiled"):
        lines.append(f"| {name} | {times[name]:.2f} | {points / times[name] / 1e6:.2f} M |")
    lines += ["", f"Compiled / numpy: **{times['compiled'] / times['numpy']:.2f}x** the time. The colours: "
                  f"largest difference {difference.max():.4f}, {int((difference > 1 / 255).sum())} points "
                  f"({100 * (difference > 1 / 255).mean():.3f} %) differ by more than one 8-bit level (a point "
                  "whose pixel lies on a rounding boundary, float64 against float32 arithmetic)."]
    print("\n".join(lines))
    if not args.no_write:
        update_section("blend", "\n".join(lines))


if __name__ == "__main__":
    main()
