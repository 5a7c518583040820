"""texrecon's (mvs-texturing's) scene folder: each photo beside a ``.cam`` file of the same name
(``color_00.jpg`` + ``color_00.cam``), as MVE, texrecon and the RGB-D texturing datasets (G2LTex's) keep them.

Conventions, and what scantex does with them:

- Line 1 of a ``.cam``: ``tx ty tz R00 R01 R02 R10 R11 R12 R20 R21 R22``, the *world-to-camera* translation
  and rotation (row by row), OpenCV's camera axes: scantex's ``world_to_camera`` as it is.
- Line 2: ``f d0 d1 paspect ppx ppy`` (texrecon's defaults for what is left off: no distortion, square pixels,
  the principal point at the centre). MVE's focal length is over the image's larger side: for a landscape
  image (``width / height * paspect >= 1``) ``fx = f width``, ``fy = fx paspect``; else ``fy = f height``,
  ``fx = fy / paspect``. The principal point is over the image's width and height, measured from its corner:
  scantex's ``cx = ppx width - 0.5``, ``cy = ppy height - 0.5``. The image size is read from the image file.
  A line whose principal point is no share of the image (over 1) is in pixels, as G2LTex writes some of its
  ``.cam`` files (``582.871 0 0 1 320 240``): ``fx = f``, ``fy = f paspect``, ``cx, cy`` as in its
  configuration (below).
- ``d0 d1``: MVE's radial distortion of the focal-normalised point, ``1 + d0 r^2 + d1 r^4`` (OpenCV's ``k1,
  k2``); with ``d1`` zero, VisualSfM's one-term model, which undistorts by ``1 + d0 r^2`` (about OpenCV's
  ``k1 = -d0``). texrecon undistorts such photos, and so does scantex (:mod:`scantex.photos.lens`) where the
  distortion moves pixels by more than ``max_distortion_px``; a smaller one is ignored.
- A ``.cam`` of one line (G2LTex writes the pose alone) takes its intrinsics from a G2LTex configuration
  (a ``.yml`` with ``RGB_fx``, ``RGB_fy``, ``RGB_cx``, ``RGB_cy`` in pixels, OpenCV's pixel centres), the
  nearest in the folder, up to three above it, or a ``Config/`` beside one of them, as G2LTex reads them; one
  for photos of another size is refused, naming the file.
- Depth: ``depth_00.png`` beside ``color_00.jpg`` (G2LTex's names; uint16 millimetres) is the photo's depth
  map. MVE's own scene layout (``views/view_0000.mve``) is not read: texrecon's scene folder is the
  portable one.
- Photos are taken in the natural order of their names (``color_2`` before ``color_10``).
"""

from __future__ import annotations

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
    pinhole_camera,
)
from scantex.photos.files import folder_of, write_photo
from scantex.photos.photoset import Distortion, PhotoSet, image_size
from scantex.views.camera import Camera

log = logging.getLogger(__name__)

FORMAT = "texrecon"
#: the image files texrecon pairs with a ``.cam`` (its own list; any case)
IMAGE_SUFFIXES = (".jpg", ".jpeg", ".png", ".tif", ".tiff")
#: the keys of a G2LTex configuration that give a one-line ``.cam`` its intrinsics
G2LTEX_KEYS = ("RGB_fx", "RGB_fy", "RGB_cx", "RGB_cy")


def natural_key(path: Path) -> list:
    """Sort key of a file name with its numbers compared as numbers (``color_2`` before ``color_10``)."""
    return [int(part) if part.isdigit() else part.lower() for part in re.split(r"(\d+)", path.stem)]


def pairs(folder: Path) -> list[tuple[Path, Path]]:
    """``(cam, image)`` pairs of ``folder`` in natural order: each ``.cam`` with the image of its name."""
    images = {}
    for p in sorted(folder.iterdir()):
        if p.suffix.lower() in IMAGE_SUFFIXES and p.is_file():
            images.setdefault(p.stem, p)
    cams = [p for p in folder.iterdir() if p.suffix.lower() == ".cam" and p.is_file()]
    return [(cam, images[cam.stem]) for cam in sorted(cams, key=natural_key) if cam.stem in images]


def is_scene_folder(folder: Path) -> bool:
    return folder.is_dir() and bool(pairs(folder))


def load_mve(path: str | Path, *, max_distortion_px: float = MAX_DISTORTION_PX) -> PhotoSet:
    """Read a texrecon scene folder (or one of its ``.cam`` files); conventions in the module docstring.

    Raises:
        ScanError: no ``.cam`` with its image, a malformed ``.cam``, no intrinsics for a one-line ``.cam``,
            non-finite or non-rigid poses, a distortion too strong to ignore.
    """
    folder = folder_of(Path(path))
    found = pairs(folder)
    if not found:
        raise ScanError(folder, "no .cam file beside an image of its name (color_00.cam + color_00.jpg): not a "
                                "texrecon scene folder")
    config, config_file = None, None
    cameras, images, depths, distortions, lenses = [], [], [], [], []
    for cam_file, image in found:
        pose, lens = _read_cam(cam_file)
        width, height = image_size(image)
        if lens is None:
            if config is None:
                config, config_file = _g2ltex_config(folder, cam_file)
            K = np.array([[config["RGB_fx"], 0.0, config["RGB_cx"]], [0.0, config["RGB_fy"], config["RGB_cy"]],
                          [0.0, 0.0, 1.0]])
            size = (config.get("RGB_width", width), config.get("RGB_height", height))
            if size != (width, height):
                raise ScanError(cam_file, f"{image.name} is {width}x{height} but the intrinsics of the G2LTex "
                                          f"configuration {config_file} are for {size[0]:.0f}x{size[1]:.0f}: "
                                          "another capture's (set its RGB_ lines to this capture's camera)")
            distortion = None
        else:
            K, distortion = lens_intrinsics(lens, width, height, cam_file)
        width, height = check_intrinsics(K, width, height, cam_file, "intrinsics")
        camera, lens = pinhole_camera(distortion, Camera(K, pose, width, height), max_distortion_px, cam_file,
                                      "line 2")
        distortions.append(distortion)
        lenses.append(lens)
        cameras.append(camera)
        images.append(image)
        depth = image.with_name(image.stem.replace("color", "depth", 1) + ".png")
        depths.append(depth if image.stem.startswith("color") and depth.is_file() else None)
    return PhotoSet(cameras=tuple(cameras), images=tuple(images), depths=tuple(depths), source=folder,
                    format=FORMAT, distortions=tuple(distortions), lenses=tuple(lenses))


def _read_cam(cam_file: Path) -> tuple[np.ndarray, list[float] | None]:
    """``((4, 4) world-to-camera, line 2's numbers or None)`` of a ``.cam`` file."""
    try:
        lines = [line.split() for line in cam_file.read_text(encoding="utf-8").splitlines() if line.strip()]
    except (OSError, UnicodeDecodeError) as e:
        raise ScanError(cam_file, f"cannot read the file ({getattr(e, 'strerror', None) or 'not text'})") from None
    try:
        numbers = [[float(v) for v in line] for line in lines[:2]]
    except ValueError:
        raise ScanError(cam_file, "not a .cam file: its first two lines are not numbers") from None
    if not numbers or len(numbers[0]) != 12:
        raise ScanError(cam_file, f"not a .cam file: line 1 has {len(numbers[0]) if numbers else 0} numbers, "
                                  "expected 12 (tx ty tz and the rotation, row by row)")
    t, R = numbers[0][:3], numbers[0][3:]
    pose = check_pose([R[0:3] + [t[0]], R[3:6] + [t[1]], R[6:9] + [t[2]]], cam_file, "line 1")
    if len(numbers) < 2:
        return pose, None
    if not 1 <= len(numbers[1]) <= 6:
        raise ScanError(cam_file, f"line 2 has {len(numbers[1])} numbers, expected 1 to 6 (f d0 d1 paspect ppx "
                                  "ppy)")
    return pose, numbers[1]


def lens_intrinsics(lens: list[float], width: int, height: int, cam_file: Path,
                    what: str = "line 2") -> tuple[np.ndarray, Distortion | None]:
    """K in scantex's convention and the distortion of a ``.cam``'s line 2 (texrecon's defaults filled in);
    ``what`` names where the numbers are, for the error."""
    f, d0, d1, paspect, ppx, ppy = lens + [0.0, 0.0, 1.0, 0.5, 0.5][len(lens) - 1:]
    if not (np.isfinite(lens).all() and f > 0 and paspect > 0):
        raise ScanError(cam_file, f"{what}: the focal length and the pixel aspect must be positive numbers, got "
                                  f"{f} and {paspect}")
    if len(lens) == 6 and max(ppx, ppy) > 1.0:  # no share of the image: pixels, as G2LTex writes some
        K = np.array([[f, 0.0, ppx], [0.0, f * paspect, ppy], [0.0, 0.0, 1.0]])
    else:
        if width / height * paspect < 1.0:  # portrait, as MVE's fill_calibration decides it
            fy = f * height
            fx = fy / paspect
        else:
            fx = f * width
            fy = fx * paspect
        K = np.array([[fx, 0.0, ppx * width - CORNER_CONVENTION], [0.0, fy, ppy * height - CORNER_CONVENTION],
                      [0.0, 0.0, 1.0]])
    if d0 == 0.0 and d1 == 0.0:
        return K, None
    if d1 != 0.0:
        return K, Distortion("MVE k2k4", (d0, d1))
    return K, Distortion("VisualSfM", (-d0,), inverse_radial=(d0,))


def _g2ltex_config(folder: Path, cam_file: Path) -> tuple[dict, Path]:
    """The colour camera's intrinsics from a G2LTex ``.yml``, and the file: the nearest in ``folder`` or up to
    three folders above it, or in a ``Config/`` there (G2LTex's release keeps ``Config/config.yml`` beside
    ``Data/<scene>/<scene>/``)."""
    for where in (folder, *list(folder.parents)[:3]):
        ymls = [p for sub in (where, where / "Config", where / "config") for pattern in ("*.yml", "*.yaml")
                for p in sorted(sub.glob(pattern))]
        for yml in ymls:
            values = _yml_numbers(yml)
            if all(k in values for k in G2LTEX_KEYS):
                return values, yml
    raise ScanError(cam_file, "holds the pose alone (one line) and no G2LTex configuration (.yml with RGB_fx, "
                              "RGB_fy, RGB_cx, RGB_cy) lies beside it or above it: add texrecon's second line, "
                              "f d0 d1 paspect ppx ppy")


def _yml_numbers(yml: Path) -> dict:
    """``key: number`` lines of an OpenCV-style YAML file (``%`` lines are comments), as floats."""
    values = {}
    try:
        text = yml.read_text(encoding="utf-8", errors="replace")
    except OSError:
        return values
    for line in text.splitlines():
        key, sep, value = line.partition(":")
        if not sep or line.lstrip().startswith(("%", "#")):
            continue
        try:
            values[key.strip()] = float(value.split("#")[0])
        except ValueError:
            continue
    return values


def write_mve(photos: PhotoSet, out_dir: str | Path) -> Path:
    """Write a texrecon scene folder: ``view_0000.<ext>`` beside ``view_0000.cam`` (both lines) per photo into
    ``out_dir``; returns ``out_dir``. Depth maps are not written (the format has none); a lens distortion ignored
    when read or a skew is dropped with a warning (texrecon's line 2 holds MVE's radial terms, not OpenCV's; a
    photo undistorted when read is written undistorted, as a PNG)."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    with atomic_files() as files:
        for i, (cam, image) in enumerate(zip(photos.cameras, photos.images)):
            warn_unwritten(photos, i, "the .cam file")
            stem = f"view_{i:04d}"
            write_photo(files, photos, i, out_dir / stem)
            files.path(out_dir / f"{stem}.cam").write_text(cam_lines(cam))
    return out_dir


def warn_unwritten(photos: PhotoSet, i: int, where: str) -> None:
    """Warn that photo ``i``'s lens distortion or skew, which MVE's cameras cannot hold, is not written to ``where``."""
    if photos.lenses[i] is None and photos.distortions[i] is not None and not photos.distortions[i].is_zero:
        log.warning("photo %d: its lens distortion is not written to %s", i, where)
    if photos.cameras[i].K[0, 1] != 0.0:
        log.warning("photo %d: its skew is not written to %s (MVE's cameras have none)", i, where)


def mve_lens(cam: Camera) -> tuple[float, float, float, float]:
    """``(f, paspect, ppx, ppy)``: ``cam``'s K as MVE keeps it (the inverse of :func:`lens_intrinsics`)."""
    (fx, _, cx), (_, fy, cy) = cam.K[0], cam.K[1]
    paspect = fy / fx
    w, h = cam.width, cam.height
    f = fy / h if w / h * paspect < 1.0 else fx / w
    return float(f), float(paspect), float((cx + CORNER_CONVENTION) / w), float((cy + CORNER_CONVENTION) / h)


def cam_lines(cam: Camera) -> str:
    """A ``.cam`` file's two lines for ``cam`` (no distortion)."""
    f, paspect, ppx, ppy = mve_lens(cam)
    R, t = cam.world_to_camera[:3, :3], cam.world_to_camera[:3, 3]
    pose = " ".join(repr(float(v)) for v in [*t, *R.reshape(-1)])
    lens = " ".join(repr(float(v)) for v in (f, 0.0, 0.0, paspect, ppx, ppy))
    return f"{pose}\n{lens}\n"
