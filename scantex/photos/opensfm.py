"""OpenSfM's ``reconstruction.json``: Mapillary's structure from motion, and OpenDroneMap's (ODM, WebODM), whose
drone and façade projects keep it in ``opensfm/`` beside their textured mesh.

Conventions (OpenSfM's source: ``io.py`` ``reconstructions_from_json``, ``src/geometry`` ``pose.h``, ``camera.cc``
``NormalizedToPixelCoordinates``, ``camera_projections_functions.h``, ``camera_distortions_functions.h``, its
``doc/source/geometry.rst``; ODM's ``stages/run_opensfm.py``, ``stages/mvstex.py``), and what scantex does with them:

- A list of reconstructions: the first (OpenSfM's largest) is read, with a warning where there are more. Its
  ``shots``, keyed by the photo's file name, hold ``camera`` (an id of ``cameras``), ``rotation`` (axis-angle) and
  ``translation``: ``x_cam = R X + t``, the camera's axes OpenCV's (+x right, +y down, +z forward), as scantex's.
- Cameras in units of the photo's longer side ``s = max(w, h)``, their pixel map ``u = s x + (w - 1) / 2``, ``v = s
  y + (h - 1) / 2`` (pixel centres at integers): ``perspective`` (``focal``, ``k1``, ``k2``; the default without a
  ``projection_type``), ``simple_radial`` and ``radial`` (``focal_x``, ``focal_y``, ``c_x``, ``c_y``, ``k1``, and
  ``k2``), ``brown`` (the same and ``k1``-``k3``, ``p1``, ``p2``: OpenCV's model), ``fisheye`` (``focal``, ``k1``,
  ``k2`` of the angle) and ``fisheye_opencv`` (``focal_x``, ``focal_y``, ``c_x``, ``c_y``, ``k1``-``k4``: OpenCV's
  fisheye). The lens is undone as each photo is read where it moves pixels by more than ``max_distortion_px``
  (:mod:`scantex.photos.lens`). The photo's size is its file's (the intrinsics being in units of its side, a photo
  scaled since reads right; one of another shape is refused). ``spherical`` (360) shots are skipped with a count;
  ``dual``, ``fisheye62`` and ``fisheye624`` cameras' shots with the reason.
- The photos: by their shot's name beside the file, in its ``images/``, in the ``images/`` a folder up (ODM's
  project: ``opensfm/reconstruction.json`` and ``images/``), or in ``image_dir``; an undistorted reconstruction's
  (``undistorted/reconstruction.json``) as the name with ``.tif``, ``.png`` or ``.jpg`` added in its ``images/``.
- The frame: ODM (from 2.4.3) rewrites ``opensfm/reconstruction.json`` in its georeferenced frame, UTM less the offset
  in ``odm_georeferencing/coords.txt``: the frame of ``odm_texturing/odm_textured_model_geo.obj``. Its
  ``reconstruction.topocentric.json`` is not (a warning says so), nor the mesh ``--align`` rewrites (its
  ``odm_textured_model_geo_unaligned.obj`` is).
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from scantex.errors import ScanError
from scantex.photos.conventions import MAX_DISTORTION_PX, check_intrinsics, pinhole_camera, world_to_camera_from
from scantex.photos.files import check_sizes, converts, find_photo, load_json, located, number
from scantex.photos.photoset import Distortion, PhotoSet, image_size
from scantex.views.camera import Camera

log = logging.getLogger(__name__)

FORMAT = "opensfm"
#: OpenSfM's camera models scantex reads: their focal and principal point keys, radial and tangential keys, and the
#: projection before the radial polynomial
MODELS = {
    "perspective": (("focal", "focal"), None, ("k1", "k2"), (), "perspective"),
    "simple_radial": (("focal_x", "focal_y"), ("c_x", "c_y"), ("k1",), (), "perspective"),
    "radial": (("focal_x", "focal_y"), ("c_x", "c_y"), ("k1", "k2"), (), "perspective"),
    "brown": (("focal_x", "focal_y"), ("c_x", "c_y"), ("k1", "k2", "k3"), ("p1", "p2"), "perspective"),
    "fisheye": (("focal", "focal"), None, ("k1", "k2"), (), "equidistant"),
    "fisheye_opencv": (("focal_x", "focal_y"), ("c_x", "c_y"), ("k1", "k2", "k3", "k4"), (), "equidistant"),
}
#: 360 photos: skipped with a count
SPHERICAL = ("spherical", "equirectangular")
#: an undistorted reconstruction's photos: the shot's name with one of these added
UNDISTORTED_SUFFIXES = (".tif", ".png", ".jpg")


def is_reconstruction(doc) -> bool:
    """Whether a parsed JSON document is OpenSfM's reconstruction list (each with ``cameras`` and ``shots``)."""
    return (isinstance(doc, list) and bool(doc) and isinstance(doc[0], dict) and isinstance(doc[0].get("shots"), dict)
            and isinstance(doc[0].get("cameras"), dict))


def is_camera_models(doc) -> bool:
    """Whether a parsed JSON document is OpenDroneMap's ``cameras.json``: its camera models by id, without poses."""
    return (isinstance(doc, dict) and bool(doc)
            and all(isinstance(v, dict) and "projection_type" in v for v in doc.values()))


#: what a user giving OpenDroneMap's ``cameras.json`` (or WebODM's download, which holds no other) is told
CAMERA_MODELS_ONLY = ("OpenDroneMap's camera models, without the photos' poses: give the ODM project's folder (its "
                      "opensfm/ and images/; WebODM's all.zip download holds neither)")


def reconstruction_file(folder: Path) -> Path | None:
    """OpenSfM's ``reconstruction.json`` in ``folder``, or in its ``opensfm/`` (an ODM project); ``None`` if none.
    Told by its opening (a list whose first object names its ``cameras`` or ``shots``), not parsed: a large project's
    file, its points included, runs to tens of megabytes, and :func:`load_opensfm` parses it once."""
    for candidate in (folder / "reconstruction.json", folder / "opensfm" / "reconstruction.json"):
        try:
            with open(candidate, "rb") as f:
                head = f.read(1 << 18).lstrip(b"\xef\xbb\xbf \t\r\n")
        except OSError:
            continue
        if head.startswith(b"[") and (b'"cameras"' in head or b'"shots"' in head):
            return candidate
    return None


def load_opensfm(path: str | Path, *, image_dir: str | Path | None = None,
                 max_distortion_px: float = MAX_DISTORTION_PX) -> PhotoSet:
    """Read OpenSfM's ``reconstruction.json`` (or a folder holding one, or an ODM project); conventions in the module
    docstring. ``image_dir``: where the photos are, by name, when they are not where OpenSfM's dataset keeps them.

    Raises:
        ScanError: not a reconstruction, no shot of a camera scantex reads, a photo not found or of another shape
            than its camera.
    """
    path = Path(path)
    file = located(path, reconstruction_file, "no OpenSfM reconstruction.json in it (nor in its opensfm/)")
    doc = load_json(file)
    if not is_reconstruction(doc):
        raise ScanError(file, "not an OpenSfM reconstruction (a list of reconstructions with cameras and shots)")
    aligned = file.parent.parent / "odm_georeferencing" / "alignment_matrix.json"
    if file.parent.name == "opensfm" and aligned.is_file():
        log.warning("%s: OpenDroneMap aligned this project (--align, %s): its odm_textured_model_geo.obj was moved out "
                    "of these cameras' frame; odm_textured_model_geo_unaligned.obj is in it", file, aligned.name)
    if len(doc) > 1:
        log.warning("%s holds %d reconstructions: reading the first (%d photos; the others' are not used)", file,
                    len(doc), len(doc[0]["shots"]))
    if file.name.lower() == "reconstruction.topocentric.json":
        log.warning("%s is OpenDroneMap's local frame, not its textured mesh's: use opensfm/reconstruction.json", file)
    cameras_doc = doc[0]["cameras"]
    cameras, images, distortions, lenses = [], [], [], []
    spherical = 0
    skipped: dict[str, int] = {}  # shots of cameras scantex does not read, by why
    for name, shot in sorted(doc[0]["shots"].items()):
        what = f"shot {name!r}"
        camera_id = shot.get("camera") if isinstance(shot, dict) else None
        if not isinstance(camera_id, str) or camera_id not in cameras_doc:
            raise ScanError(file, f"{what}: its camera {camera_id!r} is not in the reconstruction's cameras")
        model = cameras_doc[camera_id]
        if not isinstance(model, dict):
            raise ScanError(file, f"{what}: its camera {camera_id!r} is not a camera model (an object)")
        kind = str(model.get("projection_type") or "perspective").lower()
        if kind in SPHERICAL:
            spherical += 1
            continue
        if kind not in MODELS:
            why = f"a {kind} camera, which scantex does not read"
            skipped[why] = skipped.get(why, 0) + 1
            continue
        image = _photo(name, file, what, image_dir)
        w, h = image_size(image)
        K, distortion = _intrinsics(model, kind, w, h, file, what)
        R = _rotation(_vector(shot, "rotation", file, what))
        w2c = world_to_camera_from(R, -R.T @ _vector(shot, "translation", file, what), file, what)
        camera, lens = pinhole_camera(distortion, Camera(K, w2c, w, h), max_distortion_px, file, what)
        cameras.append(camera)
        images.append(image)
        distortions.append(distortion)
        lenses.append(lens)
    if not cameras:
        reasons = list(skipped) + (["its shots are spherical (360) photos, which scantex does not read"]
                                   if spherical else [])
        raise ScanError(file, f"none of its shots can be read: {'; '.join(reasons)}" if reasons else
                        "its reconstruction has no shots")
    for why, count in skipped.items():
        log.warning("%s: %d of its shots skipped: %s", file, count, why)
    if spherical:
        log.warning("%s: %d of its shots are spherical (360) photos, which a pinhole view cannot hold: skipped", file,
                    spherical)
    check_sizes(cameras, images, file)
    return PhotoSet(cameras=tuple(cameras), images=tuple(images), source=file, format=FORMAT,
                    distortions=tuple(distortions), lenses=tuple(lenses))


def _photo(name: str, file: Path, what: str, image_dir: str | Path | None) -> Path:
    """A shot's photo (see the module docstring)."""
    try:
        return find_photo(name, file, what, image_dir)
    except ScanError:
        # an undistorted reconstruction's photos: the shot's name with the undistorter's format added
        for suffix in UNDISTORTED_SUFFIXES:
            candidate = file.parent / "images" / (Path(name).name + suffix)
            if candidate.is_file():
                return candidate
        raise


def _vector(shot: dict, key: str, file: Path, what: str) -> np.ndarray:
    try:
        values = np.array(shot[key], np.float64).reshape(-1)
    except (KeyError, TypeError, ValueError):
        raise ScanError(file, f"{what}: no {key} of 3 numbers") from None
    if values.size != 3 or not np.isfinite(values).all():
        raise ScanError(file, f"{what}: its {key} is not 3 finite numbers")
    return values


def _rotation(axis_angle: np.ndarray) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    return Rotation.from_rotvec(axis_angle).as_matrix()


def _intrinsics(model: dict, kind: str, w: int, h: int, file: Path, what: str) -> tuple[np.ndarray,
                                                                                         Distortion | None]:
    """``(K, distortion)`` of an OpenSfM camera for its photo of ``w`` x ``h`` pixels."""
    stored = (model.get("width"), model.get("height"))
    # a photo scaled since is rounded to whole pixels: its shape within a pixel at the camera's size
    if (all(isinstance(v, (int, float)) and v > 0 for v in stored)
            and abs(stored[0] * h - stored[1] * w) > max(stored)):
        raise ScanError(file, f"{what}: its photo is {w}x{h}, of another shape than its camera's {stored[0]}x"
                              f"{stored[1]}")
    (fx_key, fy_key), centre, radial_keys, tangential_keys, projection = MODELS[kind]
    side = max(w, h)
    fx, fy = number(model, fx_key, file, what) * side, number(model, fy_key, file, what) * side
    cx, cy = ((number(model, centre[0], file, what, 0.0), number(model, centre[1], file, what, 0.0)) if centre
              else (0.0, 0.0))
    K = np.array([[fx, 0.0, cx * side + (w - 1) / 2.0], [0.0, fy, cy * side + (h - 1) / 2.0], [0.0, 0.0, 1.0]])
    check_intrinsics(K, w, h, file, what)
    radial = [number(model, k, file, what, 0.0) for k in radial_keys]
    while radial and radial[-1] == 0.0:
        radial.pop()
    tangential = tuple(number(model, k, file, what, 0.0) for k in tangential_keys) or (0.0, 0.0)
    if projection == "perspective" and not any(radial) and not any(tangential):
        return K, None
    return K, Distortion(f"OpenSfM {kind}", tuple(radial), tangential, projection=projection)


def write_opensfm(photos: PhotoSet, out_dir: str | Path) -> Path:
    """Write ``out_dir/reconstruction.json`` (one reconstruction, a camera per photo: ``perspective`` for a centred
    pinhole, ``brown`` or ``fisheye_opencv`` for the rest) with the photos in ``out_dir/images/`` as
    ``photo_000.<ext>``; returns its path. A photo undistorted when read is written as stored with its lens where
    OpenSfM's models hold it, else undistorted (a PNG).

    Raises:
        ValueError: a camera with a skew (OpenSfM's have none).
    """
    import json

    from scantex.io.atomic import atomic_files
    from scantex.photos.files import write_photo

    from scipy.spatial.transform import Rotation

    photos = photos.as_stored(_holds)
    out_dir = Path(out_dir)
    (out_dir / "images").mkdir(parents=True, exist_ok=True)
    cameras, shots = {}, {}
    with atomic_files() as files:
        for i, cam in enumerate(photos.cameras):
            camera = _camera(cam, photos.distortions[i], i)
            image = write_photo(files, photos, i, out_dir / "images" / f"photo_{i:03d}")
            cameras[f"camera {i}"] = camera
            shots[image.name] = {"camera": f"camera {i}", "rotation": Rotation.from_matrix(cam.R).as_rotvec().tolist(),
                                 "translation": [float(v) for v in cam.t]}
        text = json.dumps([{"cameras": cameras, "shots": shots, "points": {}}], indent=1)
        files.path(out_dir / "reconstruction.json").write_text(text)
    return out_dir / "reconstruction.json"


def _holds(distortion: Distortion, cam: Camera) -> bool:
    return converts(lambda: _camera(cam, distortion, 0))


def _camera(cam: Camera, distortion: Distortion | None, i: int) -> dict:
    """``cam`` as an OpenSfM camera (the inverse of :func:`_intrinsics`)."""
    K = cam.K
    if K[0, 1] != 0:
        raise ValueError(f"photo {i}: a skewed camera (K {K.tolist()}): OpenSfM's cameras have no skew")
    side = max(cam.width, cam.height)
    out = {"width": cam.width, "height": cam.height}
    fx, fy = float(K[0, 0]) / side, float(K[1, 1]) / side
    cx, cy = (float(K[0, 2]) - (cam.width - 1) / 2.0) / side, (float(K[1, 2]) - (cam.height - 1) / 2.0) / side
    if distortion is None or distortion.is_zero:
        if fx == fy and cx == 0.0 and cy == 0.0:
            return {**out, "projection_type": "perspective", "focal": fx, "k1": 0.0, "k2": 0.0}
        return {**out, "projection_type": "brown", "focal_x": fx, "focal_y": fy, "c_x": cx, "c_y": cy,
                **{k: 0.0 for k in ("k1", "k2", "k3", "p1", "p2")}}
    if distortion.radial_denominator or distortion.inverse_radial:
        raise ValueError(f"photo {i}: OpenSfM's models cannot hold a {distortion.model} distortion")
    radial = list(distortion.radial)
    if distortion.projection == "equidistant" and len(radial) <= 4 and not any(distortion.tangential):
        return {**out, "projection_type": "fisheye_opencv", "focal_x": fx, "focal_y": fy, "c_x": cx, "c_y": cy,
                **{f"k{n + 1}": float(k) for n, k in enumerate(radial + [0.0] * (4 - len(radial)))}}
    if distortion.projection == "perspective" and len(radial) <= 3:
        p1, p2 = distortion.tangential
        return {**out, "projection_type": "brown", "focal_x": fx, "focal_y": fy, "c_x": cx, "c_y": cy,
                **{f"k{n + 1}": float(k) for n, k in enumerate(radial + [0.0] * (3 - len(radial)))},
                "p1": float(p1), "p2": float(p2)}
    raise ValueError(f"photo {i}: OpenSfM's models cannot hold a {distortion.model} distortion")
