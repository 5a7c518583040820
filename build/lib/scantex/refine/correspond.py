"""Pixel correspondences between two views from their G-buffers (for cross-view consistency).

A pixel of view A sees the surface point ``centre_A + depth_A * ray``; its pixel in view B is that
point's projection, and B sees the *same* point only if B's depth buffer there agrees with the point's
depth in B (otherwise something nearer occludes it, or B sees the surface's other side).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from scantex.views.camera import Camera


@dataclass(frozen=True, eq=False)
class Correspondence:
    """Where the pixels of view ``a`` are seen in view ``b``.

    Attributes:
        a, b: view indices.
        pixels: ``(H, W, 2) float32`` ``(x, y)`` pixel of each A pixel in B (OpenCV centres).
        mask: ``(H, W) bool`` A pixels that B sees too.
    """

    a: int
    b: int
    pixels: np.ndarray
    mask: np.ndarray


def correspond(camera_a: Camera, depth_a: np.ndarray, valid_a: np.ndarray, camera_b: Camera,
               depth_b: np.ndarray, valid_b: np.ndarray, tolerance: float = 0.01) -> tuple[np.ndarray, np.ndarray]:
    """Pixels of view A's surface points in view B.

    Args:
        camera_a, camera_b: the views.
        depth_a, depth_b: ``(H, W)`` camera-z of each pixel's surface point (inf or anything where
            ``valid`` is False).
        valid_a, valid_b: ``(H, W) bool`` pixels with a usable surface point.
        tolerance: largest relative depth difference at which B still sees the point.

    Returns:
        ``pixels (H_a, W_a, 2) float32`` and ``mask (H_a, W_a) bool`` (see :class:`Correspondence`).
    """
    Ha, Wa = depth_a.shape
    origin, directions = camera_a.pixel_rays()
    d = np.where(valid_a, depth_a, 0).reshape(-1, 1).astype(np.float64)
    points = origin + directions.astype(np.float64) * d  # [Ha * Wa, 3]
    pix, z = camera_b.project(points)
    seen = seen_at(depth_b, valid_b, pix, z, tolerance) & valid_a.reshape(-1)
    pixels = np.where(seen[:, None], pix, 0).astype(np.float32)
    return pixels.reshape(Ha, Wa, 2), seen.reshape(Ha, Wa)


def seen_at(depth: np.ndarray, valid: np.ndarray, pix: np.ndarray, z: np.ndarray, tolerance: float) -> np.ndarray:
    """``(N,) bool``: a view with ``depth, valid (H, W)`` sees the points at ``pix (N, 2)``, depth ``z (N,)``.

    The view's depth is interpolated bilinearly at the point's pixel (a surface seen at a grazing angle
    changes depth fast from one pixel to the next), or read at the nearest pixel where a neighbour is
    unusable; the point is seen if that depth is within ``tolerance`` (relative) of its own.
    """
    H, W = depth.shape
    with np.errstate(invalid="ignore"):
        inside = (z > 0) & (pix[:, 0] > -0.5) & (pix[:, 0] < W - 0.5) & (pix[:, 1] > -0.5) & (pix[:, 1] < H - 0.5)
    x = np.where(inside, pix[:, 0], 0).clip(0, W - 1)
    y = np.where(inside, pix[:, 1], 0).clip(0, H - 1)
    d = np.where(valid, depth, np.nan)
    xn, yn = np.rint(x).astype(np.int64), np.rint(y).astype(np.int64)
    x0 = np.minimum(np.floor(x).astype(np.int64), max(W - 2, 0))
    y0 = np.minimum(np.floor(y).astype(np.int64), max(H - 2, 0))
    x1, y1 = np.minimum(x0 + 1, W - 1), np.minimum(y0 + 1, H - 1)
    fx, fy = x - x0, y - y0
    bilinear = ((d[y0, x0] * (1 - fx) + d[y0, x1] * fx) * (1 - fy) + (d[y1, x0] * (1 - fx) + d[y1, x1] * fx) * fy)
    near = d[yn, xn]
    surface = np.where(np.isnan(bilinear), near, bilinear)
    with np.errstate(invalid="ignore"):
        return inside & valid[yn, xn] & (np.abs(surface - z) <= tolerance * np.abs(z))


def partners(face_id: np.ndarray, valid: np.ndarray, n_faces: int) -> np.ndarray:
    """For every view, the other view that sees the most of the same faces: ``(N,) int64``.

    Args:
        face_id: ``(N, H, W)`` face each pixel sees (-1: none).
        valid: ``(N, H, W) bool`` usable pixels.
    """
    N = len(face_id)
    seen = np.zeros((N, n_faces), np.float32)
    for i in range(N):
        seen[i, np.unique(face_id[i][valid[i]])] = 1
    shared = seen @ seen.T
    np.fill_diagonal(shared, -1)
    return shared.argmax(axis=1)
