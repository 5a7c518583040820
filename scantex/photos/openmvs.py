"""OpenMVS's scene: the ``scene.mvs`` that ``openMVG_main_openMVG2openMVS`` (or ``InterfaceCOLMAP``, ...) writes and
OpenMVS's ``DensifyPointCloud``, ``ReconstructMesh``, ``RefineMesh`` and ``TextureMesh`` read.

Its meshes (``scene_dense_mesh_refine.ply``) are in the scene's frame. Conventions (OpenMVS's ``libs/MVS/Interface.h``,
its stream versions 0 to 7), and what scantex does with them:

- Little-endian binary: ``"MVSI"``, a ``uint32`` version and 4 reserved bytes (a file of version 0 has no header);
  then, in order, the platforms and the images (the points, lines and the rest that follow are not read). Strings
  are a ``uint64`` length and the bytes; arrays a ``uint64`` count and the items; matrices ``float64``, row by row.
- A platform: its name, its cameras (each: name, a band name from version 4, ``uint32`` width and height from
  version 1, ``K``, and ``R``, ``C``: the camera's rotation and position on the platform) and its poses (``R``:
  world to platform, ``C``: its position in the world). An image's camera: ``R = R_camera R_pose``, centre
  ``R_pose^T C_camera + C_pose``, OpenCV's axes.
- ``K``'s integer coordinates are pixel centres (scantex's convention). A camera without a resolution has ``K``
  normalised by the larger side of its images (the principal point as well, so below 3): scaled by that side; one
  with a resolution other than its image's is scaled as OpenMVS's ``ScaleK`` does (pixel centres kept).
- An image: its file name (relative to the scene's folder), a mask name from version 5, its platform, camera and
  pose (``0xFFFFFFFF``: not placed: skipped, with a count), an ID from version 3, depths and view scores from
  version 7. OpenMVS's photos are undistorted (OpenMVG exports them so); there is no distortion to read.
"""

from __future__ import annotations

import logging
import struct
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from scantex.errors import ScanError
from scantex.photos.conventions import MAX_DISTORTION_PX, check_intrinsics, world_to_camera_from
from scantex.photos.files import check_sizes, located
from scantex.photos.photoset import PhotoSet, image_size
from scantex.views.camera import Camera

log = logging.getLogger(__name__)

FORMAT = "openmvs"
MAGIC = b"MVSI"
#: the newest stream version whose layout scantex knows (OpenMVS 2.3's)
NEWEST = 7
NO_ID = 0xFFFFFFFF
#: a file's arrays and strings longer than this are taken for a corrupt file
MAX_COUNT = 10_000_000


@dataclass(frozen=True)
class _Camera:
    width: int
    height: int
    K: np.ndarray
    R: np.ndarray
    C: np.ndarray


class _Reader:
    """Reads a scene stream, a ScanError naming the file where it ends early or holds nonsense."""

    def __init__(self, data: bytes, path: Path):
        self.data, self.path, self.at = data, path, 0

    def take(self, n: int) -> bytes:
        if self.at + n > len(self.data):
            raise ScanError(self.path, f"not an OpenMVS scene scantex can read: it ends at byte {len(self.data)}, "
                                       f"inside what it holds (a truncated or other file)")
        out = self.data[self.at:self.at + n]
        self.at += n
        return out

    def u32(self) -> int:
        return struct.unpack("<I", self.take(4))[0]

    def count(self) -> int:
        n = struct.unpack("<Q", self.take(8))[0]
        if n > MAX_COUNT:
            raise ScanError(self.path, f"not an OpenMVS scene scantex can read: a count of {n:,} (a corrupt file)")
        return n

    def string(self) -> str:
        return self.take(self.count()).decode("utf-8", errors="replace")

    def doubles(self, n: int) -> np.ndarray:
        return np.frombuffer(self.take(8 * n), "<f8").astype(np.float64)


def scene_file(folder: Path) -> Path | None:
    """The OpenMVS scene in ``folder``: ``scene.mvs``, else the first ``.mvs`` by name (OpenMVS takes a ``.mvs``
    without a header for a stream of version 0); ``None`` if none."""
    try:
        scenes = sorted(p for p in folder.glob("*.mvs") if p.is_file())
    except OSError:
        return None
    return next((p for p in scenes if p.name == "scene.mvs"), scenes[0] if scenes else None)


def load_openmvs(path: str | Path, *, image_dir: str | Path | None = None,
                 max_distortion_px: float = MAX_DISTORTION_PX) -> PhotoSet:
    """Read an OpenMVS scene (the ``.mvs`` file or a folder holding one); conventions in the module docstring.
    ``image_dir``: the folder its image names are relative to (default: the scene's). ``max_distortion_px`` is
    accepted for symmetry: OpenMVS's photos are undistorted.

    Raises:
        ScanError: not a scene, a stream newer than scantex knows, no placed image, a photo not found.
    """
    path = Path(path)
    file = located(path, scene_file, "no OpenMVS scene (.mvs) in it")
    try:
        data = file.read_bytes()
    except OSError as e:
        raise ScanError(file, f"cannot read it ({e.strerror})") from None
    reader = _Reader(data, file)
    version = 0
    if data[:4] == MAGIC:
        reader.take(4)
        version = reader.u32()
        reader.take(4)
        if version > NEWEST:
            raise ScanError(file, f"an OpenMVS scene of stream version {version}, newer than scantex reads "
                                  f"({NEWEST})")
    platforms = [_platform(reader, version) for _ in range(reader.count())]
    root = Path(image_dir) if image_dir is not None else file.parent
    cameras, images = [], []
    unplaced = 0
    for i in range(reader.count()):
        name = reader.string()
        if version > 4:
            reader.string()  # the mask's name
        platform_id, camera_id, pose_id = reader.u32(), reader.u32(), reader.u32()
        if version > 2:
            reader.u32()  # the image's global ID
        if version > 6:
            reader.take(12)  # min, average and max depth
            reader.take(24 * reader.count())  # view scores: 2 uint32 and 4 float32 each
        what = f"image {i} ({name})"
        if pose_id == NO_ID:
            unplaced += 1
            continue
        try:
            platform_cameras, poses = platforms[platform_id]
            cam, (R_pose, C_pose) = platform_cameras[camera_id], poses[pose_id]
        except IndexError:
            raise ScanError(file, f"{what}: its platform {platform_id}, camera {camera_id} or pose {pose_id} is "
                                  "not in the scene") from None
        image = root / name.replace("\\", "/")
        if not image.is_file():
            raise ScanError(file, f"{what}: {image} does not exist (its photos' folder: --images DIR)")
        width, height = image_size(image)
        K = _full_K(cam, width, height)
        check_intrinsics(K, width, height, file, what)
        w2c = world_to_camera_from(cam.R @ R_pose, R_pose.T @ cam.C + C_pose, file, what)
        if not np.isfinite(w2c).all():
            raise ScanError(file, f"{what}: its pose is not finite")
        cameras.append(Camera(K, w2c, width, height))
        images.append(image)
    if unplaced:
        log.warning("%s: %d of its images are not placed (no pose): skipped", file, unplaced)
    if not cameras:
        raise ScanError(file, "none of its images is placed (no pose)" if unplaced else "lists no images")
    check_sizes(cameras, images, file)
    return PhotoSet(cameras=tuple(cameras), images=tuple(images), source=file, format=FORMAT)


def _platform(reader: _Reader, version: int) -> tuple[list[_Camera], list[tuple[np.ndarray, np.ndarray]]]:
    reader.string()  # the platform's name
    cameras = []
    for _ in range(reader.count()):
        reader.string()  # the camera's name
        if version > 3:
            reader.string()  # its band's
        width, height = (reader.u32(), reader.u32()) if version > 0 else (0, 0)
        K, R, C = reader.doubles(9).reshape(3, 3), reader.doubles(9).reshape(3, 3), reader.doubles(3)
        cameras.append(_Camera(width, height, K, R, C))
    poses = [(reader.doubles(9).reshape(3, 3), reader.doubles(3)) for _ in range(reader.count())]
    return cameras, poses


def _full_K(cam: _Camera, width: int, height: int) -> np.ndarray:
    """The camera's K at an image of ``width x height`` (OpenMVS's ``GetFullK`` and ``ScaleK``)."""
    if cam.width == width and cam.height == height:
        return cam.K.copy()
    scale = max(width, height) / (max(cam.width, cam.height) if cam.width > 0 and cam.height > 0 else 1.0)
    K = cam.K.copy()
    normalised = K[0, 2] < 3 and K[1, 2] < 3
    K[0, 0] *= scale
    K[1, 1] *= scale
    K[0, 1] *= scale
    K[0, 2] = K[0, 2] * scale if normalised else (K[0, 2] + 0.5) * scale - 0.5
    K[1, 2] = K[1, 2] * scale if normalised else (K[1, 2] + 0.5) * scale - 0.5
    return K


def write_openmvs(photos: PhotoSet, out_dir: str | Path) -> Path:
    """Write ``out_dir/scene.mvs`` (stream version 3, as OpenMVG's exporter writes: one platform, a camera of
    resolution per distinct K, a pose per photo; no points) with the photos copied to ``out_dir/images/``; returns
    its path. A photo undistorted when read is written undistorted (a PNG); a small distortion ignored when read is
    dropped with a warning (OpenMVS's photos have none)."""
    from scantex.io.atomic import atomic_files
    from scantex.photos.files import write_photo

    photos = photos.as_stored(lambda distortion, camera: False)
    out_dir = Path(out_dir)
    (out_dir / "images").mkdir(parents=True, exist_ok=True)

    def string(s: str) -> bytes:
        raw = s.encode("utf-8")
        return struct.pack("<Q", len(raw)) + raw

    def doubles(values) -> bytes:
        return np.asarray(values, "<f8").tobytes()

    models: dict[tuple, int] = {}
    names = []
    with atomic_files() as files:
        for i, cam in enumerate(photos.cameras):
            if photos.distortions[i] is not None and not photos.distortions[i].is_zero:
                log.warning("photo %d: OpenMVS's cameras hold no lens distortion; it is dropped", i)
            models.setdefault((cam.width, cam.height, cam.K.tobytes()), len(models))
            names.append(write_photo(files, photos, i, out_dir / "images" / f"{i:05d}").relative_to(out_dir))
        stream = bytearray(MAGIC + struct.pack("<II", 3, 0))
        stream += struct.pack("<Q", 1) + string("platform0") + struct.pack("<Q", len(models))
        for (width, height, K), n in models.items():
            stream += string(f"camera{n}") + struct.pack("<II", width, height)
            stream += doubles(np.frombuffer(K)) + doubles(np.eye(3)) + doubles(np.zeros(3))
        stream += struct.pack("<Q", len(photos))
        for cam in photos.cameras:
            stream += doubles(cam.R) + doubles(-cam.R.T @ cam.t)
        stream += struct.pack("<Q", len(photos))
        for i, (cam, name) in enumerate(zip(photos.cameras, names)):
            stream += string(name.as_posix()) + struct.pack("<IIII", 0, models[(cam.width, cam.height,
                                                                                 cam.K.tobytes())], i, i)
        stream += struct.pack("<QQQQQQ", 0, 0, 0, 0, 0, 0)  # points, their normals and colours; lines, theirs
        stream += doubles(np.eye(4))  # the scene's transform (version 2 on)
        files.path(out_dir / "scene.mvs").write_bytes(bytes(stream))
    return out_dir / "scene.mvs"
