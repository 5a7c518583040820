"""Peak memory of the bake and the seam blending on an 8192² atlas: the bathroom scan.

    /usr/bin/time -v python bench/bench_bake_memory.py     # "Maximum resident set size"

Loads ``../shared/data/bathroom_3dscannerapp`` (132,317 faces, 8192² JPEG atlas), bakes a new 8192²
atlas whose colour is the input texture at each surface point (cheap, so the bake's own memory shows),
then blends its seams, printing time and peak resident memory after each. Run it on two checkouts for
a before/after (the numbers go into bench/RESULTS.md by hand: one process per run, never two at once).
"""

from __future__ import annotations

import resource
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
BATHROOM = ROOT.parent / "shared" / "data" / "bathroom_3dscannerapp" / "textured_output.obj"


def peak_gib() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20


def main() -> None:
    from scantex.atlas.bake import bake
    from scantex.io import load_scan
    from scantex.uv import blend_seams
    from scantex.views.raycast import interpolate
    from scantex.views.render import sample_texture

    if not BATHROOM.exists():
        sys.exit(f"{BATHROOM}: not found (this benchmark needs ../shared/data)")
    scan = load_scan(BATHROOM)
    print(f"loaded: peak {peak_gib():.2f} GiB", flush=True)
    image, tri_uv = scan.materials[0].image, scan.triangle_uvs

    def colour(points, normals, faces, bary):
        return sample_texture(image, interpolate(faces, bary, tri_uv))[:, :3]

    t = time.perf_counter()
    (baked,) = bake(scan, colour, size=8192)
    print(f"bake: {time.perf_counter() - t:.0f} s, peak {peak_gib():.2f} GiB", flush=True)
    t = time.perf_counter()
    blend_seams(scan.replace(materials=(scan.materials[0].with_image(baked),)))
    print(f"blend seams: {time.perf_counter() - t:.0f} s, peak {peak_gib():.2f} GiB", flush=True)


if __name__ == "__main__":
    main()
