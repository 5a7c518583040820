"""enhance on the demo scans: presets (time, memory, quality) and ablations of the field's choices.

    python bench/bench_enhance.py              # presets on the paper-scale wall + ablations; ~15 min
    python bench/bench_enhance.py --ablations  # only the ablations (mid-size wall)

Each run is its own process so that peak memory is that run's. Quality is measured on held-out
views against the ground truth; the input texture's score at the same views is its baseline.
Writes the 'enhance' and 'ablations' sections of bench/RESULTS.md.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
from bench._results import run_worker, update_section  # noqa: E402

WORKER = r"""
import json, resource, sys, time
from scantex.pipeline.config import preset
from scantex.pipeline.enhance import enhance
from scantex.synth import make_wall
spec = json.loads(sys.argv[1])
demo = make_wall(**spec["wall"])
cfg = preset(spec["preset"]).override(**spec.get("override", {}))
t = time.perf_counter()
result = enhance(demo.scan, cfg, ground_truth=demo.ground_truth)
seconds = time.perf_counter() - t
m = result.metrics
print(json.dumps({"seconds": seconds, "peak_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
                  "scores": m["held_out_vs_ground_truth"], "seams": m["seam_visibility"],
                  "timings": m["timings_s"], "geometry": m["geometry"]["arrays_identical"]}))
"""

PAPER_WALL = {}  # make_wall defaults: 40,000 V / 79,202 F, 1024^2 scan atlas, 4096^2 ground truth
MID_WALL = {"grid": (100, 75), "gt_texture_size": 1024, "scan_texture_size": 256, "n_charts": 40}


def run(spec: dict) -> dict:
    return run_worker(WORKER, spec)


def row(name: str, r: dict) -> str:
    i, e = r["scores"]["input"], r["scores"]["enhanced"]
    hole = f"{i.get('hole_psnr', float('nan')):.2f} -> {e.get('hole_psnr', float('nan')):.2f}"
    return (f"| {name} | {i['psnr']:.2f} -> **{e['psnr']:.2f}** | {i['ssim']:.3f} -> {e['ssim']:.3f} | "
            f"{r['seams']['input']:.1f} -> {r['seams']['enhanced']:.1f} "
            f"({r['seams'].get('before_blending', float('nan')):.1f} before blending) | {hole} | "
            f"{r['seconds']:.0f} (train {r['timings']['train']:.0f}) | {r['peak_mb'] / 1024:.2f} | "
            f"{'yes' if r['geometry'] else 'NO'} |")


HEADER = ["| run | held-out PSNR dB (input -> enhanced) | SSIM | seam visibility | hole PSNR dB | "
          "time s | peak GiB | geometry identical |", "|---|---|---|---|---|---|---|---|"]


def presets() -> str:
    lines = ["## enhance presets on the paper-scale demo wall (40,000 V / 79,202 F, 1024² atlas)", ""] + HEADER
    for name in ("fast", "default"):
        r = run({"wall": PAPER_WALL, "preset": name})
        lines.append(row(f"`{name}`", r))
        print(lines[-1], flush=True)
    lines += ["", "Targets: `fast` <= 60 s, `default` <= 3 min and <= 4 GiB on 2 cores.",
              "Command: `python bench/bench_enhance.py`"]
    return "\n".join(lines)


ABLATIONS = [
    ("field + appearance + coarse-to-fine (default)", {}),
    ("no per-chart appearance", {"train__appearance": False}),
    ("no coarse-to-fine", {"train__coarse_to_fine": 0.0}),
    ("4 samples in a band (volumetric)", {"train__n_samples": 4}),
    ("frequency encoding (the paper's)", {"field__encoding": "frequency"}),
]


def ablations() -> str:
    lines = ["## Field ablations (mid-size wall: 100x75 grid, 256² atlas, 1024² truth; `default` preset, "
             "900 steps)", ""] + HEADER
    for name, override in ABLATIONS:
        r = run({"wall": MID_WALL, "preset": "default", "override": {"train__steps": 900, **override}})
        lines.append(row(name, r))
        print(lines[-1], flush=True)
    lines += ["", "Command: `python bench/bench_enhance.py --ablations`"]
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--ablations", action="store_true", help="only the ablations")
    args = parser.parse_args()
    if not args.ablations:
        update_section("enhance", presets())
    update_section("ablations", ablations())


if __name__ == "__main__":
    main()
