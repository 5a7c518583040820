"""MVE's scene: ``views/view_0000.mve/`` folders, each a ``meta.ini`` and the view's images, as MVE's ``makescene``
and ``sfmrecon`` write them and texrecon reads them (``texrecon scene::undistorted mesh.ply out``).

Conventions, and what scantex does with them:

- ``meta.ini``: INI sections ``[camera]`` (``focal_length``, ``pixel_aspect``, ``principal_point``,
  ``radial_distortion``, ``rotation``, ``translation``) and ``[view]`` (``id``, ``name``). The camera is a texrecon
  ``.cam`` file's, key by key (:mod:`scantex.photos.mve`): ``rotation`` and ``translation`` the *world-to-camera*
  (row by row), the focal length over the image's larger side, the principal point a share of the image from its
  corner, MVE's radial distortion (its k2k4 model, the original photo's: the undistorted image has none left). A
  view whose focal length is 0 has no camera (``sfmrecon`` could not place it): skipped, with a count in a
  warning.
- The image: ``undistorted`` (as texrecon reads it by default), else ``original`` (the photo as taken, its
  distortion checked against ``--max-distortion``), in any of the image formats scantex reads; the intrinsics are
  shares of the image, so they hold at the image's own size (MVE's smaller ``undist-L1``, ``undist-L2`` are not
  read). MVE's own ``.mvei`` depth maps (distances along the rays, at a smaller scale) are not read.
- Views are taken in the order of their folders' numbers.
"""

from __future__ import annotations

import configparser
import logging
from pathlib import Path

import numpy as np

from scantex.errors import ScanError
from scantex.io.atomic import atomic_files
from scantex.photos.conventions import MAX_DISTORTION_PX, check_intrinsics, check_pose, pinhole_camera
from scantex.photos.files import write_photo
from scantex.photos.mve import lens_intrinsics, mve_lens, natural_key, warn_unwritten
from scantex.photos.photoset import Distortion, PhotoSet, image_size
from scantex.views.camera import Camera

log = logging.getLogger(__name__)

FORMAT = "mve"
#: the images of a view that scantex reads, best first (texrecon's default embedding, then the photo as taken)
IMAGES = ("undistorted", "original")
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".tif", ".tiff")


def views_folder(path: Path) -> Path | None:
    """The ``views/`` folder of the MVE scene that ``path`` is, holds or lies in (a ``meta.ini`` or a view's
    folder names its scene), else ``None``."""
    path = Path(path)
    if path.is_file():
        path = path.parent
    for folder in (path / "views", path, path.parent):
        if folder.is_dir() and any(folder.glob("*.mve/meta.ini")):
            return folder
    return None


def load_mve_scene(path: str | Path, *, max_distortion_px: float = MAX_DISTORTION_PX) -> PhotoSet:
    """Read an MVE scene (its folder, its ``views/`` or a view's ``meta.ini``); conventions in the module docstring.

    Raises:
        ScanError: no view with a camera and an image, a malformed ``meta.ini``, a distortion too strong to ignore.
    """
    views = views_folder(Path(path))
    if views is None:
        raise ScanError(Path(path), "not an MVE scene: expected views/view_0000.mve/meta.ini")
    cameras, images, distortions, lenses = [], [], [], []
    no_camera = no_image = 0
    folders = sorted((p for p in views.glob("*.mve") if (p / "meta.ini").is_file()), key=natural_key)
    for folder in folders:
        meta = folder / "meta.ini"
        lens, pose = _read_meta(meta)
        if lens is None:
            no_camera += 1
            continue
        image = _image(folder)
        if image is None:
            no_image += 1
            continue
        width, height = image_size(image)
        K, _ = lens_intrinsics([lens[0], 0.0, 0.0, *lens[3:]], width, height, meta, "[camera]")
        check_intrinsics(K, width, height, meta, "[camera]")
        # MVE's radial distortion (k2k4) is the original photo's: its undistorted image has none left
        distortion = (Distortion("MVE k2k4", tuple(lens[1:3])) if any(lens[1:3]) and image.stem.lower() == "original"
                      else None)
        camera, lens = pinhole_camera(distortion, Camera(K, pose, width, height), max_distortion_px, meta,
                                      "radial_distortion")
        distortions.append(distortion)
        lenses.append(lens)
        cameras.append(camera)
        images.append(image)
    if not images:
        raise ScanError(views, f"none of its {len(folders)} views has both a camera (a focal length) and an image "
                               f"({' or '.join(IMAGES)})")
    if no_camera:
        log.warning("%s: %d of its %d views have no camera (focal length 0: not placed by the reconstruction): "
                    "skipped", views, no_camera, len(folders))
    if no_image:
        log.warning("%s: %d of its %d views have no image (%s): skipped", views, no_image, len(folders),
                    " or ".join(IMAGES))
    return PhotoSet(cameras=tuple(cameras), images=tuple(images), source=views, format=FORMAT,
                    distortions=tuple(distortions), lenses=tuple(lenses))


def _image(folder: Path) -> Path | None:
    """The view's image, the first of :data:`IMAGES` there is."""
    files = {p.name.lower(): p for p in folder.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES and p.is_file()}
    for name in IMAGES:
        for suffix in IMAGE_SUFFIXES:
            if name + suffix in files:
                return files[name + suffix]
    return None


def _read_meta(meta: Path) -> tuple[list[float] | None, np.ndarray | None]:
    """``(lens [f d0 d1 paspect ppx ppy] or None when the view has no camera, world-to-camera)`` of a meta.ini."""
    parser = configparser.ConfigParser(interpolation=None)
    try:
        parser.read_string(meta.read_text(encoding="utf-8-sig", errors="replace"), source=str(meta))
    except (OSError, configparser.Error) as e:
        reason = getattr(e, "strerror", None) or (str(e).splitlines()[0] if str(e) else type(e).__name__)
        raise ScanError(meta, f"not an MVE meta.ini ({reason})") from None
    if not parser.has_section("camera"):
        return None, None

    def numbers(key: str, count: int, default: list[float] | None = None) -> list[float]:
        if not parser.has_option("camera", key):
            if default is None:
                raise ScanError(meta, f"[camera] has no {key}")
            return default
        try:
            values = [float(v) for v in parser.get("camera", key).split()]
        except ValueError:
            raise ScanError(meta, f"[camera] {key} is not numbers") from None
        if len(values) != count:
            raise ScanError(meta, f"[camera] {key} has {len(values)} numbers, expected {count}")
        return values

    f = numbers("focal_length", 1)[0]
    if f == 0.0:
        return None, None
    lens = [f, *numbers("radial_distortion", 2, [0.0, 0.0]), *numbers("pixel_aspect", 1, [1.0]),
            *numbers("principal_point", 2, [0.5, 0.5])]
    R = np.array(numbers("rotation", 9)).reshape(3, 3)
    t = np.array(numbers("translation", 3))
    return lens, check_pose(np.c_[R, t], meta, "[camera] rotation and translation")


def write_mve_scene(photos: PhotoSet, out_dir: str | Path) -> Path:
    """Write an MVE scene: ``views/view_0000.mve/`` with ``meta.ini`` and the photo as ``undistorted.<ext>`` per
    photo, into ``out_dir``; returns ``out_dir``. Depth maps are not written (MVE's are its own ``.mvei``); a lens
    distortion ignored when read or a skew is dropped with a warning (a photo undistorted when read is written
    undistorted, as a PNG)."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    with atomic_files() as files:
        for i, (cam, image) in enumerate(zip(photos.cameras, photos.images)):
            warn_unwritten(photos, i, "meta.ini")
            folder = out_dir / "views" / f"view_{i:04d}.mve"
            folder.mkdir(parents=True, exist_ok=True)
            f, paspect, ppx, ppy = mve_lens(cam)

            def row(values) -> str:
                return " ".join(repr(float(v)) for v in values)

            files.path(folder / "meta.ini").write_text(
                "# MVE view meta data is stored in INI-file syntax.\n\n[camera]\n"
                f"focal_length = {f!r}\npixel_aspect = {paspect!r}\nprincipal_point = {ppx!r} {ppy!r}\n"
                f"radial_distortion = 0 0\nrotation = {row(cam.world_to_camera[:3, :3].reshape(-1))}\n"
                f"translation = {row(cam.world_to_camera[:3, 3])}\n\n[view]\nid = {i}\nname = {image.stem}\n")
            write_photo(files, photos, i, folder / "undistorted")
    return out_dir
