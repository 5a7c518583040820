"""scantex's own ``cameras.json`` (written by :func:`scantex.views.viewset.write_views`), also the shape
of the bolster RGB-D demo's poses.

``{"frames": [{"image", "width", "height", "K", "world_to_camera", "depth"?, "distortion"?}, ...]}``

Conventions: scantex's own, so no conversion at all.

- ``world_to_camera``: 4x4, ``x_cam = R X + t``, OpenCV axes (+x right, +y down, +z forward).
- ``K``: 3x3 in pixels, OpenCV's pixel convention: ``(0, 0)`` is the centre of the top-left pixel (a
  1920-pixel-wide Kinect calibration has ``cx = 959.5``). OpenCV's calibration uses this convention, so
  a K from ``cv2.calibrateCamera`` goes in unchanged; a principal point from COLMAP, nerfstudio or ARKit
  would need ``- 0.5``.
- ``image`` and ``depth`` paths are absolute or relative to the file; ``depth`` is a uint16 PNG in
  millimetres, or a float map in metres (a 32-bit TIFF, a ``.npy``). ``width``/``height`` default to the
  image's size.
- ``distortion`` (optional, written by :func:`write_cameras_json` when a photo has one): ``{"model",
  "radial", "tangential", "radial_denominator", "inverse_radial"?, "projection"?}`` as in
  :class:`~scantex.photos.photoset.Distortion` (``projection``: a fisheye's ``"equidistant"`` or ``"equisolid"``).
- A frame without ``world_to_camera`` may give the pose as ``R`` (3x3, world to camera) and ``C`` (the camera's
  centre in the world: ``t = -R C``) or ``t``, as the bolster's file also does beside ``world_to_camera``.
  Where a frame gives both, ``world_to_camera`` is used, with a warning when ``R`` and ``C`` are another pose
  (beyond a millimetre and a thousandth of a radian).
- Other keys (``split``, ...) are ignored.
"""

from __future__ import annotations

import json
import logging
from pathlib import Path

import numpy as np

from scantex.errors import ScanError
from scantex.io.atomic import atomic_files
from scantex.photos.conventions import (
    MAX_DISTORTION_PX,
    check_intrinsics,
    check_pose,
    pinhole_camera,
)
from scantex.photos.files import check_sizes, load_frames_file, need, resolve_file, write_depth, write_photo
from scantex.photos.photoset import DEPTH_SCALE_MM, Distortion, PhotoSet, image_size
from scantex.views.camera import Camera

log = logging.getLogger(__name__)

FORMAT = "cameras.json"
CONVENTION = ("OpenCV: x_cam = R X + t, +x right, +y down, +z forward; pixel = K x_cam / z with (0, 0) "
              "the centre of the top-left pixel; depth PNG uint16 millimetres (a float map: metres)")


def is_cameras_json(doc) -> bool:
    """A document of frames with a pose or intrinsics in this layout (a frame missing the rest is then refused
    naming what it misses, not as a file of no known layout)."""
    frames = doc.get("frames") if isinstance(doc, dict) else None
    return isinstance(frames, list) and bool(frames) and isinstance(frames[0], dict) \
        and any(key in frames[0] for key in ("world_to_camera", "R", "K"))


def frame_pose(frame: dict, where: Path, what: str) -> tuple[np.ndarray, bool]:
    """``((4, 4) world-to-camera, disagrees)`` of a frame: its ``world_to_camera``, else its ``R`` and ``C`` (or
    ``t``); ``disagrees``: the frame gives both, and its ``R`` and ``C`` are another pose (or no pose at all)."""
    if "R" not in frame or ("C" not in frame and "t" not in frame):
        return check_pose(need(frame, "world_to_camera", where, what), where, what), False
    try:
        R = np.asarray(frame["R"], dtype=np.float64)
        t = np.asarray(frame["t"], dtype=np.float64) if "t" in frame else -R @ np.asarray(frame["C"], dtype=np.float64)
        other = np.eye(4)
        other[:3, :3], other[:3, 3] = R, t
    except (TypeError, ValueError):
        other = None
    if "world_to_camera" not in frame:
        if other is None:
            raise ScanError(where, f"{what}: R and {'t' if 't' in frame else 'C'} are not a 3x3 matrix and a "
                                   "3-vector of numbers")
        return check_pose(other, where, what), False
    w2c = check_pose(frame["world_to_camera"], where, what)
    scale = max(1.0, float(np.abs(w2c[:3, 3]).max()))
    agree = (other is not None and np.isfinite(other).all() and np.abs(other[:3, :3] - w2c[:3, :3]).max() <= 1e-3
             and np.abs(other[:3, 3] - w2c[:3, 3]).max() <= 1e-3 * scale)
    return w2c, not agree


def load_cameras_json(path: str | Path, *, max_distortion_px: float = MAX_DISTORTION_PX) -> PhotoSet:
    """Read a ``cameras.json`` (or the folder holding one); conventions in the module docstring.

    Raises:
        ScanError: missing or malformed file, missing images, non-finite or non-rigid poses.
    """
    path, doc, frames = load_frames_file(path, "cameras.json", "")
    base = path.parent
    cameras, images, depths, distortions, lenses = [], [], [], [], []
    disagreeing = 0
    for i, frame in enumerate(frames):
        what = f"frame {i}"
        image = resolve_file(base, str(need(frame, "image", path, what)), path, f"{what}'s image")
        w2c, disagrees = frame_pose(frame, path, what)
        disagreeing += disagrees
        try:
            K = np.asarray(need(frame, "K", path, what), dtype=np.float64)
        except (TypeError, ValueError):
            raise ScanError(path, f"{what}: K is not a matrix of numbers") from None
        if K.shape != (3, 3):
            raise ScanError(path, f"{what}: K has shape {K.shape}, expected 3x3")
        if "width" in frame and "height" in frame:
            width, height = frame["width"], frame["height"]
        else:
            width, height = image_size(image)
        width, height = check_intrinsics(K, width, height, path, what)
        distortion = _distortion(frame.get("distortion"), path, what)
        camera, lens = pinhole_camera(distortion, Camera(K, w2c, width, height), max_distortion_px, path, what)
        distortions.append(distortion)
        lenses.append(lens)
        cameras.append(camera)
        images.append(image)
        depth = frame.get("depth")
        depths.append(None if depth is None else resolve_file(base, str(depth), path, f"{what}'s depth"))
    check_sizes(cameras, images, path)
    if disagreeing:
        log.warning("%s: %d of %d frames give R and C (or t) of another pose than their world_to_camera: "
                    "world_to_camera is used", path, disagreeing, len(frames))
    return PhotoSet(cameras=tuple(cameras), images=tuple(images), depths=tuple(depths), source=path,
                    format=FORMAT, distortions=tuple(distortions), lenses=tuple(lenses))


def _distortion(d, where: Path, what: str) -> Distortion | None:
    if d is None:
        return None
    tangential = d.get("tangential", (0.0, 0.0)) if isinstance(d, dict) else None
    if isinstance(tangential, (list, tuple)) and len(tangential) != 2:
        raise ScanError(where, f"{what}: distortion's tangential is not 2 numbers (p1, p2)")
    try:
        return Distortion(str(d["model"]), tuple(float(v) for v in d.get("radial", ())),
                          tuple(float(v) for v in d.get("tangential", (0.0, 0.0))),
                          tuple(float(v) for v in d.get("radial_denominator", ())),
                          tuple(float(v) for v in d.get("inverse_radial", ())),
                          str(d.get("projection", "perspective")))
    except (TypeError, ValueError, KeyError, AttributeError):
        raise ScanError(where, f"{what}: distortion is not {{model, radial, tangential, radial_denominator, "
                               "inverse_radial, projection (perspective, equidistant or equisolid)}") from None


def write_cameras_json(photos: PhotoSet, out_dir: str | Path, *, copy_images: bool = True) -> Path:
    """Write ``out_dir/cameras.json``; returns its path.

    Args:
        photos: the photos.
        out_dir: the folder.
        copy_images: copy the photos (and depth maps) next to the file as ``photo_000.<ext>``
            (``depth_000.<ext>``) and refer to them by name; else refer to the originals by absolute path.
    """
    photos = photos.as_stored()  # an undistorted photo is written as stored, with its lens
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    frames = []
    with atomic_files() as files:
        for i, (cam, image, depth) in enumerate(zip(photos.cameras, photos.images, photos.depths)):
            if copy_images:
                name = write_photo(files, photos, i, out_dir / f"photo_{i:03d}").name
            else:
                name = str(image.resolve())
            frame = {"image": name, **cam.to_dict()}
            if depth is not None:
                # an integer map in other units than millimetres is written as millimetres even when the photos
                # are not copied (referred to as it is, it would be read a thousand times too near or far), a map
                # of a lens of its own resampled into its photo's view
                written = (copy_images or photos.depth_scale != DEPTH_SCALE_MM
                           or photos.depth_warps[i] is not None)
                frame["depth"] = (write_depth(files, photos, i, out_dir / f"depth_{i:03d}", floats=True).name
                                  if written else str(depth.resolve()))
            distortion = photos.distortions[i]
            if distortion is not None and not distortion.is_zero:
                frame["distortion"] = {"model": distortion.model, "radial": list(distortion.radial),
                                       "tangential": list(distortion.tangential),
                                       "radial_denominator": list(distortion.radial_denominator)}
                if distortion.inverse_radial:
                    frame["distortion"]["inverse_radial"] = list(distortion.inverse_radial)
                if distortion.is_fisheye:
                    frame["distortion"]["projection"] = distortion.projection
            frames.append(frame)
        doc = {"convention": CONVENTION, "frames": frames}
        files.path(out_dir / "cameras.json").write_text(json.dumps(doc, indent=1))
    return out_dir / "cameras.json"
