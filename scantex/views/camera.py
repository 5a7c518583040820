"""Pinhole cameras in one convention: OpenCV.

A world point ``X`` maps to camera coordinates ``x_cam = R @ X + t`` (``world_to_camera = [[R, t],
[0, 1]]``), with +x right, +y down and +z forward; its pixel is ``K @ x_cam / z``, where pixel
``(0, 0)`` is the *centre* of the top-left pixel. This is the convention of COLMAP, OpenCV and the
``cameras.json`` files scantex reads and writes.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True, eq=False)
class Camera:
    """A pinhole camera.

    Attributes:
        K: ``(3, 3) float64`` intrinsics in pixels.
        world_to_camera: ``(4, 4) float64`` extrinsics ``[[R, t], [0, 1]]``.
        width: image width in pixels.
        height: image height in pixels.
    """

    K: np.ndarray
    world_to_camera: np.ndarray
    width: int
    height: int

    def __post_init__(self) -> None:
        object.__setattr__(self, "K", np.asarray(self.K, dtype=np.float64).reshape(3, 3))
        object.__setattr__(self, "world_to_camera",
                           np.asarray(self.world_to_camera, dtype=np.float64).reshape(4, 4))
        object.__setattr__(self, "width", int(self.width))
        object.__setattr__(self, "height", int(self.height))

    @classmethod
    def look_at(cls, eye, target, up=(0.0, 0.0, 1.0), fov_deg: float = 60.0,
                width: int = 512, height: int = 512) -> Camera:
        """A camera at ``eye`` looking at ``target``; ``fov_deg`` is the horizontal field of view."""
        eye = np.asarray(eye, dtype=np.float64)
        forward = np.asarray(target, dtype=np.float64) - eye
        forward /= np.linalg.norm(forward)
        up = np.asarray(up, dtype=np.float64)
        if abs(np.dot(forward, up / np.linalg.norm(up))) > 0.999:  # looking along up: pick another
            up = np.array([0.0, 1.0, 0.0]) if abs(forward[1]) < 0.9 else np.array([1.0, 0.0, 0.0])
        right = np.cross(forward, up)
        right /= np.linalg.norm(right)
        down = np.cross(forward, right)
        R = np.stack([right, down, forward])  # rows: camera axes in world coordinates
        w2c = np.eye(4)
        w2c[:3, :3] = R
        w2c[:3, 3] = -R @ eye
        f = 0.5 * width / np.tan(np.radians(fov_deg) / 2)
        K = np.array([[f, 0, (width - 1) / 2], [0, f, (height - 1) / 2], [0, 0, 1]])
        return cls(K, w2c, width, height)

    @property
    def R(self) -> np.ndarray:
        return self.world_to_camera[:3, :3]

    @property
    def t(self) -> np.ndarray:
        return self.world_to_camera[:3, 3]

    @property
    def center(self) -> np.ndarray:
        """``(3,)`` the camera's position in world coordinates."""
        return -self.R.T @ self.t

    @property
    def forward(self) -> np.ndarray:
        """``(3,)`` the viewing direction (+z of the camera) in world coordinates."""
        return self.R[2]

    def scaled(self, factor: float) -> Camera:
        """The same camera with an image ``factor`` times larger (pixel centres kept consistent)."""
        K = self.K.copy()
        K[:2, :2] *= factor
        K[:2, 2] = (K[:2, 2] + 0.5) * factor - 0.5
        return dataclasses.replace(self, K=K, width=round(self.width * factor),
                                   height=round(self.height * factor))

    def pixel_rays(self) -> tuple[np.ndarray, np.ndarray]:
        """Rays through every pixel centre, row-major.

        Returns:
            origin: ``(3,) float64``, the camera centre (shared by all rays).
            directions: ``(H * W, 3) float32`` world directions with unit camera-z component, so a
            hit distance along them is the pixel's depth.
        """
        xs = np.arange(self.width, dtype=np.float32)[None, :]
        ys = np.arange(self.height, dtype=np.float32)[:, None]
        directions = np.empty((self.height, self.width, 3), np.float32)
        for k, component in enumerate(self._ray_components(xs, ys)):
            directions[:, :, k] = component
        return self.center.copy(), directions.reshape(-1, 3)

    def ray_cosines(self, normals: np.ndarray) -> np.ndarray:
        """``(H, W) float32``: the absolute cosine of the angle between each pixel's ray (:meth:`pixel_rays`) and
        ``normals`` (``(H, W, 3)`` or ``(H * W, 3)`` unit vectors; a zero one gives 0), without the rays'
        ``(H * W, 3)`` array (a component at a time: several times faster)."""
        xs = np.arange(self.width, dtype=np.float32)[None, :]
        ys = np.arange(self.height, dtype=np.float32)[:, None]
        normals = np.asarray(normals).reshape(self.height, self.width, 3)
        dot = np.zeros((self.height, self.width), np.float32)
        length = np.zeros((self.height, self.width), np.float32)
        for k, d in enumerate(self._ray_components(xs, ys)):
            dot += d * normals[:, :, k]
            length += d * d
        return np.abs(dot) / np.sqrt(length)

    def _ray_components(self, x: np.ndarray, y: np.ndarray) -> Iterator[np.ndarray]:
        """The x, y and z components of the rays through pixels ``(x, y)`` (float32 arrays that broadcast), one at a
        time: numpy's loops over rows of three are several times slower. The one expression :meth:`pixel_rays`,
        :meth:`rays_through` and :meth:`ray_cosines` share, so that their rays agree bit for bit."""
        A, B, C = self._ray_axes()
        for k in range(3):
            yield x * A[k] + (y * B[k] + C[k])

    def _ray_axes(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(A, B, C)``, ``(3,) float32`` each: R^T K^-1 [x, y, 1] = A x + B y + C, pixel ``(x, y)``'s ray."""
        M = self.R.T @ np.linalg.inv(self.K)
        return tuple(M[:, k].astype(np.float32) for k in range(3))

    def rays_through(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """``(N, 3) float32`` directions through pixels ``(x, y)`` (integer columns and rows ``(N,)``): the
        same values, bit for bit, as :meth:`pixel_rays` gives those pixels."""
        x, y = np.asarray(x, np.float32), np.asarray(y, np.float32)
        directions = np.empty((len(x), 3), np.float32)
        for k, component in enumerate(self._ray_components(x, y)):
            directions[:, k] = component
        return directions

    def project(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Pixels ``(N, 2)`` and depths ``(N,)`` of world points ``(N, 3)``."""
        # the small matrices transposed into contiguous arrays: numpy multiplies by a transposed view
        # several times slower
        x_cam = points @ np.ascontiguousarray(self.R.T) + self.t
        z = x_cam[:, 2]
        uvw = x_cam @ np.ascontiguousarray(self.K.T)
        with np.errstate(divide="ignore", invalid="ignore"):
            pix = uvw[:, :2] / uvw[:, 2:3]
        return pix, z

    def to_dict(self) -> dict:
        return {"width": self.width, "height": self.height, "K": self.K.tolist(),
                "world_to_camera": self.world_to_camera.tolist()}

    @classmethod
    def from_dict(cls, d: dict) -> Camera:
        return cls(np.array(d["K"]), np.array(d["world_to_camera"]), d["width"], d["height"])
