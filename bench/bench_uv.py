"""UV planning on the paper-scale demo wall (40,000 vertices, 79,202 faces): unwrap and optimise time,
shells and seam edges before and after, stretch and texel density, and seam visibility before and after
seam blending. Where ``../shared/data`` is present, the real scans' bare geometry is unwrapped too (what an
untextured mesh with photos gets): time, charts, seams and what the unwrap fell back on; and the real textured
scans' own layouts are optimised (``--uv optimize``): shells, seams, stretch and texels before and after.

    python bench/bench_uv.py          # updates the 'uv' section of bench/RESULTS.md

Each timing is one run (the planners are deterministic; this machine is shared and noisy).
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from bench._results import update_section
from scantex.atlas.seams import seam_visibility
from scantex.scan import Scan
from scantex.synth.demo import make_geometry
from scantex.synth.wall import make_wall, wall_panels
from scantex.uv import blend_seams, plan_uvs


def timed(fn):
    start = time.perf_counter()
    out = fn()
    return out, time.perf_counter() - start


def fmt(s: dict | None, key: str) -> str:
    if s is None:
        return "-"
    d = s[key]
    return f"{d['min']:.3f} / {d['median']:.3f} / {d['max']:.3f}" if d["count"] else "-"


DATA = Path(__file__).resolve().parents[2] / "shared" / "data"
#: real scans unwrapped as bare geometry (positions and faces only)
REAL = ("facade_openmvs/scene_mesh.ply", "facade_openmvs/scene_mesh_refine.ply", "bolster_rgbd_posed/bloster.ply",
        "bathroom_3dscannerapp/textured_output.obj", "polycam_glb/potted_plant_on_rug_raw.glb",
        "polycam_glb/tyres_on_tiled_floor_raw.glb")


def real_rows() -> list[str]:
    """One table row per real scan of :data:`REAL` unwrapped at 4096² (none without ``../shared/data``)."""
    from scantex.io import load_scan

    rows = []
    for name in REAL:
        if not (DATA / name).exists():
            continue
        scan = load_scan(DATA / name)
        plan, t = timed(lambda scan=scan: plan_uvs(Scan(scan.positions, scan.faces), "unwrap", texture_size=4096))
        r = plan.report
        u = r["unwrap"]
        rows.append(f"| {name} | {scan.n_faces} | {t:.1f} | {r['after']['shells']} | {r['after']['seam_edges']} | "
                    f"{r['after']['seam_length_m']:.1f} | {r['after']['stretch']['max']:.3f} | "
                    f"{r['atlas_utilisation']:.3f} | {u['small_merged']} | {u['xatlas_regions']} | "
                    f"{'; '.join(u['fallbacks']) or '-'} |")
    return rows


#: real textured scans whose own layout is optimised
REAL_TEXTURED = ("facade_openmvs/app_style_input/scene_mesh_baked.obj",
                 "bolster_rgbd_posed/app_style_input/bolster_app_style.obj", "bathroom_3dscannerapp/textured_output.obj",
                 "polycam_glb/potted_plant_on_rug_raw.glb",
                 "polycam_glb/tyres_on_tiled_floor_raw.glb")


def optimised_rows() -> list[str]:
    """One table row per real scan of :data:`REAL_TEXTURED` optimised at its own atlas size (none without
    ``../shared/data``)."""
    from scantex.io import load_scan

    rows = []
    for name in REAL_TEXTURED:
        if not (DATA / name).exists():
            continue
        scan = load_scan(DATA / name)
        plan, t = timed(lambda scan=scan: plan_uvs(scan, "optimize"))
        r = plan.report
        b, a, o = r["before"], r["after"], r["optimize"]
        rows.append(f"| {name} | {scan.n_faces} | {t:.1f} | {b['shells']} -> {a['shells']} | "
                    f"{b['seam_edges']} -> {a['seam_edges']} | {b['stretch']['median']:.3f} / "
                    f"{b['stretch_area_weighted']:.3g} -> {a['stretch']['median']:.3f} / "
                    f"{a['stretch_area_weighted']:.3f} | {o['shells_reflattened']} | {o['shells_split']} -> "
                    f"{o['charts_from_splits']} | {o['merge']['merges']} / {o['merge']['attempts']} | "
                    f"{r['atlas_utilisation']:.3f} | {'; '.join(o['fallbacks']) or '-'} |")
    return rows


def main() -> None:
    rows = []
    # 1. unwrap the bare geometry (as a PLY without UVs would arrive)
    mesh = make_geometry(wall_panels(), 0)
    bare = Scan(mesh.positions, mesh.faces)
    plan, t_unwrap = timed(lambda: plan_uvs(bare, "unwrap", texture_size=4096))
    r = plan.report
    rows.append(("unwrap, no input UVs", bare.n_faces, "-", r["after"]["shells"], "-", r["after"]["seam_edges"],
                 fmt(r["after"], "stretch"), "-", fmt(r["after"], "density_px_per_cm"), t_unwrap))

    # 2. the demo scan (80 charts as a capture app cuts them); 1024² atlases keep the set-up short
    demo = make_wall(gt_texture_size=1024, scan_texture_size=1024)
    scan = demo.scan
    for mode in ("optimize", "unwrap"):
        plan, t = timed(lambda mode=mode: plan_uvs(scan, mode, texture_size=1024))
        r = plan.report
        rows.append((f"{mode}, demo scan", scan.n_faces, r["before"]["shells"], r["after"]["shells"],
                     r["before"]["seam_edges"], r["after"]["seam_edges"], fmt(r["after"], "stretch"),
                     fmt(r["before"], "density_px_per_cm"), fmt(r["after"], "density_px_per_cm"), t))

    # 3. seam blending on textures with per-chart exposure jumps
    blend_rows = []
    small = make_wall(grid=(40, 30), gt_texture_size=256, scan_texture_size=128)
    for name, s in (("demo wall 40x30, 128² atlas", small.scan), ("demo wall 200x200, 1024² atlas", scan)):
        before = seam_visibility(s)
        blended, t = timed(lambda s=s: blend_seams(s, band_texels=3.0))
        blend_rows.append((name, before, seam_visibility(blended), t))
    small_plan = plan_uvs(small.scan, "optimize", texture_size=128)

    lines = [
        "## UV planning on the demo wall (200 x 200 grid: 40,000 vertices, 79,202 faces)",
        "",
        ("Stretch: Sander's L2 stretch per chart (1 = isometric; threshold 1.1). Density: px/cm per chart, "
         "min / median / max."),
        "",
        ("| run | faces | shells before | after | seam edges before | after | stretch after | "
         "px/cm before | px/cm after | time (s) |"),
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for row in rows:
        lines.append("| " + " | ".join(str(x) for x in row[:-1]) + f" | {row[-1]:.2f} |")
    lines += [
        "",
        (f"Small demo wall (40 x 30, 2,262 faces) optimised: {small_plan.report['before']['shells']} -> "
        f"{small_plan.report['after']['shells']} shells, {small_plan.report['before']['seam_edges']} -> "
        f"{small_plan.report['after']['seam_edges']} seam edges, max stretch "
        f"{small_plan.report['after']['stretch']['max']:.4f}, {small_plan.report['time_s']:.2f} s."),
        "",
        "### Seam blending (band 3 texels): seam visibility, mean |RGB| difference (0-255) across seams",
        "",
        "| texture | before | after blending | time (s) |",
        "|---|---|---|---|",
    ]
    for name, before, after, t in blend_rows:
        lines.append(f"| {name} | {before:.2f} | {after:.2f} | {t:.2f} |")
    lines += [
        "",
        ("The metric reads each side one texel inside its chart, so even a perfect texture differs there by "
         "the texture's own detail over two texels."),
    ]
    real = real_rows()
    if real:
        lines += [
            "",
            "### Real scans' bare geometry unwrapped at 4096² (`../shared/data`)",
            "",
            ("| mesh | faces | time (s) | charts | seam edges | seam length (m) | stretch max | atlas used | "
             "slivers merged | xatlas regions | fell back on |"),
            "|---|---|---|---|---|---|---|---|---|---|---|",
            *real,
        ]
    optimised = optimised_rows()
    if optimised:
        lines += [
            "",
            "### Real textured scans' own layouts optimised (`--uv optimize`, at the input's atlas size)",
            "",
            ("| mesh | faces | time (s) | shells | seam edges | stretch median / area-weighted | flattened again | "
             "split -> charts | merges / tries | atlas used | fell back on |"),
            "|---|---|---|---|---|---|---|---|---|---|---|",
            *optimised,
        ]
    lines += ["", "Command: `python bench/bench_uv.py`"]
    text = "\n".join(lines)
    print(text)
    update_section("uv", text)


if __name__ == "__main__":
    np.seterr(all="ignore")
    main()
