"""COLMAP sparse models: ``cameras.txt`` + ``images.txt`` or ``cameras.bin`` + ``images.bin``.

Conventions, and what scantex does with them:

- ``images``: per image ``QW QX QY QZ TX TY TZ``, the *world-to-camera* rotation as a unit quaternion
  (scalar first; normalised on reading) and translation, in OpenCV camera axes (+y down, +z forward):
  scantex's convention already, so ``world_to_camera = [[R(q), t], [0, 1]]`` with no flip.
- ``cameras``: ``MODEL WIDTH HEIGHT PARAMS``. COLMAP's pixel coordinates put the centre of the top-left
  pixel at ``(0.5, 0.5)``: scantex's ``cx = cx - 0.5``, ``cy = cy - 0.5``. Models read: ``PINHOLE``,
  ``SIMPLE_PINHOLE``, and the distorted ``SIMPLE_RADIAL``, ``RADIAL``, ``OPENCV``, ``FULL_OPENCV``,
  and the fisheyes ``OPENCV_FISHEYE``, ``SIMPLE_RADIAL_FISHEYE``, ``RADIAL_FISHEYE`` (equidistant: a polynomial
  in the ray's angle), whose distortion is recorded in :attr:`PhotoSet.distortions` and ignored with a logged
  warning when it moves no pixel by more than ``max_distortion_px`` (1 px), undone above that when a photo is
  read (:mod:`scantex.photos.lens`: as ``colmap image_undistorter`` would, which writes a ``PINHOLE`` model and
  undistorted images). ``FOV`` and the thin-prism models are refused.
- Image names are relative to the image folder, which COLMAP keeps outside the model: scantex looks in
  ``<project>/images`` for a model in ``<project>/sparse/0`` (then ``<model>/../images``,
  ``<model>/images``, the model folder and its parents), or takes ``image_dir``.
- ``points3D`` is not read (the mesh is the geometry). COLMAP models hold no depth maps.
- Binary layout (little-endian): ``cameras.bin``: uint64 count, then per camera int32 id, int32 model
  id, uint64 width, uint64 height, float64 params; ``images.bin``: uint64 count, then per image
  int32 id, float64 qvec[4], float64 tvec[3], int32 camera id, NUL-terminated name, uint64 number of
  2D points, then (float64 x, float64 y, int64 point id) each.
"""

from __future__ import annotations

import logging
import struct
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from scantex.errors import ScanError
from scantex.io.atomic import atomic_files
from scantex.photos.conventions import (
    CORNER_CONVENTION,
    MAX_DISTORTION_PX,
    check_intrinsics,
    intrinsics,
    pinhole_camera,
    principal_point,
)
from scantex.photos.files import check_sizes, converts, photo_suffix, write_photo
from scantex.photos.photoset import Distortion, PhotoSet
from scantex.views.camera import Camera

log = logging.getLogger(__name__)

#: COLMAP's camera models: id -> (name, number of parameters); see colmap/src/colmap/sensor/models.h
MODELS = {0: ("SIMPLE_PINHOLE", 3), 1: ("PINHOLE", 4), 2: ("SIMPLE_RADIAL", 4), 3: ("RADIAL", 5),
          4: ("OPENCV", 8), 5: ("OPENCV_FISHEYE", 8), 6: ("FULL_OPENCV", 12), 7: ("FOV", 5),
          8: ("SIMPLE_RADIAL_FISHEYE", 4), 9: ("RADIAL_FISHEYE", 5), 10: ("THIN_PRISM_FISHEYE", 12),
          11: ("RAD_TAN_THIN_PRISM_FISHEYE", 16)}
MODEL_IDS = {name: (i, n) for i, (name, n) in MODELS.items()}
SUPPORTED = ("SIMPLE_PINHOLE", "PINHOLE", "SIMPLE_RADIAL", "RADIAL", "OPENCV", "FULL_OPENCV", "OPENCV_FISHEYE",
             "SIMPLE_RADIAL_FISHEYE", "RADIAL_FISHEYE")


@dataclass(frozen=True)
class _CameraModel:
    model: str
    width: int
    height: int
    params: tuple[float, ...]


@dataclass(frozen=True)
class _Image:
    qvec: tuple[float, float, float, float]
    tvec: tuple[float, float, float]
    camera_id: int
    name: str


def find_model(folder: Path) -> Path | None:
    """The folder holding a COLMAP model in or under ``folder`` (itself, ``sparse/0``, ``sparse``,
    ``colmap/sparse/0``), or ``None``."""
    for candidate in (folder, folder / "sparse" / "0", folder / "sparse", folder / "colmap" / "sparse" / "0"):
        for ext in (".bin", ".txt"):
            if (candidate / f"cameras{ext}").is_file() and (candidate / f"images{ext}").is_file():
                return candidate
    return None


def load_colmap(path: str | Path, *, image_dir: str | Path | None = None, binary: bool | None = None,
                max_distortion_px: float = MAX_DISTORTION_PX) -> PhotoSet:
    """Read a COLMAP sparse model; conventions in the module docstring.

    Args:
        path: the model folder (or a project folder with ``sparse/0``), or one of its files.
        image_dir: the folder the image names are relative to (found when ``None``).
        binary: read the ``.bin`` (True) or ``.txt`` (False) files; ``None``: the binary ones when both
            exist, or the kind of the file ``path`` names.
        max_distortion_px: the largest lens distortion ignored, in pixels.

    Raises:
        ScanError: missing or malformed files, missing images, an unsupported camera model or too
            strong a distortion.
    """
    path = Path(path)
    if path.is_file():
        if binary is None:
            binary = path.suffix == ".bin"
        path = path.parent
    if not path.exists():
        raise ScanError(path, "no such file or folder")
    model_dir = find_model(path)
    if model_dir is None:
        raise ScanError(path, "no COLMAP model here (cameras.txt/.bin and images.txt/.bin)")
    if binary is None:
        binary = (model_dir / "cameras.bin").is_file() and (model_dir / "images.bin").is_file()
    ext = ".bin" if binary else ".txt"
    cameras_file, images_file = model_dir / f"cameras{ext}", model_dir / f"images{ext}"
    if binary:
        models, frames = _read_cameras_bin(cameras_file), _read_images_bin(images_file)
    else:
        models, frames = _read_cameras_txt(cameras_file), _read_images_txt(images_file)
    if not frames:
        raise ScanError(images_file, "lists no images")
    root = _image_root(model_dir, frames[0].name, image_dir, images_file)

    from scipy.spatial.transform import Rotation

    cameras, images, distortions, lenses = [], [], [], []
    for image in frames:
        what = f"image {image.name!r}"
        if image.camera_id not in models:
            raise ScanError(images_file, f"{what} refers to camera {image.camera_id}, which "
                                         f"{cameras_file.name} does not define")
        model = models[image.camera_id]
        K, distortion = _intrinsics(model, cameras_file, what)
        check_intrinsics(K, model.width, model.height, cameras_file, what)
        q = np.asarray(image.qvec, dtype=np.float64)
        t = np.asarray(image.tvec, dtype=np.float64)
        if not (np.isfinite(q).all() and np.isfinite(t).all()):
            raise ScanError(images_file, f"{what}: pose has non-finite values")
        if np.linalg.norm(q) < 1e-6:
            raise ScanError(images_file, f"{what}: rotation quaternion is zero")
        w2c = np.eye(4)
        w2c[:3, :3] = Rotation.from_quat([q[1], q[2], q[3], q[0]]).as_matrix()  # scipy: scalar last
        w2c[:3, 3] = t
        camera, lens = pinhole_camera(distortion, Camera(K, w2c, model.width, model.height), max_distortion_px,
                                      cameras_file, what)
        distortions.append(distortion)
        lenses.append(lens)
        cameras.append(camera)
        file = root / image.name
        if not file.is_file():
            raise ScanError(images_file, f"{what}: {file} does not exist")
        images.append(file)
    check_sizes(cameras, images, images_file)
    return PhotoSet(cameras=tuple(cameras), images=tuple(images), source=model_dir,
                    format="colmap-binary" if binary else "colmap-text", distortions=tuple(distortions),
                    lenses=tuple(lenses))


def _intrinsics(model: _CameraModel, where: Path, what: str) -> tuple[np.ndarray, Distortion | None]:
    p = model.params
    name = model.model
    if name not in SUPPORTED:
        raise ScanError(where, f"{what}: camera model {name} is not supported (scantex reads "
                               f"{', '.join(SUPPORTED)}; undistort the photos with `colmap image_undistorter`)")
    if not np.isfinite(p).all():
        raise ScanError(where, f"{what}: camera parameters are not finite")
    if name in ("SIMPLE_PINHOLE", "SIMPLE_RADIAL", "RADIAL", "SIMPLE_RADIAL_FISHEYE", "RADIAL_FISHEYE"):
        fx = fy = p[0]
        cx, cy = p[1], p[2]
        rest = p[3:]
    else:
        fx, fy, cx, cy = p[:4]
        rest = p[4:]
    distortion = {
        "SIMPLE_PINHOLE": lambda: None,
        "PINHOLE": lambda: None,
        "SIMPLE_RADIAL": lambda: Distortion(name, (rest[0],)),
        "RADIAL": lambda: Distortion(name, (rest[0], rest[1])),
        "OPENCV": lambda: Distortion(name, (rest[0], rest[1]), (rest[2], rest[3])),
        "FULL_OPENCV": lambda: Distortion(name, (rest[0], rest[1], rest[4]), (rest[2], rest[3]),
                                          (rest[5], rest[6], rest[7])),
        "OPENCV_FISHEYE": lambda: Distortion(name, tuple(rest[:4]), projection="equidistant"),
        "SIMPLE_RADIAL_FISHEYE": lambda: Distortion(name, (rest[0],), projection="equidistant"),
        "RADIAL_FISHEYE": lambda: Distortion(name, (rest[0], rest[1]), projection="equidistant"),
    }[name]()
    return intrinsics(fx, fy, cx, cy, pixel_centre=CORNER_CONVENTION), distortion


def _image_root(model_dir: Path, first: str, image_dir, where: Path) -> Path:
    if image_dir is not None:
        return Path(image_dir)
    candidates = [model_dir.parent.parent / "images", model_dir.parent / "images", model_dir / "images",
                  model_dir, model_dir.parent, model_dir.parent.parent]
    for folder in candidates:
        if (folder / first).is_file():
            return folder
    raise ScanError(where, f"image {first!r} not found in {candidates[0]} nor next to the model (name the "
                           "images' folder with --images DIR)")


# ---- text ---------------------------------------------------------------------------------------

def _text_lines(path: Path) -> list[str]:
    if not path.is_file():
        raise ScanError(path, "no such file")
    try:
        return path.read_text(encoding="utf-8").splitlines()
    except UnicodeDecodeError:
        raise ScanError(path, "not a COLMAP text file (not UTF-8 text)") from None


def _read_cameras_txt(path: Path) -> dict[int, _CameraModel]:
    models = {}
    for n, line in enumerate(_text_lines(path), start=1):
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        fields = line.split()
        try:
            camera_id, name, width, height = int(fields[0]), fields[1], int(fields[2]), int(fields[3])
            params = tuple(float(v) for v in fields[4:])
        except (IndexError, ValueError):
            raise ScanError(path, f"line {n}: expected 'CAMERA_ID MODEL WIDTH HEIGHT PARAMS...', got "
                                  f"{line[:60]!r}") from None
        _check_params(path, f"line {n}", name, params)
        models[camera_id] = _CameraModel(name, width, height, params)
    return models


def _check_params(path: Path, what: str, name: str, params) -> None:
    if name not in MODEL_IDS:
        raise ScanError(path, f"{what}: unknown camera model {name!r}")
    if len(params) != MODEL_IDS[name][1]:
        raise ScanError(path, f"{what}: {name} takes {MODEL_IDS[name][1]} parameters, got {len(params)}")


def _read_images_txt(path: Path) -> list[_Image]:
    lines = _text_lines(path)
    images = []
    n = 0
    while n < len(lines):
        line = lines[n].strip()
        n += 1
        if not line or line.startswith("#"):
            continue
        fields = line.split(maxsplit=9)
        try:
            qvec = tuple(float(v) for v in fields[1:5])
            tvec = tuple(float(v) for v in fields[5:8])
            camera_id, name = int(fields[8]), fields[9]
            int(fields[0])
        except (IndexError, ValueError):
            raise ScanError(path, f"line {n}: expected 'IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME', "
                                  f"got {line[:60]!r}") from None
        images.append(_Image(qvec, tvec, camera_id, name))
        n += 1  # the next line lists the image's 2D points (possibly empty): not needed
    return images


def write_colmap_text(photos: PhotoSet, out_dir: str | Path) -> Path:
    """Write ``out_dir/sparse/0/{cameras,images,points3D}.txt`` and copy the photos to ``out_dir/images``
    (named ``frame_00001.<ext>``...); identical intrinsics share a camera. Returns the model folder.

    Raises:
        ValueError: a camera has skew, or a small distortion ignored when read that COLMAP's models cannot hold (a
            photo undistorted when read is written as stored with its lens where they hold it, else undistorted, as
            a PNG).
    """
    photos = photos.as_stored(_holds)  # an undistorted photo as stored with its lens, where a model holds it
    out_dir = Path(out_dir)
    model_dir = out_dir / "sparse" / "0"
    model_dir.mkdir(parents=True, exist_ok=True)
    (out_dir / "images").mkdir(exist_ok=True)
    models, frames = _to_colmap(photos)
    cam_lines = ["# Camera list with one line of data per camera:",
                 "#   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]", f"# Number of cameras: {len(models)}"]
    for cid, m in models.items():
        cam_lines.append(" ".join([str(cid), m.model, str(m.width), str(m.height)]
                                  + [repr(float(v)) for v in m.params]))
    img_lines = ["# Image list with two lines of data per image:",
                 "#   IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME",
                 "#   POINTS2D[] as (X, Y, POINT3D_ID)", f"# Number of images: {len(frames)}"]
    for iid, f in enumerate(frames, start=1):
        img_lines.append(" ".join([str(iid)] + [repr(float(v)) for v in f.qvec + f.tvec]
                                  + [str(f.camera_id), f.name]))
        img_lines.append("")
    with atomic_files() as files:
        for i, f in enumerate(frames):
            write_photo(files, photos, i, out_dir / "images" / Path(f.name).stem)
        files.path(model_dir / "cameras.txt").write_text("\n".join(cam_lines) + "\n")
        files.path(model_dir / "images.txt").write_text("\n".join(img_lines) + "\n")
        files.path(model_dir / "points3D.txt").write_text(
            "# 3D point list with one line of data per point:\n"
            "#   POINT3D_ID, X, Y, Z, R, G, B, ERROR, TRACK[] as (IMAGE_ID, POINT2D_IDX)\n")
    return model_dir


# ---- binary -------------------------------------------------------------------------------------

class _Reader:
    """Little-endian struct reads that fail with a ScanError naming the file."""

    def __init__(self, path: Path):
        if not path.is_file():
            raise ScanError(path, "no such file")
        self.path = path
        self.data = path.read_bytes()
        self.pos = 0

    def read(self, fmt: str):
        size = struct.calcsize(fmt)
        if self.pos + size > len(self.data):
            raise ScanError(self.path, f"truncated COLMAP binary file (needs {size} bytes at offset "
                                       f"{self.pos}, the file has {len(self.data)})")
        values = struct.unpack_from(fmt, self.data, self.pos)
        self.pos += size
        return values

    def skip(self, n: int) -> None:
        if self.pos + n > len(self.data):
            raise ScanError(self.path, f"truncated COLMAP binary file ({len(self.data)} bytes)")
        self.pos += n

    def name(self) -> str:
        end = self.data.find(b"\x00", self.pos)
        if end < 0:
            raise ScanError(self.path, "truncated COLMAP binary file (an image name has no end)")
        raw, self.pos = self.data[self.pos:end], end + 1
        try:
            return raw.decode("utf-8")
        except UnicodeDecodeError:
            raise ScanError(self.path, f"malformed COLMAP binary file (image name {raw[:40]!r})") from None

    def count(self, item_bytes: int) -> int:
        (n,) = self.read("<Q")
        if n * item_bytes > len(self.data) - self.pos:
            raise ScanError(self.path, f"malformed COLMAP binary file (claims {n} entries, the file is "
                                       f"{len(self.data)} bytes)")
        return n

    def finish(self) -> None:
        if self.pos != len(self.data):
            raise ScanError(self.path, f"malformed COLMAP binary file ({len(self.data) - self.pos} "
                                       "bytes left over)")


def _read_cameras_bin(path: Path) -> dict[int, _CameraModel]:
    r = _Reader(path)
    models = {}
    for k in range(r.count(24)):
        camera_id, model_id, width, height = r.read("<iiQQ")
        if model_id not in MODELS:
            raise ScanError(path, f"camera {k}: unknown camera model id {model_id}")
        name, n_params = MODELS[model_id]
        models[camera_id] = _CameraModel(name, int(width), int(height), r.read(f"<{n_params}d"))
    r.finish()
    return models


def _read_images_bin(path: Path) -> list[_Image]:
    r = _Reader(path)
    images = []
    for _ in range(r.count(64)):
        values = r.read("<i7di")
        name = r.name()
        (n_points,) = r.read("<Q")
        r.skip(24 * n_points)
        images.append(_Image(tuple(values[1:5]), tuple(values[5:8]), values[8], name))
    r.finish()
    return images


def write_colmap_binary(photos: PhotoSet, out_dir: str | Path) -> Path:
    """Like :func:`write_colmap_text`, in COLMAP's binary format (``cameras.bin``, ``images.bin``,
    ``points3D.bin``). Returns the model folder."""
    photos = photos.as_stored(_holds)  # an undistorted photo as stored with its lens, where a model holds it
    out_dir = Path(out_dir)
    model_dir = out_dir / "sparse" / "0"
    model_dir.mkdir(parents=True, exist_ok=True)
    (out_dir / "images").mkdir(exist_ok=True)
    models, frames = _to_colmap(photos)
    cams = bytearray(struct.pack("<Q", len(models)))
    for cid, m in models.items():
        cams += struct.pack("<iiQQ", cid, MODEL_IDS[m.model][0], m.width, m.height)
        cams += struct.pack(f"<{len(m.params)}d", *m.params)
    imgs = bytearray(struct.pack("<Q", len(frames)))
    for iid, f in enumerate(frames, start=1):
        imgs += struct.pack("<i7di", iid, *f.qvec, *f.tvec, f.camera_id)
        imgs += f.name.encode("utf-8") + b"\x00" + struct.pack("<Q", 0)
    with atomic_files() as files:
        for i, f in enumerate(frames):
            write_photo(files, photos, i, out_dir / "images" / Path(f.name).stem)
        files.path(model_dir / "cameras.bin").write_bytes(bytes(cams))
        files.path(model_dir / "images.bin").write_bytes(bytes(imgs))
        files.path(model_dir / "points3D.bin").write_bytes(struct.pack("<Q", 0))
    return model_dir


# ---- shared by the writers ----------------------------------------------------------------------

def _to_colmap(photos: PhotoSet) -> tuple[dict[int, _CameraModel], list[_Image]]:
    from scipy.spatial.transform import Rotation

    if photos.has_depth:
        log.warning("COLMAP models hold no depth maps: %s's depth maps are not written", photos.source)
    models: dict[int, _CameraModel] = {}
    ids: dict[_CameraModel, int] = {}
    frames = []
    for i, (cam, image, distortion) in enumerate(zip(photos.cameras, photos.images, photos.distortions)):
        if cam.K[0, 1] != 0:
            raise ValueError(f"photo {i}: COLMAP cameras have no skew")
        name, params = _model_params(cam, distortion, i)
        model = _CameraModel(name, cam.width, cam.height, params)
        if model not in ids:
            ids[model] = len(ids) + 1
            models[ids[model]] = model
        x, y, z, w = Rotation.from_matrix(cam.R).as_quat()
        frames.append(_Image((float(w), float(x), float(y), float(z)), tuple(float(v) for v in cam.t),
                             ids[model], f"frame_{i + 1:05d}{photo_suffix(photos, i)}"))
    return models, frames


def _holds(distortion: Distortion, cam: Camera) -> bool:
    """Whether a COLMAP model holds a lens exactly (VisualSfM's inverse model only to first order: no)."""
    return converts(lambda: _model_params(cam, distortion, 0)) and cam.K[0, 1] == 0 and not distortion.inverse_radial


def _model_params(cam: Camera, distortion: Distortion | None, i: int) -> tuple[str, tuple[float, ...]]:
    fx, fy = float(cam.K[0, 0]), float(cam.K[1, 1])
    cx, cy = principal_point(cam.K, pixel_centre=CORNER_CONVENTION)
    if distortion is None or distortion.is_zero:
        return "PINHOLE", (fx, fy, cx, cy)
    if distortion.projection == "equidistant" and len(distortion.radial) <= 4 and not any(distortion.tangential):
        return "OPENCV_FISHEYE", (fx, fy, cx, cy, *(tuple(distortion.radial) + (0.0,) * 4)[:4])
    if distortion.is_fisheye:
        raise ValueError(f"photo {i}: COLMAP's models cannot hold a {distortion.model} distortion")
    k = tuple(distortion.radial) + (0.0,) * 3
    d = tuple(distortion.radial_denominator)
    p1, p2 = distortion.tangential
    if len(distortion.radial) <= 2 and not any(d):
        return "OPENCV", (fx, fy, cx, cy, k[0], k[1], p1, p2)
    if len(distortion.radial) <= 3 and len(d) <= 3:
        d = d + (0.0,) * (3 - len(d))
        return "FULL_OPENCV", (fx, fy, cx, cy, k[0], k[1], p1, p2, k[2], *d)
    raise ValueError(f"photo {i}: COLMAP's models cannot hold a {distortion.model} distortion")
