"""Back-projection: refined views return to the atlas as a weighted fusion over the views that see a texel.

What is fused is the refiner's *change* (refined view - the view it was given), added to the base colour
the views were rendered from. An unchanged view therefore gives back the base texture exactly, at the
atlas's own resolution (resampling the base through views would blur it), and texels no view sees keep
the base colour with no step at the border of what the views cover.

A view's weight at a texel is the product of:
- its viewing angle, ``cos`` between the normal and the ray (grazing views smear);
- its pixel footprint, ``(f / z)^2 * cos``: pixels per unit of surface (finer views know more);
- a confidence ramp on the distance from the view's edges and occlusion boundaries (pixels there mix
  surfaces, and the refiner saw less context);
and zero where the view's depth buffer shows something else in front of the texel's point.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from scantex.atlas.bake import SurfaceColour
from scantex.refine.correspond import seen_at
from scantex.views.camera import Camera


@dataclass(frozen=True, eq=False)
class ViewResiduals:
    """Refined views as changes over what they were rendered from.

    Attributes:
        cameras: the views.
        residual: ``(N, H, W, 3) float32`` refined - input colour (zero where a view sees nothing usable).
        depth: ``(N, H, W) float32`` camera-z of each pixel's surface point (inf: none).
        confidence: ``(N, H, W) float32`` in [0, 1] (see :func:`edge_confidence`).
    """

    cameras: tuple[Camera, ...]
    residual: np.ndarray
    depth: np.ndarray
    confidence: np.ndarray


def edge_confidence(usable: np.ndarray, ramp: float) -> np.ndarray:
    """``(H, W) float32``: 0 at and beyond the edges of ``usable (H, W) bool``, rising smoothly to 1 at
    ``ramp`` pixels inside (image borders count as edges)."""
    padded = np.pad(usable, 1, constant_values=False)
    distance = ndimage.distance_transform_edt(padded)[1:-1, 1:-1]
    t = np.clip((distance - 0.5) / max(ramp, 1e-6), 0, 1)
    return (t * t * (3 - 2 * t)).astype(np.float32)


def occlusion_edges(depth: np.ndarray, hit: np.ndarray, jump: float = 0.02) -> np.ndarray:
    """``(H, W) bool`` pixels that see a surface with no depth discontinuity to any 4-neighbour."""
    d = np.where(hit, depth, np.inf)
    ok = hit.copy()
    for axis in (0, 1):
        with np.errstate(invalid="ignore"):
            step = np.abs(np.diff(d, axis=axis))
            edge = ~(step <= jump * np.minimum(np.take(d, range(d.shape[axis] - 1), axis),
                                                np.take(d, range(1, d.shape[axis]), axis)))
        if axis == 0:
            ok[:-1] &= ~edge
            ok[1:] &= ~edge
        else:
            ok[:, :-1] &= ~edge
            ok[:, 1:] &= ~edge
    return ok


def _bilinear(image: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """``image (H, W, C)`` at pixel centres ``(x, y)`` (clamped to the image)."""
    H, W = image.shape[:2]
    x = np.clip(x, 0, W - 1)
    y = np.clip(y, 0, H - 1)
    x0 = np.minimum(np.floor(x).astype(np.int64), W - 2) if W > 1 else np.zeros(len(x), np.int64)
    y0 = np.minimum(np.floor(y).astype(np.int64), H - 2) if H > 1 else np.zeros(len(y), np.int64)
    fx = (x - x0)[:, None].astype(np.float32)
    fy = (y - y0)[:, None].astype(np.float32)
    x1, y1 = np.minimum(x0 + 1, W - 1), np.minimum(y0 + 1, H - 1)
    top = image[y0, x0] * (1 - fx) + image[y0, x1] * fx
    bottom = image[y1, x0] * (1 - fx) + image[y1, x1] * fx
    return top * (1 - fy) + bottom * fy


def view_weights(camera: Camera, depth: np.ndarray, confidence: np.ndarray, points: np.ndarray,
                 normals: np.ndarray, tolerance: float) -> tuple[np.ndarray, np.ndarray]:
    """One view's fusion weight ``(N,)`` at surface ``points (N, 3)`` and their pixels ``(N, 2)``."""
    H, W = depth.shape
    pix, z = camera.project(points)
    visible = seen_at(depth, np.isfinite(depth), pix, z, tolerance)
    xi = np.rint(np.where(visible, pix[:, 0], 0)).astype(np.int64)
    yi = np.rint(np.where(visible, pix[:, 1], 0)).astype(np.int64)
    ray = points - camera.center
    ray /= np.linalg.norm(ray, axis=1, keepdims=True)
    cos = np.abs(np.einsum("ij,ij->i", ray, normals))
    f = float(np.sqrt(camera.K[0, 0] * camera.K[1, 1]))
    with np.errstate(divide="ignore", invalid="ignore"):
        footprint = np.where(visible, (f / np.where(visible, z, 1.0)) ** 2 * cos, 0.0)
    weight = np.where(visible, cos * footprint * confidence[yi, xi], 0.0)
    return weight, pix


def fuse_views(views: ViewResiduals, base: SurfaceColour, *, tolerance: float = 0.01) -> SurfaceColour:
    """A :data:`SurfaceColour` for :func:`scantex.atlas.bake.bake`: ``base`` plus the weighted mean of the
    views' residuals at each point (``base`` alone where no view sees it).

    Args:
        views: the refined views.
        base: the colour the views were rendered from.
        tolerance: largest relative depth difference at which a view still sees a point.
    """

    def colour(points, normals, face_ids, bary):
        rgb = np.asarray(base(points, normals, face_ids, bary), dtype=np.float32)
        total = np.zeros((len(points), 3), np.float64)
        weight_sum = np.zeros(len(points), np.float64)
        for i, camera in enumerate(views.cameras):
            w, pix = view_weights(camera, views.depth[i], views.confidence[i], points, normals, tolerance)
            sel = np.flatnonzero(w > 0)
            if sel.size == 0:
                continue
            total[sel] += w[sel, None] * _bilinear(views.residual[i], pix[sel, 0], pix[sel, 1])
            weight_sum[sel] += w[sel]
        seen = weight_sum > 0
        rgb[seen] += (total[seen] / weight_sum[seen, None]).astype(np.float32)
        return np.clip(rgb, 0, 1)

    return colour
