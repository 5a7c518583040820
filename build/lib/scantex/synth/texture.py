"""Baking a procedural albedo into an atlas, and filling the gutters around charts.

The bake evaluates the albedo at sub-texel points of every covered texel. Inside one triangle the map
from atlas pixels to 3D is affine, so the sub-texel points are the texel's centre plus that map's
Jacobian times the sub-pixel offset: no second, finer texel map is needed (an 8192² one would take
about 1 GB).
"""

from __future__ import annotations

import logging
from collections.abc import Callable

import numpy as np
from scipy import ndimage

from scantex.atlas.texelmap import TexelMap, texel_map, uv_to_pixel
from scantex.views.raycast import interpolate

log = logging.getLogger(__name__)

#: covered texels per bake chunk
CHUNK = 1 << 20

Albedo = Callable[[np.ndarray], np.ndarray]


def pixel_jacobians(triangles: np.ndarray, triangle_pixels: np.ndarray) -> np.ndarray:
    """``(F, 2, 3)`` change of the 3D point per atlas pixel step in x and in y, per face.

    Args:
        triangles: ``(F, 3, 3)`` corner positions.
        triangle_pixels: ``(F, 3, 2)`` corner positions in atlas pixels.

    Faces that are degenerate in the atlas get zeros.
    """
    e3 = triangles[:, 1:] - triangles[:, :1]  # [F, 2, 3]
    e2 = triangle_pixels[:, 1:] - triangle_pixels[:, :1]  # [F, 2, 2]: rows are pixel edges
    det = e2[:, 0, 0] * e2[:, 1, 1] - e2[:, 0, 1] * e2[:, 1, 0]
    ok = np.abs(det) > 1e-12
    inv = np.zeros_like(e2)
    inv[ok] = np.linalg.inv(e2[ok])
    # a pixel offset d = w @ e2 moves the point by w @ e3, so d -> d @ inv(e2) @ e3
    return inv @ e3


def bake_albedo(triangles: np.ndarray, triangle_uvs: np.ndarray, albedo: Albedo, size: int,
                supersample: int = 2) -> tuple[np.ndarray, TexelMap]:
    """The albedo baked into a ``size``² atlas, averaged over ``supersample``² points per texel.

    Args:
        triangles: ``(F, 3, 3)`` corner positions.
        triangle_uvs: ``(F, 3, 2)`` corner UVs.
        albedo: ``(N, 3) points -> (N, 3) float32`` colours.
        size: atlas width and height in texels.
        supersample: sub-texel points per axis (1: the texel centre only).

    Returns:
        ``(image, texels)``: ``(size, size, 3) float32`` colours (zero where no face is mapped) and the
        texel map they were baked through.
    """
    texels = texel_map(triangle_uvs, size, size)
    mask = texels.mask
    face_id = texels.face_id[mask]
    bary = texels.bary[mask]
    jac = pixel_jacobians(triangles, uv_to_pixel(triangle_uvs, size, size)).astype(np.float32)
    steps = (np.arange(supersample) + 0.5) / supersample - 0.5
    offsets = np.stack(np.meshgrid(steps, steps, indexing="ij"), axis=-1).reshape(-1, 2)
    colours = np.empty((len(face_id), 3), dtype=np.float32)
    for start in range(0, len(face_id), CHUNK):
        fid = face_id[start:start + CHUNK]
        centre = interpolate(fid, bary[start:start + CHUNK], triangles)  # [n, 3]
        j = jac[fid]  # [n, 2, 3]
        total = np.zeros((len(fid), 3), dtype=np.float32)
        for dx, dy in offsets:
            total += albedo(centre + dx * j[:, 0] + dy * j[:, 1])
        colours[start:start + CHUNK] = total / len(offsets)
    image = np.zeros((size, size, 3), dtype=np.float32)
    image[mask] = colours
    log.debug("baked %d texels (%d samples each) into %d²", len(face_id), len(offsets), size)
    return image, texels


def nearest_covered(mask: np.ndarray, max_distance: float) -> tuple[np.ndarray, np.ndarray]:
    """For every texel, the nearest covered texel, if one lies within ``max_distance`` texels.

    Returns:
        ``(rows, cols)`` ``(H, W) int`` of the nearest covered texel (the texel itself where covered),
        and ``within`` ``(H, W) bool``: covered or within reach.
    """
    distance, (rows, cols) = ndimage.distance_transform_edt(~mask, return_indices=True)
    return (rows, cols), distance <= max_distance


def dilate(image: np.ndarray, mask: np.ndarray, texels: float) -> np.ndarray:
    """Fill uncovered texels up to ``texels`` away from a chart with the nearest covered colour.

    That is what keeps bilinear lookups at chart borders from pulling in the black outside the charts.
    Texels further away are set to zero.
    """
    (rows, cols), within = nearest_covered(mask, texels)
    out = image[rows, cols]
    out[~within] = 0
    return out
