"""Photo mode on a dense mesh: the bolster's app-style input subdivided, the same photos, time and memory.

    python bench/bench_dense_photos.py                 # subdivided 0 and 3 times (12,712 and 813,568 faces)
    python bench/bench_dense_photos.py --levels 0 1 2 3
    python bench/bench_dense_photos.py --levels 3 --tiles 1 2 4 --score   # whole and tiled, scored

A fused scan of a wall or a room has hundreds of thousands of faces where the bolster has 12,712. Each level
splits every face of ``../shared/data``'s bolster app-style input into four at its edges' midpoints, with the
texture coordinates split alike: the same surface, the same atlas and the same photos, four times the faces.
The scan is written to a temporary folder outside the repository; ``scantex enhance`` then runs on it from
the command line as a user runs it (the training photos only, ``--holdout 0``), a whole process to its outputs
written: wall seconds and peak resident memory from the operating system, the stages' seconds from
``metrics.json``. ``--tiles``: each level also as that many tiles (``--tiles N``; 1: whole); ``--score``: each
output scored through the held-out photos (the protocol's, at their recorded poses, 640 px, colour-matched).
Prints Markdown; the numbers go into bench/RESULTS.md by hand. Skips without ``../shared/data``.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
from bench.bench_real_photos import capture_files, training_frames  # noqa: E402
from bench.bench_texrecon import timed  # noqa: E402


def _midpoints(corners: np.ndarray, values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``values`` with one midpoint appended per distinct edge of ``corners (F, 3)``, and each face's three
    midpoint indices ``(F, 3)`` (edges 01, 12, 20)."""
    edges = np.concatenate([corners[:, [0, 1]], corners[:, [1, 2]], corners[:, [2, 0]]])
    unique, inverse = np.unique(np.sort(edges, axis=1), axis=0, return_inverse=True)
    middle = (values[unique[:, 0]] + values[unique[:, 1]]) / 2
    return np.concatenate([values, middle]), inverse.reshape(3, -1).T + len(values)


def subdivided(scan, levels: int):
    """``scan`` with every face split into four, ``levels`` times (positions and texture coordinates alike)."""
    for _ in range(levels):
        positions, m = _midpoints(scan.faces, scan.positions)
        uvs, mu = _midpoints(scan.face_uvs, scan.uvs)

        def split(c, mid):
            return np.concatenate([np.stack([c[:, 0], mid[:, 0], mid[:, 2]], 1),
                                   np.stack([mid[:, 0], c[:, 1], mid[:, 1]], 1),
                                   np.stack([mid[:, 2], mid[:, 1], c[:, 2]], 1), mid])

        scan = type(scan)(positions, split(scan.faces, m), uvs, split(scan.face_uvs, mu),
                          np.tile(scan.face_materials, 4), scan.materials)
    return scan


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--levels", type=int, nargs="+", default=[0, 3], help="subdivisions (each: 4x the faces)")
    parser.add_argument("--tiles", type=int, nargs="+", default=[1], help="tiles (1: the scan whole)")
    parser.add_argument("--score", action="store_true", help="score each output through the held-out photos")
    args = parser.parse_args()
    files = capture_files("bolster")
    if files is None:
        return
    cameras, mesh, held = files
    from scantex.io import load_scan, save_scan

    train = training_frames(cameras, held)
    base = load_scan(mesh)
    print("| faces | tiles | wall s | peak MiB | held-out PSNR input -> output (SSIM) | stages s (metrics.json) |")
    print("|---|---|---|---|---|---|")
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        (work / "cameras.json").write_text(json.dumps({"frames": train}))
        for level in args.levels:
            scan = subdivided(base, level)
            path = work / f"bolster_{level}" / "scan.obj"
            save_scan(scan, path)
            for tiles in args.tiles:
                out = work / f"out_{level}_{tiles}"
                seconds, peak = timed([sys.executable, "-m", "scantex", "enhance", str(path), "--photos",
                                       str(work / "cameras.json"), "--holdout", "0", "--tiles", str(tiles),
                                       "-o", str(out), "--quiet"])
                stages = json.loads((out / "metrics.json").read_text())["timings_s"]
                shown = ", ".join(f"{k} {v:.1f}" for k, v in stages.items() if v >= 0.05)
                score = held_out_score(scan, out / "enhanced.obj", cameras, held) if args.score else "-"
                print(f"| {scan.n_faces:,} | {tiles} | {seconds:.1f} | {peak:.0f} | {score} | {shown} |", flush=True)


def held_out_score(scan, enhanced: Path, cameras: Path, held) -> str:
    """The input ``scan`` and the output at ``enhanced`` through the held-out photos ``held`` of ``cameras``,
    colour-matched: ``"input -> output dB (SSIM a -> b)"``."""
    from scantex.io import load_scan
    from scantex.photos import load_photos
    from scantex.photos.training import VisibilitySettings, prepare_photos, score_photos
    from scantex.views.raycast import RayCaster

    caster = RayCaster(scan.positions, scan.faces)
    views = prepare_photos(scan, load_photos(cameras), held, caster, 640, VisibilitySettings(supersample=2))
    s = score_photos({"input": scan, "output": load_scan(enhanced)}, views, caster)
    return (f"{s['input']['psnr_matched']:.2f} -> {s['output']['psnr_matched']:.2f} "
            f"({s['input']['ssim_matched']:.3f} -> {s['output']['ssim_matched']:.3f})")


if __name__ == "__main__":
    main()
