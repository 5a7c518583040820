"""Meshroom's (AliceVision's) reconstruction: a ``cameras.sfm`` (or any ``.sfm``/``.json`` of ``ConvertSfMFormat``).

Meshroom's free photogrammetry pipeline leaves its cameras in ``MeshroomCache/StructureFromMotion/<id>/cameras.sfm``
and its mesh, in the same frame, in ``MeshroomCache/Texturing/<id>/texturedMesh.obj``: ``scantex enhance`` given the
project folder, its cache or that mesh finds both (:func:`cache_sfm`). Conventions (AliceVision's
``sfmDataIO/jsonIO``), and what scantex does with them:

- Every value is a string (boost's property tree); ``version`` (``["1", "2", "5"]``) says how the intrinsics are kept.
- ``intrinsics[]``: ``width``, ``height``, ``type``; the focal length in pixels (``pxFocalLength``, one number before
  1.2.0, ``[fx, fy]`` before 1.2.2) or in millimetres (``focalLength`` over ``sensorWidth``, times the width: ``fx``,
  ``fy = fx * pixelRatio``, which held the focal ratio ``fx / fy`` before 1.2.5; since 1.2.11 ``fy``, and ``fx = fy /
  pixelRatio``); ``principalPoint`` from the image's corner before 1.2.1, else its offset from the image's centre (``w
  / 2, h / 2``); AliceVision's pixel coordinates are scantex's (the top-left pixel's centre at 0). The lens: the
  ``type`` before 1.2.8 (``pinhole``, ``radial1``, ``radial3``, ``brown``, ``fisheye4``), ``distortionType`` since
  (``none``, ``radialk1``, ``radialk3``, ``brown``, ``fisheye``), with ``distortionParams``: ``k1``; ``k1, k2, k3``;
  ``k1, k2, k3, t1, t2`` (OpenCV's ``p1, p2``); OpenCV's equidistant fisheye ``k1``-``k4``; undone as each photo is
  read where it moves pixels by more than ``max_distortion_px`` (:mod:`scantex.photos.lens`). Other models
  (``fisheye1``, ``radialk3pt``, the ``equidistant`` camera, an ``undistortionType`` such as 3DE's) are refused.
- ``poses[]``: ``poseId`` and ``pose.transform``: ``rotation`` (9 numbers, Eigen's column-major order of the
  *world-to-camera* rotation ``R``) and ``center`` (the camera's centre ``C``): ``x_cam = R (X - C)``, OpenCV's axes.
- ``views[]``: ``viewId``, ``poseId``, ``intrinsicId``, ``path`` (the photo, as it was where Meshroom ran: looked for
  there, then by name beside the file, in its ``images/`` folder or the folder above's). A view without a pose (not
  reconstructed) or of a rig (``rigId``) is skipped, with a count. ``--images DIR`` names another folder to look in.
"""

from __future__ import annotations

import json
import logging
from pathlib import Path

import numpy as np

from scantex.errors import ScanError
from scantex.photos.conventions import MAX_DISTORTION_PX, check_intrinsics, pinhole_camera, world_to_camera_from
from scantex.photos.files import check_sizes, converts, find_photo, load_json, located
from scantex.photos.photoset import Distortion, PhotoSet
from scantex.views.camera import Camera

log = logging.getLogger(__name__)

FORMAT = "meshroom"
#: AliceVision's distortion models scantex reads (``distortionType`` since version 1.2.8): their parameters' number
DISTORTIONS = {"none": 0, "radialk1": 1, "radialk3": 3, "brown": 5, "fisheye": 4}
#: the camera ``type`` of files before 1.2.8, as the distortion it names (AliceVision's compatibilityStringToEnums)
MODELS = {"pinhole": "none", "radial1": "radialk1", "radial3": "radialk3", "brown": "brown", "fisheye4": "fisheye"}
#: the newest file version whose conventions scantex knows
NEWEST = (1, 2, 14)


def is_sfm(doc) -> bool:
    """Whether a parsed JSON document is an AliceVision SfM file (its views and intrinsics)."""
    return isinstance(doc, dict) and isinstance(doc.get("views"), list) and isinstance(doc.get("intrinsics"), list)


def sfm_file(folder: Path) -> Path | None:
    """The AliceVision SfM file in ``folder``: ``cameras.sfm``, else the first ``.sfm`` by name; ``None`` if none."""
    if (folder / "cameras.sfm").is_file():
        return folder / "cameras.sfm"
    try:
        return next(iter(sorted(p for p in folder.glob("*.sfm") if p.is_file())), None)
    except OSError:
        return None


def cache_sfm(folder: Path) -> Path | None:
    """The ``cameras.sfm`` of the Meshroom cache that ``folder`` is, holds (a project folder) or lies in (a node's
    output folder, ``Texturing/<id>/``): ``StructureFromMotion/<id>/cameras.sfm``, the newest where several are;
    ``None`` if none."""
    folder = Path(folder)
    for cache in (folder, folder / "MeshroomCache", folder.parent.parent):
        try:
            found = [p for p in (cache / "StructureFromMotion").glob("*/cameras.sfm") if p.is_file()]
        except OSError:
            continue
        if found:
            newest = max(found, key=lambda p: p.stat().st_mtime)
            if len(found) > 1:
                log.warning("%s holds %d StructureFromMotion results: reading the newest, %s", cache, len(found),
                            newest.parent.name)
            return newest
    return None


def load_meshroom(path: str | Path, *, image_dir: str | Path | None = None,
                  max_distortion_px: float = MAX_DISTORTION_PX) -> PhotoSet:
    """Read a Meshroom / AliceVision SfM file (or a folder holding ``cameras.sfm``); conventions in the module
    docstring. ``image_dir``: where the photos are, by name, when they are not where Meshroom read them.

    Raises:
        ScanError: not an SfM file, no reconstructed view, an unsupported camera model, a photo not found or of
            another size than its intrinsics.
    """
    path = Path(path)
    file = located(path, sfm_file, "no Meshroom cameras.sfm in it")
    doc = load_json(file)
    if not is_sfm(doc):
        raise ScanError(file, "not a Meshroom / AliceVision SfM file (no 'views' and 'intrinsics' lists)")
    version = _version(doc.get("version"), file)
    intrinsics = {str(i.get("intrinsicId")): i for i in doc["intrinsics"] if isinstance(i, dict)}
    poses = {str(p.get("poseId")): p for p in doc.get("poses", []) if isinstance(p, dict)}
    cameras, images, distortions, lenses = [], [], [], []
    unposed = rig = 0
    for view in doc["views"]:
        if not isinstance(view, dict):
            raise ScanError(file, "a view is not an object")
        what = f"view {view.get('viewId', '?')} ({Path(str(view.get('path', '?'))).name})"
        if "rigId" in view:
            rig += 1
            continue
        pose = poses.get(str(view.get("poseId")))
        if pose is None:
            unposed += 1
            continue
        intrinsic = intrinsics.get(str(view.get("intrinsicId")))
        if intrinsic is None:
            raise ScanError(file, f"{what}: its intrinsics {view.get('intrinsicId')!r} are not in the file")
        K, size, distortion = _intrinsic(intrinsic, version, file, what)
        camera = Camera(K, _world_to_camera(pose, file, what), *size)
        camera, lens = pinhole_camera(distortion, camera, max_distortion_px, file, what)
        cameras.append(camera)
        distortions.append(distortion)
        lenses.append(lens)
        images.append(find_photo(str(view.get("path", "")), file, what, image_dir))
    for count, why in ((unposed, "have no pose (not reconstructed)"), (rig, "belong to a rig, which scantex does not "
                                                                            "read")):
        if count:
            log.warning("%s: %d of its %d views %s: skipped", file, count, len(doc["views"]), why)
    if not cameras:
        raise ScanError(file, "none of its views has a pose (not reconstructed)" if unposed else
                        "all its views belong to a rig, which scantex does not read" if rig else "lists no views")
    check_sizes(cameras, images, file)
    return PhotoSet(cameras=tuple(cameras), images=tuple(images), source=file, format=FORMAT,
                    distortions=tuple(distortions), lenses=tuple(lenses))


def _version(value, file: Path) -> tuple[int, ...]:
    if value is None:
        raise ScanError(file, "no 'version': not an AliceVision SfM file (Meshroom writes one in every cameras.sfm)")
    try:
        version = tuple(int(v) for v in value)
    except (TypeError, ValueError):
        raise ScanError(file, f"its version is not three integers ({value!r})") from None
    if version > NEWEST:
        log.warning("%s: version %s, newer than scantex knows (%s): read by %s's conventions", file,
                    ".".join(map(str, version)), ".".join(map(str, NEWEST)), ".".join(map(str, NEWEST)))
    return version


def _numbers(value, n: int | None, file: Path, what: str) -> np.ndarray:
    """Numbers kept as strings (a list of them, or one)."""
    try:
        values = np.array([float(v) for v in (value if isinstance(value, list) else [value])], np.float64)
    except (TypeError, ValueError):
        raise ScanError(file, f"{what} is not numbers ({str(value)[:40]})") from None
    if (n is not None and values.size != n) or not np.isfinite(values).all():
        raise ScanError(file, f"{what} is not {n or 'some'} finite numbers ({str(value)[:40]})")
    return values


def _intrinsic(intrinsic: dict, version: tuple[int, ...], file: Path, what: str):
    """``(K, (width, height), distortion)`` of an AliceVision intrinsic, by its file's version."""
    kind, distortion_type, undistortion = _model_of(intrinsic, version, file, what)
    if kind != "pinhole" or distortion_type not in DISTORTIONS or undistortion != "none":
        named = distortion_type if kind == "pinhole" and undistortion == "none" else (
            kind if kind != "pinhole" else undistortion)
        raise ScanError(file, f"{what}: camera model {named!r} is not supported (scantex reads pinhole cameras with "
                              f"{', '.join(DISTORTIONS)} distortion; undistort the photos in Meshroom: "
                              "PrepareDenseScene)")
    w, h = (_count(intrinsic.get(k), file, f"{what}: {k}") for k in ("width", "height"))
    centre = np.array([w / 2.0, h / 2.0])
    pp = _numbers(intrinsic.get("principalPoint"), 2, file, f"{what}: principalPoint")
    pp = pp if version < (1, 2, 1) else pp + centre
    if version < (1, 2, 0):
        fx = fy = _numbers(intrinsic.get("pxFocalLength"), 1, file, f"{what}: pxFocalLength")[0]
    elif version < (1, 2, 2):
        fx, fy = _numbers(intrinsic.get("pxFocalLength"), 2, file, f"{what}: pxFocalLength")
    else:
        mm = _numbers(intrinsic.get("focalLength"), 1, file, f"{what}: focalLength")[0]
        sensor = _numbers(intrinsic.get("sensorWidth", "36"), 1, file, f"{what}: sensorWidth")[0]
        if sensor <= 0:
            raise ScanError(file, f"{what}: sensorWidth is {sensor}, not a size in millimetres")
        ratio = _numbers(intrinsic.get("pixelRatio", "1"), 1, file, f"{what}: pixelRatio")[0]
        if version < (1, 2, 5):  # pixelRatio held the focal ratio fx / fy
            fx = mm / sensor * w
            fy = fx / ratio
        elif version < (1, 2, 11):  # the pixel ratio, the focal length fx's
            fx = mm / sensor * w
            fy = fx * ratio
        else:  # the focal length fy's
            fy = mm / sensor * w
            fx = fy / ratio
    K = np.array([[fx, 0.0, pp[0]], [0.0, fy, pp[1]], [0.0, 0.0, 1.0]])
    check_intrinsics(K, w, h, file, what)
    params = _numbers(intrinsic.get("distortionParams", []), None, file, f"{what}: distortionParams") if (
        intrinsic.get("distortionParams")) else np.zeros(0)
    expected = DISTORTIONS[distortion_type]
    if params.size and params.size != expected:
        raise ScanError(file, f"{what}: a {distortion_type} distortion has {expected} parameters, not {params.size}")
    if distortion_type == "fisheye":  # of no coefficients still a fisheye (theta = atan r)
        return K, (w, h), Distortion("fisheye4", tuple(params) or (0.0,) * 4, projection="equidistant")
    if not params.any():
        return K, (w, h), None
    if distortion_type == "brown":
        distortion = Distortion("brown", tuple(params[:3]), (params[3], params[4]))
    else:
        distortion = Distortion(distortion_type, tuple(params))
    return K, (w, h), distortion


def _model_of(intrinsic: dict, version: tuple[int, ...], file: Path, what: str) -> tuple[str, str, str]:
    """``(camera type, distortion type, undistortion type)`` of an intrinsic: from its ``type`` before 1.2.8, from
    ``type``, ``distortionType`` and ``undistortionType`` since."""
    kind = str(intrinsic.get("type", ""))
    if version < (1, 2, 8):
        return ("pinhole", MODELS[kind], "none") if kind in MODELS else (kind, "", "none")
    return kind, str(intrinsic.get("distortionType", "none")), str(intrinsic.get("undistortionType", "none"))


def _count(value, file: Path, what: str) -> int:
    number = _numbers(value, 1, file, what)[0]
    if not number.is_integer() or number < 1:
        raise ScanError(file, f"{what} is not a whole number of pixels ({value!r})")
    return int(number)


def _world_to_camera(pose: dict, file: Path, what: str) -> np.ndarray:
    try:
        transform = pose["pose"]["transform"]
        rotation, centre = transform["rotation"], transform["center"]
    except (KeyError, TypeError):
        raise ScanError(file, f"{what}: its pose has no transform (rotation, center)") from None
    R = _numbers(rotation, 9, file, f"{what}: rotation").reshape(3, 3, order="F")  # Eigen's column-major order
    C = _numbers(centre, 3, file, f"{what}: center")
    return world_to_camera_from(R, C, file, what)


def write_meshroom(photos: PhotoSet, out_dir: str | Path) -> Path:
    """Write ``out_dir/cameras.sfm`` (version 1.2.5, which AliceVision reads to this day) with the photos copied
    beside it as ``photo_000.<ext>``; returns its path. A photo undistorted when read is written as stored with its
    lens where AliceVision's models hold it, else undistorted (a PNG)."""
    from scantex.io.atomic import atomic_files
    from scantex.photos.files import write_photo

    photos = photos.as_stored(_holds)
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    views, intrinsics, poses = [], [], []
    with atomic_files() as files:
        for i, cam in enumerate(photos.cameras):
            if cam.K[0, 1] != 0:
                raise ValueError(f"photo {i}: AliceVision's cameras have no skew")
            model, params = _model(photos.distortions[i], i)
            image = write_photo(files, photos, i, out_dir / f"photo_{i:03d}")
            fx, fy = float(cam.K[0, 0]), float(cam.K[1, 1])
            intrinsics.append({"intrinsicId": str(i), "width": str(cam.width), "height": str(cam.height),
                               "serialNumber": f"scantex {i}",
                               "sensorWidth": "36", "sensorHeight": str(36 * cam.height / cam.width),
                               "type": model, "initializationMode": "calibrated",
                               "initialFocalLength": repr(fx * 36 / cam.width),
                               "focalLength": repr(fx * 36 / cam.width),
                               "pixelRatio": repr(fy / fx), "pixelRatioLocked": "false",
                               "principalPoint": [repr(float(cam.K[0, 2] - cam.width / 2)),
                                                  repr(float(cam.K[1, 2] - cam.height / 2))],
                               "distortionParams": [repr(float(p)) for p in params], "locked": "1"})
            centre = -cam.R.T @ cam.t
            poses.append({"poseId": str(i), "pose": {"transform": {
                "rotation": [repr(float(v)) for v in cam.R.ravel(order="F")],
                "center": [repr(float(v)) for v in centre]}, "locked": "1"}})
            views.append({"viewId": str(i), "poseId": str(i), "intrinsicId": str(i), "path": str(image.resolve()),
                          "width": str(cam.width), "height": str(cam.height)})
        doc = {"version": ["1", "2", "5"], "views": views, "intrinsics": intrinsics, "poses": poses}
        files.path(out_dir / "cameras.sfm").write_text(json.dumps(doc, indent=4))
    return out_dir / "cameras.sfm"


def _model(distortion: Distortion | None, i: int) -> tuple[str, tuple[float, ...]]:
    """AliceVision's model and parameters of a distortion (the inverse of :func:`_intrinsic`)."""
    if distortion is None or distortion.is_zero:
        return "pinhole", ()
    k = tuple(distortion.radial)
    if distortion.projection == "equidistant" and len(k) <= 4 and not any(distortion.tangential):
        return "fisheye4", (k + (0.0,) * 4)[:4]
    if distortion.is_fisheye or distortion.radial_denominator or distortion.inverse_radial or len(k) > 3:
        raise ValueError(f"photo {i}: AliceVision's models cannot hold a {distortion.model} distortion")
    if any(distortion.tangential):
        return "brown", (k + (0.0,) * 3)[:3] + tuple(distortion.tangential)
    return ("radial1", k[:1]) if len(k) == 1 else ("radial3", (k + (0.0,) * 3)[:3])


def _holds(distortion: Distortion, cam: Camera) -> bool:
    return converts(lambda: _model(distortion, 0)) and cam.K[0, 1] == 0
