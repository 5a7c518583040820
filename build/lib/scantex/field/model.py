"""The radiance field the views are fitted to: encoding -> MLP with a skip -> density and colour.

As in NeRF, the encoded position is concatenated again into the MLP at layer ``skip_at``; the trunk
outputs a density and a feature, and a small colour head maps the feature (plus the encoded view
direction when ``use_viewdirs``) to RGB. For a surface colour field (one sample per ray at the known
surface) the density is unused and the field is simply position -> colour.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import nn

from scantex.field.encoding import FrequencyEncoding, HashGridEncoding

ENCODINGS = ("hash", "frequency")
DENSITY_ACTIVATIONS = ("softplus", "trunc_exp")


@dataclass(frozen=True)
class FieldConfig:
    """Architecture of the radiance field."""

    encoding: str = "hash"
    """Position encoding: 'hash' (Instant-NGP multiresolution hash grid) or 'frequency' (NeRF sin/cos)."""
    n_freqs: int = 10
    """Frequencies of the position encoding when encoding='frequency'."""
    dir_freqs: int = 4
    """Frequencies of the view-direction encoding (used only with use_viewdirs)."""
    use_viewdirs: bool = False
    """Feed the view direction to the colour head (view-dependent colour); off for a diffuse texture."""
    hidden: int = 64
    """Width of the trunk MLP."""
    n_layers: int = 4
    """Hidden layers of the trunk MLP."""
    skip_at: int = 2
    """Trunk layer that sees the encoded position again (NeRF's skip); 0 disables it."""
    feature_dim: int = 15
    """Width of the feature passed from the trunk to the colour head."""
    colour_hidden: int = 64
    """Width of the colour head's hidden layer."""
    density_activation: str = "trunc_exp"
    """Density activation: 'trunc_exp' (exp with a clamped gradient, Instant-NGP) or 'softplus'."""
    n_levels: int = 16
    """Hash grid: number of resolution levels."""
    features_per_level: int = 2
    """Hash grid: features stored per level."""
    log2_table_size: int = 19
    """Hash grid: log2 of the rows per hashed level."""
    base_resolution: int = 16
    """Hash grid: cells per axis of the coarsest level (over the normalised [0, 1]^3 box)."""
    max_resolution: int = 2048
    """Hash grid: cells per axis of the finest level."""
    bf16: bool = False
    """Run the MLPs under bfloat16 autocast (AMX on CPU); the encoding and outputs stay float32."""

    def __post_init__(self):
        if self.encoding not in ENCODINGS:
            raise ValueError(f"encoding must be one of {ENCODINGS}, got {self.encoding!r}")
        if self.density_activation not in DENSITY_ACTIVATIONS:
            raise ValueError(
                f"density_activation must be one of {DENSITY_ACTIVATIONS}, got {self.density_activation!r}"
            )
        if self.hidden < 1 or self.n_layers < 1 or self.feature_dim < 1 or self.colour_hidden < 1:
            raise ValueError("hidden, n_layers, feature_dim and colour_hidden must be >= 1")
        if not 0 <= self.skip_at < self.n_layers:
            raise ValueError(f"skip_at must be in [0, n_layers), got {self.skip_at} with n_layers={self.n_layers}")


class _TruncExp(torch.autograd.Function):
    """``exp(x)`` whose gradient uses ``exp(min(x, 15))`` so a large density cannot blow up the step."""

    @staticmethod
    def forward(ctx, x: torch.Tensor) -> torch.Tensor:
        ctx.save_for_backward(x)
        return torch.exp(x)

    @staticmethod
    def backward(ctx, grad: torch.Tensor) -> torch.Tensor:
        (x,) = ctx.saved_tensors
        return grad * torch.exp(x.clamp(max=15.0))


def trunc_exp(x: torch.Tensor) -> torch.Tensor:
    return _TruncExp.apply(x)


class RadianceField(nn.Module):
    """Density and colour at points of the normalised scan box.

    ``forward(x, d)``: ``x (N, 3) float32`` in [0, 1]^3, ``d (N, 3)`` unit view directions or None ->
    ``sigma (N,) float32`` >= 0 and ``rgb (N, 3) float32`` in (0, 1).
    """

    def __init__(self, config: FieldConfig = FieldConfig()):
        super().__init__()
        self.config = c = config
        if c.encoding == "hash":
            self.encoding = HashGridEncoding(
                c.n_levels, c.features_per_level, c.log2_table_size, c.base_resolution, c.max_resolution
            )
        else:
            self.encoding = FrequencyEncoding(c.n_freqs)
        self.dir_encoding = FrequencyEncoding(c.dir_freqs) if c.use_viewdirs else None
        enc_dim = self.encoding.out_dim
        widths_in = [enc_dim] + [
            c.hidden + (enc_dim if i == c.skip_at and c.skip_at > 0 else 0) for i in range(1, c.n_layers)
        ]
        self.trunk = nn.ModuleList(nn.Linear(w, c.hidden) for w in widths_in)
        self.density_feature = nn.Linear(c.hidden, 1 + c.feature_dim)
        dir_dim = self.dir_encoding.out_dim if self.dir_encoding is not None else 0
        self.colour_head = nn.Sequential(
            nn.Linear(c.feature_dim + dir_dim, c.colour_hidden), nn.ReLU(), nn.Linear(c.colour_hidden, 3)
        )

    def _mlp(self, encoded: torch.Tensor, d: torch.Tensor | None) -> tuple[torch.Tensor, torch.Tensor]:
        c = self.config
        h = encoded
        for i, layer in enumerate(self.trunk):
            if i == c.skip_at and c.skip_at > 0:
                h = torch.cat([h, encoded.to(h.dtype)], dim=1)
            h = F.relu(layer(h))
        out = self.density_feature(h)  # [N, 1 + feature_dim]
        raw_sigma, feature = out[:, 0], out[:, 1:]
        if self.dir_encoding is not None:
            if d is None:
                raise ValueError("this field uses view directions (use_viewdirs=True); pass d")
            feature = torch.cat([feature, self.dir_encoding(d).to(feature.dtype)], dim=1)
        return raw_sigma, self.colour_head(feature)

    def forward(self, x: torch.Tensor, d: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor]:
        if x.ndim != 2 or x.shape[1] != 3:
            raise ValueError(f"field input must be (N, 3), got {tuple(x.shape)}")
        encoded = self.encoding(x)
        with torch.autocast(x.device.type, dtype=torch.bfloat16, enabled=self.config.bf16):
            raw_sigma, raw_rgb = self._mlp(encoded, d)
        raw_sigma, raw_rgb = raw_sigma.float(), raw_rgb.float()
        if self.config.density_activation == "trunc_exp":
            sigma = trunc_exp(raw_sigma)
        else:
            sigma = F.softplus(raw_sigma)
        return sigma, torch.sigmoid(raw_rgb)

    def colour(self, x: torch.Tensor, d: torch.Tensor | None = None) -> torch.Tensor:
        """RGB ``(N, 3) float32`` at ``x (N, 3)`` in [0, 1]^3 (the surface colour a bake reads)."""
        return self.forward(x, d)[1]


@torch.no_grad()
def evaluate_colour(
    field: RadianceField, x: torch.Tensor, d: torch.Tensor | None = None, chunk: int = 4096
) -> torch.Tensor:
    """:meth:`RadianceField.colour` of many points ``x (N, 3)`` in chunks, without autograd: ``(N, 3) float32``.

    On CPU, chunks of 4k points were never slower than 65k ones and up to 1.7x faster for the 8 x 256 MLP
    (``bench/bench_field.py``; the activations stay in cache), and they bound the memory used.
    """
    out = torch.empty(x.shape[0], 3, dtype=torch.float32, device=x.device)
    for start in range(0, x.shape[0], chunk):
        stop = start + chunk
        out[start:stop] = field.colour(x[start:stop], None if d is None else d[start:stop])
    return out
