"""Per-chart appearance: an affine colour transform per UV chart of the input atlas.

Capture apps texture each chart from a different photo, so charts differ in exposure and white
balance and a line shows where they meet. The field is continuous in 3D and cannot put a jump at a
seam cheaply; a chart's transform can. Fitting ``observed = A_k · colour + b_k`` lets the jumps live in
``(A_k, b_k)`` while the field learns one canonical appearance, which is what gets baked.
"""

from __future__ import annotations

import torch
from torch import nn


class ChartAppearance(nn.Module):
    """``(n_charts, 3, 4)`` affine colour transforms, initialised at identity (or at given gains).

    Args:
        n_charts: number of charts.
        chart_weights: ``(n_charts,)`` share of the training rays in each chart; the regulariser keeps
            the *weighted* mean gain at the identity and the mean offset at zero, which fixes the
            canonical exposure to the scan's average one.
    """

    def __init__(self, n_charts: int, chart_weights: torch.Tensor | None = None,
                 initial_gains: torch.Tensor | None = None):
        super().__init__()
        self.delta = nn.Parameter(torch.zeros(n_charts, 3, 4))
        if initial_gains is not None:  # e.g. from the seams (scantex.atlas.levelling.chart_gains)
            with torch.no_grad():
                self.delta[:, :, :3] = torch.diag_embed(initial_gains.float() - 1)
        w = torch.ones(n_charts) if chart_weights is None else chart_weights.float()
        self.register_buffer("weights", w / w.sum().clamp_min(1e-12))

    def forward(self, rgb: torch.Tensor, chart: torch.Tensor) -> torch.Tensor:
        """Observed colour ``(N, 3)`` of canonical ``rgb (N, 3)`` seen through charts ``chart (N,)``."""
        d = self.delta[chart]  # [N, 3, 4]
        return rgb + torch.einsum("nij,nj->ni", d[:, :, :3], rgb) + d[:, :, 3]

    def regulariser(self) -> torch.Tensor:
        """Squared weighted-mean deviation from identity, plus a small pull of every chart towards it."""
        mean = torch.einsum("k,kij->ij", self.weights, self.delta)
        return (mean**2).sum() + 1e-3 * (self.delta**2).mean()

    @torch.no_grad()
    def canonical(self, observed: torch.Tensor, chart: torch.Tensor) -> torch.Tensor:
        """Invert the transform: the canonical colour ``(N, 3)`` of ``observed (N, 3)`` in ``chart (N,)``."""
        d = self.delta[chart]
        A = torch.eye(3, device=d.device) + d[:, :, :3]
        return torch.linalg.solve(A, (observed - d[:, :, 3]).unsqueeze(-1)).squeeze(-1)

    def gains(self) -> torch.Tensor:
        """``(n_charts, 3)`` diagonal gains, for reports."""
        return 1 + torch.diagonal(self.delta[:, :, :3], dim1=1, dim2=2)
