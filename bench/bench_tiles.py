"""Tiled enhancement of the demo wall: 4 tiles against the untiled run, scored on the same held-out views.

    python bench/bench_tiles.py            # the demo wall (80k faces), `fast` preset; writes 'tiles' in RESULTS.md
    python bench/bench_tiles.py --quick    # a toy wall, prints only

Runs, same preset and seed:
- untiled: ``enhance`` on the whole wall;
- 4 tiles (2 x 2, 15 % overlap), each enhanced in its own process on a 2-worker local pool, fused with smooth
  weights, with and without levelling the tiles' colours (the same tile outputs fused twice).

Scores: unlit renders at the held-out cameras of the untiled run against the ground truth (PSNR / SSIM).
Tile borders: a frontal render of the whole wall is compared with the ground truth's; the *step* across a line is
the difference of the mean error (result - truth, mean RGB, 0-255) in bands of 3 cm on either side, per 25 cm
of line, averaged along it. It is measured on the tile borders (the middle of each overlap and both overlap edges)
and, as a control, on parallel lines away from every border; for the tiled and the untiled result alike.
Writes ``bench/out/tiles_*.png``: the frontal renders (tiled, untiled, truth) and the tiled - untiled
difference, amplified 8x, with the tile borders drawn.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
from bench._results import update_section  # noqa: E402

OUT = Path(__file__).with_name("out")


def frontal(scan, width: int):
    """A camera square in front of the wall's face (the wall lies in x-z, facing -y) that sees all of it."""
    from scantex.views.camera import Camera

    lo, hi = scan.bounds
    centre = (lo + hi) / 2
    w, h = hi[0] - lo[0], hi[2] - lo[2]
    fov = 40.0
    dist = 0.53 * w / np.tan(np.radians(fov / 2))
    height = int(round(width * h / w * 1.02))
    return Camera.look_at(centre + np.array([0.0, -dist, 0.0]), centre, up=(0, 0, 1), fov_deg=fov,
                          width=width, height=height)


def border_steps(plan, cam, caster, triangles, pairs: dict, band_m=0.03, segment_m=0.25):
    """Steps across tile borders and across control lines (see the module docstring) of the difference
    ``a - b`` of each named pair of images ``(a, b)``."""
    from scantex.views.raycast import cast_gbuffer, interpolate

    g = cast_gbuffer(caster, cam, np.zeros((len(triangles), 3)))
    hit = g.face_id >= 0
    pts = interpolate(g.face_id[hit], g.bary[hit], triangles)
    st = plan.coords(pts)
    lines = []  # (axis, value, lo, hi of the other coordinate, kind)
    m0, m1 = plan.margins
    (nx, ny) = plan.grid
    cells = plan.cells
    s_bounds = sorted({c for c in cells[:, 1] if np.isfinite(c)})
    for s in s_bounds:
        for off, kind in ((0.0, "border (overlap middle)"), (-m0, "border (overlap edge)"), (m0, "border (overlap edge)")):
            lines.append((0, s + off, -np.inf, np.inf, kind))
    for c in cells:
        if np.isfinite(c[3]):
            for off, kind in ((0.0, "border (overlap middle)"), (-m1, "border (overlap edge)"), (m1, "border (overlap edge)")):
                lines.append((1, c[3] + off, c[0], c[1], kind))
    # control lines: parallel to the borders, at least 2 overlaps away from all of them
    lo, hi = st.min(axis=0), st.max(axis=0)
    for axis, margin in ((0, m0), (1, m1)):
        borders = np.array([v for a, v, *_ in lines if a == axis] or [np.inf])
        for v in np.linspace(lo[axis], hi[axis], 41)[2:-2]:
            if np.abs(borders - v).min() > 2 * margin:
                lines.append((axis, v, -np.inf, np.inf, "control"))
    errors = {name: (a[hit] - b[hit]).mean(axis=1) * 255 for name, (a, b) in pairs.items()}
    out = {name: {} for name in pairs}
    for axis, v, a, b, kind in lines:
        other = st[:, 1 - axis]
        along = (other >= a) & (other < b)
        left = along & (st[:, axis] >= v - band_m) & (st[:, axis] < v)
        right = along & (st[:, axis] >= v) & (st[:, axis] < v + band_m)
        seg = np.floor(other / segment_m)
        for name, e in errors.items():
            steps = []
            for k in np.unique(seg[left | right]):
                l_, r_ = left & (seg == k), right & (seg == k)
                if l_.sum() > 20 and r_.sum() > 20:
                    steps.append(abs(e[l_].mean() - e[r_].mean()))
            if steps:
                out[name].setdefault(kind, []).append(float(np.mean(steps)))
    return {name: {k: (float(np.mean(v)), float(np.max(v)), len(v)) for k, v in d.items()} for name, d in out.items()}


def save_pngs(cam, caster, triangles, plan, images: dict, truth_img, tag: str):
    from PIL import Image

    from scantex.views.raycast import cast_gbuffer, interpolate
    from scantex.views.render import to_uint8

    OUT.mkdir(exist_ok=True)
    for name, img in {**images, "truth": truth_img}.items():
        Image.fromarray(to_uint8(img)).save(OUT / f"tiles_{tag}_{name}.png")
    diff = np.clip(0.5 + 8 * (images["tiled"] - images["untiled"]).mean(axis=2, keepdims=True), 0, 1)
    diff = np.repeat(diff, 3, axis=2)
    # draw the middles of the overlaps (where the home tile changes) in red
    g = cast_gbuffer(caster, cam, np.zeros((len(triangles), 3)))
    hit = g.face_id >= 0
    home = np.full(g.face_id.shape, -1)
    st = plan.coords(interpolate(g.face_id[hit], g.bary[hit], triangles))
    cell = np.zeros(len(st), int)
    for k, (s0, s1, t0, t1) in enumerate(plan.cells):
        cell[(st[:, 0] >= s0) & (st[:, 0] < s1) & (st[:, 1] >= t0) & (st[:, 1] < t1)] = k
    home[hit] = cell
    edge = np.zeros_like(hit)
    edge[:, 1:] |= (home[:, 1:] != home[:, :-1]) & hit[:, 1:] & hit[:, :-1]
    edge[1:, :] |= (home[1:, :] != home[:-1, :]) & hit[1:, :] & hit[:-1, :]
    marked = diff.copy()
    marked[edge] = (1.0, 0.0, 0.0)
    Image.fromarray(to_uint8(marked)).save(OUT / f"tiles_{tag}_difference_x8.png")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--quick", action="store_true", help="a toy wall; print only")
    parser.add_argument("--tiles", type=int, default=4)
    parser.add_argument("--workers", type=int, default=2)
    args = parser.parse_args()

    from scantex.atlas.holes import untextured_faces
    from scantex.metrics.views import score_views
    from scantex.pipeline.config import preset
    from scantex.pipeline.enhance import enhance
    from scantex.scale.executors import LocalPool
    from scantex.scale.tiles import TilingConfig, assemble_tiles, plan_tiles, run_tiles, tile_scan
    from scantex.synth import make_wall
    from scantex.views.raycast import RayCaster
    from scantex.views.render import render

    if args.quick:
        from scantex.synth.degrade import Degradation

        demo = make_wall(grid=(40, 30), gt_texture_size=512, scan_texture_size=128, seed=0,
                         degradation=Degradation(hole_share=0.02))
        cfg = preset("fast").override(views__n_views=8, views__width=128, views__height=96, train__steps=150,
                                      refine__enabled=False)
    else:
        demo = make_wall(seed=0)
        cfg = preset("fast")
    scan, truth = demo.scan, demo.ground_truth
    t = time.perf_counter()
    untiled = enhance(scan, cfg, ground_truth=truth)
    untiled_s = time.perf_counter() - t

    tiling = TilingConfig(tiles=args.tiles)
    runner = LocalPool(workers=args.workers)
    t = time.perf_counter()
    plan = plan_tiles(scan, tiling.count(scan.n_faces), tiling.overlap)
    subs = [tile_scan(scan, f) for f in plan.faces]
    outputs = run_tiles(scan, plan, subs, cfg, runner)
    tiles_s = time.perf_counter() - t
    results = {}
    for harmonize in (True, False):
        t = time.perf_counter()
        r = assemble_tiles(scan, plan, outputs, cfg, TilingConfig(tiles=args.tiles, harmonize=harmonize), runner.name,
                           {"tiles": tiles_s}, ground_truth=truth)
        results[harmonize] = (r, tiles_s + time.perf_counter() - t)

    caster = RayCaster(scan.positions, scan.faces)
    views = untiled.views.views
    test = [views.cameras[i] for i in views.test]
    same_cameras = all(np.allclose(a.world_to_camera, b.world_to_camera) for a, b in
                       zip(test, [results[True][0].views.views.cameras[i] for i in results[True][0].views.views.test]))
    scored = score_views(lambda cam: render(truth, cam, caster, supersample=2),
                         {"input": scan, "untiled": untiled.scan, "tiled": results[True][0].scan,
                          "tiled, no colour levelling": results[False][0].scan},
                         test, caster, untextured_faces(scan))
    cam = frontal(scan, 800 if args.quick else 1600)
    imgs = {name: render(s, cam, caster, supersample=2)[0] for name, s in
            (("tiled", results[True][0].scan), ("untiled", untiled.scan), ("tiled_no_levelling", results[False][0].scan),
             ("input", scan))}
    truth_img = render(truth, cam, caster, supersample=2)[0]
    pairs = {name: (img, truth_img) for name, img in imgs.items()}
    pairs.update({"tiled - untiled": (imgs["tiled"], imgs["untiled"]),
                  "tiled_no_levelling - untiled": (imgs["tiled_no_levelling"], imgs["untiled"])})
    steps = border_steps(plan, cam, caster, scan.triangles, pairs)
    save_pngs(cam, caster, scan.triangles, plan, imgs, truth_img, "quick" if args.quick else "wall")
    geometry = all(r.metrics["geometry"]["arrays_identical"] and r.scan.positions is scan.positions
                   and np.array_equal(r.scan.uvs, scan.uvs) for r, _ in results.values())
    report = {"untiled_s": untiled_s, "tiles_s": tiles_s, "same_cameras": same_cameras, "scores": scored,
              "steps": steps, "geometry_identical": geometry, "tiles": results[True][0].metrics["tiles"],
              "faces": scan.n_faces, "grid": plan.grid}
    print(json.dumps(report, indent=1, default=str))
    (OUT / f"tiles_{'quick' if args.quick else 'wall'}.json").write_text(json.dumps(report, indent=1, default=str))
    if args.quick:
        return
    rows = ["| run | held-out PSNR vs truth | SSIM | time (s) | step at tile borders: overlap middle / edges (mean, max) | step on control lines (mean, max) |",
            "|---|---|---|---|---|---|"]
    names = {"input": "input", "untiled": "untiled `fast`", "tiled": f"{args.tiles} tiles, fused, colours levelled",
             "tiled, no colour levelling": f"{args.tiles} tiles, fused, no levelling"}
    step_key = {"input": "input", "untiled": "untiled", "tiled": "tiled", "tiled, no colour levelling": "tiled_no_levelling"}
    times = {"input": "", "untiled": f"{untiled_s:.0f}", "tiled": f"{results[True][1]:.0f}",
             "tiled, no colour levelling": f"{results[False][1]:.0f}"}
    for key, label in names.items():
        s = scored[key]
        st = steps[step_key[key]]
        mid, edge, ctl = (st.get("border (overlap middle)"), st.get("border (overlap edge)"), st.get("control"))
        f = (lambda x: f"{x[0]:.2f}, {x[1]:.2f}" if x else "-")
        rows.append(f"| {label} | {s['psnr']:.2f} dB | {s['ssim']:.3f} | {times[key]} | {f(mid)} / {f(edge)} | {f(ctl)} |")
    diff_rows = []
    for key, label in (("tiled - untiled", "levelled"), ("tiled_no_levelling - untiled", "not levelled")):
        st = steps[key]
        diff_rows.append(f"| tiled ({label}) - untiled | {st['border (overlap middle)'][0]:.2f} | "
                         f"{st['border (overlap edge)'][0]:.2f} | {st['control'][0]:.2f} (max {st['control'][1]:.2f}) |")
    per_tile = ", ".join(f"{t['faces']:,} faces {t['seconds']:.0f} s {t['peak_memory_gib']:.2f} GiB"
                         for t in results[True][0].metrics["tiles"]["per_tile"])
    md = f"""## Tiled enhancement: the demo wall ({scan.n_faces:,} faces) in {args.tiles} tiles ({plan.grid[0]} x {plan.grid[1]}, 15 % overlap) vs untiled, `fast` preset

{chr(10).join(rows)}

What tiling changed, alone: the same steps measured on the difference of the tiled and the untiled render
(their common errors cancel), mean over lines:

| difference | step at overlap middles | at overlap edges | on control lines |
|---|---|---|---|
{chr(10).join(diff_rows)}

Scores: unlit renders at the untiled run's {len(test)} held-out cameras (the tiled run plans the same ones: {same_cameras})
against the ground truth. Step: difference of the mean error (result - truth, 0-255) in 3 cm bands either side of a
line, per 25 cm of line, on a 1600-px frontal render; control lines are parallel to the borders and at least two
overlaps away from them. Geometry and UVs identical to the input's in every tiled run: {geometry}.
Tiles ({args.workers}-worker local pool, each its own process): {per_tile}. Colour gains per tile (levelled run):
{results[True][0].metrics['tiles']['gains']}.
Renders: `bench/out/tiles_wall_*.png` (not committed).

Command: `python bench/bench_tiles.py` (a shared 2-core machine: other jobs ran at the same time, so times are noisy)
"""
    update_section("tiles", md)


if __name__ == "__main__":
    main()
