"""Polycam's raw data export: ``keyframes/images/<id>.jpg`` + ``keyframes/cameras/<id>.json``
(+ ``keyframes/depth/<id>.png``), ``<id>`` an integer (a timestamp).

Conventions, and what scantex does with them:

- A camera file holds ``fx, fy, cx, cy, width, height`` and ``t_00 ... t_23``: the rows of a 3x4
  *camera-to-world* (``t_ij`` is row i, column j) in ARKit's convention (camera +x right, +y up,
  looking down -z; world +y up), the frame of the mesh Polycam exports (``raw.glb``). scantex:
  ``world_to_camera = inv([[t], [0, 0, 0, 1]] @ diag(1, -1, -1, 1))``: camera axes flipped, world kept.
  (nerfstudio's ``ns-process-data polycam`` also permutes the *world* axes, to z-up; scantex does not,
  so the cameras stay in the mesh's frame.)
- The principal point is ARKit's, measured from the image's corner: scantex's ``cx = cx - 0.5``,
  ``cy = cy - 0.5``. Polycam stores no lens distortion. ``blur_score`` is not used.
- When ``keyframes/corrected_images`` and ``keyframes/corrected_cameras`` exist (Polycam's refined
  poses and matching images), they are read instead of ``images``/``cameras``, as nerfstudio does.
- Depth maps: uint16 millimetres, ``keyframes/depth/<id>.png``, at the LiDAR's resolution.
- Files whose name is not an integer (``123(1).jpg``, duplicates left by unzipping) are ignored.
"""

from __future__ import annotations

import json
import logging
from pathlib import Path

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
    principal_point,
    world_to_camera_from_opengl,
)
from scantex.photos.files import check_sizes, load_json, need, number, write_depth, write_photo
from scantex.photos.photoset import PhotoSet
from scantex.views.camera import Camera

log = logging.getLogger(__name__)

FORMAT = "polycam"
IMAGE_SUFFIXES = (".jpg", ".jpeg", ".png")
POSE_KEYS = tuple(f"t_{r}{c}" for r in range(3) for c in range(4))


def keyframes_folder(path: Path) -> Path | None:
    """The ``keyframes`` folder of a Polycam export given as its root, ``keyframes`` itself, or a file
    inside ``keyframes/<sub>/``; ``None`` when there is none."""
    path = Path(path)
    for candidate in (path, path / "keyframes", path.parent.parent):
        if candidate.name == "keyframes" and ((candidate / "cameras").is_dir()
                                              or (candidate / "corrected_cameras").is_dir()):
            return candidate
    return None


def load_polycam(path: str | Path, *, max_distortion_px: float = MAX_DISTORTION_PX) -> PhotoSet:
    """Read a Polycam raw data folder (its root or its ``keyframes``); conventions in the module
    docstring. ``max_distortion_px`` is accepted for symmetry: the format stores no distortion.

    Raises:
        ScanError: no keyframes, a photo without its camera file, malformed JSON, non-finite poses.
    """
    path = Path(path)
    if not path.exists():
        raise ScanError(path, "no such file or folder")
    root = keyframes_folder(path)
    if root is None:
        raise ScanError(path, "no keyframes/cameras folder: not a Polycam raw data export")
    corrected = (root / "corrected_images").is_dir() and (root / "corrected_cameras").is_dir()
    image_dir = root / ("corrected_images" if corrected else "images")
    camera_dir = root / ("corrected_cameras" if corrected else "cameras")
    if not image_dir.is_dir():
        raise ScanError(root, f"no {image_dir.name} folder")
    files = [p for p in image_dir.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES and p.stem.isdigit()]
    if not files:
        raise ScanError(image_dir, "holds no keyframe images (<id>.jpg)")
    files.sort(key=lambda p: int(p.stem))
    cameras, depths = [], []
    for image in files:
        file = camera_dir / f"{image.stem}.json"
        if not file.is_file():
            raise ScanError(camera_dir, f"keyframe {image.name} has no camera file {file.name}")
        doc = load_json(file)
        what = "camera"
        c2w = check_pose([number(doc, k, file, what) for k in POSE_KEYS], file, what)
        width = pixel_count(need(doc, "width", file, what), "width", file, what)
        height = pixel_count(need(doc, "height", file, what), "height", file, what)
        K = intrinsics(number(doc, "fx", file, what), number(doc, "fy", file, what),
                       number(doc, "cx", file, what), number(doc, "cy", file, what),
                       pixel_centre=CORNER_CONVENTION)
        width, height = check_intrinsics(K, width, height, file, what)
        cameras.append(Camera(K, world_to_camera_from_opengl(c2w), width, height))
        depth = root / "depth" / f"{image.stem}.png"
        depths.append(depth if depth.is_file() else None)
    check_sizes(cameras, files, image_dir)
    return PhotoSet(cameras=tuple(cameras), images=tuple(files), depths=tuple(depths), source=root,
                    format=FORMAT)


def write_polycam(photos: PhotoSet, out_dir: str | Path) -> Path:
    """Write ``out_dir/keyframes/{images,cameras,depth}/<id>.*`` with ids 1, 2, ...; returns the
    ``keyframes`` folder. Lens distortions are not written (the format has none): a photo undistorted when read
    is written undistorted, a small distortion ignored is dropped with a warning; skew raises ``ValueError``."""
    root = Path(out_dir) / "keyframes"
    for sub in ("images", "cameras") + (("depth",) if photos.has_depth else ()):
        (root / sub).mkdir(parents=True, exist_ok=True)
    with atomic_files() as files:
        for i, (cam, image) in enumerate(zip(photos.cameras, photos.images)):
            if cam.K[0, 1] != 0:
                raise ValueError(f"photo {i}: Polycam cameras have no skew")
            if photos.lenses[i] is None and photos.distortions[i] is not None and not photos.distortions[i].is_zero:
                log.warning("photo %d: Polycam cameras hold no lens distortion; it is dropped", i)
            stem = str(i + 1)
            cx, cy = principal_point(cam.K, pixel_centre=CORNER_CONVENTION)
            c2w = opengl_camera_to_world(cam)
            doc = {"fx": float(cam.K[0, 0]), "fy": float(cam.K[1, 1]), "cx": cx, "cy": cy,
                   "width": cam.width, "height": cam.height, "blur_score": 1.0}
            doc.update({f"t_{r}{c}": float(c2w[r, c]) for r in range(3) for c in range(4)})
            write_photo(files, photos, i, root / "images" / stem)
            files.path(root / "cameras" / f"{stem}.json").write_text(json.dumps(doc, indent=1))
            if photos.depths[i] is not None:
                write_depth(files, photos, i, root / "depth" / stem, floats=False)
    return root
