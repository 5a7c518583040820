"""ScanNet's exported frames (its ``SensReader``: ``color/``, ``depth/``, ``pose/``, ``intrinsic/``), the layout
many RGB-D pipelines write a room's frames in.

Conventions, and what scantex does with them:

- ``pose/N.txt``: a 4x4 *camera-to-world* (four rows of four numbers), OpenCV's camera axes (+y down, +z
  forward) in the scene's world frame, the frame of its mesh. scantex: ``world_to_camera = inv(pose)``. A
  frame whose tracking was lost holds ``-inf`` (or ``nan``): it is skipped, and a warning says how many were.
- ``intrinsic/intrinsic_color.txt``: the colour camera's 4x4 (its 3x3 upper left is K, OpenCV's pixel
  centres), one for every frame. The image size is read from the images.
- ``color/N.jpg`` (or ``.png``) is frame N's photo; frames are taken in the order of their numbers, those
  without a photo skipped.
- ``depth/N.png``: uint16 millimetres, usually 640x480 beside 1296x968 photos, kept as the photo's depth map,
  registered to the colour camera (its centre and axes), its lens ``intrinsic/intrinsic_depth.txt`` (4x4):
  scantex resamples it into the photo's view where that lens differs from the photo's (:attr:`PhotoSet.depth_warps`;
  ScanNet's own scenes give the colour camera's K scaled, to a hundredth of a pixel: no resampling). Without that
  file the map is taken to cover the photo's view. Each photo's map is judged against the mesh before it is used.
"""

from __future__ import annotations

import logging
import re
from pathlib import Path

from scantex.errors import ScanError
from scantex.photos.conventions import MAX_DISTORTION_PX, check_intrinsics, registered_depths
from scantex.photos.files import check_sizes, read_matrix, world_to_camera_of
from scantex.photos.photoset import PhotoSet, image_size
from scantex.views.camera import Camera

log = logging.getLogger(__name__)

FORMAT = "scannet"
INTRINSICS = Path("intrinsic") / "intrinsic_color.txt"
DEPTH_INTRINSICS = Path("intrinsic") / "intrinsic_depth.txt"
IMAGE_SUFFIXES = (".jpg", ".jpeg", ".png")
NUMBERED = re.compile(r"^(\d+)$")


def export_folder(path: Path) -> Path | None:
    """The export folder ``path`` is or lies in (``path`` itself, or the folder of its ``intrinsic/``, ``pose/``
    or ``color/``), else ``None``."""
    for folder in (path, path.parent):
        if (folder / INTRINSICS).is_file() and (folder / "pose").is_dir() and (folder / "color").is_dir():
            return folder
    return None


def load_scannet(path: str | Path, *, max_distortion_px: float = MAX_DISTORTION_PX) -> PhotoSet:
    """Read a ScanNet export folder (or its ``intrinsic/``, ``pose/`` or ``color/``); conventions in the module
    docstring. ``max_distortion_px`` is accepted for symmetry: the format stores no distortion.

    Raises:
        ScanError: not an export folder, a malformed pose or intrinsics file, no frame with a pose and a photo.
    """
    path = Path(path)
    folder = export_folder(path)
    if folder is None:
        raise ScanError(path, f"not a ScanNet export: expected {INTRINSICS}, pose/ and color/")
    K = read_matrix(folder / INTRINSICS, "4x4 intrinsics file")[:3, :3].copy()
    K_depth = None
    if (folder / DEPTH_INTRINSICS).is_file():
        K_depth = read_matrix(folder / DEPTH_INTRINSICS, "4x4 intrinsics file")[:3, :3].copy()
    photos = {}
    for p in (folder / "color").iterdir():
        if p.suffix.lower() in IMAGE_SUFFIXES and NUMBERED.match(p.stem):
            photos.setdefault(int(p.stem), p)
    poses = sorted((int(p.stem), p) for p in (folder / "pose").glob("*.txt") if NUMBERED.match(p.stem))
    cameras, images, depths = [], [], []
    lost = 0
    size = None
    for number, pose_file in poses:
        image = photos.get(number)
        if image is None:
            continue
        w2c = world_to_camera_of(pose_file)
        if w2c is None:
            lost += 1
            continue
        if size is None:
            size = check_intrinsics(K, *image_size(image), folder / INTRINSICS, "intrinsics")
        cameras.append(Camera(K, w2c, *size))
        images.append(image)
        depth = folder / "depth" / f"{number}.png"
        depths.append(depth if depth.is_file() else None)
    if not images:
        raise ScanError(folder, f"none of its {len(poses)} pose/N.txt files has both a finite pose and its photo "
                                "(color/N.jpg)")
    if lost:
        log.warning("%s: %d frames have no pose (tracking lost: -inf): skipped", folder, lost)
    check_sizes(cameras, images, folder)
    depths, warps = registered_depths(depths, K_depth, K, size, folder / DEPTH_INTRINSICS)
    return PhotoSet(cameras=tuple(cameras), images=tuple(images), depths=depths, source=folder, format=FORMAT,
                    depth_warps=warps)
