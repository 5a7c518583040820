"""Packing charts into one square atlas: turn each chart to its smallest bounding box, then shelves, then
a skyline that may turn boxes a quarter and fills the room beside a tall box that shelves leave empty
(compiled; in Python, where numba is missing, for up to :data:`SKYLINE_MAX_CHARTS` charts).

Written here rather than with xatlas's packer because the charts come from several sources (kept
input shells, planar charts, xatlas charts from a subprocess) and must share one texel density; shelf
and skyline packing of tightly turned boxes are deterministic, fast and simple to test.
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


def shelves(boxes: np.ndarray, order: np.ndarray, size: int) -> np.ndarray | None:
    """``(n, 2)`` top-left corners of boxes ``(n, 2)`` (width, height) put on shelves of a ``size``-wide square
    in ``order``, each shelf as tall as its tallest box; ``None`` when they do not fit its height."""
    corner = np.zeros((len(boxes), 2), dtype=np.int64)
    x = y = shelf = 0
    for c in order:
        if x + boxes[c, 0] > size:
            x, y, shelf = 0, y + shelf, 0
        corner[c] = (x, y)
        x += boxes[c, 0]
        shelf = max(shelf, boxes[c, 1])
    return corner if y + shelf <= size else None


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
        return shelves(boxes, order, size)

    # shelf packing is nearly monotone in the scale
    scale, best = _largest_scale(place, 0.0, _scale_bound(extent, size), steps=40, rtol=1e-4)
    if best is None:
        raise ValueError(f"{n} charts do not fit a {size}² atlas with {gutter}-texel gutters")
    return scale, best


def _scale_bound(extent: np.ndarray, size: int) -> float:
    """The scale at which boxes of ``extent (n, 2)`` would use every texel of ``size``²: an upper bound."""
    return size / np.sqrt(float(np.maximum(extent, 1e-12).prod(axis=1).sum()))


def _largest_scale(place, lo: float, hi: float, steps: int, rtol: float):
    """Bisection between ``lo`` and ``hi`` for the largest scale at which ``place(scale)`` gives a layout
    (``None``: it does not fit), ``steps`` at most, until the bracket is under ``rtol`` of ``hi``: that scale
    and its layout, or ``lo`` and ``None`` where no scale tried fitted."""
    best = None
    for _ in range(steps):
        mid = 0.5 * (lo + hi)
        got = place(mid)
        if got is None:
            hi = mid
        else:
            lo, best = mid, got
        if hi - lo < rtol * hi:
            break
    return lo, best


#: charts packed by :func:`skyline_pack` after the shelves where numba is missing (the search in Python is
#: quadratic in the boxes: 20,000 boxes take about 50 s); compiled, every layout is
SKYLINE_MAX_CHARTS = 400


def skyline_place(boxes: np.ndarray, size: int, by_area: bool) -> tuple[np.ndarray, np.ndarray] | None:
    """Boxes ``(n, 2)`` (width, height in texels) placed in ``size``² bottom-left on a skyline, largest
    first (by area, or by their longer side), each box upright or turned a quarter, whichever lands it lower
    (then further left): ``(n, 2)`` top-left corners and ``(n,)`` whether each is turned, or ``None`` where
    they do not all fit. Compiled (:mod:`scantex.jit`), or :func:`skyline_place_reference` where numba is
    missing: the same layout."""
    from scantex import jit

    kernel = jit.compiled(_skyline_kernel)
    if kernel is None:
        return skyline_place_reference(boxes, size, by_area)
    n = len(boxes)
    boxes = np.ascontiguousarray(boxes, dtype=np.int64)
    corner = np.zeros((n, 2), dtype=np.int64)
    turned = np.zeros(n, dtype=np.bool_)
    scratch = np.zeros((4, 2 * n + 2), dtype=np.int64)  # the skyline and the next one: each box adds 2 segments
    fits = kernel(boxes, _skyline_order(boxes, by_area), int(size), corner, turned, scratch)
    return (corner, turned) if fits else None


def _skyline_order(boxes: np.ndarray, by_area: bool) -> np.ndarray:
    """The order :func:`skyline_place` places ``boxes`` in: largest first (area or longer side), then the
    wider of their shorter sides."""
    first = boxes.prod(axis=1) if by_area else boxes.max(axis=1)
    return np.lexsort((-boxes.min(axis=1), -first)).astype(np.int64)


def _skyline_kernel(boxes, order, size, corner, turned, scratch):
    """:func:`skyline_place`'s kernel: ``corner`` and ``turned`` filled in, and whether every box fitted.
    ``scratch (4, 2n + 2)``: the skyline's segment starts and heights, and the next skyline's."""
    xs, ys, nx, ny = scratch[0], scratch[1], scratch[2], scratch[3]
    xs[0], ys[0] = 0, 0
    m = 1  # the skyline: segment k spans [xs[k], xs[k + 1]) (the last one up to size) at height ys[k]
    for c in order:
        found = False
        best_key_y, best_key_x, best_top, best_w, best_h, best_turn = 0, 0, 0, 0, 0, False
        turns = 2 if boxes[c, 0] != boxes[c, 1] else 1
        for t in range(turns):
            w, h = (boxes[c, 1], boxes[c, 0]) if t == 1 else (boxes[c, 0], boxes[c, 1])
            for k in range(m):
                x = xs[k]
                if x + w > size:
                    break
                top, j = 0, k  # the highest segment under [x, x + w)
                while j < m and xs[j] < x + w:
                    top = max(top, ys[j])
                    j += 1
                if top + h <= size and (not found or top + h < best_key_y
                                        or (top + h == best_key_y and x < best_key_x)):
                    found = True
                    best_key_y, best_key_x, best_top, best_w, best_h, best_turn = top + h, x, top, w, h, t == 1
        if not found:
            return False
        x, top, w, h = best_key_x, best_top, best_w, best_h
        corner[c, 0], corner[c, 1], turned[c] = x, top, best_turn
        # the box's far side becomes the skyline over [x, x + w): (start, height) of every segment after it,
        # neighbours at one height joined
        n = 0
        for k in range(m):
            a, b, y = xs[k], xs[k + 1] if k + 1 < m else size, ys[k]
            for part in range(3):
                if part == 0 and a < x:
                    start, height = a, y  # (the part of) a segment before the box
                elif part == 1 and a <= x < b:
                    start, height = x, top + h
                elif part == 2 and b > x + w:
                    start, height = max(a, x + w), y  # (the part of) a segment after it
                else:
                    continue
                if n == 0 or height != ny[n - 1]:
                    nx[n], ny[n] = start, height
                    n += 1
        for k in range(n):
            xs[k], ys[k] = nx[k], ny[k]
        m = n
    return True


def skyline_place_reference(boxes: np.ndarray, size: int, by_area: bool) -> tuple[np.ndarray, np.ndarray] | None:
    """:func:`skyline_place` in plain Python (where numba is missing, and the kernel's twin in the tests)."""
    n = len(boxes)
    order = _skyline_order(boxes, by_area)
    xs, ys = [0], [0]  # the skyline: segment k spans [xs[k], xs[k + 1]) at height ys[k]
    corner = np.zeros((n, 2), dtype=np.int64)
    turned = np.zeros(n, dtype=bool)
    for c in order:
        best = None
        for turn in (False, True) if boxes[c, 0] != boxes[c, 1] else (False,):
            w, h = (boxes[c, 1], boxes[c, 0]) if turn else (boxes[c, 0], boxes[c, 1])
            for k in range(len(xs)):
                x = xs[k]
                if x + w > size:
                    break
                top, j = 0, k  # the highest segment under [x, x + w)
                while j < len(xs) and xs[j] < x + w:
                    top = max(top, ys[j])
                    j += 1
                if top + h <= size and (best is None or (top + h, x) < best[0]):
                    best = ((top + h, x), x, top, w, h, turn)
        if best is None:
            return None
        _, x, top, w, h, turn = best
        corner[c], turned[c] = (x, top), turn
        # the box's far side becomes the skyline over [x, x + w): (start, height) of every segment after it
        segments = []
        for a, b, y in zip(xs, xs[1:] + [size], ys):
            if a < x:
                segments.append((a, y))  # (the part of) a segment before the box
            if a <= x < b:
                segments.append((x, top + h))
            if b > x + w:
                segments.append((max(a, x + w), y))  # (the part of) a segment after it
        xs, ys = [segments[0][0]], [segments[0][1]]
        for a, y in segments[1:]:
            if y != ys[-1]:  # neighbours at one height are one segment
                xs.append(a)
                ys.append(y)
    return corner, turned


def skyline_compiled() -> bool:
    """Whether :func:`skyline_place` runs compiled (every layout is then packed on a skyline too)."""
    from scantex import jit

    return jit.compiled(_skyline_kernel) is not None


def skyline_pack(extent: np.ndarray, size: int, gutter: int, floor: float) -> tuple[float, np.ndarray, np.ndarray]:
    """The largest scale above ``floor`` (the shelves' scale) at which :func:`skyline_place` fits boxes of
    ``extent (n, 2)`` in ``size``², in either order, found by bisection: the scale, ``(n, 2)`` top-left
    corners (gutters included) and ``(n,)`` turned flags; ``floor`` and ``None`` corners where the skyline
    does no better. (Neither order wins everywhere: a square beside strips wants area first, the real scans'
    layouts gain 0-3 % either way.)"""
    scale, best = floor, None
    for by_area in (True, False):
        tried, got = _largest_scale(
            lambda mid, by_area=by_area: skyline_place(np.ceil(extent * mid).astype(np.int64) + 2 * gutter, size,
                                                        by_area),
            scale, _scale_bound(extent, size), steps=12, rtol=1e-3)
        if got is not None:
            scale, best = tried, got
    if best is None:
        return floor, None, None
    return scale, best[0], best[1]


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
    if C <= SKYLINE_MAX_CHARTS or skyline_compiled():
        sky_scale, sky_corner, turned = skyline_pack(extent, size, gutter, scale)
        if sky_corner is not None:
            scale, corner = sky_scale, sky_corner
            for c in np.flatnonzero(turned):  # a quarter turn (a rotation, never a mirror), then its box again
                idx = order[bounds[c + 1]:bounds[c + 2]]
                local[idx] = local[idx] @ np.array([[0.0, 1.0], [-1.0, 0.0]])
                lo[c] = local[idx].min(axis=0)
                extent[c] = local[idx].max(axis=0) - lo[c]
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
