"""The conversions between the formats' camera conventions and scantex's, in one place.

scantex (and OpenCV): ``x_cam = R X + t``; camera +x right, +y down, +z forward; pixel ``(0, 0)`` is the
centre of the top-left pixel, so an image ``W`` pixels wide spans ``x`` in ``[-0.5, W - 0.5]``.

- **Camera axes.** OpenGL, Blender, nerfstudio and ARKit (3D Scanner App, Polycam) cameras look down -z
  with +y up. The same camera in OpenCV axes is the OpenGL camera-to-world with its y and z columns
  negated (``c2w_cv = c2w_gl @ diag(1, -1, -1, 1)``); the world frame is untouched, so the mesh stays
  where it is.
- **Pixel centres.** COLMAP, nerfstudio and ARKit measure the principal point from the image's corner
  (the centre of the top-left pixel is ``(0.5, 0.5)``; COLMAP documents it, nerfstudio casts rays
  through ``pixel + 0.5``, Apple: "offsets of the principal point from the top-left corner of the
  image frame"): scantex's ``cx = cx_format - 0.5``. OpenCV's calibration (and scantex's own
  ``cameras.json``) already uses pixel centres: no shift.
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from scantex.errors import ScanError
from scantex.photos.photoset import Distortion
from scantex.views.camera import Camera

if TYPE_CHECKING:
    from scantex.photos.lens import Lens

log = logging.getLogger(__name__)

#: largest pixel shift of a lens distortion that importers ignore (with a warning) by default
MAX_DISTORTION_PX = 1.0

#: OpenGL/ARKit camera axes (+x right, +y up, looking down -z) to OpenCV's (+y down, +z forward), and
#: back: the same diagonal flip both ways
FLIP_YZ = np.diag([1.0, -1.0, -1.0, 1.0])

#: where the centre of the top-left pixel lies in COLMAP, nerfstudio and ARKit pixel coordinates
CORNER_CONVENTION = 0.5
#: ... and in OpenCV's and scantex's
CENTRE_CONVENTION = 0.0


def check_pose(matrix, where: Path, what: str) -> np.ndarray:
    """A ``(4, 4) float64`` rigid transform from a ``(4, 4)`` or ``(3, 4)`` array-like, or a ScanError.

    The rotation must be orthonormal with determinant +1 (to 1e-3): scaled or mirrored poses are
    refused rather than silently misread.
    """
    try:
        m = np.asarray(matrix, dtype=np.float64)
    except (TypeError, ValueError):
        raise ScanError(where, f"{what}: pose is not a matrix of numbers") from None
    if m.shape == (16,):
        m = m.reshape(4, 4)
    if m.shape == (12,):
        m = m.reshape(3, 4)
    if m.shape == (3, 4):
        m = np.vstack([m, [0.0, 0.0, 0.0, 1.0]])
    if m.shape != (4, 4):
        raise ScanError(where, f"{what}: pose has shape {m.shape}, expected 4x4 or 3x4")
    if not np.isfinite(m).all():
        raise ScanError(where, f"{what}: pose has non-finite values")
    if not np.allclose(m[3], [0.0, 0.0, 0.0, 1.0], atol=1e-6):
        raise ScanError(where, f"{what}: pose's last row is {m[3].tolist()}, expected [0, 0, 0, 1]")
    R = m[:3, :3]
    if np.abs(R).max() > 2 or not np.allclose(R @ R.T, np.eye(3), atol=1e-3) or np.linalg.det(R) < 0:
        raise ScanError(where, f"{what}: pose's rotation is not a rotation (scaled or mirrored poses "
                               "are not supported)")
    return m


#: largest photo side accepted, pixels (a 100-megapixel sensor is about 12000 wide)
MAX_PHOTO_SIDE = 65536


def pixel_count(value, key: str, where: Path, what: str) -> int:
    """``value`` as a positive whole number of pixels (at most :data:`MAX_PHOTO_SIDE`), else a ScanError."""
    if isinstance(value, str):
        try:
            value = float(value)
        except ValueError:
            pass
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise ScanError(where, f"{what}: '{key}' is not a number of pixels ({str(value)[:40]!r})")
    if not np.isfinite(value) or value != int(value):
        raise ScanError(where, f"{what}: '{key}' is not a whole number of pixels ({value!r})")
    if not 0 < value <= MAX_PHOTO_SIDE:
        raise ScanError(where, f"{what}: '{key}' is {int(value)}, expected 1 to {MAX_PHOTO_SIDE} pixels")
    return int(value)


#: a principal point farther than this share of the image's side from its centre is refused: a lens's is within
#: a few per cent of it, and intrinsics for an image twice the photo's size put it at the photo's edge
MAX_PRINCIPAL_OFFSET = 0.4

#: a principal point this near the centre of the image turned by 90 degrees (a share of its sides), and farther
#: than :data:`TURNED_OFFSET` from the centre of the image as it is, says the photo was turned after capture (a
#: phone's portrait photo saved upright, its intrinsics for the sensor's landscape grid)
TURNED_NEAR, TURNED_OFFSET = 0.05, 0.15


def check_intrinsics(K: np.ndarray, width, height, where: Path, what: str) -> tuple[int, int]:
    """Check a pinhole camera's ``K`` and image size; returns ``(width, height)`` as ints."""
    width = pixel_count(width, "width", where, what)
    height = pixel_count(height, "height", where, what)
    K = np.asarray(K, dtype=np.float64)
    if not np.isfinite(K).all():
        raise ScanError(where, f"{what}: intrinsics have non-finite values")
    if K[0, 0] <= 0 or K[1, 1] <= 0:
        raise ScanError(where, f"{what}: focal lengths must be positive, got {K[0, 0]}, {K[1, 1]}")
    if not np.allclose(K[2], [0.0, 0.0, 1.0]) or K[1, 0] != 0:
        raise ScanError(where, f"{what}: intrinsics {K.tolist()} are not of the form "
                               "[[fx, s, cx], [0, fy, cy], [0, 0, 1]]")
    off = np.abs(K[:2, 2] - [(width - 1) / 2, (height - 1) / 2]) / [width, height]
    turned = np.abs(K[:2, 2] - [(height - 1) / 2, (width - 1) / 2]) / [height, width]
    if width != height and (off > TURNED_OFFSET).any() and (turned < TURNED_NEAR).all():
        raise ScanError(where, f"{what}: the intrinsics are for a {height}x{width} image, the photo is "
                               f"{width}x{height}: it was turned by 90 degrees after capture (a portrait photo "
                               "saved upright?); give the photo as the camera recorded it")
    if (off > MAX_PRINCIPAL_OFFSET).any():
        raise ScanError(where, f"{what}: the principal point ({K[0, 2]:.1f}, {K[1, 2]:.1f}) lies at or past the "
                               f"edge of the {width}x{height} image: the intrinsics are for another image size "
                               "(a photo resized after capture? scale fx, fy, cx and cy with it)")
    return width, height


def registered_depths(depths: list, K_depth: np.ndarray | None, K_photo: np.ndarray, photo_size: tuple[int, int],
                      where: Path | None, expected_size: tuple[int, int] | None = None) -> tuple[tuple, tuple]:
    """``(depths, warps)`` for a :class:`~scantex.photos.photoset.PhotoSet` of a capture whose depth camera's K
    ``K_depth`` is given in ``where`` (``None``: the maps cover the photos' view; ``expected_size``: the maps' size,
    where the capture says): its depth maps (``None`` per photo without one) and their warps into the photos' view
    (:func:`scantex.photos.photoset.depth_warp`). A K that is no pinhole's for the maps' size (an unset
    calibration, another size's), or a first map that is no image, leaves the depth maps out with a warning: the
    photos are used without them, as without depth."""
    from scantex.photos.photoset import depth_warp, image_size

    first = next((d for d in depths if d is not None), None)
    if K_depth is None or first is None:
        return tuple(depths), (None,) * len(depths)
    try:
        size = image_size(first, "depth map")
        if expected_size is not None and size != tuple(expected_size):
            raise ScanError(where, f"its depth camera is {expected_size[0]}x{expected_size[1]} but {first.name} "
                                   f"is {size[0]}x{size[1]}")
        K = np.asarray(K_depth, dtype=np.float64)
        if not np.isfinite(K).all() or K[0, 0] <= 0 or K[1, 1] <= 0:
            raise ScanError(where, f"the depth camera's intrinsics {np.round(K, 3).tolist()} have no positive focal "
                                   "lengths")
        check_intrinsics(K, *size, where, "the depth camera's intrinsics")
    except ScanError as e:
        log.warning("%s: the depth maps are not used", e)
        return (None,) * len(depths), (None,) * len(depths)
    warp = depth_warp(K, size, K_photo, photo_size)
    return tuple(depths), tuple(None if d is None else warp for d in depths)


def intrinsics(fx, fy, cx, cy, *, pixel_centre: float) -> np.ndarray:
    """``(3, 3)`` K in scantex's convention from a principal point given in a convention where the
    centre of the top-left pixel is ``(pixel_centre, pixel_centre)``: 0.5 for COLMAP, nerfstudio and
    ARKit (coordinates from the image's corner), 0 for OpenCV and scantex."""
    return np.array([[fx, 0.0, cx - pixel_centre], [0.0, fy, cy - pixel_centre], [0.0, 0.0, 1.0]],
                    dtype=np.float64)


def principal_point(K: np.ndarray, *, pixel_centre: float) -> tuple[float, float]:
    """The inverse of :func:`intrinsics`' shift: ``(cx, cy)`` in a format's own convention."""
    return float(K[0, 2] + pixel_centre), float(K[1, 2] + pixel_centre)


def world_to_camera_from_opengl(camera_to_world_gl: np.ndarray) -> np.ndarray:
    """``(4, 4)`` OpenCV world-to-camera from an OpenGL/ARKit camera-to-world (camera looks down -z,
    +y up): flip the camera's y and z axes (columns 1 and 2), then invert."""
    return np.linalg.inv(camera_to_world_gl @ FLIP_YZ)


def opengl_camera_to_world(camera: Camera) -> np.ndarray:
    """The inverse of :func:`world_to_camera_from_opengl`: ``(4, 4)`` OpenGL/ARKit camera-to-world."""
    return np.linalg.inv(camera.world_to_camera) @ FLIP_YZ


def world_to_camera_from(R: np.ndarray, centre: np.ndarray, where: Path, what: str,
                         problem: str = "its rotation is no rotation") -> np.ndarray:
    """``(4, 4)`` OpenCV world-to-camera of a world-to-camera rotation ``R`` and the camera's centre (``x_cam = R (X -
    C)``), as the photogrammetry formats keep a pose; a ScanError saying ``problem`` where ``R`` is no rotation
    (orthonormal to 1e-3, determinant positive), or the pose is not finite."""
    R, centre = np.asarray(R, np.float64), np.asarray(centre, np.float64)
    if not (np.isfinite(R).all() and np.isfinite(centre).all()):  # NaN passes the tests below
        raise ScanError(where, f"{what}: its pose is not finite")
    if np.abs(R @ R.T - np.eye(3)).max() > 1e-3 or np.linalg.det(R) < 0:
        raise ScanError(where, f"{what}: {problem}")
    w2c = np.eye(4)
    w2c[:3, :3], w2c[:3, 3] = R, -R @ centre
    return w2c


def pinhole_camera(distortion: Distortion | None, camera: Camera, max_px: float, where: Path,
                   what: str) -> tuple[Camera, Lens | None]:
    """``(camera, None)`` for a photo without distortion or with one that moves no pixel by more than ``max_px``
    (ignored, with a warning); else its undistorted pinhole camera and the :class:`~scantex.photos.lens.Lens`
    :meth:`PhotoSet.load_image` undoes the distortion with (``camera``: the photo's stored intrinsics).

    Raises:
        ScanError: a distortion model that cannot be undone (:func:`scantex.photos.lens.pinhole_lens`).
    """
    if distortion is None or distortion.is_zero:
        return camera, None
    coefficients = (distortion.radial + tuple(distortion.tangential) + distortion.radial_denominator
                    + distortion.inverse_radial)
    if not np.isfinite(coefficients).all():
        raise ScanError(where, f"{what}: lens distortion ({distortion.model}) has coefficients that are not finite "
                               f"numbers")
    shift = distortion.max_shift_px(camera)
    if shift <= max_px:
        log.warning("%s: %s: ignoring a small lens distortion (%s, at most %.2f px)", where, what,
                    distortion.model, shift)
        return camera, None
    from scantex.photos.lens import pinhole_lens

    lens = pinhole_lens(camera, distortion, where, what)
    log.debug("%s: %s: lens distortion (%s) moves pixels by up to %.1f px: the photo is undistorted when read",
              where, what, distortion.model, shift)
    return Camera(lens.K, camera.world_to_camera, camera.width, camera.height), lens
