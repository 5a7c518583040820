"""Filling holes on the surface: harmonic interpolation of colour over the mesh.

A hash-grid field is not trustworthy where no ray taught it: its fine levels there read table entries
trained by other places (hash collisions) and show noise. Hole faces instead get the smoothest colour
that agrees with the surface around them: vertex colours solving Laplace's equation on the mesh graph
with the colours of the vertices at the hole's border held fixed.
"""

from __future__ import annotations

import numpy as np

from scantex.scan import Scan

#: how many known positions, nearest in space, colour a vertex that no known vertex connects to (``nearest``)
NEAREST_SEEDS = 8


def grow_faces(scan: Scan, faces: np.ndarray, rings: int = 1, *, welded: bool = False) -> np.ndarray:
    """``(F,) bool`` ``faces`` grown by ``rings`` rings of faces that share a vertex with them (``welded``: a
    position, so that the rings cross the UV seams where a file repeats positions)."""
    corners = scan.welded[scan.faces] if welded else scan.faces
    grown = faces.copy()
    for _ in range(rings):
        touched = np.zeros(int(corners.max()) + 1 if corners.size else 0, bool)
        touched[corners[grown].ravel()] = True
        grown |= touched[corners].any(axis=1)
    return grown


def harmonic_vertex_colours(scan: Scan, known: np.ndarray, colours: np.ndarray,
                            unanchored: np.ndarray | None = None, *, nearest: bool = False) -> np.ndarray:
    """Colours ``(V, C)`` at every vertex: ``colours`` where ``known (V,) bool``, harmonic elsewhere.

    Uses the uniform graph Laplacian of the mesh edges, on positions welded by value: a capture app's OBJ
    or GLB repeats a position at every UV seam (the façade's app-style input: 44,127 vertices at 7,378
    positions), and its faces do not connect across a seam; a hole would be cut off from the colours
    around it. A welded position is known where any of its vertices is (their mean colour); a known vertex
    keeps its own colour. Vertices in a part with no known vertex get ``unanchored`` ``(C,)`` (default:
    the mean known colour), or with ``nearest`` the mean colour of the ``NEAREST_SEEDS`` nearest positions
    in space that are known or interpolated, averaged over the part (a fused scan's loose fragments lie on
    or beside the surfaces they belong to, which may be holes themselves; one position's colour alone may be
    a seed's noise).
    """
    from scipy.sparse import coo_matrix, diags
    from scipy.sparse.csgraph import connected_components
    from scipy.sparse.linalg import spsolve

    weld = scan.welded
    V = int(weld.max()) + 1 if weld.size else 0
    f = weld[scan.faces]
    n_known = np.bincount(weld[known], minlength=V).astype(np.float64)
    welded_known = n_known > 0
    welded = np.zeros((V, colours.shape[1]), np.float64)
    for c in range(colours.shape[1]):
        welded[:, c] = np.bincount(weld[known], colours[known, c], minlength=V)
    welded[welded_known] /= n_known[welded_known, None]
    i = np.concatenate([f[:, 0], f[:, 1], f[:, 2], f[:, 1], f[:, 2], f[:, 0]])
    j = np.concatenate([f[:, 1], f[:, 2], f[:, 0], f[:, 0], f[:, 1], f[:, 2]])
    keep = i != j
    A = coo_matrix((np.ones(int(keep.sum())), (i[keep], j[keep])), shape=(V, V)).tocsr()
    A.data[:] = 1.0  # duplicate edges count once
    L = diags(np.asarray(A.sum(axis=1)).ravel()) - A
    unknown = ~welded_known & (np.asarray(A.sum(axis=1)).ravel() > 0)
    if unknown.any():
        # parts of the unknown set that touch no known vertex have nothing to interpolate from
        n_parts, label = connected_components(A[unknown][:, unknown] + 0, directed=False)
        u_idx = np.flatnonzero(unknown)
        touches = np.asarray(A[unknown][:, welded_known].sum(axis=1)).ravel() > 0
        anchored = np.zeros(n_parts, bool)
        anchored[np.unique(label[touches])] = True
        solvable = anchored[label]
        s_idx = u_idx[solvable]
        if s_idx.size:
            Luu = L[s_idx][:, s_idx].tocsc()
            rhs = -(L[s_idx][:, welded_known] @ welded[welded_known])
            welded[s_idx] = np.column_stack([spsolve(Luu, rhs[:, c]) for c in range(colours.shape[1])])
        if nearest and welded_known.any() and not solvable.all():
            from scipy.spatial import cKDTree

            # the surface beside a loose fragment may be a hole itself: its solved colours count as well
            where = np.zeros((V, 3))
            where[weld] = scan.positions
            coloured = welded_known.copy()
            coloured[s_idx] = True
            coloured_idx = np.flatnonzero(coloured)
            k = min(NEAREST_SEEDS, coloured_idx.size)
            lone = u_idx[~solvable]
            _, closest = cKDTree(where[coloured]).query(where[lone], k=k)
            near = welded[coloured_idx[closest.reshape(-1, k)]].mean(axis=1)
            # one colour a part: a large unseen object is not painted as a patchwork of whatever lies nearest
            part = np.unique(label[~solvable], return_inverse=True)[1].ravel()
            count = np.bincount(part).astype(np.float64)
            welded[lone] = np.column_stack([np.bincount(part, near[:, c]) / count for c in range(near.shape[1])])[part]
        else:
            if unanchored is None:
                unanchored = colours[known].mean(axis=0) if known.any() else np.full(colours.shape[1], 0.5)
            welded[u_idx[~solvable]] = unanchored
    out = welded[weld]
    out[known] = colours[known]
    return out
