"""The texel map: for every texel of an atlas, the face and barycentrics it shows.

Made by rasterising the UV triangles into texel space. The fast path is a compiled scan-conversion
(:mod:`scantex.jit`: each triangle's texel box, its texel centres tested by their barycentrics; about 0.05 s for
the bolster's 2048^2 atlas, where Embree took 1.1 s of CPU). Where numba is missing, one ray is cast per texel centre
at the UV triangles laid flat in a plane (Embree as a 2D rasteriser: about 4x faster than numpy
scan-conversion). :func:`texel_map_reference` is the slow, obviously correct twin the tests compare both with.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

from scantex.views.raycast import RayCaster, interpolate

#: texel rows per ray-casting strip (bounded memory for 8192^2 atlases)
ROWS_PER_STRIP = 512
#: the side, in texels, of the cells that say where a strip's rays are cast (where a triangle's box reaches)
BOX_BLOCK = 8
#: a strip whose cells reached by triangles' boxes are at most this share of it casts rays only there
SPARSE_STRIP = 0.5


@dataclass(frozen=True, eq=False)
class TexelMap:
    """Which surface point each texel of a ``(height, width)`` atlas shows.

    Attributes:
        face_id: ``(H, W) int32`` face index into the scan, -1 for texels no triangle covers.
        bary: ``(H, W, 2) float32`` barycentrics ``(u, v)``: point = (1-u-v)·p0 + u·p1 + v·p2.
    """

    face_id: np.ndarray
    bary: np.ndarray

    @property
    def mask(self) -> np.ndarray:
        return self.face_id >= 0

    @property
    def shape(self) -> tuple[int, int]:
        return self.face_id.shape

    def points(self, corner_values: np.ndarray) -> np.ndarray:
        """Interpolate ``(F, 3, C)`` corner values at the covered texels: ``(N, C)`` in row-major order."""
        m = self.mask
        return interpolate(self.face_id[m], self.bary[m], corner_values)


def uv_to_pixel(uv: np.ndarray, width: int, height: int) -> np.ndarray:
    """UVs to continuous pixel coordinates whose integers are texel centres."""
    return np.stack([uv[..., 0] * width - 0.5, (1.0 - uv[..., 1]) * height - 0.5], axis=-1)


def texel_strips(triangle_uvs: np.ndarray, width: int, height: int, faces: np.ndarray | None = None, *,
                 rows: int | None = None) -> Iterator[tuple[int, TexelMap]]:
    """Rasterise UV triangles into a ``height x width`` atlas, ``rows`` texel rows at a time.

    Yields ``(y0, strip)``: the :class:`TexelMap` of atlas rows ``y0 .. y0 + strip.shape[0]``, top to
    bottom. Memory is bounded by one strip whatever the atlas size (the whole map of an 8192^2 atlas
    is 0.8 GB). Arguments as :func:`texel_map`; ``rows`` defaults to :data:`ROWS_PER_STRIP`.
    """
    from scantex import jit

    rows = rows or ROWS_PER_STRIP
    selected = np.arange(len(triangle_uvs)) if faces is None else np.asarray(faces)
    kernel = jit.compiled(_rasterise) if selected.size else None
    if kernel is not None:
        yield from _rasterised_strips(kernel, triangle_uvs, width, height, selected, rows)
        return
    caster = None
    if selected.size:
        pix = uv_to_pixel(triangle_uvs[selected], width, height)  # [f, 3, 2]
        flat = np.concatenate([pix.reshape(-1, 2), np.zeros((pix.shape[0] * 3, 1))], axis=1)
        caster = RayCaster(flat, np.arange(flat.shape[0]).reshape(-1, 3))
        # each triangle's texel box, a texel wider all round than the centres it can cover
        with np.errstate(invalid="ignore"):
            lo = np.floor(pix.min(axis=1)) - 1
            hi = np.ceil(pix.max(axis=1)) + 1
        finite = np.isfinite(lo).all(axis=1) & np.isfinite(hi).all(axis=1)
        lo = np.clip(np.where(finite[:, None], lo, 0), 0, [width - 1, height - 1]).astype(np.int64)
        hi = np.clip(np.where(finite[:, None], hi, -1), -1, [width - 1, height - 1]).astype(np.int64)
    xs = np.arange(width, dtype=np.float64)
    for y0 in range(0, height, rows):
        y1 = min(y0 + rows, height)
        if caster is None:
            yield y0, TexelMap(np.full((y1 - y0, width), -1, np.int32), np.zeros((y1 - y0, width, 2), np.float32))
            continue
        reached = _in_boxes(lo, hi, y0, y1, width)
        # rays only where a triangle's box reaches when that is a small part of the strip (an app's atlas is
        # mostly empty: the bathroom's 8192^2 is 14 % covered, its boxes' cells 18 %); else one ray a texel
        # (a ray that misses costs little, picking the others more)
        at = np.flatnonzero(reached) if reached.mean() <= SPARSE_STRIP else None
        # each ray's origin written column by column (np.stack of the columns took 0.4 s of the bolster's bake)
        origins = np.empty(((y1 - y0) * width if at is None else len(at), 3))
        if at is None:
            grid = origins.reshape(y1 - y0, width, 3)  # [rows, width, 3], a view
            grid[:, :, 0] = xs
            grid[:, :, 1] = np.arange(y0, y1, dtype=np.float64)[:, None]
        else:
            origins[:, 0] = at % width
            origins[:, 1] = at // width + y0
        origins[:, 2] = 1.0
        hits = caster.intersect(origins, np.broadcast_to(np.array([0.0, 0.0, -1.0]), origins.shape))
        hit = np.flatnonzero(hits.face_id >= 0)
        fid = np.full((y1 - y0) * width, -1, np.int32)
        fid[hit if at is None else at[hit]] = selected[hits.face_id[hit]]
        if at is None:
            bary = hits.bary
        else:
            bary = np.zeros(((y1 - y0) * width, 2), np.float32)
            bary[at] = hits.bary
        yield y0, TexelMap(fid.reshape(y1 - y0, width), bary.reshape(y1 - y0, width, 2))


def _rasterised_strips(kernel, triangle_uvs: np.ndarray, width: int, height: int, selected: np.ndarray,
                       rows: int) -> Iterator[tuple[int, TexelMap]]:
    """:func:`texel_strips` by the compiled scan-conversion ``kernel`` (:func:`_rasterise`)."""
    pix = np.ascontiguousarray(uv_to_pixel(triangle_uvs[selected], width, height), np.float64)  # [f, 3, 2]
    with np.errstate(invalid="ignore"):
        top, bottom = pix[:, :, 1].min(axis=1), pix[:, :, 1].max(axis=1)  # NaN for a face without finite UVs
    names = selected.astype(np.int32)
    for y0 in range(0, height, rows):
        y1 = min(y0 + rows, height)
        drawn = np.flatnonzero((bottom >= y0 - 1) & (top <= y1))  # NaN compares false: left out
        face_id = np.full((y1 - y0) * width, -1, np.int32)
        bary = np.zeros(((y1 - y0) * width, 2), np.float32)
        kernel(pix, drawn, names, y0, y1, width, face_id, bary)
        yield y0, TexelMap(face_id.reshape(y1 - y0, width), bary.reshape(y1 - y0, width, 2))


def _rasterise(pix, drawn, names, y0, y1, width, face_id, bary):
    """The kernel of :func:`_rasterised_strips`: triangles ``pix[drawn]`` (``(f, 3, 2)`` corner pixels, integers at
    texel centres) drawn into atlas rows ``y0 .. y1`` (``face_id``, ``bary``: ``((y1 - y0) * width, ...)``), each
    texel centre inside a triangle getting its name and barycentrics ``(u, v)`` (the point is ``(1-u-v) p0 + u p1
    + v p2``). A texel on an edge is inside (within rounding: a centre on the edge two triangles share is drawn
    by one of them, never by neither); where triangles overlap, the later one drawn wins."""
    eps = 1e-7
    for j in range(drawn.shape[0]):
        f = drawn[j]
        ax, ay = pix[f, 0, 0], pix[f, 0, 1]
        bx, by = pix[f, 1, 0], pix[f, 1, 1]
        cx, cy = pix[f, 2, 0], pix[f, 2, 1]
        det = (bx - ax) * (cy - ay) - (cx - ax) * (by - ay)
        if not (det != 0 and np.isfinite(det)):  # degenerate, or not finite
            continue
        x_lo = max(int(np.ceil(min(ax, bx, cx) - eps)), 0)
        x_hi = min(int(np.floor(max(ax, bx, cx) + eps)), width - 1)
        y_lo = max(int(np.ceil(min(ay, by, cy) - eps)), y0)
        y_hi = min(int(np.floor(max(ay, by, cy) + eps)), y1 - 1)
        for y in range(y_lo, y_hi + 1):
            dy = y - ay
            for x in range(x_lo, x_hi + 1):
                dx = x - ax
                u = (dx * (cy - ay) - (cx - ax) * dy) / det
                v = ((bx - ax) * dy - dx * (by - ay)) / det
                if u >= -eps and v >= -eps and u + v <= 1 + eps:
                    at = (y - y0) * width + x
                    face_id[at] = names[f]
                    bary[at, 0] = u
                    bary[at, 1] = v


def _in_boxes(lo: np.ndarray, hi: np.ndarray, y0: int, y1: int, width: int, block: int = BOX_BLOCK) -> np.ndarray:
    """``((y1 - y0) * width,) bool``: the texels of rows ``y0 .. y1`` in a ``block`` x ``block`` cell of texels
    that at least one box ``lo .. hi`` reaches (``(n, 2)`` inclusive texel corners, x then y; an empty box has
    ``hi < lo``): every texel of every box, and a few around them. Boxes are marked at their cells' corners and
    summed (two cumulative sums over the cells, not over every texel)."""
    h = y1 - y0
    box = np.flatnonzero((lo[:, 1] < y1) & (hi[:, 1] >= y0) & (hi[:, 0] >= lo[:, 0]))
    top = (np.maximum(lo[box, 1], y0) - y0) // block
    bottom = (np.minimum(hi[box, 1], y1 - 1) - y0) // block + 1
    left, right = lo[box, 0] // block, hi[box, 0] // block + 1
    rows, cols = -(-h // block), -(-width // block)
    marks = np.zeros((rows + 1) * (cols + 1), np.int64)
    for rows_at, cols_at, sign in ((top, left, 1), (top, right, -1), (bottom, left, -1), (bottom, right, 1)):
        marks += sign * np.bincount(rows_at * (cols + 1) + cols_at, minlength=marks.size)
    cells = marks.reshape(rows + 1, cols + 1).cumsum(axis=0).cumsum(axis=1)[:rows, :cols] > 0
    return np.repeat(np.repeat(cells, block, axis=0), block, axis=1)[:h, :width].reshape(-1)


def texel_map(triangle_uvs: np.ndarray, width: int, height: int, faces: np.ndarray | None = None) -> TexelMap:
    """Rasterise UV triangles into a ``height x width`` atlas.

    Args:
        triangle_uvs: ``(F, 3, 2)`` UVs of every face's corners.
        width, height: atlas size in texels.
        faces: indices of the faces to rasterise (e.g. one material's); default all.

    Where triangles overlap in UV space, one of them wins (the texel then shows one of the surface
    points mapped there, as any renderer of that atlas would). The whole map is ``12 * width *
    height`` bytes: large atlases are better streamed with :func:`texel_strips`.
    """
    face_id = np.full((height, width), -1, dtype=np.int32)
    bary = np.zeros((height, width, 2), dtype=np.float32)
    for y0, strip in texel_strips(triangle_uvs, width, height, faces):
        y1 = y0 + strip.shape[0]
        face_id[y0:y1] = strip.face_id
        bary[y0:y1] = strip.bary
    return TexelMap(face_id, bary)


def covered_texels(triangle_uvs: np.ndarray, width: int, height: int, faces: np.ndarray | None = None) -> np.ndarray:
    """``(H, W) bool``: the texels some triangle covers (:func:`texel_map`'s mask, streamed: 1 byte a texel)."""
    mask = np.zeros((height, width), dtype=bool)
    for y0, strip in texel_strips(triangle_uvs, width, height, faces):
        mask[y0:y0 + strip.shape[0]] = strip.mask
    return mask


def rasterised_cheaply() -> bool:
    """Whether the compiled scan-conversion draws the texel maps (a few hundredths of a second for a 2048^2
    atlas, against a second of CPU for Embree's 2-D ray casts where numba is missing): whether drawing an atlas's
    texel map twice costs next to nothing."""
    from scantex import jit

    return jit.compiled(_rasterise) is not None


def texel_map_reference(triangle_uvs: np.ndarray, width: int, height: int) -> TexelMap:
    """Per-triangle loop rasteriser: slow, plainly correct; for tests only."""
    face_id = np.full((height, width), -1, dtype=np.int32)
    bary = np.zeros((height, width, 2), dtype=np.float32)
    pix = uv_to_pixel(triangle_uvs, width, height)
    for f, (a, b, c) in enumerate(pix):
        lo = np.maximum(np.floor(np.minimum(np.minimum(a, b), c)), 0).astype(int)
        hi = np.minimum(np.ceil(np.maximum(np.maximum(a, b), c)), [width - 1, height - 1]).astype(int)
        if (hi < lo).any():
            continue
        ys, xs = np.mgrid[lo[1]:hi[1] + 1, lo[0]:hi[0] + 1]
        p = np.stack([xs.ravel(), ys.ravel()], axis=1).astype(np.float64)
        m = np.array([b - a, c - a]).T  # columns: edges
        det = np.linalg.det(m)
        if abs(det) < 1e-12:
            continue
        uv = np.linalg.solve(m, (p - a).T).T  # weights of corners 1 and 2
        inside = (uv[:, 0] >= 0) & (uv[:, 1] >= 0) & (uv.sum(axis=1) <= 1)
        face_id[ys.ravel()[inside], xs.ravel()[inside]] = f
        bary[ys.ravel()[inside], xs.ravel()[inside]] = uv[inside]
    return TexelMap(face_id, bary)
