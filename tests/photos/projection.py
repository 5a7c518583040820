"""Where a photo read by scantex shows world points, for the importers' tests against each tool's own projection."""

from __future__ import annotations

import numpy as np


def stored_pixel(photos, i: int, points) -> np.ndarray:
    """``(N, 2)`` pixels of world ``points (N, 3)`` in photo ``i``'s image as stored: scantex's pose, its stored
    intrinsics and its lens as read (``PhotoSet.as_stored``), skew included."""
    stored = photos.as_stored().cameras[i]
    x_cam = stored.world_to_camera[:3, :3] @ np.asarray(points).T + stored.world_to_camera[:3, 3:]
    x, y = x_cam[0] / x_cam[2], x_cam[1] / x_cam[2]
    if photos.distortions[i] is not None:
        x, y = photos.distortions[i].distort(x, y)
    K = stored.K
    return np.stack([K[0, 0] * x + K[0, 1] * y + K[0, 2], K[1, 1] * y + K[1, 2]], 1)
