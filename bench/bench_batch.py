"""A batch of 8 small scans: one after another, on the local process pool, and on a local Ray cluster.

    python bench/bench_batch.py             # writes the 'batch' section of RESULTS.md
    python bench/bench_batch.py --scans 4   # fewer scans, prints only

The same 8 synthetic walls (seeds 0-7, each with its ground truth) and the same config in every run, each run
into a fresh output folder, in one process, one after another:
- sequential: the local pool with one worker (each scan still in its own process, all cores for its torch);
- local pool: ``scantex batch`` as it runs by default (workers and threads sized to the machine);
- Ray: a local Ray cluster started here (``ray.init(num_cpus=<cores>)``), one task per scan declaring 1 CPU.
Wall time of the whole batch (Ray: including starting the cluster), the sum of the scans' own times, and the
largest peak memory of a scan's worker.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
from bench._results import update_section  # noqa: E402


def make_scans(root: Path, n: int) -> None:
    from scantex.io import save_scan
    from scantex.synth import make_wall

    for seed in range(n):
        demo = make_wall(grid=(24, 18), size_m=(2.0, 1.5), gt_texture_size=256, scan_texture_size=128, seed=seed)
        folder = root / f"wall{seed}"
        folder.mkdir(parents=True)
        save_scan(demo.scan, folder / "scan.obj")
        save_scan(demo.ground_truth, folder / "ground_truth.obj")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--scans", type=int, default=8)
    args = parser.parse_args()

    from scantex.pipeline.config import preset
    from scantex.scale import batch
    from scantex.scale.resources import machine

    # small scans, a small field: the benchmark is about running many of them, not about one's quality
    config = preset("fast").override(views__n_views=4, views__width=96, views__height=72, train__steps=40,
                                     field__log2_table_size=15, field__n_levels=8, refine__enabled=False)
    cores = machine().cores
    rows = []
    with tempfile.TemporaryDirectory(prefix="bench_batch_") as tmp:
        tmp = Path(tmp)
        make_scans(tmp / "scans", args.scans)
        faces = None
        for label, kwargs in (("sequential (local pool, 1 worker)", {"workers": 1}),
                              (f"local pool ({cores} workers, default)", {}),
                              (f"Ray, local cluster ({cores} CPUs, 1 per task)", {"ray": "auto"})):
            t = time.perf_counter()
            if "ray" in kwargs:
                import ray

                ray.init(num_cpus=cores, include_dashboard=False, log_to_driver=False)
            result = batch([tmp / "scans"], tmp / f"out{len(rows)}", config, **kwargs)
            seconds = time.perf_counter() - t
            if "ray" in kwargs:
                ray.shutdown()
            assert not result.failed, result.failed
            faces = result.records[0]["faces"]
            psnr = sum(r["scores"]["psnr_enhanced"] for r in result.records) / len(result.records)
            rows.append((label, seconds, sum(r["seconds"] for r in result.records),
                         max(r["peak_memory_gib"] for r in result.records), psnr))
            print(rows[-1], flush=True)
    base = rows[0][1]
    table = ["| executor | wall time (s) | vs sequential | sum of scan times (s) | largest peak memory of a scan | mean held-out PSNR |",
             "|---|---|---|---|---|---|"]
    table += [f"| {label} | {s:.0f} | {base / s:.2f}x | {total:.0f} | {peak:.2f} GiB | {psnr:.2f} dB |"
              for label, s, total, peak, psnr in rows]
    load = os.getloadavg()
    md = f"""## Batch: {args.scans} small scans ({faces:,} faces, 128² atlas, `fast` with 4 views of 96x72, 40 steps, a 2^15 x 8-level hash grid, no refiner)

{chr(10).join(table)}

One run, the three executors one after another on the same scans and config. Every scan runs in its own worker process
(spawned: about 3 s of interpreter and torch start-up each), which the sequential row pays too. The machine has
{cores} cores (load average {load[0]:.1f} / {load[1]:.1f} / {load[2]:.1f} when the run ended), which bound the parallel
speed-up; on a many-core machine or a cluster the pool and Ray scale with the cores. Ray's row includes starting the
local cluster.

Command: `python bench/bench_batch.py`
"""
    if args.scans == 8:
        update_section("batch", md)
    print(md)


if __name__ == "__main__":
    main()
