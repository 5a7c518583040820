"""Parameterising one chart: planar projection, least-squares conformal maps, and their distortion.

A chart is given as its own small mesh: ``points (N, 3)`` and ``triangles (n, 3)`` into them. Maps
return ``(N, 2)`` coordinates in metres (a planar projection is exactly that; an LSCM is scaled so its
UV area equals the surface area).

Distortion is measured per face by the singular values ``σ1 >= σ2`` of the Jacobian from the face's
own 2D frame to UV, and per chart by Sander et al.'s L2 stretch after scaling the chart's UV area to its
surface area: ``sqrt(Σ A (Γ1² + Γ2²) / 2 / Σ A)`` with ``Γ = 1 / σ`` the singular values of the inverse
map (how far one texel reaches on the surface). It is 1 for an isometry and grows with any distortion,
anisotropic or a change of scale across the chart (a conformal map of a sphere cap is not 1).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from scantex.arrays import uv_areas


def face_frames(triangles_3d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each face in its own orthonormal 2D frame.

    Args:
        triangles_3d: ``(n, 3, 3)`` corner positions.

    Returns:
        ``(n, 3, 2)`` corner coordinates (corner 0 at the origin, corner 1 on +x) and ``(n,)`` areas.
    """
    e1 = triangles_3d[:, 1] - triangles_3d[:, 0]
    e2 = triangles_3d[:, 2] - triangles_3d[:, 0]
    n = np.cross(e1, e2)
    area2 = np.linalg.norm(n, axis=1)
    l1 = np.linalg.norm(e1, axis=1)
    x_axis = np.divide(e1, l1[:, None], out=np.zeros_like(e1), where=l1[:, None] > 0)
    normal = np.divide(n, area2[:, None], out=np.zeros_like(n), where=area2[:, None] > 0)
    y_axis = np.cross(normal, x_axis)
    local = np.zeros(triangles_3d.shape[:1] + (3, 2))
    local[:, 1, 0] = l1
    local[:, 2, 0] = (e2 * x_axis).sum(axis=1)
    local[:, 2, 1] = (e2 * y_axis).sum(axis=1)
    return local, 0.5 * area2


def jacobians(triangles_3d: np.ndarray, triangles_uv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(n, 2, 2)`` Jacobians from each face's 2D frame to UV, and ``(n,)`` surface areas.

    Degenerate faces (no surface area) get a zero Jacobian.
    """
    local, area = face_frames(triangles_3d)
    P = np.stack([local[:, 1] - local[:, 0], local[:, 2] - local[:, 0]], axis=2)  # [n, 2, 2] columns
    U = np.stack([triangles_uv[:, 1] - triangles_uv[:, 0], triangles_uv[:, 2] - triangles_uv[:, 0]], axis=2)
    det = P[:, 0, 0] * P[:, 1, 1] - P[:, 0, 1] * P[:, 1, 0]
    ok = np.abs(det) > 1e-30
    inv = np.zeros_like(P)
    inv[ok, 0, 0] = P[ok, 1, 1] / det[ok]
    inv[ok, 1, 1] = P[ok, 0, 0] / det[ok]
    inv[ok, 0, 1] = -P[ok, 0, 1] / det[ok]
    inv[ok, 1, 0] = -P[ok, 1, 0] / det[ok]
    return U @ inv, np.where(ok, area, 0.0)


@dataclass(frozen=True)
class Distortion:
    """How far a chart's UVs are from an isometry.

    Attributes:
        stretch: L2 stretch after normalising the chart's UV area to its surface area (1 = isometric).
        max_anisotropy: largest per-face ``σ1 / σ2`` (faces with surface area only).
        flipped_share: share of the surface area whose UV triangle is mirrored relative to the rest.
        surface_area: chart area in m².
        uv_area: chart area in UV units².
    """

    stretch: float
    max_anisotropy: float
    flipped_share: float
    surface_area: float
    uv_area: float


def distortion(triangles_3d: np.ndarray, triangles_uv: np.ndarray) -> Distortion:
    """Distortion of one chart from its ``(n, 3, 3)`` corner positions and ``(n, 3, 2)`` corner UVs."""
    return distortions(triangles_3d, triangles_uv, np.zeros(len(triangles_3d), int), 1)[0]


def _face_terms(triangles_3d: np.ndarray, triangles_uv: np.ndarray):
    """Each face's surface area, Jacobian determinant, σ1² + σ2² and inverse stretch Γ1² + Γ2² (0 without
    surface), ``(n,)`` each: what :func:`distortions` and :func:`stretch_sums` sum."""
    J, area = jacobians(triangles_3d, triangles_uv)
    det = J[:, 0, 0] * J[:, 1, 1] - J[:, 0, 1] * J[:, 1, 0]
    frob2 = (J ** 2).sum(axis=(1, 2))  # σ1² + σ2²
    used = area > 0
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        # Sander et al.'s stretch is of the inverse map (texels onto the surface): Γ1² + Γ2² = (σ1² + σ2²) / det²
        inverse = np.where(used, frob2 / np.where(used, det ** 2, 1.0), 0.0)
    return area, det, frob2, inverse


def stretch_sums(triangles_3d: np.ndarray, triangles_uv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """What :func:`distortion`'s stretch of a chart is summed from, over its ``(n, 3, 3)`` corner positions and
    ``(n, 3, 2)`` corner UVs: ``[surface area, UV area, area x inverse stretch² / 2, signed UV area]``, and
    each face's signed UV area ``(n,)`` (its sign against the chart's says a mirrored face). The sums of two
    pieces are their union's when neither's layout changes (:func:`stretch_of_sums`)."""
    area, det, _, inverse = _face_terms(triangles_3d, triangles_uv)
    signed = det * area
    return np.array([area.sum(), np.abs(signed).sum(), (area * inverse / 2).sum(), signed.sum()]), signed


def stretch_of_sums(sums: np.ndarray) -> float:
    """The L2 stretch of a chart from its :func:`stretch_sums` (infinite without surface or UV area)."""
    total, uv_area, inverse, _ = sums
    if not total > 0 or not uv_area > 0:
        return float("inf")
    return float(np.sqrt(inverse / total) * np.sqrt(uv_area / total))


def distortions(triangles_3d: np.ndarray, triangles_uv: np.ndarray, chart_of_face: np.ndarray,
                n_charts: int | None = None) -> list[Distortion]:
    """:func:`distortion` of every chart ``0 .. n_charts-1`` at once, from all faces' ``(F, 3, 3)`` corner
    positions and ``(F, 3, 2)`` corner UVs and ``chart_of_face (F,)``: the per-face terms are computed once
    and summed per chart (a fused room scan's 25,000 charts one by one took 10 s). A chart without surface
    area (or UV area) gets an infinite stretch and anisotropy."""
    C = int(chart_of_face.max()) + 1 if n_charts is None else int(n_charts)
    area, det, frob2, inverse = _face_terms(triangles_3d, triangles_uv)
    used = area > 0
    # σ1, σ2 from the trace and determinant of JᵀJ
    disc = np.sqrt(np.maximum(frob2 ** 2 - 4 * det ** 2, 0.0))
    s1 = np.sqrt(0.5 * (frob2 + disc))
    s2 = np.sqrt(np.maximum(0.5 * (frob2 - disc), 0.0))
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        aniso = np.where(used, np.where(s2 > 0, s1 / np.maximum(s2, 1e-300), np.inf), -np.inf)

    def per_chart(values: np.ndarray) -> np.ndarray:
        return np.bincount(chart_of_face, values, C)

    total, uv_area = per_chart(area), per_chart(np.abs(det) * area)
    worst = np.full(C, -np.inf)
    np.maximum.at(worst, chart_of_face, aniso)
    with np.errstate(divide="ignore", invalid="ignore"):
        l2 = np.sqrt(per_chart(area * inverse / 2) / total)
        stretch = l2 * np.sqrt(uv_area / total)
    orientation = np.sign(per_chart(det * area))
    orientation[orientation == 0] = 1.0
    flipped = per_chart(np.where(det * orientation[chart_of_face] < 0, area, 0.0))
    out = []
    for c in range(C):
        if total[c] <= 0 or uv_area[c] <= 0:
            out.append(Distortion(float("inf"), float("inf"), 0.0, float(total[c]), float(uv_area[c])))
        else:
            out.append(Distortion(float(stretch[c]), float(worst[c]), float(flipped[c] / total[c]),
                                  float(total[c]), float(uv_area[c])))
    return out


def planar_projection(points: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """``(N, 2)`` coordinates in metres on the plane through the chart with its area-weighted mean normal.

    The axes are chosen so that faces keep their winding (counter-clockwise seen from the front).
    """
    tri = points[triangles]
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]).sum(axis=0)  # area-weighted (x2)
    length = np.linalg.norm(n)
    if length <= 0:
        n = np.array([0.0, 0.0, 1.0])
    else:
        n = n / length
    helper = np.eye(3)[np.argmin(np.abs(n))]
    x_axis = np.cross(helper, n)
    x_axis /= np.linalg.norm(x_axis)
    y_axis = np.cross(n, x_axis)
    centred = points - points.mean(axis=0)
    return np.stack([centred @ x_axis, centred @ y_axis], axis=1)


def planar_projections(points: np.ndarray, triangles: np.ndarray, chart_of_face: np.ndarray, n_charts: int,
                       chart_of_point: np.ndarray) -> np.ndarray:
    """:func:`planar_projection` of many charts at once: ``points (N, 3)`` (each chart's own, ``chart_of_point
    (N,)``), ``triangles (F, 3)`` into them, ``chart_of_face (F,)``. Returns ``(N, 2)``."""
    tri = points[triangles]
    cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    n = np.stack([np.bincount(chart_of_face, cross[:, k], n_charts) for k in range(3)], axis=1)
    length = np.linalg.norm(n, axis=1)
    n = np.where(length[:, None] > 0, n / np.where(length > 0, length, 1.0)[:, None], [0.0, 0.0, 1.0])
    helper = np.eye(3)[np.argmin(np.abs(n), axis=1)]
    x_axis = np.cross(helper, n)
    x_axis /= np.linalg.norm(x_axis, axis=1, keepdims=True)
    y_axis = np.cross(n, x_axis)
    count = np.maximum(np.bincount(chart_of_point, minlength=n_charts), 1)
    mean = np.stack([np.bincount(chart_of_point, points[:, k], n_charts) for k in range(3)], axis=1) / count[:, None]
    centred = points - mean[chart_of_point]
    return np.stack([np.einsum("ij,ij->i", centred, x_axis[chart_of_point]),
                     np.einsum("ij,ij->i", centred, y_axis[chart_of_point])], axis=1)


def lscm(points: np.ndarray, triangles: np.ndarray, pins: tuple[np.ndarray, np.ndarray] | None = None
         ) -> np.ndarray:
    """Least-squares conformal map (Lévy et al. 2002) of a disc-like chart, ``(N, 2)`` in metres.

    Without ``pins``, two far-apart vertices are pinned and the result is rescaled so that its UV area equals
    the surface area and mirrored if needed so that faces keep their winding. With ``pins = (ids (k,), uv
    (k, 2))``, k >= 2 of the triangles' vertices keep the given coordinates and the others are placed around
    them, in the pins' scale and orientation (a piece joined to a chart whose layout stays as it is).
    Vertices no face uses stay at 0. Written here because no maintained Python library exposes LSCM without
    a heavy dependency.
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.linalg import splu

    N, n = len(points), len(triangles)
    local, area = face_frames(points[triangles])
    # W_j = (x_l - x_k) + i (y_l - y_k) for corners (j, k, l) in cyclic order, over sqrt(2A)
    nxt, prv = local[:, [1, 2, 0]], local[:, [2, 0, 1]]
    w = prv - nxt  # [n, 3, 2]
    scale = np.where(area > 0, 1.0 / np.sqrt(np.maximum(2 * area, 1e-300)), 0.0)[:, None]
    wr, wi = w[..., 0] * scale, w[..., 1] * scale  # [n, 3]
    rows = np.repeat(np.arange(n), 3)
    cols = triangles.ravel()
    # real rows: Re(W)·u - Im(W)·v ; imaginary rows: Im(W)·u + Re(W)·v
    r = np.concatenate([rows, rows, rows + n, rows + n])
    c = np.concatenate([cols, cols + N, cols, cols + N])
    v = np.concatenate([wr.ravel(), -wi.ravel(), wi.ravel(), wr.ravel()])
    A = coo_matrix((v, (r, c)), shape=(2 * n, 2 * N)).tocsc()

    used = np.unique(triangles)
    if pins is None:
        centre = points[used].mean(axis=0)
        p0 = used[np.argmax(np.linalg.norm(points[used] - centre, axis=1))]
        p1 = used[np.argmax(np.linalg.norm(points[used] - points[p0], axis=1))]
        ids, pin_uv = np.array([p0, p1]), np.array([[0.0, 0.0], [np.linalg.norm(points[p1] - points[p0]), 0.0]])
    else:
        ids, pin_uv = np.asarray(pins[0]), np.asarray(pins[1], dtype=np.float64)
    pinned = np.concatenate([ids, ids + N])
    pinned_values = np.concatenate([pin_uv[:, 0], pin_uv[:, 1]])
    free = np.setdiff1d(np.concatenate([used, used + N]), pinned)
    Af, Ap = A[:, free], A[:, pinned]
    rhs = -(Ap @ pinned_values)
    AtA = (Af.T @ Af).tocsc()
    AtA = AtA + 1e-12 * coo_matrix((np.ones(len(free)), (np.arange(len(free)),) * 2),
                                   shape=AtA.shape).tocsc()
    x = np.zeros(2 * N)
    # AtA is symmetric positive definite: SuperLU in its symmetric mode (a minimum-degree ordering of A + A^T, the
    # diagonal as pivots, as a Cholesky factorisation would) solves it 20-35 % faster than its default for
    # general matrices (column ordering, partial pivoting), to 1e-9 of the same solution
    x[free] = splu(AtA, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0,
                   options={"SymmetricMode": True}).solve(Af.T @ rhs)
    x[pinned] = pinned_values
    uv = np.stack([x[:N], x[N:]], axis=1)
    return normalise(points, triangles, uv) if pins is None else uv


def normalise(points: np.ndarray, triangles: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """``uv`` scaled so its area equals the surface area, mirrored if most of it is mirrored."""
    d = distortion(points[triangles], uv[triangles])
    if not np.isfinite(d.stretch) or d.uv_area <= 0:
        return uv
    J, area = jacobians(points[triangles], uv[triangles])
    det = J[:, 0, 0] * J[:, 1, 1] - J[:, 0, 1] * J[:, 1, 0]
    out = uv * np.sqrt(d.surface_area / d.uv_area)
    if (det * area).sum() < 0:
        out[:, 0] = -out[:, 0]
    return out


def overlap_share(triangles_uv: np.ndarray, texels: int | None = None) -> float:
    """Share of a chart's rasterised UV area covered by more than one triangle.

    The chart is rasterised at about ``texels`` texels (default: 8 per triangle, 2k to 200k); a texel
    centre counts for a triangle when it lies strictly inside it, so triangles that only share an edge
    never count as overlapping.
    """
    n = len(triangles_uv)
    texels = int(np.clip(8 * n, 2048, 200_000)) if texels is None else texels
    if n == 0:
        return 0.0
    area = uv_areas(triangles_uv).sum()
    if area <= 0:
        return 0.0
    lo = triangles_uv.reshape(-1, 2).min(axis=0)
    scale = np.sqrt(texels / area)
    for _ in range(8):
        boxes = _texel_boxes(triangles_uv, lo, scale)
        if boxes[3].sum() <= 20_000_000:
            break
        scale *= 0.5
        boxes = None
    overlapped, covered = overlap_counts(triangles_uv, lo, scale, boxes)
    return float(overlapped / max(covered, 1))


def flat_triangles(triangles: np.ndarray) -> np.ndarray:
    """``(n, 3, 2)``: the triangles ``(n, 3, 3)`` (corner positions) laid flat at their true side lengths, p0 at
    the origin, p1 along +x, p2 above; moved so that their corners' minimum is 0."""
    lengths = np.linalg.norm(triangles[:, [1, 2, 0]] - triangles, axis=2)  # |p1 - p0|, |p2 - p1|, |p0 - p2|
    a, b, c = lengths[:, 0], lengths[:, 1], lengths[:, 2]
    x2 = np.divide(a * a + c * c - b * b, 2 * a, out=np.zeros_like(a), where=a > 0)
    y2 = np.sqrt(np.maximum(c * c - x2 * x2, 0.0))
    flat = np.zeros((len(lengths), 3, 2))
    flat[:, 1, 0] = a
    flat[:, 2, 0], flat[:, 2, 1] = x2, y2
    return flat - flat.min(axis=1, keepdims=True)


def _texel_boxes(triangles_uv: np.ndarray, lo: np.ndarray, scale: float):
    """``(n, 3, 2)`` triangles in texels of size ``1 / scale`` from ``lo``, each one's first texel ``(n, 2)``,
    texel counts along x and y ``(n, 2)`` and in all ``(n,)`` (the texel centres in its bounding box)."""
    pix = (triangles_uv - lo) * scale  # [n, 3, 2]
    tmin = np.floor(pix.min(axis=1) - 0.5).astype(np.int64) + 1  # first texel centre x+0.5 >= min
    tmax = np.floor(pix.max(axis=1) - 0.5).astype(np.int64)
    count = np.maximum(tmax - tmin + 1, 0)
    return pix, tmin, count, count[:, 0] * count[:, 1]


def overlap_counts(triangles_uv: np.ndarray, lo: np.ndarray, scale: float, boxes: tuple | None = None
                   ) -> tuple[int, int]:
    """Texels (of size ``1 / scale``, on the grid from ``lo``) whose centre lies strictly inside more than one
    of the ``(n, 3, 2)`` triangles, and inside at least one (see :func:`overlap_share`). ``boxes``: their
    :func:`_texel_boxes` at that grid, where the caller has them."""
    pix, tmin, count, _ = boxes if boxes is not None else _texel_boxes(triangles_uv, lo, scale)
    _, x, y = _inside_texels(pix, tmin, count)
    if x.size == 0:
        return 0, 0
    width = int(x.max()) + 2
    hits = np.bincount(y * width + x)
    return int((hits > 1).sum()), int((hits > 0).sum())


def _inside_texels(pix: np.ndarray, tmin: np.ndarray, count: np.ndarray
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(tri, x, y)``: every texel whose centre lies strictly inside one of the triangles ``pix (n, 3, 2)``
    (texel coordinates), with its triangle, from their :func:`_texel_boxes` ``tmin`` and ``count``."""
    n, per = len(pix), count[:, 0] * count[:, 1]
    tri = np.repeat(np.arange(n), per)
    offset = np.arange(per.sum()) - np.repeat(np.cumsum(per) - per, per)
    w = np.maximum(count[tri, 0], 1)
    x = tmin[tri, 0] + offset % w
    y = tmin[tri, 1] + offset // w
    px, py = x + 0.5, y + 0.5
    a, b, c = pix[tri, 0], pix[tri, 1], pix[tri, 2]

    def edge(p, q):
        return (q[:, 0] - p[:, 0]) * (py - p[:, 1]) - (q[:, 1] - p[:, 1]) * (px - p[:, 0])

    s0, s1, s2 = edge(a, b), edge(b, c), edge(c, a)
    inside = ((s0 > 0) & (s1 > 0) & (s2 > 0)) | ((s0 < 0) & (s1 < 0) & (s2 < 0))
    return tri[inside], x[inside], y[inside]


#: candidate texels (a triangle's bounding box) rasterised at once by :func:`overlap_shares`
_OVERLAP_BATCH = 4_000_000


def overlap_shares(triangles_uv: np.ndarray, chart_of_face: np.ndarray, n_charts: int) -> np.ndarray:
    """:func:`overlap_share` of every chart ``0 .. n_charts-1`` at once (``(n_charts,)``), each rasterised at
    its own default resolution: the same values, without a call per chart (a fused room's 29,000 small
    charts took 24 s one by one). Charts of one or two faces are 0 without rasterising: two triangles that
    share an edge and do not mirror each other lie on its two sides (a caller checks for mirrored faces)."""
    out = np.zeros(n_charts)
    n = np.bincount(chart_of_face, minlength=n_charts)
    area = np.bincount(chart_of_face, uv_areas(triangles_uv), n_charts)
    faces = np.flatnonzero((n[chart_of_face] > 2) & (area[chart_of_face] > 0))
    if faces.size == 0:
        return out
    chart = chart_of_face[faces]
    uv = triangles_uv[faces]
    lo = np.full((n_charts, 2), np.inf)
    np.minimum.at(lo, chart, uv.min(axis=1))
    scale = np.sqrt(np.clip(8 * n, 2048, 200_000) / np.where(area > 0, area, 1.0))
    pix = (uv - lo[chart][:, None]) * scale[chart][:, None, None]
    tmin = np.floor(pix.min(axis=1) - 0.5).astype(np.int64) + 1
    tmax = np.floor(pix.max(axis=1) - 0.5).astype(np.int64)
    count = np.maximum(tmax - tmin + 1, 0)
    per = count[:, 0] * count[:, 1]
    candidates = np.bincount(chart, per, n_charts)
    extent = np.zeros(n_charts, np.int64)
    np.maximum.at(extent, chart, tmax.max(axis=1))
    # a chart the one-by-one function would rasterise coarser (over 20 M candidates), or one too wide for the
    # texel keys below (2^21 texels), goes to it
    single = (candidates > 20_000_000) | (extent >= 2**21 - 1)
    for c in np.flatnonzero(single):
        out[c] = overlap_share(triangles_uv[chart_of_face == c])
    keep = ~single[chart]
    faces_of = np.flatnonzero(keep)[np.argsort(chart[keep], kind="stable")]  # faces grouped by chart
    if faces_of.size == 0:
        return out
    bounds = np.flatnonzero(np.diff(chart[faces_of])) + 1
    starts = np.concatenate([[0], bounds])
    ends = np.concatenate([bounds, [faces_of.size]])
    total = np.cumsum(per[faces_of])
    s = 0
    while s < len(starts):
        # whole charts, up to about _OVERLAP_BATCH candidates
        first = total[starts[s] - 1] if starts[s] > 0 else 0
        e = max(s + 1, int(np.searchsorted(total[ends - 1], first + _OVERLAP_BATCH, side="right")))
        sel = faces_of[starts[s]:ends[e - 1]]
        _rasterised_overlaps(pix[sel], tmin[sel], count[sel], chart[sel], out)
        s = e
    return out


def overlapped_faces(triangles_px: np.ndarray, size: int) -> np.ndarray:
    """``(F,) bool``: the faces of ``triangles_px (F, 3, 2)`` (in texels of the ``size``² atlas they are packed
    in) with a texel centre strictly inside another face too: a texel two surfaces share, one of them painted
    with the other's colours. One compiled pass over the faces (its numpy twin below, where numba is missing)."""
    from scantex import jit

    out = np.zeros(len(triangles_px), bool)
    kernel = jit.compiled(_owned_texels)
    if kernel is not None:
        kernel(np.ascontiguousarray(triangles_px, np.float64), int(size), out)
        return out
    pix, tmin, count, _ = _texel_boxes(triangles_px, np.zeros(2), 1.0)
    tri, x, y = _inside_texels(pix, tmin, count)
    keep = (x >= 0) & (x < size) & (y >= 0) & (y < size)
    tri, key = tri[keep], y[keep] * size + x[keep]
    _, at, hits = np.unique(key, return_inverse=True, return_counts=True)
    out[tri[hits[at] > 1]] = True
    return out


def _owned_texels(pix, size, out):
    """The compiled twin of :func:`overlapped_faces`: each face's texel centres (strictly inside it, within the
    atlas) claimed in turn; a face reaching one another face claimed flags both in ``out``."""
    owner = np.full(size * size, -1, np.int32)
    for f in range(pix.shape[0]):
        ax, ay, bx, by, cx, cy = pix[f, 0, 0], pix[f, 0, 1], pix[f, 1, 0], pix[f, 1, 1], pix[f, 2, 0], pix[f, 2, 1]
        x0 = max(int(np.floor(min(ax, bx, cx) - 0.5)) + 1, 0)
        x1 = min(int(np.floor(max(ax, bx, cx) - 0.5)), size - 1)
        y0 = max(int(np.floor(min(ay, by, cy) - 0.5)) + 1, 0)
        y1 = min(int(np.floor(max(ay, by, cy) - 0.5)), size - 1)
        for y in range(y0, y1 + 1):
            py = y + 0.5
            for x in range(x0, x1 + 1):
                px = x + 0.5
                s0 = (bx - ax) * (py - ay) - (by - ay) * (px - ax)
                s1 = (cx - bx) * (py - by) - (cy - by) * (px - bx)
                s2 = (ax - cx) * (py - cy) - (ay - cy) * (px - cx)
                if (s0 > 0 and s1 > 0 and s2 > 0) or (s0 < 0 and s1 < 0 and s2 < 0):
                    k = y * size + x
                    if owner[k] < 0:
                        owner[k] = f
                    elif owner[k] != f:
                        out[f] = True
                        out[owner[k]] = True


def _rasterised_overlaps(pix: np.ndarray, tmin: np.ndarray, count: np.ndarray, chart: np.ndarray,
                         out: np.ndarray) -> None:
    """:func:`overlap_share`'s rasterisation for the faces of whole charts (``chart`` of each face, grouped):
    writes each chart's share into ``out``."""
    tri, x, y = _inside_texels(pix, tmin, count)
    if tri.size == 0:
        return
    ids, local = np.unique(chart, return_inverse=True)  # a batch holds few charts: their ids fit in 21 bits
    key = (local[tri].astype(np.int64) << 42) | (y << 21) | x
    texel, hits = np.unique(key, return_counts=True)
    of = texel >> 42
    covered = np.bincount(of, minlength=len(ids))
    twice = np.bincount(of[hits > 1], minlength=len(ids))
    out[ids] = twice / np.maximum(covered, 1)
