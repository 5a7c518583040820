"""G-buffer ray casting throughput on a paper-scale (79k-face) wall, against trimesh's ray API.

    python bench/bench_gbuffer.py          # updates the 'gbuffer' section of bench/RESULTS.md

Ratios are measured in the same run (this machine is noisy); the target is >= 5 M rays/s.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from bench._results import median_time, update_section  # noqa: E402
from scantex.views.camera import Camera  # noqa: E402
from scantex.views.raycast import RayCaster, cast_gbuffer  # noqa: E402


def wall(n: int = 200, size: float = 4.0, seed: int = 0):
    rng = np.random.default_rng(seed)
    u, v = np.meshgrid(np.linspace(0, 1, n), np.linspace(0, 1, n))
    positions = np.stack([u.ravel() * size, rng.normal(0, 0.002, n * n), v.ravel() * size * 0.75], axis=1)
    idx = np.arange(n * n).reshape(n, n)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, 1:].ravel(), idx[1:, :-1].ravel()
    return positions, np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])


def main() -> None:
    import trimesh

    positions, faces = wall()
    mesh = trimesh.Trimesh(positions, faces, process=False)
    normals = mesh.face_normals
    side = 1024
    cam = Camera.look_at([2.0, -2.5, 1.5], [2.0, 0.0, 1.5], width=side, height=side, fov_deg=80)
    origins, directions = cam.pixel_rays()
    n_rays = side * side

    caster = RayCaster(positions, faces)
    build = median_time(lambda: RayCaster(positions, faces), 3)
    t_gbuf = median_time(lambda: cast_gbuffer(caster, cam, normals))
    t_hits2 = median_time(lambda: caster.intersect(origins, directions))
    caster.threads = 1
    t_hits1 = median_time(lambda: caster.intersect(origins, directions))
    hit_fraction = float((cast_gbuffer(caster, cam, normals).face_id >= 0).mean())
    tm = trimesh.ray.ray_pyembree.RayMeshIntersector(mesh)
    all_origins = np.broadcast_to(origins, directions.shape)
    t_tm = median_time(lambda: tm.intersects_first(all_origins, directions), 3)

    rows = [
        ("scantex `cast_gbuffer` (face id, barycentrics, depth, normal), 2 threads", t_gbuf),
        ("scantex `RayCaster.intersect` (face id, barycentrics, t), 2 threads", t_hits2),
        ("scantex `RayCaster.intersect`, 1 thread", t_hits1),
        ("baseline: trimesh `intersects_first` (face id only)", t_tm),
    ]
    lines = [f"## G-buffer ray casting: {len(faces):,}-face wall, {side}x{side} = {n_rays:,} rays "
             f"({hit_fraction:.0%} hit), median of 5",
             "", "| path | time (s) | M rays/s | vs trimesh |", "|---|---|---|---|"]
    for name, t in rows:
        lines.append(f"| {name} | {t:.3f} | {n_rays / t / 1e6:.2f} | {t_tm / t:.2f}x |")
    lines += ["", f"BVH build: {build * 1000:.0f} ms. Target: >= 5 M rays/s for the G-buffer "
                  f"({'met' if n_rays / t_gbuf >= 5e6 else 'MISSED'}).",
              "", "Command: `python bench/bench_gbuffer.py`"]
    text = "\n".join(lines)
    print(text)
    update_section("gbuffer", text)


if __name__ == "__main__":
    main()
