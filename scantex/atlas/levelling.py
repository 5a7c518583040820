"""Per-chart exposure from the seams: the classical global colour adjustment.

Along a seam the same surface point is stored twice, in two charts; with per-chart gains ``g``
(observed = g x canonical), both sides' canonical colours agree when ``log g_a - log g_b = log c_a - log c_b``.
Solving that over all seam samples in least squares (weighted mean log gain fixed at 0) gives every chart's
exposure, including charts no training view saw, where the learned appearance has nothing to go on.
"""

from __future__ import annotations

import numpy as np

from scantex.arrays import unique_rows
from scantex.atlas.seams import SeamEdges, seam_edges, seam_side_colours, texture_vertices
from scantex.scan import Scan

#: samples darker than this (0-1) are not used: black holes and deep shadow carry no exposure information
MIN_LEVEL = 0.03


def chart_gains(scan: Scan, charts: np.ndarray, *, edges: SeamEdges | None = None, samples_per_edge: int = 4,
                inset_texels: float = 1.5, prior: float = 0.05) -> np.ndarray:
    """``(n_charts, 3)`` per-channel gains (observed / canonical); 1 for charts without usable seams.

    Args:
        charts: ``(F,)`` chart id of every face.
        prior: weight pulling each log gain to 0 (keeps charts without seams at 1 and the system solvable).
    """
    from scipy.sparse import coo_matrix, vstack
    from scipy.sparse.linalg import lsqr

    n = int(charts.max()) + 1
    gains = np.ones((n, 3))
    edges = seam_edges(scan) if edges is None else edges
    if len(edges) == 0 or not scan.is_textured:
        return gains
    S = samples_per_edge
    t = np.tile((np.arange(S) + 0.5) / S, len(edges))
    a_face, b_face = np.repeat(edges.faces[:, 0], S), np.repeat(edges.faces[:, 1], S)
    ca = seam_side_colours(scan, a_face, np.repeat(edges.corners[:, 0], S, axis=0), t, inset_texels)
    cb = seam_side_colours(scan, b_face, np.repeat(edges.corners[:, 1], S, axis=0), t, inset_texels)
    ka, kb = charts[a_face], charts[b_face]
    usable = (ka != kb) & (ca.min(axis=1) > MIN_LEVEL) & (cb.min(axis=1) > MIN_LEVEL)
    if not usable.any():
        return gains
    ka, kb, ca, cb = ka[usable], kb[usable], ca[usable], cb[usable]
    m = len(ka)
    rows = np.repeat(np.arange(m), 2)
    cols = np.stack([ka, kb], axis=1).ravel()
    vals = np.tile([1.0, -1.0], m)
    seams = coo_matrix((vals, (rows, cols)), shape=(m, n))
    reg = coo_matrix((np.full(n, prior * np.sqrt(m / n)), (np.arange(n), np.arange(n))), shape=(n, n))
    A = vstack([seams, reg]).tocsr()
    log_ratio = np.log(ca) - np.log(cb)  # [m, 3]
    for c in range(3):
        rhs = np.concatenate([log_ratio[:, c], np.zeros(n)])
        x = lsqr(A, rhs, atol=1e-8, btol=1e-8)[0]
        gains[:, c] = np.exp(x - x.mean())
    return gains


#: seams on a crease sharper than this join two surfaces (a wall and the floor), whose colours differ for real:
#: levelling leaves them
MAX_CREASE_DEG = 30.0


def seam_offsets(scan: Scan, *, exclude: np.ndarray | None = None, edges: SeamEdges | None = None,
                 samples_per_edge: int = 4, inset_texels: float = 1.5, smoothness: float = 1.0,
                 anchor: float = 1e-3, robust: float = 0.05, max_step: float = 0.15,
                 max_crease_deg: float = MAX_CREASE_DEG, iterations: int = 2) -> np.ndarray:
    """Local seam levelling: an additive colour offset ``(T, 3)`` per UV vertex (texture coordinate).

    The classical global + local adjustment (Lempitsky & Ivanov 2007; Waechter et al. 2014), solved over
    the atlas's texture vertices (:func:`~scantex.atlas.seams.texture_vertices`: a file that gives every
    face corner a UV index of its own still has one offset where its faces meet): ``g`` is interpolated
    over each face from its corners' offsets and added to the input's texels. It is the least-squares
    solution of

    - seams: at samples along every seam edge, the two sides' corrected colours agree
      (``c_a + g_a = c_b + g_b``);
    - smoothness (weight ``smoothness``): neighbouring UV vertices get the same offset, so the
      correction is a smooth field inside each chart: constant over a chart whose every seam shows the
      same step (a chart exposed differently), fading away from a seam whose step is local;
    - an anchor (weight ``anchor``) pulling every offset to 0: where the input has no step, nothing moves,
      and the overall colour balance stays the input's.

    What is not exposure is left out, so that it cannot drag a chart's colour along: samples on ``exclude``
    faces (holes and their border) or darker than ``MIN_LEVEL``; steps larger than ``max_step`` in any
    channel (0-1 scale: beyond what exposure and white balance do between keyframes, a real colour edge
    or a misregistered texture); seams on a crease sharper than ``max_crease_deg`` (where a wall meets the
    floor the colour changes for real); and, by iteratively reweighted least squares (Huber, ``robust``),
    samples the solution cannot explain. Since ``g`` is continuous inside every chart, it cannot put an
    edge anywhere but on a seam.
    """
    from scipy.sparse import coo_matrix, diags
    from scipy.sparse.linalg import cg

    if not scan.is_textured or scan.face_uvs is None:
        return np.zeros((0 if scan.uvs is None else len(scan.uvs), 3))
    T = len(scan.uvs)
    offsets = np.zeros((T, 3))
    nodes = texture_vertices(scan)  # [F, 3]
    N = int(nodes.max()) + 1
    # seams on a sharp crease join two surfaces, whose colours differ for real
    edges = (seam_edges(scan) if edges is None else edges).smooth(scan.face_normals, max_crease_deg)
    if len(edges) == 0:
        return offsets
    S = samples_per_edge
    t = np.tile((np.arange(S) + 0.5) / S, len(edges))
    fa, fb = np.repeat(edges.faces[:, 0], S), np.repeat(edges.faces[:, 1], S)
    corners_a = np.repeat(edges.corners[:, 0], S, axis=0)
    corners_b = np.repeat(edges.corners[:, 1], S, axis=0)
    ca = seam_side_colours(scan, fa, corners_a, t, inset_texels)
    cb = seam_side_colours(scan, fb, corners_b, t, inset_texels)
    usable = (ca.min(axis=1) > MIN_LEVEL) & (cb.min(axis=1) > MIN_LEVEL)
    usable &= np.abs(cb - ca).max(axis=1) <= max_step
    if exclude is not None:
        usable &= ~exclude[fa] & ~exclude[fb]
    if not usable.any():
        return offsets
    rows_ok = np.flatnonzero(usable)
    m = rows_ok.size
    ua = nodes[fa[rows_ok][:, None], corners_a[rows_ok]]  # [m, 2] texture vertices of side a's edge ends
    ub = nodes[fb[rows_ok][:, None], corners_b[rows_ok]]
    tt = t[rows_ok]
    rows = np.repeat(np.arange(m), 4)
    cols = np.stack([ua[:, 0], ua[:, 1], ub[:, 0], ub[:, 1]], axis=1).ravel()
    vals = np.stack([1 - tt, tt, -(1 - tt), -tt], axis=1).ravel()
    seams = coo_matrix((vals, (rows, cols)), shape=(m, N)).tocsr()
    step = (cb - ca)[rows_ok].astype(np.float64)  # [m, 3]: g_a - g_b should equal c_b - c_a

    # smoothness over the texture vertices' edges (each counted once)
    fu = nodes
    i = np.concatenate([fu[:, 0], fu[:, 1], fu[:, 2]])
    j = np.concatenate([fu[:, 1], fu[:, 2], fu[:, 0]])
    keep = i != j
    lo, hi = np.minimum(i[keep], j[keep]), np.maximum(i[keep], j[keep])
    pairs = unique_rows(np.stack([lo, hi], axis=1))
    n_e = len(pairs)
    D = coo_matrix((np.tile([1.0, -1.0], n_e), (np.repeat(np.arange(n_e), 2), pairs.ravel())),
                   shape=(n_e, N)).tocsr()
    # the seam terms and the smoothness terms are balanced per sample and per edge; the anchor keeps the
    # system positive definite (UV vertices of untouched charts stay at 0)
    smooth = smoothness * (D.T @ D) + anchor * diags(np.ones(N))
    weight = np.ones(m)
    offsets = np.zeros((N, 3))
    preconditioner = None
    for _ in range(max(1, iterations)):
        system = (seams.T @ diags(weight) @ seams + smooth).tocsr()
        rhs = seams.T @ (weight[:, None] * step)
        # algebraic multigrid (pyamg) as the preconditioner of conjugate gradients: a sparse LU of this
        # Laplacian-like system stalled on a 79k-vertex room atlas, plain CG needed ~600 iterations; the
        # hierarchy is built once and still preconditions the reweighted systems well
        if preconditioner is None:
            preconditioner = _multigrid(system)
        offsets = np.column_stack([cg(system, rhs[:, c], x0=offsets[:, c], rtol=1e-6, maxiter=500,
                                      M=preconditioner)[0] for c in range(3)])
        residual = np.abs(seams @ offsets - step).max(axis=1)
        weight = np.minimum(1.0, robust / np.maximum(residual, 1e-9))
    # each UV index takes its texture vertex's offset (the mean, where an index serves several positions)
    uv, node = scan.face_uvs.reshape(-1), nodes.reshape(-1)
    count = np.bincount(uv, minlength=T).astype(np.float64)
    out = np.column_stack([np.bincount(uv, offsets[node, c], minlength=T) for c in range(3)])
    return out / np.maximum(count, 1)[:, None]


def _multigrid(system):
    """pyamg's smoothed-aggregation hierarchy of ``system``, as a preconditioner. pyamg estimates spectral
    radii from a random start drawn from numpy's global generator: here it is drawn from a fixed seed (the
    caller's global state restored after), so that a run gives the texture the last run gave (unseeded, the
    offsets moved in their last digits from one process to the next, and about 140 of a 4.2 M-texel photo-mode
    atlas's texels by one level in one run of five)."""
    import pyamg

    state = np.random.get_state()
    np.random.seed(0)
    try:
        return pyamg.smoothed_aggregation_solver(system, symmetry="hermitian").aspreconditioner()
    finally:
        np.random.set_state(state)
