"""Packing charts into one square atlas: turn each chart to its smallest bounding box, then shelves.

Written here rather than with xatlas's packer because the charts come from several sources (kept
input shells, planar charts, xatlas charts from a subprocess) and must share one texel density; shelf
packing of tightly turned boxes is deterministic, fast for thousands of charts and simple to test.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from scantex.uv.charts import Charts

log = logging.getLogger(__name__)


@dataclass(frozen=True, eq=False)
class PackedAtlas:
    """Charts placed in a ``size``² atlas.

    Attributes:
        uvs: ``(T, 2) float64`` texture coordinates in [0, 1] (same indexing as the charts' ``uvs``).
        face_uvs: ``(F, 3) int64`` the charts' ``face_uvs``.
        texels_per_metre: the scale every chart was packed at.
        size: atlas width and height in texels.
        utilisation: share of the atlas the charts' bounding boxes (with gutters) cover.
    """

    uvs: np.ndarray
    face_uvs: np.ndarray
    texels_per_metre: float
    size: int
    utilisation: float


def min_area_rotation(points: np.ndarray) -> np.ndarray:
    """``(2, 2)`` rotation turning ``points (N, 2)`` so their bounding box is smallest and wider than tall."""
    from scipy.spatial import ConvexHull, QhullError

    try:
        hull = points[ConvexHull(points).vertices]
    except (QhullError, ValueError):
        hull = points
    if len(hull) < 3:
        return np.eye(2)
    edges = np.roll(hull, -1, axis=0) - hull
    angles = np.unique(np.mod(np.arctan2(edges[:, 1], edges[:, 0]), np.pi / 2))
    best, best_area, best_wide = np.eye(2), np.inf, True
    for a in angles:
        c, s = np.cos(a), np.sin(a)
        R = np.array([[c, s], [-s, c]])  # turns the edge onto the x axis
        q = hull @ R.T
        ext = q.max(axis=0) - q.min(axis=0)
        area = ext[0] * ext[1]
        if area < best_area * (1 - 1e-9):
            best, best_area, best_wide = R, area, ext[0] >= ext[1]
    if not best_wide:
        best = np.array([[0.0, -1.0], [1.0, 0.0]]) @ best  # a quarter turn: rotation, never a mirror
    return best


def shelf_pack(extent: np.ndarray, size: int, gutter: int) -> tuple[float, np.ndarray]:
    """The largest scale (texels per unit) at which boxes of ``extent (n, 2)`` fit ``size``² on shelves.

    Returns the scale and ``(n, 2)`` top-left corners in texels (gutters included in each box).
    """
    n = len(extent)
    order = np.lexsort((-extent[:, 0], -extent[:, 1]))  # tallest first

    def place(scale: float):
        boxes = np.ceil(extent * scale).astype(np.int64) + 2 * gutter
        if boxes[:, 0].max() > size:
            return None
        corner = np.zeros((n, 2), dtype=np.int64)
        x = y = shelf = 0
        for c in order:
            if x + boxes[c, 0] > size:
                x, y, shelf = 0, y + shelf, 0
            corner[c] = (x, y)
            x += boxes[c, 0]
            shelf = max(shelf, boxes[c, 1])
        return corner if y + shelf <= size else None

    area = float(np.maximum(extent, 1e-12).prod(axis=1).sum())
    hi = size / np.sqrt(area)  # every texel used: an upper bound
    lo = 0.0
    best = None
    for _ in range(40):  # bisection on the scale; shelf packing is nearly monotone in it
        mid = 0.5 * (lo + hi)
        corner = place(mid)
        if corner is None:
            hi = mid
        else:
            lo, best = mid, corner
        if hi - lo < 1e-4 * hi:
            break
    if best is None:
        raise ValueError(f"{n} charts do not fit a {size}² atlas with {gutter}-texel gutters")
    return lo, best


def pack(charts: Charts, size: int, gutter: int = 4) -> PackedAtlas:
    """Place every chart in a ``size``² atlas at one common scale, ``gutter`` empty texels around each."""
    F = len(charts.face_uvs)
    C = charts.n_charts
    T = len(charts.uvs)
    chart_of_uv = np.full(T, -1, dtype=np.int64)
    chart_of_uv[charts.face_uvs.ravel()] = np.repeat(charts.chart_of_face, 3)
    local = charts.uvs.copy()
    order = np.argsort(chart_of_uv, kind="stable")
    bounds = np.searchsorted(chart_of_uv[order], np.arange(-1, C + 1))
    lo = np.zeros((C, 2))
    extent = np.zeros((C, 2))
    for c in range(C):
        idx = order[bounds[c + 1]:bounds[c + 2]]
        if idx.size == 0:
            continue
        R = min_area_rotation(local[idx])
        q = local[idx] @ R.T
        local[idx] = q
        lo[c] = q.min(axis=0)
        extent[c] = q.max(axis=0) - lo[c]
    scale, corner = shelf_pack(extent, size, gutter)
    uvs = np.zeros((T, 2))
    used = chart_of_uv >= 0
    ch = chart_of_uv[used]
    x = corner[ch, 0] + gutter + (local[used, 0] - lo[ch, 0]) * scale
    # the chart's y axis points up in the texture: rows grow downwards
    y_down = corner[ch, 1] + gutter + (extent[ch, 1] - (local[used, 1] - lo[ch, 1])) * scale
    uvs[used] = np.stack([x / size, 1.0 - y_down / size], axis=1)
    boxes = (np.ceil(extent * scale) + 2 * gutter).prod(axis=1).sum()
    log.debug("packed %d charts (%d faces) at %.1f texels/m into %d²", C, F, scale, size)
    return PackedAtlas(uvs, charts.face_uvs, float(scale), size, float(boxes / size ** 2))
