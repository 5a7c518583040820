"""Seconds outside the stages: imports, reading an 8192² JPEG atlas, PNG encoding, writing OBJ and GLB.

    python bench/bench_io.py [--no-write]

Uses the bathroom scan (``../shared/data/bathroom_3dscannerapp``: 132,317 faces, 8192² JPEG atlas) when
it is there, else a synthetic wall with an 8192² atlas. "Before" rows re-create what the outputs did
before each atlas was encoded once: the OBJ's PNG at zlib level 1, then trimesh encoding the GLB's at
zlib's default level 6. Writes the 'io' section of bench/RESULTS.md (``--no-write``: prints it only).
"""

from __future__ import annotations

import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
from bench._results import update_section  # noqa: E402

BATHROOM = ROOT.parent / "shared" / "data" / "bathroom_3dscannerapp" / "textured_output.obj"


def timed(fn, repeats: int = 1) -> tuple[float, object]:
    times, out = [], None
    for _ in range(repeats):
        t = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t)
    return float(np.median(times)), out


def import_seconds(module: str, repeats: int = 3) -> float:
    code = f"import time; t = time.perf_counter(); import {module}; print(time.perf_counter() - t)"
    runs = [float(subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True,
                                 cwd=ROOT).stdout) for _ in range(repeats)]
    return float(np.median(runs))


def main() -> None:
    import io as _io

    from PIL import Image

    import scantex.io.trimesh_formats as tf
    from scantex.io import load_scan, save_scan
    from scantex.io.images import TextureEncoder

    rows = []
    for module in ("scantex", "scantex.cli", "scantex.pipeline.enhance", "torch"):
        rows.append((f"`import {module}` (fresh process, median of 3)", import_seconds(module)))
        print(rows[-1], flush=True)

    if BATHROOM.exists():
        s, scan = timed(lambda: load_scan(BATHROOM))
        rows.append((f"load the bathroom scan ({scan.n_faces:,} faces, OBJ + 8192² JPEG)", s))
        jpeg = BATHROOM.with_suffix(".jpg")
        Image.MAX_IMAGE_PIXELS = None
        s, _ = timed(lambda: np.asarray(Image.open(jpeg).convert("RGB")))
        rows.append(("of which: decode the 8192² JPEG", s))
        source = "bathroom scan"
    else:
        from scantex.synth import make_wall

        demo = make_wall(gt_texture_size=8192, scan_texture_size=8192)
        scan = demo.scan
        source = "synthetic wall (no ../shared/data)"
    for row in rows[-2:]:
        print(row, flush=True)
    image = scan.materials[0].image
    for level in (1, 6):
        def encode(level=level):
            buffer = _io.BytesIO()
            Image.fromarray(image).save(buffer, format="PNG", compress_level=level)
            return buffer.getbuffer().nbytes
        s, size = timed(encode)
        rows.append((f"encode the {image.shape[1]}x{image.shape[0]} atlas as PNG, zlib level {level} "
                     f"({size / 2**20:.0f} MiB)", s))
        print(rows[-1], flush=True)

    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp)
        plain = tf._embedded

        def before():
            encoder = TextureEncoder()
            save_scan(scan, out / "a.obj", encoder=encoder)
            tf._embedded = lambda image, data: Image.fromarray(image)  # trimesh encodes at level 6
            try:
                save_scan(scan, out / "a.glb", encoder=encoder)
            finally:
                tf._embedded = plain

        def after():
            encoder = TextureEncoder()
            save_scan(scan, out / "b.obj", encoder=encoder)
            save_scan(scan, out / "b.glb", encoder=encoder)

        s_before, _ = timed(before)
        s_after, _ = timed(after)
        rows.append(("write OBJ (+PNG) and GLB, before: two encodings, the GLB's at level 6", s_before))
        rows.append(("write OBJ (+PNG) and GLB, now: one encoding at level 1, shared", s_after))
        encoded = TextureEncoder()
        encoded.colour(image)
        s_obj, _ = timed(lambda: save_scan(scan, out / "c.obj", encoder=encoded))
        rows.append(("of which: the OBJ + MTL text alone (PNG already encoded)", s_obj))
        for row in rows[-3:]:
            print(row, flush=True)
        from scantex.deps import has_module

        if has_module("pxr"):  # the usd extra: a USD input's outputs include a USDZ
            s_usdz, _ = timed(lambda: save_scan(scan, out / "c.usdz", encoder=encoded))
            rows.append(("write the USDZ (PNG already encoded)", s_usdz))
            s_read, _ = timed(lambda: load_scan(out / "c.usdz"))
            rows.append(("load that USDZ (its PNG decoded)", s_read))
            for row in rows[-2:]:
                print(row, flush=True)

    lines = [f"## Start-up and I/O outside the stages ({source})", "", "| step | seconds |", "|---|---|"]
    lines += [f"| {name} | {s:.2f} |" for name, s in rows]
    lines += ["", "Command: `python bench/bench_io.py` (one run each unless stated; the machine was shared, so "
              "times are noisy: compare rows of one run)."]
    if "--no-write" in sys.argv:
        print("\n".join(lines))
    else:
        update_section("io", "\n".join(lines))


if __name__ == "__main__":
    main()
