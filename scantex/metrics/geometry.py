"""Geometry kept: exact identity checks, volume, and surface distances between two meshes.

The paper reports vertex / face counts, volume, Hausdorff distance and mean point-to-mesh distance
between the input and the output mesh. scantex never moves a vertex, so on every enhance output the
distances must be exactly zero; they are measured anyway, honestly, so that a change would show.

Distances are measured from points on one surface to the other surface: every vertex plus
area-weighted random surface samples. The closest point on the other mesh is found exactly: a k-d tree
over face centroids (scipy) gives candidate faces, whose exact point-triangle distances (trimesh's
``closest_point`` on triangle/point pairs) are taken. trimesh's own ``proximity`` needs ``rtree``, which
scantex does not depend on. A sample taken on a triangle that the other mesh holds bitwise identically
(the same three corner positions) is at distance exactly 0: it lies on that triangle by construction,
and recomputing it in floating point would only add rounding noise.
"""

from __future__ import annotations

import numpy as np

from scantex.arrays import unique_rows
from scantex.scan import Scan, triangle_multiset_key

#: query points per k-d tree ball query (bounds the candidate lists held at once)
QUERY_CHUNK = 2048
#: faces larger than this many times the median face are checked against every point, not via the tree
BIG_FACE_FACTOR = 4.0
#: at most this many faces are treated as big (each costs one distance per query point)
MAX_BIG_FACES = 256


def geometry_identity(a: Scan, b: Scan) -> dict:
    """Compare the geometry of two scans exactly.

    Returns a JSON-ready dict: vertex and face counts of both, distinct position counts, whether the
    positions and faces arrays are identical, whether the triangle multisets (corner positions, winding
    kept) are bitwise identical, and the largest vertex displacement when the vertex lists align.
    """
    same_arrays = (a.positions.shape == b.positions.shape and a.faces.shape == b.faces.shape
                   and np.array_equal(a.positions, b.positions) and np.array_equal(a.faces, b.faces))
    # identical arrays hold identical triangles by definition; the canonical sort (0.3 s a 79k-face mesh)
    # is only needed to recognise the same triangles stored another way
    same_triangles = same_arrays or (a.n_faces == b.n_faces and np.array_equal(
        triangle_multiset_key(a.positions, a.faces), triangle_multiset_key(b.positions, b.faces)))
    max_disp = (float(np.abs(a.positions - b.positions).max())
                if a.positions.shape == b.positions.shape else None)
    distinct = len(unique_rows(a.positions))
    return {
        "vertices": [a.n_vertices, b.n_vertices],
        "faces": [a.n_faces, b.n_faces],
        "distinct_positions": [distinct, distinct if same_arrays else len(unique_rows(b.positions))],
        "arrays_identical": bool(same_arrays),
        "triangles_identical": bool(same_triangles),
        "max_vertex_displacement": max_disp,
    }


# -- volume -------------------------------------------------------------------------------------------


def volume_info(scan: Scan) -> dict:
    """Surface area, and the enclosed volume when the surface is closed.

    Closedness is judged with coincident positions merged (scans often repeat a position where the file
    splits a vertex); the scan itself is not touched. An open surface, as LiDAR scans of rooms and walls
    almost always are, encloses no volume: ``volume`` is then ``None`` and ``note`` says why, rather than a
    number that depends on where the origin is. Its open edges are counted on the positions welded by value
    (:attr:`Scan.welded`); only a surface without any is handed to trimesh (its import alone took 0.3 s of a
    run), which judges it closed or not and measures its volume.

    Returns:
        ``{"area", "watertight", "boundary_edges", "volume", "note"}``.
    """
    faces = scan.welded[scan.faces]
    edges = np.sort(faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    _, counts = unique_rows(edges, return_counts=True)
    boundary = int((counts == 1).sum())
    merged = None
    if boundary == 0 and scan.n_faces:
        import trimesh

        merged = trimesh.Trimesh(scan.positions, scan.faces.copy(), process=False, validate=False)
        merged.merge_vertices(merge_tex=True, merge_norm=True)
    watertight = merged is not None and bool(merged.is_watertight)
    out = {"area": float(scan.face_areas.sum()), "watertight": watertight, "boundary_edges": boundary,
           "volume": None, "note": ""}
    if watertight and not merged.is_winding_consistent:
        # faces wound both ways: their signed volumes cancel (a cube with one flipped face: 0.5). The
        # copy is wound one way; a surface that cannot be (one-sided) encloses nothing
        trimesh.repair.fix_winding(merged)
    if watertight and merged.is_winding_consistent:
        out["volume"] = float(abs(merged.volume))
        out["note"] = "closed surface: enclosed volume"
    elif watertight:
        out["note"] = "closed but one-sided surface (its faces cannot all face one way): it encloses no volume"
    else:
        why = f"{boundary:,} boundary edges" if boundary else "non-manifold edges"
        out["note"] = (f"open surface ({why}): it encloses no volume, so none is reported "
                       f"(LiDAR scans of walls and rooms are open)")
    return out


# -- closest points -----------------------------------------------------------------------------------


def point_triangle_distance(points: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """``(N,)`` exact distance from ``points (N, 3)`` to ``triangles (N, 3, 3)``, pair by pair."""
    from trimesh.triangles import closest_point

    if len(points) == 0:
        return np.zeros(0)
    return np.linalg.norm(closest_point(triangles, points) - points, axis=1)


def point_triangle_distance_reference(point: np.ndarray, triangle: np.ndarray) -> float:
    """The same distance for one pair, the plain way: the plane when the projection falls inside the
    triangle, else the nearest of the three edges. Slow; for tests."""
    a, b, c = (np.asarray(v, np.float64) for v in triangle)
    p = np.asarray(point, np.float64)
    n = np.cross(b - a, c - a)
    if np.dot(n, n) > 0:
        q = p - np.dot(p - a, n) / np.dot(n, n) * n  # projection onto the plane
        inside = all(np.dot(np.cross(v1 - v0, q - v0), n) >= 0 for v0, v1 in ((a, b), (b, c), (c, a)))
        if inside:
            return float(np.linalg.norm(p - q))

    def segment(v0, v1):
        d = v1 - v0
        t = 0.0 if not np.dot(d, d) else float(np.clip(np.dot(p - v0, d) / np.dot(d, d), 0.0, 1.0))
        return float(np.linalg.norm(p - (v0 + t * d)))

    return min(segment(a, b), segment(b, c), segment(c, a))


class ClosestSurface:
    """Exact distance from any point to a triangle mesh's surface.

    Faces are split into ordinary ones, found through a k-d tree over their centroids, and the few very
    large ones (a floor made of two triangles), checked against every query point. A face can hold a
    point within distance ``d`` only if its centroid is within ``d + radius`` of it, where ``radius`` is
    the face's bounding radius about its centroid: so a ball query with an upper bound on the distance
    returns every face that can matter, and the result is exact, not approximate.
    """

    def __init__(self, positions: np.ndarray, faces: np.ndarray):
        from scipy.spatial import cKDTree

        self.triangles = np.asarray(positions, np.float64)[np.asarray(faces)]  # [F, 3, 3]
        self.centroids = self.triangles.mean(axis=1)
        self.radius = np.linalg.norm(self.triangles - self.centroids[:, None], axis=2).max(axis=1)
        F = len(self.triangles)
        limit = BIG_FACE_FACTOR * float(np.median(self.radius)) if F else 0.0
        if F > MAX_BIG_FACES:
            limit = max(limit, float(np.partition(self.radius, F - MAX_BIG_FACES - 1)[F - MAX_BIG_FACES - 1]))
        big = self.radius > limit
        self.big = np.flatnonzero(big)
        self.small = np.flatnonzero(~big)
        self.tree = cKDTree(self.centroids[self.small]) if self.small.size else None
        self.small_radius = float(self.radius[self.small].max()) if self.small.size else 0.0

    def distance(self, points: np.ndarray) -> np.ndarray:
        """``(N,)`` distance of ``points (N, 3)`` to the surface."""
        points = np.asarray(points, np.float64)
        out = np.empty(len(points))
        for s in range(0, len(points), QUERY_CHUNK):
            out[s:s + QUERY_CHUNK] = self._distance(points[s:s + QUERY_CHUNK])
        return out

    def _distance(self, p: np.ndarray) -> np.ndarray:
        N = len(p)
        best = np.full(N, np.inf)
        for f in self.big:  # few: one vectorised pass each
            best = np.minimum(best, point_triangle_distance(p, np.broadcast_to(self.triangles[f], (N, 3, 3))))
        if self.tree is None:
            return best
        # an upper bound from the faces of the nearest centroids...
        k = min(4, self.small.size)
        _, near = self.tree.query(p, k=k)
        near = near.reshape(N, k)
        for j in range(k):
            best = np.minimum(best, point_triangle_distance(p, self.triangles[self.small[near[:, j]]]))
        # ...then every face that could be closer than it
        lists = self.tree.query_ball_point(p, best + self.small_radius, return_sorted=False)
        counts = np.fromiter((len(c) for c in lists), np.int64, N)
        if counts.sum() == 0:
            return best
        point_of = np.repeat(np.arange(N), counts)
        face_of = self.small[np.concatenate([np.asarray(c, np.int64) for c in lists])]
        gap = np.linalg.norm(p[point_of] - self.centroids[face_of], axis=1) - self.radius[face_of]
        keep = gap <= best[point_of]
        point_of, face_of = point_of[keep], face_of[keep]
        d = point_triangle_distance(p[point_of], self.triangles[face_of])
        np.minimum.at(best, point_of, d)
        return best


# -- surface distances ----------------------------------------------------------------------------


def _row_keys(rows: np.ndarray) -> np.ndarray:
    """``(N,)`` hashable byte strings of float64 rows (bitwise equality)."""
    rows = np.ascontiguousarray(rows, dtype=np.float64)
    return rows.view(np.dtype((np.void, rows.shape[1] * 8))).ravel()


def _triangle_keys(triangles: np.ndarray) -> np.ndarray:
    """Keys of ``(F, 3, 3)`` triangles as point sets: corners sorted, so order and winding do not matter."""
    F = len(triangles)
    flat = triangles.reshape(-1, 3)
    # sort corners within each triangle: lexsort over (face, x, y, z)
    face = np.repeat(np.arange(F), 3)
    order = np.lexsort((flat[:, 2], flat[:, 1], flat[:, 0], face))
    return _row_keys(flat[order].reshape(F, 9))


def sample_surface(scan: Scan, count: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """``count`` area-weighted random points: ``(points (count, 3), face (count,))``."""
    rng = np.random.default_rng(seed)
    area = scan.face_areas
    if count <= 0 or area.sum() <= 0:
        return np.zeros((0, 3)), np.zeros(0, np.int64)
    face = rng.choice(scan.n_faces, size=count, p=area / area.sum())
    r1, r2 = rng.random(count), rng.random(count)
    flip = r1 + r2 > 1  # fold the unit square onto the triangle: uniform over its area
    r1[flip], r2[flip] = 1 - r1[flip], 1 - r2[flip]
    t = scan.triangles[face]
    points = t[:, 0] + r1[:, None] * (t[:, 1] - t[:, 0]) + r2[:, None] * (t[:, 2] - t[:, 0])
    return points, face


def directed_distances(src: Scan, dst: Scan, samples: int = 100_000, seed: int = 0) -> dict:
    """Distances from ``src``'s surface to ``dst``'s: ``{"vertices": (V',), "surface": (samples,)}``.

    ``vertices`` are the positions ``src``'s faces use; ``surface`` the area-weighted random samples.
    Points that ``dst`` holds exactly (a vertex at the same position, a sample on a bitwise identical
    triangle) are at distance 0.0.
    """
    used = np.unique(src.faces)
    vertices = src.positions[used]
    points, face = sample_surface(src, samples, seed)

    dst_vertex_keys = set(_row_keys(dst.positions[np.unique(dst.faces)]).tolist())
    vertex_known = np.fromiter((k in dst_vertex_keys for k in _row_keys(vertices).tolist()), bool, len(vertices))
    dst_triangle_keys = set(_triangle_keys(dst.triangles).tolist())
    face_known = np.fromiter((k in dst_triangle_keys for k in _triangle_keys(src.triangles).tolist()), bool,
                             src.n_faces)
    sample_known = face_known[face]

    vertex_d = np.zeros(len(vertices))
    surface_d = np.zeros(len(points))
    if not (vertex_known.all() and sample_known.all()):
        closest = ClosestSurface(dst.positions, dst.faces)
        vertex_d[~vertex_known] = closest.distance(vertices[~vertex_known])
        surface_d[~sample_known] = closest.distance(points[~sample_known])
    return {"vertices": vertex_d, "surface": surface_d}


def surface_distances(a: Scan, b: Scan, samples: int = 100_000, seed: int = 0) -> dict:
    """Hausdorff and mean point-to-mesh distances between two surfaces, both ways.

    Args:
        a, b: the two scans (e.g. input and output).
        samples: random surface points per direction, on top of every vertex.
        seed: seeds the samples.

    Returns:
        a JSON-ready dict, distances in the scans' units (and ``*_rel``: as a share of ``a``'s bounding
        box diagonal): ``hausdorff`` (symmetric: the larger one-sided value), ``hausdorff_a_to_b`` /
        ``hausdorff_b_to_a`` (max over vertices and samples), ``mean_a_to_b`` / ``mean_b_to_a`` (mean over
        the area-weighted samples), ``mean`` (their average), and ``samples``. A Hausdorff distance from
        samples can only under-estimate the true one; with every vertex included it is exact for
        vertex displacements.
    """
    ab = directed_distances(a, b, samples, seed)
    ba = directed_distances(b, a, samples, seed + 1)

    def one_sided(d):
        parts = [x for x in (d["vertices"], d["surface"]) if x.size]
        return float(max(x.max() for x in parts)) if parts else 0.0

    def mean(d):
        return float(d["surface"].mean()) if d["surface"].size else 0.0

    lo, hi = a.bounds
    diagonal = float(np.linalg.norm(hi - lo)) or 1.0
    out = {
        "hausdorff_a_to_b": one_sided(ab),
        "hausdorff_b_to_a": one_sided(ba),
        "mean_a_to_b": mean(ab),
        "mean_b_to_a": mean(ba),
    }
    out["hausdorff"] = max(out["hausdorff_a_to_b"], out["hausdorff_b_to_a"])
    out["mean"] = 0.5 * (out["mean_a_to_b"] + out["mean_b_to_a"])
    out["hausdorff_rel"] = out["hausdorff"] / diagonal
    out["mean_rel"] = out["mean"] / diagonal
    out["diagonal"] = diagonal
    out["samples"] = int(samples)
    return out


def geometry_metrics(a: Scan, b: Scan, samples: int = 100_000, seed: int = 0) -> dict:
    """Everything the paper measures about geometry between an input ``a`` and an output ``b``.

    The keys of :func:`geometry_identity`, plus ``volume`` (:func:`volume_info` of each, as a pair) and
    ``distance`` (:func:`surface_distances`). JSON-ready.
    """
    out = geometry_identity(a, b)
    volume = volume_info(a)
    # the volume depends on positions and faces only: identical arrays have the same one
    out["volume"] = [volume, volume if out["arrays_identical"] else volume_info(b)]
    # and the same surface: sampling distances between them would measure a surface against itself
    out["distance"] = same_surface_distances(a) if out["arrays_identical"] else surface_distances(a, b, samples, seed)
    return out


def same_surface_distances(a: Scan) -> dict:
    """:func:`surface_distances`' keys for two scans with identical positions and faces arrays: every distance
    is exactly 0, nothing sampled (``samples`` 0, and a ``note`` that says so)."""
    lo, hi = a.bounds
    zero = {key: 0.0 for key in ("hausdorff_a_to_b", "hausdorff_b_to_a", "mean_a_to_b", "mean_b_to_a", "hausdorff",
                                 "mean", "hausdorff_rel", "mean_rel")}
    return {**zero, "diagonal": float(np.linalg.norm(hi - lo)) or 1.0, "samples": 0,
            "note": "identical positions and faces arrays: the same surface, every distance exactly 0 (not sampled)"}
