"""UV shells (charts) and seams of a scan's texture layout, and how visible the seams are.

A *shell* is a connected set of faces in UV space: faces that share a UV index. A *seam edge* is a
mesh edge (two faces sharing two positions) whose two faces use different UV indices along it, so the
same 3D points are looked up at two places in the atlas; where those two places hold different
colours, a line shows on the model.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

from scantex.arrays import read_only, unique_rows
from scantex.scan import Material, Scan
from scantex.views.render import sample_texture


def texture_vertices(scan: Scan) -> np.ndarray:
    """``(F, 3) int64``: one id per texture vertex, for every face corner: corners share an id when they share
    a position, a texture coordinate and a material, all by value.

    The faces of one chart meet at such shared corners. Their indices need not say so: a glTF file repeats a
    position at every UV seam, and some OBJ writers (OpenMVS: the façade's app-style input, 44,127 texture
    coordinates for 14,709 faces) give every face corner a texture coordinate of its own. Requires UVs.
    Computed once per layout (:meth:`Scan.layout_memo`); read-only."""
    return scan.layout_memo("texture_vertices", lambda: read_only(_texture_vertices(scan)))


def _texture_vertices(scan: Scan) -> np.ndarray:
    # the texture coordinates by value (+ 0.0: -0.0 and 0.0 are one), then (position, coordinate, material)
    # as two small integers a corner: unique_rows's fast path
    _, uv_id = unique_rows(scan.uvs + 0.0, return_inverse=True)
    uv_key = uv_id.reshape(-1)[scan.face_uvs] * len(scan.materials) + scan.face_materials[:, None]
    key = np.column_stack([scan.welded[scan.faces].reshape(-1), uv_key.reshape(-1)])
    _, node = unique_rows(key, return_inverse=True)
    return node.reshape(-1, 3).astype(np.int64)


def uv_shells(scan: Scan) -> np.ndarray:
    """``(F,) int`` shell id of every face: faces joined through shared :func:`texture_vertices` (so faces in
    different materials never share a shell).

    Untextured scans get one shell per material. Computed once per layout (:meth:`Scan.layout_memo`);
    read-only.
    """
    return scan.layout_memo("uv_shells", lambda: read_only(_uv_shells(scan)))


def _uv_shells(scan: Scan) -> np.ndarray:
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    if scan.face_uvs is None:
        return scan.face_materials.astype(np.int64)
    F = scan.n_faces
    node = texture_vertices(scan).ravel()
    rows = np.repeat(np.arange(F), 3)
    cols = F + node
    n = F + int(node.max()) + 1
    graph = coo_matrix((np.ones(rows.size), (rows, cols)), shape=(n, n))
    _, labels = connected_components(graph, directed=False)
    _, shell = np.unique(labels[:F], return_inverse=True)
    return shell


@dataclass(frozen=True, eq=False)
class SeamEdges:
    """Mesh edges shared by two faces whose UVs differ along the edge.

    Attributes:
        faces: ``(E, 2) int64`` the two faces of each seam edge.
        corners: ``(E, 2, 2) int64`` for each face, its local corner indices (0..2) of the edge's two
            positions, in the same position order for both faces.
    """

    faces: np.ndarray
    corners: np.ndarray

    def __len__(self) -> int:
        return len(self.faces)

    def smooth(self, normals: np.ndarray, max_crease_deg: float) -> SeamEdges:
        """The seam edges whose two faces (``normals (F, 3)``, unit) meet at no sharper crease than
        ``max_crease_deg``: one surface stored twice, not two surfaces (a wall meeting the floor)."""
        keep = (normals[self.faces[:, 0]] * normals[self.faces[:, 1]]).sum(axis=1) >= np.cos(np.radians(max_crease_deg))
        return SeamEdges(self.faces[keep], self.corners[keep])


def with_seams_of(edges: SeamEdges, other: SeamEdges) -> SeamEdges:
    """``edges`` and the edges of ``other`` it lacks (two faces share one edge at most: an edge is its faces):
    one layout's seams and another's on the same faces (the old layout's then lie inside the new charts)."""
    def keys(e: SeamEdges) -> np.ndarray:
        return np.sort(e.faces, axis=1) @ np.array([1, 1 << 32], np.int64) if len(e) else np.zeros(0, np.int64)

    extra = ~np.isin(keys(other), keys(edges))
    return SeamEdges(np.concatenate([edges.faces, other.faces[extra]]),
                     np.concatenate([edges.corners, other.corners[extra]]))


def seam_edges(scan: Scan) -> SeamEdges:
    """Find the seam edges (only edges shared by exactly two faces; non-manifold ones are skipped). Computed
    once per layout (:meth:`Scan.layout_memo`); read-only."""
    def find() -> SeamEdges:
        edges = _seam_edges(scan)
        return SeamEdges(read_only(edges.faces), read_only(edges.corners))

    return scan.layout_memo("seam_edges", find)


def _seam_edges(scan: Scan) -> SeamEdges:
    if scan.face_uvs is None:
        return SeamEdges(np.zeros((0, 2), np.int64), np.zeros((0, 2, 2), np.int64))
    # edges are matched by position *value*: glTF-style meshes repeat a position along every UV seam,
    # so the two faces of a seam edge do not share vertex indices (an analysis-only weld)
    f = scan.welded[scan.faces]
    F = len(f)
    local = np.array([[0, 1], [1, 2], [2, 0]])
    a = f[:, local[:, 0]].ravel()  # [F*3]
    b = f[:, local[:, 1]].ravel()
    lo, hi = np.minimum(a, b), np.maximum(a, b)
    face = np.repeat(np.arange(F), 3)
    # local corner of the smaller / larger position index, so both faces list the edge alike
    ca = np.tile(local[:, 0], F)
    cb = np.tile(local[:, 1], F)
    c_lo = np.where(a <= b, ca, cb)
    c_hi = np.where(a <= b, cb, ca)
    order = np.lexsort((hi, lo))
    lo, hi, face, c_lo, c_hi = lo[order], hi[order], face[order], c_lo[order], c_hi[order]
    same = (lo[1:] == lo[:-1]) & (hi[1:] == hi[:-1])
    start = np.flatnonzero(same)
    # keep pairs that are exactly two (not part of a longer run)
    run_ok = np.ones(len(start), bool)
    if len(start):
        prev = np.concatenate([[False], same])[start]
        nxt = np.concatenate([same, [False]])[start + 1]
        run_ok = ~prev & ~nxt
    i, j = start[run_ok], start[run_ok] + 1
    fi, fj = face[i], face[j]
    uv_i = np.stack([scan.face_uvs[fi, c_lo[i]], scan.face_uvs[fi, c_hi[i]]], axis=1)
    uv_j = np.stack([scan.face_uvs[fj, c_lo[j]], scan.face_uvs[fj, c_hi[j]]], axis=1)
    differs = (uv_i != uv_j).any(axis=1) | (scan.face_materials[fi] != scan.face_materials[fj])
    # identical UV coordinates under different indices are no seam
    coords_i = scan.uvs[uv_i]
    coords_j = scan.uvs[uv_j]
    differs &= ~np.all(coords_i == coords_j, axis=(1, 2)) | (scan.face_materials[fi] != scan.face_materials[fj])
    sel = np.flatnonzero(differs)
    faces = np.stack([fi[sel], fj[sel]], axis=1)
    corners = np.stack([np.stack([c_lo[i][sel], c_hi[i][sel]], 1), np.stack([c_lo[j][sel], c_hi[j][sel]], 1)], 1)
    return SeamEdges(faces, corners)


def seam_visibility(scan: Scan, edges: SeamEdges | None = None, samples_per_edge: int = 8,
                    inset_texels: float = 1.0) -> float:
    """Mean absolute RGB difference (0-255 scale) between the two sides of every seam.

    Points along each seam edge are looked up in the atlas through each of its two faces; each lookup
    is moved ``inset_texels`` into its own face, perpendicular to the edge, so that it reads the
    chart's texels, not the gutter.
    """
    edges = seam_edges(scan) if edges is None else edges
    if len(edges) == 0 or not scan.is_textured:
        return 0.0
    S = samples_per_edge
    t = np.tile((np.arange(S) + 0.5) / S, len(edges))  # along each edge
    sides = []
    for side in range(2):
        faces = np.repeat(edges.faces[:, side], S)
        corners = np.repeat(edges.corners[:, side], S, axis=0)
        sides.append(seam_side_colours(scan, faces, corners, t, inset_texels))
    return float(np.abs(sides[0] - sides[1]).mean() * 255.0)


def seam_side_colours(scan: Scan, faces: np.ndarray, corners: np.ndarray, t: np.ndarray,
                       inset_texels: float) -> np.ndarray:
    """``(N, 3)`` colour at parameter ``t (N,)`` along each seam edge's UV segment in face ``faces (N,)``,
    looked up ``inset_texels`` inside the face (away from the gutter)."""
    return seam_sides(scan, faces, corners, inset_texels).colours(scan, np.arange(len(faces)), t)


@dataclass(frozen=True)
class SeamSides:
    """Seam edges' UV segments as the faces of one side hold them, and the step inside each face that a
    lookup along the segment takes (:func:`seam_sides`): what :func:`seam_side_colours` computes per edge,
    kept for a caller that reads many points of the same edges (seam blending: a few dozen texels an edge)."""

    start: np.ndarray  # (N, 2) the segment's first corner, in UV
    along: np.ndarray  # (N, 2) from the first corner to the second
    inset: np.ndarray  # (N, 2) the lookup's step inside the face, in UV (0 for no material image)
    material: np.ndarray  # (N,) the face's material

    def colours(self, scan: Scan, rows: np.ndarray, t: np.ndarray) -> np.ndarray:
        """``(n, 3)`` colour at parameter ``t (n,)`` along sides ``rows (n,)``, the step inside included."""
        point = self.start[rows] + t[:, None] * self.along[rows]
        out = np.zeros((len(rows), 3), np.float32)
        for material, sel in _textured_rows(scan, self.material[rows]):
            out[sel] = sample_texture(material.image, point[sel] + self.inset[rows[sel]])[:, :3]
        return out


def _textured_rows(scan: Scan, material_of: np.ndarray) -> Iterator[tuple[Material, np.ndarray]]:
    """Each material of ``scan`` that has an image, with the rows of ``material_of (n,)`` (a material index a row)
    that are its."""
    for m, material in enumerate(scan.materials):
        sel = np.flatnonzero(material_of == m)
        if material.image is not None and sel.size:
            yield material, sel


def seam_sides(scan: Scan, faces: np.ndarray, corners: np.ndarray, inset_texels: float) -> SeamSides:
    """The :class:`SeamSides` of the seam edges whose corners ``corners (N, 2)`` (0-2) are in faces
    ``faces (N,)``, looked up ``inset_texels`` inside each face (at most half its height there)."""
    rows = np.arange(len(faces))
    uv_tri = scan.uvs[scan.face_uvs[faces]]  # [N, 3, 2]
    p0, p1 = uv_tri[rows, corners[:, 0]], uv_tri[rows, corners[:, 1]]
    opposite = uv_tri[rows, 3 - corners[:, 0] - corners[:, 1]]
    inset = np.zeros((len(faces), 2), np.float64)
    mat = scan.face_materials[faces]
    for material, sel in _textured_rows(scan, mat):
        H, W = material.image.shape[:2]
        px = np.array([W, H], np.float64)
        e = (p1[sel] - p0[sel]) * px
        normal = np.stack([-e[:, 1], e[:, 0]], axis=1)
        length = np.linalg.norm(normal, axis=1, keepdims=True)
        normal = np.divide(normal, length, out=np.zeros_like(normal), where=length > 0)
        height = ((opposite[sel] - p0[sel]) * px * normal).sum(axis=1, keepdims=True)
        step = np.sign(height) * np.minimum(inset_texels, 0.5 * np.abs(height))
        inset[sel] = normal * step / px
    return SeamSides(p0, p1 - p0, inset, mat)
