"""Input encodings of the radiance field: NeRF's frequency encoding and Instant-NGP's hash grid.

The hash grid is written for CPU eager speed (measured in ``bench/bench_field.py``):

* all levels are indexed in one vectorised pass: per-axis corner terms are computed once and combined
  into the 8 corners by broadcasting, instead of 8 separate index computations per level;
* coarse levels whose dense grid fits the table are indexed densely (no collisions), finer levels are
  hashed with ``& (T - 1)`` (``T`` a power of two) instead of a modulo;
* the 8-corner gather and weighted sum run in a custom autograd function whose backward scatters the
  table gradient with ``torch.bincount(..., weights=...)``; the default backward of an embedding
  lookup (``embedding_dense_backward``) is several times slower on CPU.

:func:`hash_grid_reference` is the slow, obviously correct twin the tests compare against.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import nn

# Instant-NGP's spatial hash primes (Teschner et al. 2003 with the first prime set to 1 for coherence)
HASH_PRIMES = (1, 2654435761, 805459861)


class FrequencyEncoding(nn.Module):
    """NeRF positional encoding ``[x, sin(2^k pi x), cos(2^k pi x)]`` for ``k = 0 .. n_freqs - 1``.

    Input ``(N, in_dim) float32``; output ``(N, out_dim) float32`` laid out as
    ``[x | sin for every k and axis | cos for every k and axis]`` (frequency-major within each block).
    """

    def __init__(self, n_freqs: int, include_input: bool = True, in_dim: int = 3):
        super().__init__()
        if n_freqs < 0:
            raise ValueError(f"n_freqs must be >= 0, got {n_freqs}")
        self.n_freqs = n_freqs
        self.include_input = include_input
        self.in_dim = in_dim
        self.register_buffer("bands", (2.0 ** torch.arange(n_freqs, dtype=torch.float32)) * math.pi, persistent=False)

    @property
    def out_dim(self) -> int:
        return self.in_dim * (int(self.include_input) + 2 * self.n_freqs)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        N = x.shape[0]
        scaled = (x[:, None, :] * self.bands[:, None]).reshape(N, -1)  # [N, n_freqs * in_dim]
        parts = [x] if self.include_input else []
        return torch.cat(parts + [torch.sin(scaled), torch.cos(scaled)], dim=1)


@dataclass(frozen=True)
class HashGridLayout:
    """Where each level of a multiresolution hash grid lives in one flat ``(rows, F)`` table."""

    resolutions: tuple[int, ...]
    """Cells per axis of each level; a level has ``resolution + 1`` vertices per axis."""
    offsets: tuple[int, ...]
    """First table row of each level (hashed levels first, each at a multiple of ``T``; dense levels after)."""
    n_dense: int
    """Leading levels whose ``(resolution + 1)^3`` vertices fit the table: indexed densely, no hash."""
    table_size: int
    """Rows per hashed level, ``T = 2^log2_table_size``."""
    rows: int
    """Total rows of the table."""

    @property
    def n_levels(self) -> int:
        return len(self.resolutions)


def hash_grid_layout(n_levels: int, log2_table_size: int, base_resolution: int, max_resolution: int) -> HashGridLayout:
    """Resolutions growing geometrically from ``base_resolution`` to ``max_resolution`` (Instant-NGP eq. 2-3).

    A level gets ``min(T, (resolution + 1)^3)`` rows: coarse levels are stored densely and use fewer rows.
    Hashed levels are stored first so each starts at a multiple of ``T``: a hashed row is then
    ``offset | (hash & (T - 1))``, which lets the offset be folded into one axis' term before the XOR.
    """
    if n_levels < 1:
        raise ValueError(f"n_levels must be >= 1, got {n_levels}")
    if not 1 <= base_resolution <= max_resolution:
        raise ValueError(f"need 1 <= base_resolution <= max_resolution, got {base_resolution}, {max_resolution}")
    if not 4 <= log2_table_size <= 28:
        raise ValueError(f"log2_table_size must be in [4, 28], got {log2_table_size}")
    T = 1 << log2_table_size
    growth = math.exp((math.log(max_resolution) - math.log(base_resolution)) / max(n_levels - 1, 1))
    resolutions = tuple(math.floor(base_resolution * growth**level + 1e-6) for level in range(n_levels))
    dense = [(r + 1) ** 3 <= T for r in resolutions]
    n_dense = dense.index(False) if False in dense else n_levels  # resolutions grow, so dense levels lead
    offsets = [0] * n_levels
    row = 0
    for level in range(n_dense, n_levels):
        offsets[level] = row
        row += T
    for level in range(n_dense):
        offsets[level] = row
        row += (resolutions[level] + 1) ** 3
    if row >= 2**31:
        raise ValueError(f"hash grid of {row} rows is too large (rows are indexed with int32)")
    return HashGridLayout(resolutions, tuple(offsets), n_dense, T, row)


def _combine_corners(terms: torch.Tensor, hashed: bool) -> torch.Tensor:
    """Per-axis row terms ``(N, L, 3, 2)`` (lower, upper corner) into ``(N, L, 8)``, corner ``c = kx + 2 ky + 4 kz``."""
    N, L = terms.shape[:2]
    x, y, z = terms[:, :, 0, None, None, :], terms[:, :, 1, None, :, None], terms[:, :, 2, :, None, None]
    combined = ((z ^ y) ^ x) if hashed else ((z + y) + x)  # [N, L, 2, 2, 2] as [kz, ky, kx]; z, y first: half size
    return combined.reshape(N, L, 8)


def hash_grid_corners(x: torch.Tensor, layout: HashGridLayout) -> tuple[torch.Tensor, torch.Tensor]:
    """Table rows and trilinear weights of the 8 corners around each point, at every level.

    Args:
        x: ``(N, 3) float32`` points in [0, 1]^3 (clamped there).
        layout: the grid's levels.

    Returns:
        rows: ``(N, L, 8) int32`` rows of the flat table (level offsets included).
        weights: ``(N, L, 8) float32`` trilinear weights, summing to 1 over the corners; differentiable in ``x``.
    """
    N = x.shape[0]
    L, d = layout.n_levels, layout.n_dense
    device = x.device
    x = x.clamp(0.0, 1.0)
    res = torch.tensor(layout.resolutions, dtype=x.dtype, device=device)
    pos = x[:, None, :] * res[:, None]  # [N, L, 3]
    cell = torch.minimum(pos.detach().floor(), (res - 1)[:, None])  # x == 1 falls in the last cell
    frac = pos - cell  # [N, L, 3] in [0, 1]
    cell = cell.long()
    upper = torch.arange(2, device=device)  # lower and upper corner along an axis

    # Per-axis terms are small ([N, L, 3, 2]); do the int64 arithmetic, masking and level offsets there
    # and only the 8-corner combination at full size, in int32.
    offsets = torch.tensor(layout.offsets, dtype=torch.int64, device=device)
    rows = torch.empty(N, L, 8, dtype=torch.int32, device=device)
    if d > 0:
        side = torch.tensor([r + 1 for r in layout.resolutions[:d]], dtype=torch.int64, device=device)
        strides = torch.stack([torch.ones_like(side), side, side * side], dim=1)[:, :, None]  # [d, 3, 1]
        terms = (cell[:, :d, :, None] + upper) * strides  # [N, d, 3, 2]
        terms[:, :, 0] += offsets[:d, None]
        rows[:, :d] = _combine_corners(terms.int(), hashed=False)
    if d < L:
        primes = torch.tensor(HASH_PRIMES, dtype=torch.int64, device=device)[:, None]  # [3, 1]
        terms = ((cell[:, d:, :, None] + upper) * primes) & (layout.table_size - 1)  # [N, L - d, 3, 2]
        terms[:, :, 0] |= offsets[d:, None]  # offsets are multiples of T, above the masked bits
        # the low bits of the int64 products equal Instant-NGP's uint32 wrap-around hash
        rows[:, d:] = _combine_corners(terms.int(), hashed=True)

    w = torch.stack([1.0 - frac, frac], dim=-1)  # [N, L, 3, 2]
    wx, wy, wz = w[:, :, 0, None, None, :], w[:, :, 1, None, :, None], w[:, :, 2, :, None, None]
    weights = ((wz * wy) * wx).reshape(N, L, 8)
    return rows, weights


def _gather_rows(table: torch.Tensor, rows: torch.Tensor) -> torch.Tensor:
    """``table[rows]`` as ``(*rows.shape, F)``; a row of 2 float32 is moved as one int64 word.

    The 1-D 8-byte gather measured ~1.6x faster than a 2-D ``index_select`` on CPU; the bits are copied
    unchanged, so the result is identical.
    """
    rows_flat = rows.reshape(-1)
    F_ = table.shape[1]
    if table.dtype == torch.float32 and F_ == 2 and table.is_contiguous():
        words = table.view(torch.int64).view(-1)  # [rows]
        out = words.index_select(0, rows_flat).view(torch.float32)
    else:
        out = table.index_select(0, rows_flat)
    return out.view(*rows.shape, F_)


class _InterpolateCorners(torch.autograd.Function):
    """``sum_c weights[..., c] * table[rows[..., c]]`` with a ``bincount`` scatter in the backward."""

    @staticmethod
    def forward(ctx, table: torch.Tensor, rows: torch.Tensor, weights: torch.Tensor) -> torch.Tensor:
        corners = _gather_rows(table, rows)  # [N, L, 8, F]
        ctx.save_for_backward(table, rows, weights)
        return torch.einsum("nlcf,nlc->nlf", corners, weights)

    @staticmethod
    def backward(ctx, grad_out: torch.Tensor):
        table, rows, weights = ctx.saved_tensors
        grad_table = grad_weights = None
        rows_flat = rows.reshape(-1)
        if ctx.needs_input_grad[0]:
            n_rows, F_ = table.shape
            columns = []
            for f in range(F_):  # one 1-D weighted bincount per feature: contiguous weights, no (M, F) copy
                contrib = (weights * grad_out[:, :, f, None]).reshape(-1)  # [N * L * 8]
                columns.append(torch.bincount(rows_flat, weights=contrib, minlength=n_rows).to(table.dtype))
            grad_table = torch.stack(columns, dim=1)
        if ctx.needs_input_grad[2]:
            grad_weights = torch.einsum("nlcf,nlf->nlc", _gather_rows(table, rows), grad_out)
        return grad_table, None, grad_weights


def hash_grid_encode(
    x: torch.Tensor, table: torch.Tensor, layout: HashGridLayout, *, fused_backward: bool = True
) -> torch.Tensor:
    """Encode ``x (N, 3)`` in [0, 1]^3 with the hash grid ``table (rows, F)``: ``(N, L * F)``, level-major.

    ``fused_backward=False`` uses ``F.embedding`` with PyTorch's default backward (the naive eager baseline
    the benchmark compares against); values and gradients are the same.
    """
    N = x.shape[0]
    rows, weights = hash_grid_corners(x, layout)
    if fused_backward:
        features = _InterpolateCorners.apply(table, rows, weights)  # [N, L, F]
    else:
        corners = F.embedding(rows, table)  # [N, L, 8, F]
        features = (corners * weights[..., None]).sum(dim=2)
    return features.reshape(N, -1)


class HashGridEncoding(nn.Module):
    """Instant-NGP multiresolution hash grid with trilinear interpolation (Muller et al. 2022).

    Input ``(N, 3) float32`` in [0, 1]^3; output ``(N, n_levels * features_per_level) float32``, level-major.
    Device-agnostic: the table and index arithmetic follow the input's device.
    """

    def __init__(
        self,
        n_levels: int = 16,
        features_per_level: int = 2,
        log2_table_size: int = 19,
        base_resolution: int = 16,
        max_resolution: int = 2048,
    ):
        super().__init__()
        self.layout = hash_grid_layout(n_levels, log2_table_size, base_resolution, max_resolution)
        self.features_per_level = features_per_level
        self.table = nn.Parameter(torch.empty(self.layout.rows, features_per_level).uniform_(-1e-4, 1e-4))
        # 1 for active levels, 0 for masked ones (coarse-to-fine training); not part of the state
        self.register_buffer("level_mask", torch.ones(self.out_dim), persistent=False)

    def set_active_levels(self, n: float) -> None:
        """Use only the ``n`` coarsest levels (fractional ``n`` fades the next one in)."""
        levels = torch.arange(self.layout.n_levels, dtype=torch.float32, device=self.level_mask.device)
        self.level_mask.copy_(torch.clamp(n - levels, 0.0, 1.0).repeat_interleave(self.features_per_level))

    @property
    def out_dim(self) -> int:
        return self.layout.n_levels * self.features_per_level

    def forward(self, x: torch.Tensor, *, fused_backward: bool = True) -> torch.Tensor:
        if x.ndim != 2 or x.shape[1] != 3:
            raise ValueError(f"hash grid input must be (N, 3), got {tuple(x.shape)}")
        encoded = hash_grid_encode(x.to(self.table.dtype), self.table, self.layout, fused_backward=fused_backward)
        return encoded * self.level_mask


def hash_grid_reference(encoding: HashGridEncoding, x: torch.Tensor) -> torch.Tensor:
    """Slow, obviously correct twin of :class:`HashGridEncoding` (per level, per corner, plain indexing).

    Differentiable w.r.t. the table and ``x`` through PyTorch's default autograd.
    """
    layout = encoding.layout
    table = encoding.table
    T = layout.table_size
    x = x.clamp(0.0, 1.0)
    levels = []
    for level, res in enumerate(layout.resolutions):
        pos = x * res
        cell = torch.clamp(torch.floor(pos.detach()), max=res - 1)
        frac = pos - cell
        i = cell.long()
        dense = (res + 1) ** 3 <= T
        feature = torch.zeros(x.shape[0], table.shape[1], dtype=table.dtype, device=table.device)
        for corner in range(8):
            kx, ky, kz = corner & 1, (corner >> 1) & 1, (corner >> 2) & 1
            ix, iy, iz = i[:, 0] + kx, i[:, 1] + ky, i[:, 2] + kz
            if dense:
                index = ix + iy * (res + 1) + iz * (res + 1) ** 2
            else:
                index = (ix * HASH_PRIMES[0] ^ iy * HASH_PRIMES[1] ^ iz * HASH_PRIMES[2]) % T
            wx = frac[:, 0] if kx else 1 - frac[:, 0]
            wy = frac[:, 1] if ky else 1 - frac[:, 1]
            wz = frac[:, 2] if kz else 1 - frac[:, 2]
            feature = feature + (wx * wy * wz)[:, None] * table[layout.offsets[level] + index]
        levels.append(feature)
    return torch.cat(levels, dim=1)
