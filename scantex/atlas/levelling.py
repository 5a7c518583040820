"""Per-chart exposure from the seams: the classical global colour adjustment.

Along a seam the same surface point is stored twice, in two charts; with per-chart gains ``g``
(observed = g x canonical), both sides' canonical colours agree when ``log g_a - log g_b = log c_a - log c_b``.
Solving that over all seam samples in least squares (weighted mean log gain fixed at 0) gives every chart's
exposure, including charts no training view saw, where the learned appearance has nothing to go on.
"""

from __future__ import annotations

import numpy as np

from scantex.atlas.seams import SeamEdges, seam_edges, seam_side_colours
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
