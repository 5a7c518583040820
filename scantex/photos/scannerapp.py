"""3D Scanner App's "All Data" export: ``frame_00012.jpg`` + ``frame_00012.json`` (+ ``depth_00012.png``,
``conf_00012.png``) side by side in one folder.

Conventions, and what scantex does with them:

- ``cameraPoseARFrame``: 16 numbers, a row-major 4x4 *camera-to-world* (translation in elements 3, 7,
  11), ARKit's camera axes (+x right, +y up, the camera looks down -z) in ARKit's world frame (+y up,
  gravity-aligned), which is the frame of the mesh the app exports with the frames. scantex:
  ``world_to_camera = inv(pose @ diag(1, -1, -1, 1))``: the camera axes are flipped, the world is not.
- ``intrinsics``: 9 numbers, a row-major 3x3 ``[fx, 0, cx, 0, fy, cy, 0, 0, 1]`` for the frame's JPEG.
  ARKit measures the principal point "from the top-left corner of the image frame" (the centre of the
  top-left pixel is ``(0.5, 0.5)``): scantex's ``cx = cx - 0.5``, ``cy = cy - 0.5``. ARKit's images are
  already undistorted (no distortion is stored). The image size is read from the image file.
- The app writes a JSON (pose) for many more frames than it keeps photos for: frames without an image
  (``.jpg``, ``.jpeg`` or ``.png``) are skipped.
- ``depth_XXXXX.png``: uint16 millimetres at the LiDAR's resolution (256x192 on iPhones), kept as
  the frame's depth map; the confidence maps are not read.
"""

from __future__ import annotations

import json
import logging
import re
from pathlib import Path

import numpy as np

from scantex.errors import ScanError
from scantex.io.atomic import atomic_files
from scantex.photos.conventions import (
    CORNER_CONVENTION,
    MAX_DISTORTION_PX,
    check_intrinsics,
    check_pose,
    opengl_camera_to_world,
    world_to_camera_from_opengl,
)
from scantex.photos.files import folder_of, load_json, need, write_depth, write_photo
from scantex.photos.photoset import PhotoSet, image_size
from scantex.views.camera import Camera

log = logging.getLogger(__name__)

FORMAT = "3dscannerapp"
FRAME = re.compile(r"^frame_(\d+)\.json$")
IMAGE_SUFFIXES = (".jpg", ".jpeg", ".png", ".JPG", ".JPEG", ".PNG")


def frame_files(folder: Path) -> list[Path]:
    """``frame_*.json`` files of ``folder`` in frame order."""
    found = [p for p in folder.glob("frame_*.json") if FRAME.match(p.name)]
    return sorted(found, key=lambda p: int(FRAME.match(p.name).group(1)))


def load_3dscannerapp(path: str | Path, *, max_distortion_px: float = MAX_DISTORTION_PX) -> PhotoSet:
    """Read a 3D Scanner App "All Data" folder (or one of its ``frame_*.json``); conventions in the
    module docstring. ``max_distortion_px`` is accepted for symmetry: the format stores no distortion.

    Raises:
        ScanError: no frames, no frame with an image, malformed JSON, non-finite or non-rigid poses.
    """
    folder = folder_of(Path(path))
    jsons = frame_files(folder)
    if not jsons:
        raise ScanError(folder, "no frame_*.json files: not a 3D Scanner App 'All Data' export")
    cameras, images, depths = [], [], []
    skipped = 0
    for file in jsons:
        stem = file.stem
        image = next((file.with_name(stem + s) for s in IMAGE_SUFFIXES if file.with_name(stem + s).is_file()),
                     None)
        if image is None:
            skipped += 1
            continue
        doc = load_json(file)
        c2w = check_pose(need(doc, "cameraPoseARFrame", file, "frame"), file, "cameraPoseARFrame")
        try:
            K = np.asarray(need(doc, "intrinsics", file, "frame"), dtype=np.float64)
        except (TypeError, ValueError):
            raise ScanError(file, "intrinsics are not numbers") from None
        if K.shape != (9,) and K.shape != (3, 3):
            raise ScanError(file, f"intrinsics have {K.size} numbers, expected 9 (row-major 3x3)")
        K = K.reshape(3, 3).copy()
        width, height = image_size(image)
        width, height = check_intrinsics(K, width, height, file, "intrinsics")
        K[:2, 2] -= CORNER_CONVENTION
        cameras.append(Camera(K, world_to_camera_from_opengl(c2w), width, height))
        images.append(image)
        depth = folder / f"depth_{stem[len('frame_'):]}.png"
        depths.append(depth if depth.is_file() else None)
    if not images:
        raise ScanError(folder, f"none of the {len(jsons)} frame_*.json files has its image "
                                "(frame_XXXXX.jpg)")
    if skipped:
        log.info("%s: %d of %d frames have no photo and are skipped", folder, skipped, len(jsons))
    return PhotoSet(cameras=tuple(cameras), images=tuple(images), depths=tuple(depths), source=folder,
                    format=FORMAT)


def write_3dscannerapp(photos: PhotoSet, out_dir: str | Path) -> Path:
    """Write ``frame_00000.<ext>`` + ``frame_00000.json`` (+ ``depth_00000.png``, uint16 millimetres as the app
    writes them: another map is converted) per photo into ``out_dir``; returns ``out_dir``. Lens distortions are
    not written (the format has none): a photo undistorted when read is written undistorted, a small distortion
    ignored is dropped with a warning."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    with atomic_files() as files:
        for i, (cam, image) in enumerate(zip(photos.cameras, photos.images)):
            if photos.lenses[i] is None and photos.distortions[i] is not None and not photos.distortions[i].is_zero:
                log.warning("photo %d: 3D Scanner App frames hold no lens distortion; it is dropped", i)
            stem = f"frame_{i:05d}"
            K = cam.K.copy()
            K[:2, 2] += CORNER_CONVENTION
            doc = {"cameraPoseARFrame": opengl_camera_to_world(cam).reshape(-1).tolist(),
                   "intrinsics": K.reshape(-1).tolist(), "frame_index": i}
            write_photo(files, photos, i, out_dir / stem)
            files.path(out_dir / f"{stem}.json").write_text(json.dumps(doc, indent=1))
            if photos.depths[i] is not None:
                write_depth(files, photos, i, out_dir / f"depth_{i:05d}", floats=False)
    return out_dir
