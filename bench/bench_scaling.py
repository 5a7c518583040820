"""How `enhance` scales: time and peak memory per stage on synthetic walls of ~100 k, 300 k and 1 M faces
baked into 2048², 4096² and 8192² atlases (the `fast` preset, on the CPU).

    python bench/bench_scaling.py                  # the full 3 x 3 grid (hours on 2 shared cores)
    python bench/bench_scaling.py --runs 100k:2048 100k:8192 1M:8192   # a subset

Each run is its own process. Per stage, the peak resident memory is that stage's own: the process's
high-water mark (VmHWM) is reset before each stage (``/proc/self/clear_refs``, Linux) and read after it.
"Write" is the outputs (OBJ + PNG, GLB, renders, report) into a temporary folder. Stage times overlap
nothing: they add up to the run (bar the scan's synthesis, which is not timed). Writes the 'scaling'
section of bench/RESULTS.md.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
from bench._results import run_worker, update_section  # noqa: E402

WORKER = r"""
import contextlib, json, sys, tempfile, time
from pathlib import Path

def hwm_mb():
    for line in open("/proc/self/status"):
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) / 1024

def reset_hwm():
    with open("/proc/self/clear_refs", "w") as f:
        f.write("5")

spec = json.loads(sys.argv[1])
from scantex.pipeline.config import preset
from scantex.pipeline.enhance import Reporter, enhance
from scantex.pipeline.outputs import write_outputs
from scantex.synth import make_wall
stages = {}

class Measure(Reporter):
    @contextlib.contextmanager
    def stage(self, name):
        reset_hwm()
        t = time.perf_counter()
        yield lambda done, total: None
        stages[name] = {"s": time.perf_counter() - t, "peak_mb": hwm_mb()}

n = spec["grid"]
demo = make_wall(grid=(n, n), gt_texture_size=1024, scan_texture_size=1024, n_charts=spec["charts"])
scan = demo.scan
del demo
cfg = preset(spec["preset"]).override(bake__texture_size=spec["atlas"])
t = time.perf_counter()
result = enhance(scan, cfg, reporter=Measure())
seconds = time.perf_counter() - t
with tempfile.TemporaryDirectory() as out, Measure().stage("writing outputs"):
    write_outputs(result, out)
print(json.dumps({"faces": scan.n_faces, "seconds": seconds, "stages": stages,
                  "timings": result.metrics["timings_s"], "geometry": result.metrics["geometry"]["arrays_identical"]}))
"""

#: faces -> vertices per side of the square wall grid (2 (n - 1)^2 faces)
GRIDS = {"100k": 225, "300k": 388, "1M": 708}
ATLASES = (2048, 4096, 8192)
COLUMNS = [("planning views", "plan"), ("rendering views", "render"), ("training the field", "train"),
           ("UV layout (keep)", "uv"), ("refining (ViT)", "refine"), ("baking the texture", "bake + blend"),
           ("measuring", "metrics"), ("writing outputs", "write")]


def grid_side(faces: str) -> int:
    """Vertices per side for ``faces`` (a key of GRIDS, or a number of faces)."""
    return GRIDS[faces] if faces in GRIDS else round((int(faces) / 2) ** 0.5) + 1


def run(faces: str, atlas: int, preset: str) -> dict:
    return run_worker(WORKER, {"grid": grid_side(faces), "atlas": atlas, "preset": preset, "charts": 80})


def row(faces: str, atlas: int, r: dict) -> str:
    cells = []
    for name, _ in COLUMNS:
        s = r["stages"].get(name)
        cells.append(f"{s['s']:.0f} / {s['peak_mb'] / 1024:.2f}" if s else "-")
    peak = max(s["peak_mb"] for s in r["stages"].values()) / 1024
    total = r["seconds"] + r["stages"].get("writing outputs", {"s": 0})["s"]
    return (f"| {r['faces']:,} | {atlas}² | " + " | ".join(cells) + f" | **{total:.0f}** | **{peak:.2f}** | "
            f"{'yes' if r['geometry'] else 'NO'} |")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", nargs="*", help="faces:atlas pairs, e.g. 100k:2048 1M:8192 or 5000:512 (default: all)")
    parser.add_argument("--preset", default="fast")
    args = parser.parse_args()
    runs = [(f, int(a)) for f, a in (r.split(":") for r in args.runs)] if args.runs else \
        [(f, a) for f in GRIDS for a in ATLASES]
    lines = [f"## Scaling: synthetic walls, `{args.preset}` preset, time s / peak resident GiB per stage", "",
             "| faces | atlas | " + " | ".join(c for _, c in COLUMNS) + " | total s | peak GiB | geometry identical |",
             "|---|---|" + "---|" * (len(COLUMNS) + 3)]
    for faces, atlas in runs:
        r = run(faces, atlas, args.preset)
        lines.append(row(faces, atlas, r))
        print(lines[-1], flush=True)
    cmd = "python bench/bench_scaling.py" + (" --runs " + " ".join(args.runs) if args.runs else "")
    lines += ["", f"Command: `{cmd}`" + ("" if args.preset == "fast" else f" --preset {args.preset}"), ""]
    update_section("scaling", "\n".join(lines))


if __name__ == "__main__":
    main()
