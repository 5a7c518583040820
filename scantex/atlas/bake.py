"""Baking: the colour of every covered texel from a function of the surface point, then gutters.

The geometry and the UV layout are the scan's own; only the texture images are new.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from scantex.atlas.padding import pad_gutters
from scantex.atlas.texelmap import texel_map
from scantex.scan import Scan
from scantex.views.render import to_uint8

#: colour of surface points: (points (N, 3), unit normals (N, 3), face ids (N,), barycentrics (N, 2))
#: -> rgb (N, 3) in [0, 1]
SurfaceColour = Callable[[np.ndarray, np.ndarray, np.ndarray, np.ndarray], np.ndarray]


def output_size(scan: Scan, material: int, requested: int = 0, cap: int = 8192) -> tuple[int, int]:
    """Atlas size for a material: ``requested`` square, or twice the input atlas (at most ``cap``)."""
    if requested:
        return requested, requested
    image = scan.materials[material].image
    if image is None:
        return 1024, 1024
    H, W = image.shape[:2]
    return min(2 * H, cap), min(2 * W, cap)


def bake(scan: Scan, colour: SurfaceColour, *, size: int = 0, chunk: int = 16384,
         progress: Callable[[int, int], None] | None = None) -> tuple[np.ndarray, ...]:
    """New ``(H, W, 3) uint8`` images, one per material (``None`` for materials without UVs/faces).

    Every texel some triangle covers gets ``colour`` at its surface point; the rest are filled from the
    nearest covered texel (gutter padding).
    """
    tri_uv = scan.triangle_uvs
    corners = scan.triangles
    normals = scan.face_normals
    plans = []
    for m in range(len(scan.materials)):
        faces = np.flatnonzero(scan.face_materials == m)
        if faces.size == 0:
            plans.append(None)
            continue
        H, W = output_size(scan, m, size)
        plans.append((faces, H, W))
    maps = [texel_map(tri_uv, p[2], p[1], p[0]) if p else None for p in plans]
    images, done = [], 0
    total = sum(int(t.mask.sum()) for t in maps if t is not None)
    for plan, tmap in zip(plans, maps):
        if plan is None:
            images.append(None)
            continue
        _, H, W = plan
        covered = tmap.mask
        points = tmap.points(corners)
        face_of_texel = tmap.face_id[covered]
        bary = tmap.bary[covered]
        rgb = np.zeros((len(points), 3), np.float32)
        for s in range(0, len(points), chunk):
            e = min(s + chunk, len(points))
            rgb[s:e] = colour(points[s:e], normals[face_of_texel[s:e]], face_of_texel[s:e], bary[s:e])
            done += e - s
            if progress:
                progress(done, total)
        image = np.zeros((H, W, 3), np.float32)
        image[covered] = rgb
        images.append(to_uint8(pad_gutters(image, covered)))
    return tuple(images)
