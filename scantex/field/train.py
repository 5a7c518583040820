"""Fitting the radiance field to views of the scan.

Rays come from the views' G-buffers: each pixel that sees a usable face (textured, not a hole) gives
a ray, the depth of the surface it hits (for mesh-guided sampling) and the colour to match. The loop
samples random batches, renders them through the field within a band around the surface, applies the
ray's chart transform and minimises the squared error; checkpoints make it resumable.
"""

from __future__ import annotations

import logging
import os
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from scantex.field.appearance import ChartAppearance
from scantex.field.model import FieldConfig, RadianceField
from scantex.field.rays import RayDataset
from scantex.field.volume import BoxNormaliser, render_rays

log = logging.getLogger(__name__)


@dataclass(frozen=True, eq=False)
class FittedField:
    """A trained field with what is needed to query it in world coordinates."""

    field: RadianceField
    appearance: ChartAppearance | None
    normaliser: BoxNormaliser
    n_samples: int
    band: float
    losses: np.ndarray
    seconds: float
    steps_run: int

    @torch.no_grad()
    def surface_colour(self, points: np.ndarray, normals: np.ndarray, device: torch.device) -> np.ndarray:
        """Canonical colour ``(N, 3)`` at surface ``points (N, 3)`` with unit ``normals (N, 3)``.

        The field is rendered along a short ray that crosses the surface along its normal, the way
        training rays crossed it, so a banded (volumetric) field bakes what it renders.
        """
        n = torch.as_tensor(normals, dtype=torch.float32, device=device)
        p = torch.as_tensor(points, dtype=torch.float32, device=device)
        half = 0.5 * self.band
        origins = p + n * half
        rgb, _ = render_rays(self.field, origins, -n, torch.full((len(p),), half, device=device),
                             self.n_samples, self.band, self.normaliser, stratified=False)
        return rgb.clamp(0, 1).cpu().numpy()


Progress = Callable[[int, int], None]


def resolve_device(name: str) -> torch.device:
    """``auto`` (CUDA when present, else the CPU), ``cpu`` or ``cuda``; asking for CUDA without it is an error."""
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    device = torch.device(name)
    if device.type == "cuda" and not torch.cuda.is_available():
        raise ValueError(f"device {name!r} asked for, but this torch build sees no CUDA GPU "
                         f"(torch {torch.__version__}); use --device cpu or auto")
    return device


def fit_field(data: RayDataset, normaliser: BoxNormaliser, field_config: FieldConfig, train,
              n_charts: int, band: float, *, device: torch.device, seed: int = 0, progress: Progress | None = None,
              initial_gains: np.ndarray | None = None, appearance_weights: np.ndarray | None = None,
              checkpoint: Path | None = None, resume: bool = False, run_key: str = "") -> FittedField:
    """Train a :class:`RadianceField` (and per-chart appearance) on ``data``.

    Args:
        train: a :class:`scantex.pipeline.config.TrainConfig`.
        band: width of the sampling band around the surface, world units.
        appearance_weights: ``(n_charts,)`` how much each appearance group counts in fixing the canonical
            appearance (default: its number of rays). Photo mode gives the synthetic views' charts 0, so
            the canonical appearance is the photos' average one.
        checkpoint: file to save state to every ``train.checkpoint_every`` steps; with ``resume``,
            training continues from it when it exists.
        run_key: identifies the run (input and settings) in the checkpoint: resuming from a checkpoint
            with another key is refused.
    """
    torch.manual_seed(seed)
    gen = torch.Generator(device="cpu").manual_seed(seed)
    # built on the CPU (the same starting weights whatever the device), then moved
    with torch.device("cpu"):
        field = RadianceField(field_config)
        counts = torch.bincount(torch.as_tensor(data.chart), minlength=n_charts)
        if appearance_weights is not None:
            counts = torch.as_tensor(appearance_weights, dtype=torch.float32)
        gains0 = torch.as_tensor(initial_gains) if initial_gains is not None else None
        appearance = ChartAppearance(n_charts, counts, gains0) if train.appearance else None
    field = field.to(device)
    appearance = appearance.to(device) if appearance is not None else None
    groups = [{"params": field.parameters(), "lr": train.lr}]
    if appearance is not None:
        groups.append({"params": appearance.parameters(), "lr": train.appearance_lr})
    # fused Adam: ~10 % of a CPU step, ~12x faster than the default on a large hash table alone
    optim = torch.optim.Adam(groups, betas=(0.9, 0.99), eps=1e-15, fused=True)
    # exponential decay to 10 % of the learning rate by the last step
    sched = torch.optim.lr_scheduler.LambdaLR(optim, lambda s: 0.1 ** (s / max(1, train.steps)))

    start, losses = 0, []
    if resume and checkpoint is not None and checkpoint.exists():
        start, losses = _load(checkpoint, device, field, appearance, optim, sched, gen, train.steps, run_key)
        log.info("resuming field training at step %d of %d", start, train.steps)

    origins = torch.as_tensor(data.origins, device=device)
    directions = torch.as_tensor(data.directions, device=device)
    depth = torch.as_tensor(data.depth, device=device)
    target = torch.as_tensor(data.rgb, device=device)
    chart = torch.as_tensor(data.chart, device=device)
    # weighted rays are drawn in proportion to their weight (inverse-CDF sampling) rather than
    # down-weighted in the loss: the same objective in expectation, and a batch is not mostly rays of
    # little weight (photo mode: a few photo rays among many synthetic ones)
    cdf = None
    if data.weight is not None:
        cdf = torch.cumsum(torch.as_tensor(data.weight, dtype=torch.float64, device=device), 0)
        cdf = cdf / cdf[-1]
    R = len(data)
    t0 = time.perf_counter()
    coarse_steps = int(train.coarse_to_fine * train.steps)
    levels = getattr(field.encoding, "set_active_levels", None)
    n_levels = field_config.n_levels
    for step in range(start, train.steps):
        if levels is not None and coarse_steps:
            # coarse to fine: while the field is smooth, only the chart transforms can explain an
            # exposure jump at a seam; fine levels arrive once the transforms have taken it
            levels(train.start_levels + (n_levels - train.start_levels) * min(1.0, step / coarse_steps))
        if cdf is None:
            # drawn from the CPU generator (the same batches on any device), then moved
            idx = torch.randint(0, R, (min(train.batch_rays, R),), generator=gen, device="cpu").to(device)
        else:
            u = torch.rand(min(train.batch_rays, R), generator=gen, dtype=torch.float64, device="cpu").to(device)
            idx = torch.searchsorted(cdf, u).clamp_max(R - 1)
        rgb, _ = render_rays(field, origins[idx], directions[idx], depth[idx], train.n_samples, band,
                             normaliser, stratified=True)
        if appearance is not None:
            rgb = appearance(rgb, chart[idx])
        loss = torch.mean((rgb - target[idx]) ** 2)
        total = loss + (train.appearance_reg * appearance.regulariser() if appearance is not None else 0.0)
        optim.zero_grad(set_to_none=True)
        total.backward()
        optim.step()
        sched.step()
        losses.append(loss.item())
        if progress:
            progress(step + 1, train.steps)
        if checkpoint is not None and (step + 1) % train.checkpoint_every == 0 and step + 1 < train.steps:
            _save(checkpoint, field, appearance, optim, sched, gen, step + 1, losses, run_key)
    seconds = time.perf_counter() - t0
    if levels is not None:
        levels(n_levels)
    field.eval()
    return FittedField(field, appearance, normaliser, train.n_samples, band, np.array(losses), seconds,
                       steps_run=train.steps - start)


def _load(path: Path, device, field, appearance, optim, sched, gen, steps: int,
          run_key: str = "") -> tuple[int, list[float]]:
    """Restore a checkpoint written by :func:`_save`; ``(step, losses)``.

    Raises:
        ScanError: the file is damaged, or was written by a run with other settings or another input
            (the error says to run again without ``--resume``).
    """
    from scantex.errors import ScanError

    try:
        state = torch.load(path, map_location=device, weights_only=True)
        if state.get("run_key", "") != run_key:
            raise ValueError("it was written for another input or other settings")
        field.load_state_dict(state["field"])
        if appearance is not None:
            appearance.load_state_dict(state["appearance"])
        optim.load_state_dict(state["optim"])
        sched.load_state_dict(state["sched"])
        gen.set_state(state["rng"])
        step, losses = int(state["step"]), state["losses"].tolist()
        if not 0 < step <= steps or len(losses) != step:
            raise ValueError(f"it stopped at step {step} of a run of {steps}")
    except Exception as e:  # torch raises anything from pickle errors to RuntimeError on a mismatch
        detail = (str(e).strip().splitlines() or [type(e).__name__])[0][:100]
        raise ScanError(path, f"cannot resume from this checkpoint: it is damaged or from a run with other "
                              f"settings ({type(e).__name__}: {detail}); run again without --resume") from None
    return step, losses


def _save(path: Path, field, appearance, optim, sched, gen, step: int, losses: list[float],
          run_key: str = "") -> None:
    state = {"field": field.state_dict(), "optim": optim.state_dict(), "sched": sched.state_dict(),
             "rng": gen.get_state(), "step": step, "losses": torch.tensor(losses, device="cpu"), "run_key": run_key}
    if appearance is not None:
        state["appearance"] = appearance.state_dict()
    tmp = path.with_suffix(".tmp")
    torch.save(state, tmp)
    os.replace(tmp, path)
