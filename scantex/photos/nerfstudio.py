"""nerfstudio's ``transforms.json`` (also the Blender / instant-ngp layout it grew from).

Conventions, and what scantex does with them:

- ``transform_matrix``: camera-to-world, 4x4 (3x4 accepted), OpenGL camera axes (+x right, +y up, the
  camera looks down -z). scantex: ``world_to_camera = inv(transform_matrix @ diag(1, -1, -1, 1))``;
  the world frame is kept as it is, so it must be the mesh's (see ``applied_transform`` below).
- Intrinsics ``fl_x, fl_y, cx, cy, w, h`` at the top level or per frame (a frame's own values win).
  nerfstudio casts rays through ``pixel + 0.5``, so its principal point is measured from the image's
  corner: scantex's ``cx = cx - 0.5``, ``cy = cy - 0.5``. Without ``fl_x``, Blender's
  ``camera_angle_x`` (horizontal field of view, radians) gives ``fl_x = fl_y = w / 2 / tan(angle / 2)``
  and the principal point defaults to the image centre (``w / 2, h / 2`` in nerfstudio's convention).
  Without ``w, h`` the image's own size is used.
- ``camera_model``: ``OPENCV`` (the default; ``k1, k2, k3, k4`` radial as a polynomial in r^2 up to r^8,
  ``p1, p2`` tangential), ``OPENCV_FISHEYE`` (equidistant, ``k1``-``k4`` a polynomial in the ray's angle),
  ``PINHOLE`` or ``SIMPLE_PINHOLE``. The distortion is recorded in :attr:`PhotoSet.distortions`; one that moves no
  pixel by more than ``max_distortion_px`` (1 px) is ignored with a logged warning, a larger one undone when a
  photo is read (:mod:`scantex.photos.lens`). Equirectangular models are refused.
- ``file_path`` and ``depth_file_path`` are relative to the file's folder (absolute paths kept); a
  ``file_path`` without extension (Blender's ``./train/r_0``) gets ``.png``, then ``.jpg``. Depth maps
  are uint16 PNG in millimetres (nerfstudio's default ``depth_unit_scale_factor`` of 1e-3).
- ``applied_transform`` (written by ``ns-process-data``: the 3x4 that took COLMAP's world to this
  file's) is left applied by default, so the cameras are in this file's world frame; pass
  ``undo_applied_transform=True`` when the mesh is in the original (COLMAP) frame.
"""

from __future__ import annotations

import json
import logging
import math
from pathlib import Path

import numpy as np

from scantex.errors import ScanError
from scantex.io.atomic import atomic_files
from scantex.photos.conventions import (
    CORNER_CONVENTION,
    MAX_DISTORTION_PX,
    check_intrinsics,
    pixel_count,
    check_pose,
    intrinsics,
    opengl_camera_to_world,
    pinhole_camera,
    principal_point,
    world_to_camera_from_opengl,
)
from scantex.photos.files import (
    check_sizes,
    converts,
    load_frames_file,
    need,
    number,
    resolve_file,
    write_depth,
    write_photo,
)
from scantex.photos.photoset import Distortion, PhotoSet, image_size
from scantex.views.camera import Camera

log = logging.getLogger(__name__)

FORMAT = "nerfstudio"
PINHOLE_MODELS = ("PINHOLE", "SIMPLE_PINHOLE")
DISTORTED_MODELS = ("OPENCV", "OPENCV_FISHEYE")
RADIAL_KEYS = ("k1", "k2", "k3", "k4")


def load_nerfstudio(path: str | Path, *, max_distortion_px: float = MAX_DISTORTION_PX,
                    undo_applied_transform: bool = False) -> PhotoSet:
    """Read a nerfstudio ``transforms.json`` (or the folder holding one); conventions in the module
    docstring.

    Raises:
        ScanError: missing or malformed file, missing images, non-finite or non-rigid poses, an
            unsupported camera model or too strong a lens distortion.
    """
    path, doc, frames = load_frames_file(path, "transforms.json", ": not a nerfstudio transforms.json")
    applied = None
    if "applied_transform" in doc:
        applied = check_pose(doc["applied_transform"], path, "applied_transform")
        if not undo_applied_transform:
            log.info("%s: cameras kept in the file's world frame (its applied_transform is not undone)",
                     path)
    base = path.parent
    cameras, images, depths, distortions, lenses = [], [], [], [], []
    for i, frame in enumerate(frames):
        what = f"frame {i}"
        if not isinstance(frame, dict):
            raise ScanError(path, f"{what} is not an object")
        scope = {**doc, **frame}  # a frame's own intrinsics win over the file's
        get = scope.get
        if "file_path" not in frame:
            raise ScanError(path, f"{what}: missing 'file_path'")
        image = _image_path(base, str(frame["file_path"]), path, what)
        if get("w") is not None and get("h") is not None:
            width = pixel_count(need(scope, "w", path, what), "w", path, what)
            height = pixel_count(need(scope, "h", path, what), "h", path, what)
        else:
            width, height = image_size(image)
        if get("fl_x") is not None:
            fx = number(scope, "fl_x", path, what)
            fy = number(scope, "fl_y", path, what) if get("fl_y") is not None else fx
        elif get("camera_angle_x") is not None:
            angle = number(scope, "camera_angle_x", path, what)
            if not 0 < angle < math.pi:
                raise ScanError(path, f"{what}: camera_angle_x is {angle!r}, expected radians between 0 and pi")
            fx = fy = 0.5 * width / math.tan(0.5 * angle)
        else:
            raise ScanError(path, f"{what}: no focal length ('fl_x' or 'camera_angle_x')")
        cx = number(scope, "cx", path, what) if get("cx") is not None else width / 2
        cy = number(scope, "cy", path, what) if get("cy") is not None else height / 2
        K = intrinsics(fx, fy, cx, cy, pixel_centre=CORNER_CONVENTION)
        width, height = check_intrinsics(K, width, height, path, what)

        c2w = check_pose(need(frame, "transform_matrix", path, what), path, what)
        if applied is not None and undo_applied_transform:
            c2w = np.linalg.inv(applied) @ c2w
        camera = Camera(K, world_to_camera_from_opengl(c2w), width, height)

        model = str(get("camera_model", "OPENCV"))
        if model in PINHOLE_MODELS:
            distortion = None
        elif model in DISTORTED_MODELS:
            coeffs = {k: number(scope, k, path, what) if get(k) is not None else 0.0
                      for k in RADIAL_KEYS + ("p1", "p2")}
            radial = tuple(coeffs[k] for k in RADIAL_KEYS)
            while radial and radial[-1] == 0.0:
                radial = radial[:-1]
            fisheye = model == "OPENCV_FISHEYE"  # its p1, p2 are not read: nerfstudio's fisheye has none
            distortion = Distortion(model, radial, (0.0, 0.0) if fisheye else (coeffs["p1"], coeffs["p2"]),
                                    projection="equidistant" if fisheye else "perspective")
        else:
            raise ScanError(path, f"{what}: camera_model {model} is not supported (scantex takes "
                                  f"pinhole photos: {', '.join(PINHOLE_MODELS + DISTORTED_MODELS)})")
        camera, lens = pinhole_camera(distortion, camera, max_distortion_px, path, what)
        distortions.append(distortion)
        lenses.append(lens)
        cameras.append(camera)
        images.append(image)
        depth = frame.get("depth_file_path")
        depths.append(None if depth is None else resolve_file(base, str(depth), path, f"{what}'s depth"))
    check_sizes(cameras, images, path)
    return PhotoSet(cameras=tuple(cameras), images=tuple(images), depths=tuple(depths), source=path,
                    format=FORMAT, distortions=tuple(distortions), lenses=tuple(lenses))


def _image_path(base: Path, name: str, where: Path, what: str) -> Path:
    candidate = Path(name) if Path(name).is_absolute() else base / name
    if not candidate.suffix and not candidate.is_file():  # Blender's extensionless "./train/r_0"
        for suffix in (".png", ".jpg", ".jpeg"):
            if candidate.with_suffix(suffix).is_file():
                return candidate.with_suffix(suffix)
    return resolve_file(base, name, where, f"{what}'s image")


def write_nerfstudio(photos: PhotoSet, out_dir: str | Path) -> Path:
    """Write ``out_dir/transforms.json`` with the photos copied to ``out_dir/images/frame_00001.<ext>``
    (and depth maps to ``out_dir/depth/``); per-frame intrinsics. Returns the ``transforms.json`` path.

    Raises:
        ValueError: a camera has skew, or a small distortion ignored when read that nerfstudio's models cannot hold
            (a photo undistorted when read is written as stored with its lens where they hold it, else undistorted,
            as a PNG).
    """
    photos = photos.as_stored(_holds)  # an undistorted photo as stored with its lens, where a model holds it
    out_dir = Path(out_dir)
    (out_dir / "images").mkdir(parents=True, exist_ok=True)
    if photos.has_depth:
        (out_dir / "depth").mkdir(exist_ok=True)
    frames = []
    with atomic_files() as files:
        for i, (cam, image) in enumerate(zip(photos.cameras, photos.images)):
            if cam.K[0, 1] != 0:
                raise ValueError(f"photo {i}: nerfstudio cameras have no skew")
            cx, cy = principal_point(cam.K, pixel_centre=CORNER_CONVENTION)
            name = write_photo(files, photos, i, out_dir / "images" / f"frame_{i + 1:05d}").relative_to(
                out_dir).as_posix()
            frame = {"file_path": name, "w": cam.width, "h": cam.height, "fl_x": float(cam.K[0, 0]),
                     "fl_y": float(cam.K[1, 1]), "cx": cx, "cy": cy,
                     "transform_matrix": opengl_camera_to_world(cam).tolist()}
            frame.update(_distortion_keys(photos.distortions[i], i))
            if photos.depths[i] is not None:
                written = write_depth(files, photos, i, out_dir / "depth" / f"frame_{i + 1:05d}", floats=False)
                frame["depth_file_path"] = written.relative_to(out_dir).as_posix()
            frames.append(frame)
        doc = {"camera_model": "OPENCV", "frames": frames}
        files.path(out_dir / "transforms.json").write_text(json.dumps(doc, indent=1))
    return out_dir / "transforms.json"


def _holds(distortion: Distortion, cam: Camera) -> bool:
    """Whether nerfstudio's models hold a lens exactly (VisualSfM's inverse model only to first order: no)."""
    return converts(lambda: _distortion_keys(distortion, 0)) and cam.K[0, 1] == 0 and not distortion.inverse_radial


def _distortion_keys(distortion: Distortion | None, i: int) -> dict:
    if distortion is None or distortion.is_zero:
        return {"camera_model": "PINHOLE"}
    fisheye = distortion.projection == "equidistant"
    if (distortion.radial_denominator or len(distortion.radial) > len(RADIAL_KEYS)
            or distortion.projection == "equisolid" or (fisheye and any(distortion.tangential))):
        raise ValueError(f"photo {i}: nerfstudio's OPENCV models cannot hold a {distortion.model} "
                         "distortion")
    if fisheye:
        return {"camera_model": "OPENCV_FISHEYE", **dict.fromkeys(RADIAL_KEYS, 0.0),
                **dict(zip(RADIAL_KEYS, distortion.radial))}
    keys = {"camera_model": "OPENCV", "p1": distortion.tangential[0], "p2": distortion.tangential[1]}
    keys.update({k: 0.0 for k in RADIAL_KEYS})
    keys.update(zip(RADIAL_KEYS, distortion.radial))
    return keys
