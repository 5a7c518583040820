"""Mesh-guided sampling and volume rendering.

The scan's geometry is known, so every pixel's G-buffer gives the depth of the surface it sees. Samples
are placed only in a narrow band around that depth: a few samples per ray instead of NeRF's hundreds,
which is what makes fitting affordable on a CPU. With one sample per ray the field degenerates to a
surface colour field, ``rgb = field(surface point)``.

Distances here are metric (metres along unit directions); :func:`render_rays` converts the G-buffer's
camera-z depth along non-unit pixel directions.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from scantex.field.model import RadianceField


@dataclass(frozen=True)
class BoxNormaliser:
    """Maps world points in the box ``[lo, hi]`` to the field's [0, 1]^3."""

    lo: tuple[float, float, float]
    """World corner that maps to (0, 0, 0)."""
    hi: tuple[float, float, float]
    """World corner that maps to (1, 1, 1)."""

    def __post_init__(self):
        if len(self.lo) != 3 or len(self.hi) != 3 or not all(h > l for l, h in zip(self.lo, self.hi)):
            raise ValueError(f"BoxNormaliser needs 3-vectors with hi > lo, got lo={self.lo}, hi={self.hi}")

    @classmethod
    def from_points(cls, points, margin: float = 0.05, cubic: bool = True) -> BoxNormaliser:
        """Box around ``points (N, 3)`` grown by ``margin`` (a fraction of the largest extent) on every side.

        ``cubic`` makes the box a cube around the points' centre, so grid cells stay cubes in world units
        (a hash grid's resolution then means the same cell size along every axis).
        """
        p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        if len(p) == 0 or not np.isfinite(p).all():
            raise ValueError("BoxNormaliser.from_points needs at least one finite point")
        lo, hi = p.min(axis=0), p.max(axis=0)
        extent = max(float((hi - lo).max()), 1e-6)
        pad = margin * extent
        if cubic:
            centre = (lo + hi) / 2
            half = extent / 2 + pad
            lo, hi = centre - half, centre + half
        else:
            lo, hi = lo - pad, hi + pad
        return cls(tuple(float(v) for v in lo), tuple(float(v) for v in hi))

    @property
    def scale(self) -> float:
        """Largest side of the box in world units (a normalised cell of size ``1/R`` is ``scale/R`` metres)."""
        return max(h - l for l, h in zip(self.lo, self.hi))

    def apply(self, points: torch.Tensor) -> torch.Tensor:
        """``(..., 3)`` world points -> ``(..., 3)`` normalised points (inside [0, 1] for points in the box)."""
        lo = torch.tensor(self.lo, dtype=points.dtype, device=points.device)
        hi = torch.tensor(self.hi, dtype=points.dtype, device=points.device)
        return (points - lo) / (hi - lo)


def band_samples(
    depth: torch.Tensor,
    n_samples: int,
    band_width: float,
    *,
    stratified: bool,
    generator: torch.Generator | None = None,
) -> torch.Tensor:
    """Sample distances ``(R, S) float32`` inside ``[depth - band/2, depth + band/2]`` around the surface.

    The band is split into ``S`` equal bins; training (``stratified``) takes one uniform sample per bin,
    evaluation takes the bin midpoints. ``S == 1`` puts the sample exactly at the surface.
    """
    if n_samples < 1:
        raise ValueError(f"n_samples must be >= 1, got {n_samples}")
    if band_width < 0:
        raise ValueError(f"band_width must be >= 0, got {band_width}")
    R = depth.shape[0]
    if n_samples == 1:
        return depth[:, None].clone()
    bins = torch.arange(n_samples, dtype=depth.dtype, device=depth.device)
    if stratified:
        offsets = bins + torch.rand(R, n_samples, dtype=depth.dtype, device=depth.device, generator=generator)
    else:
        offsets = (bins + 0.5).expand(R, n_samples)
    return depth[:, None] - band_width / 2 + offsets * (band_width / n_samples)


def volume_render(
    sigma: torch.Tensor,
    rgb: torch.Tensor,
    t: torch.Tensor,
    *,
    background: torch.Tensor | None = None,
    last_delta: float | None = None,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Alpha-composite samples along rays (NeRF eq. 3).

    Args:
        sigma: ``(R, S)`` density at the samples (per metre).
        rgb: ``(R, S, 3)`` colour at the samples.
        t: ``(R, S)`` increasing sample distances (metres).
        background: ``(3,)`` or ``(R, 3)`` colour behind the band, weighted by ``1 - opacity``; None adds nothing.
        last_delta: length given to the last sample; default the band's mean spacing ``(t_S - t_1) / (S - 1)``
            (equal to ``band / S`` for :func:`band_samples` midpoints).

    Returns:
        rgb: ``(R, 3)``; weights: ``(R, S)``; opacity: ``(R,)`` (the weights' sum).
        With ``S == 1`` (a surface field) the sample's colour is returned with weight 1.
    """
    R, S = sigma.shape
    if S == 1:
        ones = torch.ones(R, 1, dtype=rgb.dtype, device=rgb.device)
        return rgb[:, 0], ones, ones[:, 0]
    deltas = t[:, 1:] - t[:, :-1]  # [R, S - 1]
    if last_delta is None:
        last = (t[:, -1:] - t[:, :1]) / (S - 1)
    else:
        last = torch.full_like(t[:, :1], float(last_delta))
    deltas = torch.cat([deltas, last], dim=1)  # [R, S]
    optical = sigma * deltas
    alpha = 1.0 - torch.exp(-optical)
    # transmittance before each sample, exp(-sum of earlier optical depths): no cumprod of (1 - alpha)
    transmittance = torch.exp(-(torch.cumsum(optical, dim=1) - optical))
    weights = alpha * transmittance
    colour = (weights[..., None] * rgb).sum(dim=1)
    opacity = weights.sum(dim=1)
    if background is not None:
        colour = colour + (1.0 - opacity)[:, None] * background
    return colour, weights, opacity


def volume_render_reference(
    sigma: torch.Tensor, rgb: torch.Tensor, t: torch.Tensor, *, background=None, last_delta: float | None = None
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Slow twin of :func:`volume_render`: a loop over rays and samples with ``T *= 1 - alpha``."""
    R, S = sigma.shape
    colour = torch.zeros(R, 3, dtype=rgb.dtype, device=rgb.device)
    weights = torch.zeros(R, S, dtype=sigma.dtype, device=sigma.device)
    for r in range(R):
        transmittance = 1.0
        for i in range(S):
            if S == 1:
                alpha = 1.0
            elif i < S - 1:
                alpha = 1.0 - float(torch.exp(-sigma[r, i] * (t[r, i + 1] - t[r, i])))
            else:
                delta = (t[r, -1] - t[r, 0]) / (S - 1) if last_delta is None else last_delta
                alpha = 1.0 - float(torch.exp(-sigma[r, i] * delta))
            weights[r, i] = transmittance * alpha
            colour[r] += weights[r, i] * rgb[r, i]
            transmittance *= 1.0 - alpha
        if background is not None and S > 1:
            bg = torch.as_tensor(background, dtype=rgb.dtype, device=rgb.device)
            colour[r] += (1.0 - weights[r].sum()) * (bg if bg.ndim == 1 else bg[r])
    return colour, weights, weights.sum(dim=1)


def render_rays(
    field: RadianceField,
    origins: torch.Tensor,
    directions: torch.Tensor,
    depth: torch.Tensor,
    n_samples: int,
    band_width: float,
    normaliser: BoxNormaliser,
    stratified: bool,
    *,
    background: torch.Tensor | None = None,
    generator: torch.Generator | None = None,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Render rays that hit the mesh, sampling the field only in a band around the surface.

    Args:
        field: the radiance field (inputs in [0, 1]^3).
        origins: ``(R, 3)`` or ``(3,)`` world ray origins.
        directions: ``(R, 3)`` world directions, not necessarily unit: the surface is at
            ``origins + depth * directions`` (the G-buffer's camera-z depth with unit-z pixel rays).
        depth: ``(R,)`` surface parameter along ``directions``.
        n_samples: samples per ray (1 = surface colour field).
        band_width: band thickness in world units (metres), centred on the surface.
        normaliser: world -> [0, 1]^3.
        stratified: jittered samples (training) or bin midpoints (evaluation).

    Returns:
        rgb: ``(R, 3) float32``; weights: ``(R, S) float32``.
    """
    R = directions.shape[0]
    norm = directions.norm(dim=1, keepdim=True).clamp_min(1e-12)
    unit = directions / norm  # [R, 3]
    t = band_samples(depth * norm[:, 0], n_samples, band_width, stratified=stratified, generator=generator)  # [R, S]
    points = origins.reshape(-1, 1, 3) + t[..., None] * unit[:, None, :]  # [R, S, 3]
    x = normaliser.apply(points).reshape(R * n_samples, 3)
    d = unit[:, None, :].expand(R, n_samples, 3).reshape(R * n_samples, 3) if field.config.use_viewdirs else None
    sigma, rgb = field(x, d)
    sigma = sigma.reshape(R, n_samples)
    rgb = rgb.reshape(R, n_samples, 3)
    colour, weights, _ = volume_render(sigma, rgb, t, background=background)
    return colour, weights
