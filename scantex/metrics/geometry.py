"""Geometry kept: the checks every enhance run makes between its input and output."""

from __future__ import annotations

import numpy as np

from scantex.scan import Scan, triangle_multiset_key


def geometry_identity(a: Scan, b: Scan) -> dict:
    """Compare the geometry of two scans exactly.

    Returns a JSON-ready dict: vertex and face counts of both, distinct position counts, whether the
    positions and faces arrays are identical, whether the triangle multisets (corner positions, winding
    kept) are bitwise identical, and the largest vertex displacement when the vertex lists align.
    """
    same_arrays = (a.positions.shape == b.positions.shape and a.faces.shape == b.faces.shape
                   and np.array_equal(a.positions, b.positions) and np.array_equal(a.faces, b.faces))
    same_triangles = a.n_faces == b.n_faces and np.array_equal(
        triangle_multiset_key(a.positions, a.faces), triangle_multiset_key(b.positions, b.faces))
    max_disp = (float(np.abs(a.positions - b.positions).max())
                if a.positions.shape == b.positions.shape else None)
    return {
        "vertices": [a.n_vertices, b.n_vertices],
        "faces": [a.n_faces, b.n_faces],
        "distinct_positions": [len(np.unique(a.positions, axis=0)), len(np.unique(b.positions, axis=0))],
        "arrays_identical": bool(same_arrays),
        "triangles_identical": bool(same_triangles),
        "max_vertex_displacement": max_disp,
    }
