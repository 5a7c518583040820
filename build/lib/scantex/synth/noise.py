"""Smooth random fields and integer hashes for procedural textures.

A field is a periodic lattice of Gaussian-smoothed white noise, read back by bilinear interpolation
(value noise). Sampling a precomputed lattice costs a handful of numpy operations per point, several
times less than hashing lattice corners on the fly, which is what lets the albedo of a 4096² atlas be
evaluated in seconds.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage


@dataclass(frozen=True, eq=False)
class NoiseField:
    """A smooth, periodic random field on the plane with zero mean and unit variance.

    Attributes:
        lattice: ``(n, n) float32`` values at the lattice nodes, ``n`` a power of two.
        spacing: metres between lattice nodes; the field repeats every ``n * spacing`` metres.
    """

    lattice: np.ndarray
    spacing: float

    @classmethod
    def random(cls, rng: np.random.Generator, spacing: float, n: int = 256, smooth: float = 1.5) -> NoiseField:
        """White noise smoothed by a Gaussian of ``smooth`` lattice cells, normalised to unit variance."""
        if n & (n - 1):
            raise ValueError(f"lattice size must be a power of two, got {n}")
        lattice = ndimage.gaussian_filter(rng.standard_normal((n, n)), smooth, mode="wrap")
        lattice = (lattice - lattice.mean()) / lattice.std()
        return cls(lattice.astype(np.float32), float(spacing))

    def __call__(self, u: np.ndarray, v: np.ndarray) -> np.ndarray:
        """Field values ``(N,) float32`` at plane coordinates ``u, v (N,)`` in metres."""
        n = self.lattice.shape[0]
        x = np.asarray(u, dtype=np.float32) * np.float32(1.0 / self.spacing)
        y = np.asarray(v, dtype=np.float32) * np.float32(1.0 / self.spacing)
        xf = np.floor(x)
        yf = np.floor(y)
        fx = x - xf
        fy = y - yf
        mask = n - 1
        i0 = xf.astype(np.int64) & mask
        j0 = yf.astype(np.int64) & mask
        i1 = (i0 + 1) & mask
        row0 = j0 * n
        row1 = ((j0 + 1) & mask) * n
        flat = self.lattice.reshape(-1)
        top = flat.take(row0 + i0) * (1 - fx) + flat.take(row0 + i1) * fx
        bottom = flat.take(row1 + i0) * (1 - fx) + flat.take(row1 + i1) * fx
        return top * (1 - fy) + bottom * fy


def hash_uniform(a: np.ndarray, b: np.ndarray, salt: int) -> np.ndarray:
    """A deterministic pseudo-random number in [0, 1) ``(N,) float32`` per integer pair ``(a, b)``."""
    h = (np.asarray(a, dtype=np.int64) * 73856093) ^ (np.asarray(b, dtype=np.int64) * 19349663)
    h ^= (salt * 83492791) & 0x7FFFFFFF
    h = h.astype(np.uint32)
    # murmur3 finaliser: spreads neighbouring integers over the whole range
    h ^= h >> np.uint32(16)
    h *= np.uint32(0x85EBCA6B)
    h ^= h >> np.uint32(13)
    h *= np.uint32(0xC2B2AE35)
    h ^= h >> np.uint32(16)
    return (h >> np.uint32(8)).astype(np.float32) * np.float32(1.0 / (1 << 24))


def smoothstep(edge0: float, edge1: float, x: np.ndarray) -> np.ndarray:
    """Hermite step from 0 at ``edge0`` to 1 at ``edge1`` (``edge0 > edge1`` gives the falling step)."""
    t = np.clip((x - np.float32(edge0)) * np.float32(1.0 / (edge1 - edge0)), 0.0, 1.0)
    return t * t * (3 - 2 * t)
