"""RGB-D frames as files of their own (``frame-000000.color.png``, ``.depth.png``, ``.pose.txt``): the layout of the
Intrinsic3D and shading-refinement datasets (a Structure Sensor on an iPad: 1296x968 photos, 640x480 depth), of
BundleFusion's and ScanNet's C++ ``.sens`` export, of 3RScan's sequences and of 3DMatch's.

Conventions, and what scantex does with them:

- ``<name>NNNNNN.color.png`` (or ``.jpg``) is a frame's photo, ``<name>NNNNNN.pose.txt`` its pose: a 4x4
  *camera-to-world* (four rows of four numbers) in OpenCV's camera axes (+y down, +z forward), in the world frame
  of the scan: scantex's ``world_to_camera = inv(pose)``. A frame whose tracking was lost holds ``-inf`` (or
  ``nan``): it is skipped, and a warning says how many were. A photo without a pose is no frame. Frames are taken
  in the order of their numbers.
- ``<name>NNNNNN.depth.png`` (or ``.pgm``, as ScanNet's C++ SensReader and 3RScan write it) is its depth map,
  16-bit, in millimetres (in ``1 / m_depthShift`` metres where an ``_info.txt`` says so: 5000 for TUM's units).
- The intrinsics, in the frames' folder or the one above (the first found): ``colorIntrinsics.txt`` and
  ``depthIntrinsics.txt``, a 4x4 each (Intrinsic3D); ``_info.txt`` or ``info.txt`` (a ``.sens`` export:
  ``m_calibrationColorIntrinsic`` and ``m_calibrationDepthIntrinsic``, 16 numbers each, ``m_colorWidth``,
  ``m_colorHeight``, ``m_depthWidth``, ``m_depthHeight``); ``camera-intrinsics.txt``, a 3x3 (3DMatch: the depth
  map covers the photo's view). K in OpenCV's pixel centres, as scantex's. The depth camera is registered to the
  colour camera (its centre and axes), its lens given apart: where it differs from the photo's, its map is
  resampled into the photo's view (:attr:`PhotoSet.depth_warps`); a depth K that is no pinhole's for the maps'
  size (an unset calibration, another size's) leaves the depth maps out, with a warning. An ``_info.txt`` whose
  colour camera is not at the pose (a colour extrinsic other than the identity) is refused; one whose depth camera
  is elsewhere keeps the photos without their depth maps, with a warning. An ``info.txt`` without
  ``m_calibrationColorIntrinsic`` is another program's: passed over.
"""

from __future__ import annotations

import logging
import re
from pathlib import Path
from typing import NamedTuple

import numpy as np

from scantex.errors import ScanError
from scantex.photos.conventions import MAX_DISTORTION_PX, check_intrinsics, pixel_count, registered_depths
from scantex.photos.files import check_sizes, folder_of, read_matrix, world_to_camera_of
from scantex.photos.photoset import DEPTH_SCALE_MM, PhotoSet, image_size
from scantex.views.camera import Camera

log = logging.getLogger(__name__)

FORMAT = "rgbd-frames"
#: a frame's depth map, ``<name>NNNNNN.depth`` and one of these (ScanNet's C++ SensReader writes 16-bit PGM)
DEPTH_SUFFIXES = (".png", ".pgm")
COLOUR = re.compile(r"^(?P<stem>.*?(?P<number>\d+))\.color\.(?:png|jpe?g)$", re.IGNORECASE)
#: the intrinsics files, in the order they are looked for: Intrinsic3D's, a .sens export's, 3DMatch's
INTRINSICS_FILES = ("colorIntrinsics.txt", "_info.txt", "info.txt", "camera-intrinsics.txt")


class Intrinsics(NamedTuple):
    K: np.ndarray
    K_depth: np.ndarray | None = None  # None: the depth map covers the photo's view
    depth_file: Path | None = None  # the file K_depth comes from
    size: tuple[int, int] | None = None  # the photos' (w, h) where the file says
    depth_size: tuple[int, int] | None = None
    depth_scale: float = DEPTH_SCALE_MM
    depth_used: bool = True


def frames(folder: Path) -> list[tuple[int, Path, Path]]:
    """``(number, photo, pose file)`` of each frame of ``folder`` with both, in the order of their numbers."""
    found = {}
    for p in sorted(folder.iterdir()):  # a frame's .jpg before its .png, whatever the file system's order
        match = COLOUR.match(p.name)
        if match and p.is_file():
            pose = folder / f"{match['stem']}.pose.txt"
            if pose.is_file():
                found.setdefault((int(match["number"]), match["stem"]), (p, pose))
    return [(key[0], *found[key]) for key in sorted(found)]


def is_frames_folder(folder: Path) -> bool:
    return folder.is_dir() and any(folder.glob("*.pose.txt")) and bool(frames(folder))


def intrinsics_file(folder: Path) -> Path | None:
    """The first of :data:`INTRINSICS_FILES` in ``folder``, else in the folder above; names in any case (some
    converters write ``colorintrinsics.txt``)."""
    for where in (folder, folder.parent):
        for found in _named(where, INTRINSICS_FILES):
            if found.name.lower() not in ("_info.txt", "info.txt") or _is_sens_info(found):
                return found
    return None


def _is_sens_info(path: Path) -> bool:
    """Whether a ``_info.txt`` / ``info.txt`` is a ``.sens`` export's (another program's ``info.txt`` is not)."""
    try:
        with open(path, "rb") as f:
            return b"m_calibrationColorIntrinsic" in f.read(1 << 16)
    except OSError:
        return False


def _named(folder: Path, names) -> list[Path]:
    """The files of ``folder`` whose names are ``names`` in any case, in the order of ``names``."""
    wanted = [name.lower() for name in names]
    try:
        files = {p.name.lower(): p for p in folder.iterdir() if p.name.lower() in wanted and p.is_file()}
    except OSError:
        return []
    return [files[name] for name in wanted if name in files]


def load_rgbd_frames(path: str | Path, *, max_distortion_px: float = MAX_DISTORTION_PX) -> PhotoSet:
    """Read a folder of RGB-D frames (or one of its files); conventions in the module docstring.
    ``max_distortion_px`` is accepted for symmetry: the layout stores no distortion.

    Raises:
        ScanError: no frame with a photo and a pose, no intrinsics file, a malformed pose or intrinsics file,
            photos of another size than the intrinsics', no frame with a finite pose.
    """
    folder = folder_of(Path(path))
    found = frames(folder)
    if not found:
        raise ScanError(folder, "no frame with both a photo and a pose (frame-000000.color.png + "
                                "frame-000000.pose.txt)")
    source = intrinsics_file(folder)
    if source is None:
        raise ScanError(folder, f"no intrinsics for its frames: expected {', '.join(INTRINSICS_FILES)} beside "
                                "them or in the folder above")
    lens = _intrinsics(source)
    width, height = image_size(found[0][1])
    if lens.size is not None and lens.size != (width, height):
        raise ScanError(source, f"its colour camera is {lens.size[0]}x{lens.size[1]} but {found[0][1].name} is "
                                f"{width}x{height}: another capture's intrinsics")
    check_intrinsics(lens.K, width, height, source, "colour intrinsics")
    cameras, images, depths = [], [], []
    lost = 0
    for _, image, pose_file in found:
        w2c = world_to_camera_of(pose_file)
        if w2c is None:
            lost += 1
            continue
        cameras.append(Camera(lens.K, w2c, width, height))
        images.append(image)
        stem = image.name[:image.name.lower().rindex(".color.")]
        depth = next((d for d in (image.with_name(f"{stem}.depth{ext}") for ext in DEPTH_SUFFIXES) if d.is_file()),
                     None)
        depths.append(depth if lens.depth_used else None)
    if not images:
        raise ScanError(folder, f"none of its {len(found)} frames has a finite pose (tracking lost: -inf)")
    if lost:
        log.warning("%s: %d frames have no pose (tracking lost: -inf): skipped", folder, lost)
    check_sizes(cameras, images, folder)
    depths, warps = registered_depths(depths, lens.K_depth, lens.K, (width, height), lens.depth_file, lens.depth_size)
    return PhotoSet(cameras=tuple(cameras), images=tuple(images), depths=depths, source=folder, format=FORMAT,
                    depth_scale=lens.depth_scale, depth_warps=warps)


def _intrinsics(source: Path) -> Intrinsics:
    """The cameras an intrinsics file describes (Intrinsic3D's colour file with its depth file beside it)."""
    if source.name.lower() == "colorintrinsics.txt":
        K = read_matrix(source, "4x4 intrinsics file")[:3, :3].copy()
        depth_file = _named(source.parent, ("depthIntrinsics.txt",))
        if not depth_file:
            return Intrinsics(K)
        return Intrinsics(K, read_matrix(depth_file[0], "4x4 intrinsics file")[:3, :3].copy(), depth_file[0])
    if source.name.lower() == "camera-intrinsics.txt":
        return Intrinsics(read_matrix(source, "3x3 intrinsics file", ((3, 3),)))
    return _sens_info(source)


def _sens_info(source: Path) -> Intrinsics:
    try:
        text = source.read_text(encoding="utf-8", errors="replace")  # a sensor's name in another encoding is no matter
    except OSError as e:
        raise ScanError(source, f"cannot read the file ({e.strerror})") from None
    keys = {}
    for line in text.splitlines():
        key, eq, value = line.partition("=")
        if eq:
            keys[key.strip()] = value.split()

    def matrix(key: str, required: bool = True) -> np.ndarray | None:
        if key not in keys:
            if required:
                raise ScanError(source, f"no {key} line: not the info file of a .sens export")
            return None
        try:
            values = [float(v) for v in keys[key]]
        except ValueError:
            raise ScanError(source, f"{key} is not 16 numbers") from None
        if len(values) != 16:
            raise ScanError(source, f"{key} has {len(values)} numbers, expected 16 (a 4x4 row by row)")
        return np.array(values).reshape(4, 4)

    def size(prefix: str) -> tuple[int, int] | None:
        if f"m_{prefix}Width" not in keys or f"m_{prefix}Height" not in keys:
            return None
        return tuple(pixel_count(" ".join(keys[f"m_{prefix}{side}"]), f"m_{prefix}{side}", source, "size")
                     for side in ("Width", "Height"))

    K = matrix("m_calibrationColorIntrinsic")[:3, :3].copy()
    K_depth = matrix("m_calibrationDepthIntrinsic", required=False)
    colour_extrinsic = matrix("m_calibrationColorExtrinsic", required=False)
    depth_extrinsic = matrix("m_calibrationDepthExtrinsic", required=False)
    if colour_extrinsic is not None and not np.allclose(colour_extrinsic, np.eye(4), atol=1e-6):
        raise ScanError(source, "m_calibrationColorExtrinsic is not the identity: scantex takes each pose to be "
                                "the colour camera's (give the colour camera's poses)")
    if K_depth is not None:
        K_depth = K_depth[:3, :3].copy()
    shift = 1000.0
    if "m_depthShift" in keys:
        try:
            shift = float(keys["m_depthShift"][0])
        except (ValueError, IndexError):
            shift = float("nan")
        if not (np.isfinite(shift) and shift > 0):
            raise ScanError(source, f"m_depthShift is {' '.join(keys['m_depthShift'])!r}, expected depth units "
                                    "per metre (1000: millimetres)")
    if depth_extrinsic is not None and not np.allclose(depth_extrinsic, np.eye(4), atol=1e-6):
        log.warning("%s: the depth camera is not at the colour camera (m_calibrationDepthExtrinsic is not the "
                    "identity): its depth maps are not used", source)
        return Intrinsics(K, size=size("color"), depth_used=False)
    return Intrinsics(K, K_depth, source, size("color"), size("depth"), 1.0 / shift)
