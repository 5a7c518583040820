"""Radiance field throughput on the CPU: training steps (forward + backward + Adam) and baking evaluation.

    python bench/bench_field.py          # updates the 'field' section of bench/RESULTS.md

Every number is samples per second on 2 threads. Variants are timed in interleaved rounds and the median
is reported, so that the machine's drift hits all of them alike; the ratios are the point.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np
import torch
from torch import nn

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from bench._results import median_time, update_section  # noqa: E402
from scantex.field import (  # noqa: E402
    FieldConfig,
    HashGridEncoding,
    RadianceField,
    evaluate_colour,
    hash_grid_encode,
    hash_grid_layout,
    hash_grid_reference,
)

NERF_MLP = {
    "encoding": "frequency",
    "n_freqs": 10,
    "dir_freqs": 4,
    "use_viewdirs": True,
    "hidden": 256,
    "n_layers": 8,
    "skip_at": 4,
    "feature_dim": 256,
    "colour_hidden": 128,
}


class _GridVariant(nn.Module):
    """The same hash grid evaluated another way: 'naive' (F.embedding, default autograd) or 'reference' (loop)."""

    def __init__(self, grid: HashGridEncoding, mode: str):
        super().__init__()
        self.grid, self.mode = grid, mode
        self.out_dim = grid.out_dim

    def forward(self, x):
        if self.mode == "reference":
            return hash_grid_reference(self.grid, x)
        return hash_grid_encode(x, self.grid.table, self.grid.layout, fused_backward=False)


def training_step(field: RadianceField, batch: int, fused_adam: bool = True, seed: int = 0):
    """A closure running one fit step on ``batch`` random surface points (one sample per ray)."""
    g = torch.Generator().manual_seed(seed)
    x = torch.rand(batch, 3, generator=g)
    d = torch.nn.functional.normalize(torch.randn(batch, 3, generator=g), dim=1)
    target = torch.rand(batch, 3, generator=g)
    opt = torch.optim.Adam(
        field.parameters(), lr=1e-2, eps=1e-15, fused=fused_adam, foreach=None if fused_adam else True
    )
    use_d = d if field.config.use_viewdirs else None

    def step():
        loss = (field.colour(x, use_d) - target).square().mean()
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()

    return step


def interleaved(variants: dict, rounds: int, warmup: int = 1) -> dict:
    """Median seconds per call of each closure, timed round-robin."""
    for fn in variants.values():
        for _ in range(warmup):
            fn()
    times = {name: [] for name in variants}
    for _ in range(rounds):
        for name, fn in variants.items():
            times[name].append(median_time(fn, repeats=1))
    return {name: float(np.median(t)) for name, t in times.items()}


def main() -> None:
    torch.set_num_threads(2)
    torch.manual_seed(0)
    started = time.perf_counter()
    lines = []

    # 1. hash grid + 64-wide MLP, one fit step, batch 65k
    batch = 65536
    hash_variants, names = {}, {}
    for key, label, mode, cfg, fused_adam in [
        ("fast", "fast path (per-axis corners, `bincount` backward), fused Adam", None, FieldConfig(), True),
        ("fast_bf16", "fast path, MLP under bf16 autocast", None, FieldConfig(bf16=True), True),
        ("fast_foreach", "fast path, default (foreach) Adam", None, FieldConfig(), False),
        ("naive", "naive eager: same indices, `F.embedding` + default autograd", "naive", FieldConfig(), True),
        (
            "reference",
            "per-level loop twin (`hash_grid_reference`) + default autograd",
            "reference",
            FieldConfig(),
            True,
        ),
    ]:
        field = RadianceField(cfg)
        if mode is not None:
            field.encoding = _GridVariant(field.encoding, mode)
        hash_variants[key] = training_step(field, batch, fused_adam)
        names[key] = label
    rounds = 5
    t = interleaved({k: v for k, v in hash_variants.items() if k != "reference"}, rounds)
    t.update(interleaved({"reference": hash_variants.pop("reference")}, 2, warmup=0))
    del hash_variants
    lines += [
        (
            f"## Hash grid (16 levels x 2 features, 2^19 table, 2048 finest) + 64-wide MLP: fit step "
            f"(fwd + bwd + Adam), batch {batch:,}, 2 threads, median of {rounds} interleaved rounds"
        ),
        "",
        "| variant | s/step | k samples/s | vs naive |",
        "|---|---|---|---|",
    ]
    for key in ("fast", "fast_bf16", "fast_foreach", "naive", "reference"):
        lines.append(f"| {names[key]} | {t[key]:.3f} | {batch / t[key] / 1e3:.0f} | {t['naive'] / t[key]:.2f}x |")
    print("\n".join(lines), flush=True)

    # 1b. table size and finest resolution: the table's zeroed gradient and Adam update scale with its rows
    sizes = [(19, 2048), (21, 4096), (22, 4096)]
    sweep = {
        s: training_step(RadianceField(FieldConfig(log2_table_size=s[0], max_resolution=s[1])), batch) for s in sizes
    }
    ts = interleaved(sweep, 3)
    del sweep
    lines += [
        "",
        f"Table size (fast path, fp32, batch {batch:,}):",
        "",
        "| log2 table | finest resolution | parameters (M) | s/step | k samples/s |",
        "|---|---|---|---|---|",
    ]
    for s in sizes:
        rows = hash_grid_layout(16, s[0], 16, s[1]).rows
        lines.append(f"| {s[0]} | {s[1]} | {rows * 2 / 1e6:.1f} | {ts[s]:.3f} | {batch / ts[s] / 1e3:.0f} |")
    print("\n".join(lines[-len(sizes) - 4 :]), flush=True)

    # 2. NeRF MLP (8 x 256, skip at 4, frequency encoding 10 / 4), batch 4096: fp32 vs bf16 autocast
    nerf_batch = 4096
    nerf = {
        "fp32": training_step(RadianceField(FieldConfig(**NERF_MLP)), nerf_batch),
        "bf16": training_step(RadianceField(FieldConfig(**NERF_MLP, bf16=True)), nerf_batch),
        "small_fp32": training_step(RadianceField(FieldConfig(encoding="frequency")), nerf_batch),
        "small_bf16": training_step(RadianceField(FieldConfig(encoding="frequency", bf16=True)), nerf_batch),
    }
    tn = interleaved(nerf, 7)
    lines += [
        "",
        f"## Frequency-encoding MLPs: fit step, batch {nerf_batch:,}, 2 threads",
        "",
        "| model | fp32 k samples/s | bf16 autocast k samples/s | bf16 speed-up |",
        "|---|---|---|---|",
        (
            f"| NeRF MLP 8 x 256, skip at 4, view dirs (10 / 4 freqs) | {nerf_batch / tn['fp32'] / 1e3:.0f} | "
            f"{nerf_batch / tn['bf16'] / 1e3:.0f} | {tn['fp32'] / tn['bf16']:.2f}x |"
        ),
        (
            f"| small MLP 4 x 64, skip at 2 (10 freqs) | {nerf_batch / tn['small_fp32'] / 1e3:.0f} | "
            f"{nerf_batch / tn['small_bf16'] / 1e3:.0f} | {tn['small_fp32'] / tn['small_bf16']:.2f}x |"
        ),
    ]
    print("\n".join(lines[-6:]), flush=True)

    # 3. baking: evaluate_colour under no_grad, chunks of 4k vs 65k
    n_points = 262144
    points = torch.rand(n_points, 3, generator=torch.Generator().manual_seed(1))
    dirs = torch.nn.functional.normalize(torch.randn(n_points, 3), dim=1)
    models = {
        "hash grid + 64-wide MLP, fp32": RadianceField(FieldConfig()),
        "hash grid + 64-wide MLP, bf16": RadianceField(FieldConfig(bf16=True)),
        "NeRF MLP 8 x 256, fp32": RadianceField(FieldConfig(**NERF_MLP)),
        "NeRF MLP 8 x 256, bf16": RadianceField(FieldConfig(**NERF_MLP, bf16=True)),
    }
    evals = {}
    for label, model in models.items():
        d = dirs if model.config.use_viewdirs else None
        for chunk in (4096, 65536):
            evals[(label, chunk)] = lambda m=model, c=chunk, d=d: evaluate_colour(m, points, d, chunk=c)
    te = interleaved(evals, 3)
    lines += [
        "",
        f"## Baking: `evaluate_colour` (no_grad) over {n_points:,} points, 2 threads, median of 3 interleaved rounds",
        "",
        "| model | chunk 4,096: M points/s | chunk 65,536: M points/s | 4k vs 65k |",
        "|---|---|---|---|",
    ]
    for label in models:
        a, b = te[(label, 4096)], te[(label, 65536)]
        lines.append(f"| {label} | {n_points / a / 1e6:.2f} | {n_points / b / 1e6:.2f} | {b / a:.2f}x |")
    print("\n".join(lines[-7:]), flush=True)

    lines += ["", f"Total bench time {time.perf_counter() - started:.0f} s. Command: `python bench/bench_field.py`"]
    update_section("field", "\n".join(lines))


if __name__ == "__main__":
    main()
