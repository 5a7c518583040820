"""Training rays: what the field learns from, gathered from the views' G-buffers or the photos.

Plain arrays, no torch: gathering and counting rays needs no learning library, so a run that trains no
field (photo mode's projective texturing) never imports one.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True, eq=False)
class RayDataset:
    """Training rays.

    Attributes:
        origins: ``(R, 3) float32`` ray origins (camera centres), world.
        directions: ``(R, 3) float32`` directions with unit camera-z, so ``depth`` is a ray parameter.
        depth: ``(R,) float32`` the mesh surface's depth along each ray.
        rgb: ``(R, 3) float32`` target colours in [0, 1].
        chart: ``(R,) int64`` the appearance group of each ray: the input atlas chart it sees (synthetic
            views), or its photo (photo mode).
        weight: ``(R,) float32`` weight of each ray in the loss (rays are drawn in proportion to it), or
            ``None`` for all 1.
    """

    origins: np.ndarray
    directions: np.ndarray
    depth: np.ndarray
    rgb: np.ndarray
    chart: np.ndarray
    weight: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.depth)

    def weights(self) -> np.ndarray:
        """``(R,) float32`` loss weights (ones when none were given)."""
        return np.ones(len(self), np.float32) if self.weight is None else self.weight

    @staticmethod
    def concatenate(parts: list[RayDataset]) -> RayDataset:
        arrays = [np.concatenate([getattr(p, k) for p in parts])
                  for k in ("origins", "directions", "depth", "rgb", "chart")]
        weight = None
        if any(p.weight is not None for p in parts):
            weight = np.concatenate([p.weights() for p in parts])
        return RayDataset(*arrays, weight=weight)
