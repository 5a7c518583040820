"""OpenMVG's reconstruction: an ``sfm_data.json`` (its ``SfM_Data`` in cereal's JSON).

OpenMVG's pipeline (``openMVG_main_SfM``) writes its reconstruction as ``reconstruction_*/sfm_data.bin``, cereal's
binary, which scantex does not read: ``openMVG_main_ConvertSfM_DataFormat -i sfm_data.bin -o sfm_data.json`` writes
the JSON, which keeps everything. (``openMVG_main_openMVG2openMVS`` writes an OpenMVS ``scene.mvs`` with undistorted
photos, which scantex reads too: :mod:`scantex.photos.openmvs`.) Conventions (OpenMVG's ``sfm_data_io_cereal``,
``cameras/*_io.hpp``, ``geometry/pose3_io.hpp``), and what scantex does with them:

- ``sfm_data_version``; ``root_path``, the photos' folder where OpenMVG ran (a relative one from the folder it ran in:
  the file's, or one or two above it).
- ``views[]``: ``{key, value: {ptr_wrapper: {data: {local_path, filename, width, height, id_view, id_intrinsic,
  id_pose}}}}``; a view whose ``id_pose`` is not among the ``extrinsics`` (not reconstructed) is skipped, with a
  count. The photo: ``root_path/local_path/filename``, else by name in ``--images DIR``, beside the file, in its
  ``images/`` folder or the folder above's.
- ``intrinsics[]``: ``{key, value: {polymorphic_id, polymorphic_name, ptr_wrapper: {data: {width, height,
  focal_length, principal_point, <parameters>}}}}``; cereal names a type at its first object only (``polymorphic_id``
  with its high bit set), later ones by its number. One focal length in pixels; the principal point from the image's
  corner, the top-left pixel's centre at 0 (scantex's: ``openMVG2openMVS`` copies K as it is into OpenMVS's scene,
  read the same way). The lens: ``pinhole`` (none), ``pinhole_radial_k1`` (``disto_k1``: ``k1``),
  ``pinhole_radial_k3`` (``disto_k3``: ``k1, k2, k3``), ``pinhole_brown_t2`` (``disto_t2``: ``k1, k2, k3, t1, t2``,
  OpenCV's ``p1, p2``) and ``fisheye`` (``fisheye``: OpenCV's equidistant ``k1``-``k4``), undone as each photo is
  read where it moves pixels by more than ``max_distortion_px`` (:mod:`scantex.photos.lens`); ``spherical`` cameras
  (360 photos) are skipped with a count.
- ``extrinsics[]``: ``{key: id_pose, value: {rotation (3 rows, the world-to-camera R), center}}``: ``x_cam = R (X -
  C)``, OpenCV's axes.
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

FORMAT = "openmvg"
#: OpenMVG's intrinsic types scantex reads: the key of their lens parameters and how many there are
MODELS = {"pinhole": (None, 0), "pinhole_radial_k1": ("disto_k1", 1), "pinhole_radial_k3": ("disto_k3", 3),
          "pinhole_brown_t2": ("disto_t2", 5), "fisheye": ("fisheye", 4)}
#: cereal's flag on the first object of a polymorphic type (it carries the type's name) and of a shared pointer
#: (it carries the object)
FIRST = 0x80000000


def is_sfm_data(doc) -> bool:
    """Whether a parsed JSON document is an OpenMVG ``SfM_Data`` (its version and views)."""
    return isinstance(doc, dict) and "sfm_data_version" in doc and isinstance(doc.get("views"), list)


def sfm_data_file(folder: Path, suffix: str = ".json") -> Path | None:
    """The OpenMVG ``sfm_data.json`` in ``folder``, or in its ``reconstruction_*`` folder (the newest where several
    are); ``None`` if none. ``suffix`` ``".bin"``: such an ``sfm_data.bin`` (which :func:`load_openmvg` refuses,
    saying how to convert it)."""
    try:
        found = [p for p in [folder / f"sfm_data{suffix}", *folder.glob(f"reconstruction*/sfm_data{suffix}")]
                 if p.is_file()]
    except OSError:
        return None
    if not found:
        return None
    return found[0] if found[0].parent == folder else max(found, key=lambda p: p.stat().st_mtime)


def load_openmvg(path: str | Path, *, image_dir: str | Path | None = None,
                 max_distortion_px: float = MAX_DISTORTION_PX) -> PhotoSet:
    """Read an OpenMVG ``sfm_data.json`` (or a folder holding one); conventions in the module docstring.
    ``image_dir``: where the photos are, by name, when they are not where OpenMVG read them.

    Raises:
        ScanError: cereal's binary, not an ``SfM_Data``, no reconstructed view, an unsupported camera model, a photo
            not found or of another size than its intrinsics.
    """
    path = Path(path)
    file = located(path, sfm_data_file, "no OpenMVG sfm_data.json in it")
    if file.suffix.lower() == ".bin":
        raise ScanError(file, "OpenMVG's binary sfm_data: scantex reads its JSON (openMVG_main_ConvertSfM_DataFormat "
                              "-i sfm_data.bin -o sfm_data.json)")
    doc = load_json(file)
    if not is_sfm_data(doc):
        raise ScanError(file, "not an OpenMVG sfm_data (no 'sfm_data_version' and 'views')")
    pointers: dict[int, dict] = {}
    types: dict[int, str] = {}
    intrinsics = {str(key): _intrinsic(value, file, types, pointers)
                  for key, value in _entries(doc.get("intrinsics", []), file, "intrinsics")}
    poses = {str(key): value for key, value in _entries(doc.get("extrinsics", []), file, "extrinsics")}
    root = Path(str(doc.get("root_path", "")))
    cameras, images, distortions, lenses = [], [], [], []
    unposed = spherical = 0
    views = _entries(doc["views"], file, "views")
    for key, value in views:
        view = _pointed(value, file, f"view {key}", pointers)
        what = f"view {key} ({view.get('filename', '?')})"
        pose = poses.get(str(view.get("id_pose")))
        if pose is None:
            unposed += 1
            continue
        intrinsic = intrinsics.get(str(view.get("id_intrinsic")))
        if intrinsic is None:
            raise ScanError(file, f"{what}: its intrinsics {view.get('id_intrinsic')!r} are not in the file")
        if intrinsic == "spherical":
            spherical += 1
            continue
        kind, data = intrinsic
        K, size, distortion = _camera_model(kind, data, file, what)
        camera = Camera(K, _world_to_camera(pose, file, what), *size)
        camera, lens = pinhole_camera(distortion, camera, max_distortion_px, file, what)
        cameras.append(camera)
        distortions.append(distortion)
        lenses.append(lens)
        images.append(find_photo(_recorded(root / str(view.get("local_path", "")) / str(view.get("filename", "")),
                                           file), file, what, image_dir))
    for count, why in ((unposed, "have no pose (not reconstructed)"),
                       (spherical, "are spherical (360) photos, which a pinhole view cannot hold")):
        if count:
            log.warning("%s: %d of its %d views %s: skipped", file, count, len(views), why)
    if not cameras:
        raise ScanError(file, "none of its views has a pose (not reconstructed: read the sfm_data of a "
                              "reconstruction_* folder)" if unposed else
                        "all its views are spherical (360) photos, which scantex does not read" if spherical else
                        "lists no views")
    check_sizes(cameras, images, file)
    return PhotoSet(cameras=tuple(cameras), images=tuple(images), source=file, format=FORMAT,
                    distortions=tuple(distortions), lenses=tuple(lenses))


def _recorded(path: Path, file: Path) -> str:
    """A view's photo as OpenMVG names it: ``root_path`` may be relative to the folder OpenMVG ran in (its
    tutorials' ``-i images/``), which is the file's folder or one or two above it (``matches/``,
    ``reconstruction_sequential/``); the first where the photo is, else the file's folder's."""
    if path.is_absolute():
        return str(path)
    for base in list(file.parents)[:3]:
        if (base / path).is_file():
            return str(base / path)
    return str(file.parent / path)


def _entries(value, file: Path, name: str) -> list[tuple[object, dict]]:
    """``(key, value)`` of a cereal map (a list of ``{key, value}`` objects)."""
    if not isinstance(value, list):
        raise ScanError(file, f"'{name}' is not a list")
    out, keys = [], set()
    for entry in value:
        if not isinstance(entry, dict) or "key" not in entry or not isinstance(entry.get("value"), dict):
            raise ScanError(file, f"an entry of '{name}' is not a {{key, value}} object")
        if str(entry["key"]) in keys:  # OpenMVG would keep the first, silently: which one was meant is unknown
            raise ScanError(file, f"key {entry['key']!r} appears twice in '{name}'")
        keys.add(str(entry["key"]))
        out.append((entry["key"], entry["value"]))
    return out


def _pointed(value: dict, file: Path, what: str, pointers: dict[int, dict]) -> dict:
    """The object behind a cereal shared pointer: its ``data`` at its first appearance, else the object an earlier
    one carried under the same ``id``."""
    wrapper = value.get("ptr_wrapper")
    ident = wrapper.get("id") if isinstance(wrapper, dict) else None
    if not isinstance(ident, int):
        raise ScanError(file, f"{what}: no ptr_wrapper with an id")
    if "data" in wrapper:
        if not isinstance(wrapper["data"], dict):
            raise ScanError(file, f"{what}: its data is not an object")
        pointers[ident & ~FIRST] = wrapper["data"]
        return wrapper["data"]
    if ident & ~FIRST not in pointers:
        raise ScanError(file, f"{what}: it points to object {ident}, which no earlier entry holds")
    return pointers[ident & ~FIRST]


def _intrinsic(value: dict, file: Path, types: dict[int, str], pointers: dict[int, dict]):
    """``(type name, data)`` of an intrinsic, or ``"spherical"``; its type named by cereal's polymorphic id."""
    ident = value.get("polymorphic_id")
    if not isinstance(ident, int):
        raise ScanError(file, "an intrinsic has no polymorphic_id")
    if ident & FIRST:
        if not value.get("polymorphic_name"):
            raise ScanError(file, f"an intrinsic's type {ident} has no polymorphic_name")
        types[ident & ~FIRST] = str(value["polymorphic_name"])
    kind = types.get(ident & ~FIRST)
    if kind is None:
        raise ScanError(file, f"an intrinsic's type {ident} is named by no earlier intrinsic")
    data = _pointed(value, file, f"intrinsic of type {kind!r}", pointers)
    if kind == "spherical":
        return kind
    if kind not in MODELS:
        raise ScanError(file, f"camera model {kind!r} is not supported (scantex reads {', '.join(MODELS)} and skips "
                              "spherical cameras)")
    return kind, data


def _numbers(value, n: int, file: Path, what: str) -> np.ndarray:
    try:
        values = np.array(value if isinstance(value, list) else [value], np.float64).ravel()
    except (TypeError, ValueError):
        raise ScanError(file, f"{what} is not numbers ({str(value)[:40]})") from None
    if values.size != n or not np.isfinite(values).all():
        raise ScanError(file, f"{what} is not {n} finite number{'s' if n > 1 else ''} ({str(value)[:40]})")
    return values


def _camera_model(kind: str, data: dict, file: Path, what: str):
    """``(K, (width, height), distortion)`` of an intrinsic's data."""
    w, h = (_numbers(data.get(k), 1, file, f"{what}: {k}")[0] for k in ("width", "height"))
    f = _numbers(data.get("focal_length"), 1, file, f"{what}: focal_length")[0]
    cx, cy = _numbers(data.get("principal_point"), 2, file, f"{what}: principal_point")
    K = np.array([[f, 0.0, cx], [0.0, f, cy], [0.0, 0.0, 1.0]])
    w, h = check_intrinsics(K, w, h, file, what)
    key, n = MODELS[kind]
    if key is None:
        return K, (w, h), None
    params = _numbers(data.get(key), n, file, f"{what}: {key}")
    if not params.any() and kind != "fisheye":  # a fisheye of no coefficients is still one (theta = atan r)
        return K, (w, h), None
    if kind == "fisheye":
        distortion = Distortion(kind, tuple(params), projection="equidistant")
    elif kind == "pinhole_brown_t2":
        distortion = Distortion(kind, tuple(params[:3]), (params[3], params[4]))
    else:
        distortion = Distortion(kind, tuple(params))
    return K, (w, h), distortion


def _world_to_camera(pose: dict, file: Path, what: str) -> np.ndarray:
    R = _numbers(pose.get("rotation"), 9, file, f"{what}: rotation").reshape(3, 3)  # rows, as OpenMVG writes them
    C = _numbers(pose.get("center"), 3, file, f"{what}: center")
    return world_to_camera_from(R, C, file, what)


def write_openmvg(photos: PhotoSet, out_dir: str | Path) -> Path:
    """Write ``out_dir/sfm_data.json`` (version 0.3) with the photos copied beside it as ``photo_000.<ext>``; returns
    its path. A photo undistorted when read is written as stored with its lens where OpenMVG's models hold it, else
    undistorted (a PNG).

    Raises:
        ValueError: a camera with two focal lengths or a skew (OpenMVG's have one focal length).
    """
    from scantex.io.atomic import atomic_files
    from scantex.photos.files import write_photo

    photos = photos.as_stored(_holds)
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    views, intrinsics, extrinsics = [], [], []
    type_ids: dict[str, int] = {}
    pointer = iter(range(1, 2 * len(photos) + 1))
    with atomic_files() as files:
        for i, cam in enumerate(photos.cameras):
            if not _square(cam):
                raise ValueError(f"photo {i}: OpenMVG's cameras have one focal length and no skew "
                                 f"(fx {cam.K[0, 0]}, fy {cam.K[1, 1]}, skew {cam.K[0, 1]})")
            image = write_photo(files, photos, i, out_dir / f"photo_{i:03d}")
            views.append({"key": i, "value": {"polymorphic_id": 1 << 30, "ptr_wrapper": {
                "id": FIRST | next(pointer), "data": {
                    "local_path": "", "filename": image.name, "width": cam.width, "height": cam.height,
                    "id_view": i, "id_intrinsic": i, "id_pose": i}}}})
        for i, cam in enumerate(photos.cameras):
            kind, key, params = _model(photos.distortions[i], i)
            first = kind not in type_ids  # cereal names a type at its first object only
            number = type_ids.setdefault(kind, len(type_ids) + 1)
            value = ({"polymorphic_id": FIRST | number, "polymorphic_name": kind} if first
                     else {"polymorphic_id": number})
            data = {"width": cam.width, "height": cam.height, "focal_length": float(cam.K[0, 0]),
                    "principal_point": [float(cam.K[0, 2]), float(cam.K[1, 2])]}
            if key is not None:
                data[key] = [float(p) for p in params]
            value["ptr_wrapper"] = {"id": FIRST | next(pointer), "data": data}
            intrinsics.append({"key": i, "value": value})
            extrinsics.append({"key": i, "value": {"rotation": cam.R.tolist(),
                                                    "center": (-cam.R.T @ cam.t).tolist()}})
        doc = {"sfm_data_version": "0.3", "root_path": str(out_dir.resolve()), "views": views,
               "intrinsics": intrinsics, "extrinsics": extrinsics, "structure": [], "control_points": []}
        files.path(out_dir / "sfm_data.json").write_text(json.dumps(doc, indent=4))
    return out_dir / "sfm_data.json"


def _square(cam: Camera) -> bool:
    return cam.K[0, 1] == 0 and abs(cam.K[0, 0] - cam.K[1, 1]) <= 1e-9 * abs(cam.K[0, 0])


def _model(distortion: Distortion | None, i: int) -> tuple[str, str | None, tuple[float, ...]]:
    """OpenMVG's type, parameters' key and parameters of a distortion (the inverse of :func:`_camera_model`)."""
    if distortion is None or distortion.is_zero:
        return "pinhole", None, ()
    k = tuple(distortion.radial)
    if distortion.projection == "equidistant" and len(k) <= 4 and not any(distortion.tangential):
        return "fisheye", "fisheye", (k + (0.0,) * 4)[:4]
    if distortion.is_fisheye or distortion.radial_denominator or distortion.inverse_radial or len(k) > 3:
        raise ValueError(f"photo {i}: OpenMVG's models cannot hold a {distortion.model} distortion")
    if any(distortion.tangential):
        return "pinhole_brown_t2", "disto_t2", (k + (0.0,) * 3)[:3] + tuple(distortion.tangential)
    return ("pinhole_radial_k1", "disto_k1", k[:1]) if len(k) == 1 else (
        "pinhole_radial_k3", "disto_k3", (k + (0.0,) * 3)[:3])


def _holds(distortion: Distortion, cam: Camera) -> bool:
    return converts(lambda: _model(distortion, 0)) and _square(cam)
