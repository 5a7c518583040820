"""Shells and seams seen by the UV optimiser: how far apart a seam's two sides lie in the atlas,
which shells touch along how much seam, and each shell's distortion and texel density.

Builds on :mod:`scantex.atlas.seams` (``uv_shells``, ``seam_edges``) and never changes a scan.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from scantex.arrays import uv_areas
from scantex.atlas.seams import SeamEdges, seam_edges, uv_shells
from scantex.scan import Scan
from scantex.uv.param import distortions


def material_sizes(scan: Scan, texture_size: int = 1024) -> np.ndarray:
    """``(M, 2)`` atlas ``(width, height)`` in texels per material (``texture_size`` where no image)."""
    sizes = np.full((len(scan.materials), 2), texture_size, dtype=np.int64)
    for m, material in enumerate(scan.materials):
        if material.image is not None:
            sizes[m] = material.image.shape[1], material.image.shape[0]
    return sizes


def texel_uvs(scan: Scan, texture_size: int = 1024) -> np.ndarray:
    """``(F, 3, 2)`` corner UVs in texels of each face's own atlas."""
    size = material_sizes(scan, texture_size)[scan.face_materials]  # [F, 2]
    return scan.triangle_uvs * size[:, None, :]


def seam_distances(scan: Scan, edges: SeamEdges | None = None, texture_size: int = 1024) -> np.ndarray:
    """``(E,)`` distance in texels between the two sides of every seam edge.

    The mean, over the edge's two end points, of the distance between the UVs the two faces give that
    point (0 would be no seam at all). Edges between faces of different materials are ``inf``: their
    sides lie in different atlases.
    """
    edges = seam_edges(scan) if edges is None else edges
    if len(edges) == 0:
        return np.zeros(0)
    tex = texel_uvs(scan, texture_size)
    side_a = tex[edges.faces[:, 0:1], edges.corners[:, 0]]  # [E, 2, 2]: end point, (x, y)
    side_b = tex[edges.faces[:, 1:2], edges.corners[:, 1]]
    d = np.linalg.norm(side_a - side_b, axis=2).mean(axis=1)
    cross = scan.face_materials[edges.faces[:, 0]] != scan.face_materials[edges.faces[:, 1]]
    return np.where(cross, np.inf, d)


def edge_lengths(scan: Scan, edges: SeamEdges) -> np.ndarray:
    """``(E,)`` 3D length of every seam edge in metres."""
    f = scan.faces[edges.faces[:, 0]]
    rows = np.arange(len(edges))
    p0 = scan.positions[f[rows, edges.corners[:, 0, 0]]]
    p1 = scan.positions[f[rows, edges.corners[:, 0, 1]]]
    return np.linalg.norm(p1 - p0, axis=1)


def texel_density(scan: Scan, chart_of_face: np.ndarray | None = None, texture_size: int = 1024) -> np.ndarray:
    """``(C,)`` texels per centimetre of every chart: ``sqrt(texel area / surface area in cm²)``."""
    if chart_of_face is None:
        chart_of_face = uv_shells(scan)
    uv_area = uv_areas(texel_uvs(scan, texture_size))
    C = int(chart_of_face.max()) + 1
    surface = np.bincount(chart_of_face, scan.face_areas, C) * 1e4  # cm²
    texels = np.bincount(chart_of_face, uv_area, C)
    return np.sqrt(np.divide(texels, surface, out=np.zeros(C), where=surface > 0))


def stats(values: np.ndarray) -> dict:
    """``{"min", "median", "max", "count"}`` of finite values, JSON-ready (``None`` when empty)."""
    v = np.asarray(values, dtype=np.float64)
    v = v[np.isfinite(v)]
    if v.size == 0:
        return {"min": None, "median": None, "max": None, "count": 0}
    return {"min": float(v.min()), "median": float(np.median(v)), "max": float(v.max()), "count": int(v.size)}


@dataclass(frozen=True)
class LayoutSummary:
    """Counts and statistics of one UV layout (see :func:`summarise`)."""

    shells: int
    seam_edges: int
    seam_length_m: float
    seam_distance_texels: dict
    stretch: dict
    stretch_area_weighted: float
    density_px_per_cm: dict
    collapsed_faces: int = 0
    """faces of some surface whose UV triangle is a line (corners in a row): their texels are stretched without
    bound, so the stretch figures leave them out (the bathroom's 10 made its largest stretch 7.7e11)"""

    def as_dict(self) -> dict:
        return dict(self.__dict__)


def summarise(scan: Scan, texture_size: int = 1024) -> LayoutSummary | None:
    """Shells, seams, distortion and texel density of a scan's UV layout (``None`` without UVs)."""
    if not scan.has_uvs:
        return None
    shells = uv_shells(scan)
    edges = seam_edges(scan)
    uvs = texel_uvs(scan, texture_size)
    collapsed = (_flatness(uvs, uv_areas(uvs)) < COLLAPSED) & (_flatness(scan.triangles, scan.face_areas) >= FLAT)
    keep = ~collapsed
    dist = distortions(scan.triangles[keep], uvs[keep], shells[keep], int(shells.max()) + 1)
    stretch = np.array([d.stretch for d in dist])
    area = np.array([d.surface_area for d in dist])
    ok = np.isfinite(stretch)
    weighted = float((stretch[ok] * area[ok]).sum() / max(area[ok].sum(), 1e-300)) if ok.any() else float("nan")
    return LayoutSummary(
        shells=int(shells.max()) + 1,
        seam_edges=len(edges),
        seam_length_m=float(edge_lengths(scan, edges).sum()),
        seam_distance_texels=stats(seam_distances(scan, edges, texture_size)),
        stretch=stats(stretch),
        stretch_area_weighted=weighted,
        # over the charts of some surface: a chart of faces of no area has no density (the bathroom's 3,869 such
        # faces made the median 0)
        density_px_per_cm=stats(texel_density(scan, shells, texture_size)[area > 0]),
        collapsed_faces=int(collapsed.sum()),
    )


#: a UV triangle whose area is below this share of its longest edge squared is a line (:func:`summarise`)
COLLAPSED = 1e-6
#: ... where its 3D triangle's is at least this (a sliver in 3D may be a sliver in UV)
FLAT = 1e-3


def _flatness(corners: np.ndarray, area: np.ndarray) -> np.ndarray:
    """``(F,)`` each triangle's ``area (F,)`` over its longest edge squared, from its ``(F, 3, D)`` corners (2-D or
    3-D): about 0.43 for an equilateral triangle, 0 for corners in a row."""
    longest = ((corners[:, [1, 2, 0]] - corners) ** 2).sum(axis=2).max(axis=1)
    return np.divide(area, longest, out=np.zeros_like(area, dtype=np.float64), where=longest > 0)
