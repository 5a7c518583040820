"""enhance on the demo scans: presets (time, memory, quality) and ablations of the field's choices.

    python bench/bench_enhance.py              # presets on the paper-scale wall + ablations; ~15 min
    python bench/bench_enhance.py --presets    # only the presets, timed as a user runs them; ~3 min
    python bench/bench_enhance.py --presets --baseline REV   # ... and the same commands at git REV, interleaved
    python bench/bench_enhance.py --ablations  # only the ablations (mid-size wall)

Presets are timed from command to written outputs (`scantex enhance demo/scan.obj --ground-truth ...`:
start-up, loading, the stages, writing the OBJ, GLB, renders and report), each in its own process so that
peak memory is that run's. Quality is measured on held-out views against the ground truth; the input
texture's score at the same views is its baseline. Writes the 'enhance' and 'ablations' sections of
bench/RESULTS.md.
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


def cli_run(demo: Path, preset: str, out: Path, source: Path | None = None) -> dict:
    """``scantex enhance`` on the demo scan in a fresh process (the package from ``source`` when given):
    wall seconds, the children's peak memory, and the run's metrics.json."""
    import json
    import os
    import subprocess
    import time

    env = dict(os.environ, PYTHONPATH=str(source)) if source else None
    cmd = [sys.executable, "-m", "scantex", "enhance", str(demo / "scan.obj"), "--ground-truth",
           str(demo / "ground_truth.obj"), "-o", str(out), "--preset", preset, "--overwrite", "--quiet"]
    t = time.perf_counter()
    # cwd: `-m` puts the working directory first on sys.path, ahead of PYTHONPATH
    proc = subprocess.run(cmd, capture_output=True, text=True, env=env, cwd=out.parent, check=False)
    seconds = time.perf_counter() - t
    if proc.returncode != 0:
        raise RuntimeError(proc.stderr[-3000:])
    metrics = json.loads((out / "metrics.json").read_text())
    return {"seconds": seconds,
            "scores": metrics["held_out_vs_ground_truth"], "seams": metrics["seam_visibility"],
            "timings": metrics["timings_s"], "geometry": metrics["geometry"]["arrays_identical"]}


def cli_row(name: str, r: dict) -> str:
    i, e = r["scores"]["input"], r["scores"]["enhanced"]
    stages = ", ".join(f"{k} {v:.1f}" for k, v in r["timings"].items() if k != "total" and v >= 0.05)
    outside = r["seconds"] - r["timings"]["total"]
    return (f"| {name} | {i['psnr']:.2f} -> **{e['psnr']:.2f}** | {i['ssim']:.3f} -> {e['ssim']:.3f} | "
            f"{r['seams']['input']:.1f} -> {r['seams']['enhanced']:.1f} | **{r['seconds']:.1f}** | "
            f"{r['timings']['total']:.1f} ({stages}) | {outside:.1f} | "
            f"{'yes' if r['geometry'] else 'NO'} |")


def presets(baseline: str | None = None) -> str:
    """The presets timed end to end, interleaved with the same commands at ``baseline`` (a git revision)."""
    import subprocess
    import tempfile

    lines = ["## enhance presets on the paper-scale demo wall (40,000 V / 79,202 F, 1024² atlas), command to "
             "written outputs", "",
             "| run | held-out PSNR dB (input -> enhanced) | SSIM | seam visibility | wall s | stages s | "
             "outside the stages s | geometry identical |", "|---|---|---|---|---|---|---|---|"]
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        demo = tmp / "demo"
        subprocess.run([sys.executable, "-m", "scantex", "demo-scan", "-o", str(demo), "--overwrite"], check=True,
                       capture_output=True)
        sources = [("", None)]
        if baseline:
            tree = tmp / "baseline"
            subprocess.run(["git", "worktree", "add", "--detach", "-q", str(tree), baseline], cwd=ROOT, check=True)
            sources.insert(0, (f" at {baseline}", tree))
        try:
            for name in ("fast", "default"):
                for label, source in sources:
                    r = cli_run(demo, name, tmp / f"out_{name}", source)
                    lines.append(cli_row(f"`{name}`{label}", r))
                    print(lines[-1], flush=True)
        finally:
            if baseline:
                subprocess.run(["git", "worktree", "remove", "--force", str(tmp / "baseline")], cwd=ROOT, check=False)
    lines += ["", "Targets (issue 13): `fast` <= 20 s, `default` <= 60 s on 2 cores, quality no lower. Stages "
              "from the run's metrics.json; outside them: start-up (imports), loading, writing the outputs and "
              "the report. Peak memory: bench/RESULTS.md \"scaling\" and \"bake memory\".",
              f"Command: `python bench/bench_enhance.py --presets{' --baseline ' + baseline if baseline else ''}`"]
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
    parser.add_argument("--presets", action="store_true", help="only the presets")
    parser.add_argument("--baseline", metavar="REV", help="also time the presets at this git revision")
    args = parser.parse_args()
    if not args.ablations:
        update_section("enhance", presets(args.baseline))
    if not args.presets:
        update_section("ablations", ablations())


if __name__ == "__main__":
    main()
