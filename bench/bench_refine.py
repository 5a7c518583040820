"""Ablations of the refinement stage (the ViT refiner, its self-supervision, the diffusion denoiser).

    python bench/bench_refine.py            # demo wall + room; writes the 'refine' section of RESULTS.md
    python bench/bench_refine.py --per-term # also each self-supervised term left out in turn (~12 min)
    python bench/bench_refine.py --quick    # toy sizes, prints the table only

Rows, per scene, all with the same preset, seed and therefore the same views and field:
- field only: ``enhance`` without refinement (what the pipeline does with ``--no-refine``);
- + ViT without self-supervision: the same network, steps and views, trained on plain reconstruction of
  the uncorrupted canonical views (no masking, no cross-view term, no downscale to undo);
- + ViT with the default terms (masked completion + super-resolution; cross-view consistency is off by
  default because leaving it out measured better), and with all three terms;
- + ViT without one of the three terms, and with super-resolution only (per-term ablations);
- + ViT + diffusion: the refined views also denoised by the diffusion model (``--diffusion``);
- the default bake of a textured scan (the input's own texels, levelled) without and with the refiner
  (``refine.over_input``, ``--refine``): the rows above all bake the field's colour (``bake.source`` field),
  where the refiner is on by default.

Every run is its own process. Scores: unlit renders at held-out cameras planned with their own seed
(seen by no run) against the ground truth's, as in bench_suite; seam visibility of the output atlas along
the input's seams; wall time of the whole ``enhance`` and of its refinement stage.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
from bench._results import run_worker, update_section  # noqa: E402

WORKER = r"""
import json, sys, time
from scantex.atlas.holes import untextured_faces
from scantex.atlas.seams import seam_edges, seam_visibility
from scantex.metrics.views import score_views
from scantex.pipeline.config import preset
from scantex.pipeline.enhance import enhance
from scantex.synth import make_room, make_wall
from scantex.views.planning import plan_views
from scantex.views.raycast import RayCaster
from scantex.views.render import render
spec = json.loads(sys.argv[1])
demo = (make_wall if spec["scene"] == "wall" else make_room)(**spec["make"])
scan, truth = demo.scan, demo.ground_truth
cfg = preset(spec["preset"]).override(**spec.get("override", {}))
t = time.perf_counter()
result = enhance(scan, cfg)
seconds = time.perf_counter() - t
caster = RayCaster(scan.positions, scan.faces)
W, H = spec["eval_size"]
cameras = plan_views(scan, spec["eval_views"], width=W, height=H, fov_deg=60.0, seed=1000, caster=caster)
scores = score_views(lambda cam: render(truth, cam, caster, supersample=2), {"input": scan, "enhanced": result.scan},
                     cameras, caster, untextured_faces(scan))
edges = seam_edges(scan)
print(json.dumps({"seconds": seconds, "scores": scores, "timings": result.metrics["timings_s"],
                  "seams": {"input": seam_visibility(scan, edges), "enhanced": seam_visibility(result.scan, edges)},
                  "refine": result.metrics.get("refine"),
                  "geometry": result.metrics["geometry"]["arrays_identical"]}))
"""

ALL = {"refine__enabled": True, "refine__masked": True, "refine__cross_view": True, "refine__super_resolution": True}
OFF = {"refine__masked": False, "refine__cross_view": False, "refine__super_resolution": False}
DEFAULT = {**ALL, "refine__cross_view": False}  # what the presets use (see RefineConfig)
# the refiner is on by default where the bake is the field's colour, so the ablations bake the field; the last
# two rows are the default bake of a textured scan (its own texels, levelled) without and with the refiner
FIELD = {"bake__source": "field"}
ROWS = [(name, {**FIELD, **override}) for name, override in [
    ("field only", {"refine__enabled": False}),
    ("+ ViT, default terms (masked + super-resolution)", DEFAULT),
    ("+ ViT without self-supervision (plain reconstruction)", {**ALL, **OFF}),
    ("+ ViT, all three terms (masked + cross-view + super-resolution)", ALL),
    ("+ ViT, all but masked completion", {**ALL, "refine__masked": False}),
    ("+ ViT, all but super-resolution", {**ALL, "refine__super_resolution": False}),
    ("+ ViT, super-resolution only", {**ALL, **OFF, "refine__super_resolution": True}),
    ("+ ViT (default terms) + diffusion", {**DEFAULT, "refine__diffusion": True}),
]]
INPUT_ROWS = [
    ("input texels levelled (the default bake), no refiner", {"bake__source": "input"}),
    ("input texels levelled + ViT (`refine.over_input`)", {**DEFAULT, "bake__source": "input", "refine__over_input": True}),
]

SCENES = {
    "full": [
        ("demo wall (79k faces, 1024² atlas), `fast`", "wall", {}, "fast", ROWS[:4] + ROWS[-1:] + INPUT_ROWS),
        ("room (4.8k faces, 256² atlas), `fast`", "room", {}, "fast", ROWS[:4] + ROWS[-1:] + INPUT_ROWS),
    ],
    "quick": [
        ("toy wall", "wall", {"grid": (24, 18), "gt_texture_size": 256, "scan_texture_size": 64}, "fast",
         ROWS[:3]),
    ],
}


def run(spec: dict) -> dict:
    return run_worker(WORKER, spec)


def row(scene: str, name: str, r: dict) -> str:
    i, e = r["scores"]["input"], r["scores"]["enhanced"]
    hole = f"{e['hole_psnr']:.2f}" if "hole_psnr" in e else "—"
    refine = r["timings"].get("refine")
    return (f"| {scene} | {name} | {i['psnr']:.2f} -> **{e['psnr']:.2f}** | {e['mse'] * 1e3:.2f} | "
            f"{i['ssim']:.3f} -> {e['ssim']:.3f} | {hole} | {r['seams']['input']:.1f} -> {r['seams']['enhanced']:.2f} | "
            f"{r['seconds']:.0f} | {'—' if refine is None else f'{refine:.0f}'} | {'yes' if r['geometry'] else 'NO'} |")


HEADER = ["| scene | run | held-out PSNR dB (input -> result) | MSE x1e3 | SSIM | hole PSNR dB | seam visibility | "
          "enhance s | refine s | geometry identical |", "|---|---|---|---|---|---|---|---|---|---|"]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="toy sizes; print the table only")
    parser.add_argument("--per-term", action="store_true",
                        help="also the per-term ablations (all but masking, all but super-resolution, "
                             "super-resolution only; 'all but cross-view' is the default row)")
    args = parser.parse_args()
    lines = list(HEADER)
    start = time.perf_counter()
    eval_views, eval_size = (2, (96, 72)) if args.quick else (6, (320, 240))
    for scene, kind, make, preset, rows in SCENES["quick" if args.quick else "full"]:
        if args.per_term and not args.quick:
            rows = rows[:-3] + ROWS[4:7] + rows[-3:]
        for name, override in rows:
            r = run({"scene": kind, "make": make, "preset": preset, "override": override,
                     "eval_views": eval_views, "eval_size": eval_size})
            lines.append(row(scene, name, r))
            print(lines[-1], json.dumps(r["refine"]) if r["refine"] else "", flush=True)
    total = time.perf_counter() - start
    table = "\n".join(lines)
    print(table, f"\ntotal {total:.0f} s")
    if not args.quick:
        update_section("refine", "## Refinement ablations: ViT refiner, its self-supervision, diffusion\n\n"
                       f"Held-out: {eval_views} cameras per scene ({eval_size[0]}x{eval_size[1]}, planned with "
                       "their own seed, seen by no run), unlit renders against the ground truth's; MSE over "
                       "covered pixels; hole PSNR over pixels of faces the input left black; seam visibility "
                       "along the input's seams in the output atlas (mean RGB step, 0-255). Rows of a scene "
                       "share preset, seed, views and field. Each run is its own process.\n\n"
                       f"{table}\n\nTotal bench time {total:.0f} s. Command: `python bench/bench_refine.py`")


if __name__ == "__main__":
    main()
