"""Reading the importers' files with errors that name the file and the frame."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np

from scantex.errors import ScanError
from scantex.photos.photoset import DEPTH_SCALE_MM, PhotoSet, image_size
from scantex.views.camera import Camera


def resolve_file(base: Path, name: str, where: Path, what: str) -> Path:
    """``name`` relative to ``base`` (absolute names kept); a ScanError when there is no such file."""
    if not name.strip():
        raise ScanError(where, f"{what}: no file named (an empty path)")
    path = Path(name)
    path = path if path.is_absolute() else base / path
    if path.is_dir():
        raise ScanError(where, f"{what}: {path} is a folder, not a file")
    if not path.is_file():
        raise ScanError(where, f"{what}: {path} does not exist")
    return path


def find_photo(recorded: str, file: Path, what: str, image_dir: str | Path | None = None) -> Path:
    """The photo a photogrammetry file names by the path it had where the reconstruction ran (Meshroom's, OpenMVG's):
    there (a relative path from ``file``'s folder, never from the working folder: another capture's photo of that name
    could be there), else by its name in ``image_dir``, beside ``file`` or in an ``images/`` folder there or a folder
    up."""
    named = Path(recorded.replace("\\", "/"))
    named = named if named.is_absolute() else file.parent / named
    try:
        if named.is_file():
            return named
    except OSError:  # a name too long for this system: looked for by its last part below
        pass
    folders = ([Path(image_dir)] if image_dir is not None else []) + [file.parent, file.parent / "images",
                                                                       file.parent.parent / "images"]
    for folder in folders:
        if (folder / named.name).is_file():
            return folder / named.name
    raise ScanError(file, f"{what}: its photo is neither at {recorded} nor in {', '.join(str(f) for f in folders)} "
                          "(name the photos' folder with --images DIR)")


def folder_of(path: Path) -> Path:
    """The folder ``path`` is, or holds it when it is a file (one frame's file names its capture's folder); a
    ScanError when there is none."""
    folder = path.parent if path.is_file() else path
    if not folder.is_dir():
        raise ScanError(path, "no such folder")
    return folder


def located(path: Path, finder: Callable[[Path], Path | None], missing: str) -> Path:
    """``path`` itself, or the file ``finder`` finds in it when it is a folder; a ScanError saying ``missing`` (what
    the folder lacks) when it finds none."""
    file = finder(path) if path.is_dir() else path
    if file is None:
        raise ScanError(path, missing)
    return file


def load_frames_file(path: Path, default_name: str, what: str = "") -> tuple[Path, dict, list]:
    """The file (``default_name`` inside a folder), its JSON document and its non-empty ``frames`` list.

    ``what`` is appended to the error for a document without frames (e.g. ": not a transforms.json").
    """
    path = Path(path)
    if path.is_dir():
        path = path / default_name
    if not path.is_file():
        raise ScanError(path, "no such file")
    doc = load_json(path)
    frames = doc.get("frames") if isinstance(doc, dict) else None
    if not isinstance(frames, list) or not frames:
        raise ScanError(path, f"has no 'frames' list{what}")
    return path, doc, frames


def load_json(path: Path):
    import json

    try:
        return json.loads(path.read_text(encoding="utf-8-sig"))  # -sig: a byte-order mark (Windows' editors) read too
    except json.JSONDecodeError as e:
        raise ScanError(path, f"not valid JSON ({e.msg} at line {e.lineno}, column {e.colno})") from None
    except UnicodeDecodeError:
        raise ScanError(path, "not valid JSON (not UTF-8 text)") from None
    except RecursionError:
        raise ScanError(path, "not a camera file (JSON nested too deeply)") from None
    except OSError as e:
        raise ScanError(path, f"cannot read the file ({e.strerror})") from None


def load_xml(path: Path, max_bytes: int, what: str):
    """The root element of an XML camera file, refused without being parsed when larger than ``max_bytes`` (``what``
    it is, for that error)."""
    import xml.etree.ElementTree as ET

    try:
        size = path.stat().st_size
    except OSError as e:
        raise ScanError(path, f"cannot read it ({e.strerror})") from None
    if size > max_bytes:
        raise ScanError(path, f"is {size / 2**20:.0f} MB, more than {what}")
    try:
        return ET.parse(path).getroot()
    except ET.ParseError as e:
        raise ScanError(path, f"not an XML file scantex can read ({e})") from None
    except OSError as e:
        raise ScanError(path, f"cannot read it ({e.strerror})") from None


def quiet_loadtxt(path: Path, ndmin: int) -> np.ndarray:
    """``numpy.loadtxt`` of floats without its warning on an empty file (the caller says what is wrong, in one
    line)."""
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        return np.loadtxt(path, dtype=np.float64, ndmin=ndmin)


def read_matrix(path: Path, what: str, shapes: Sequence[tuple[int, int]] = ((4, 4),)) -> np.ndarray:
    """A text file of rows of numbers (a pose, a K) as a ``float64`` array of one of ``shapes``; a ScanError
    naming the file otherwise (non-finite numbers are the caller's to judge: a lost frame's pose is -inf)."""
    try:
        m = quiet_loadtxt(path, ndmin=2)
    except (OSError, ValueError) as e:
        raise ScanError(path, f"not a {what}: {e}".rstrip(": ")) from None
    if m.shape not in [tuple(s) for s in shapes]:
        expected = " or ".join(f"{r}x{c}" for r, c in shapes)
        raise ScanError(path, f"not a {what}: {m.shape[0]}x{m.shape[1]} numbers, expected {expected}")
    return m


def world_to_camera_of(pose_file: Path) -> np.ndarray | None:
    """The world-to-camera of a text file holding a 4x4 *camera-to-world* (ScanNet's and the RGB-D frame files'
    poses), checked rigid before it is inverted; ``None`` where the frame's tracking was lost (``-inf`` or ``nan``)."""
    from scantex.photos.conventions import check_pose

    c2w = read_matrix(pose_file, "4x4 camera-to-world pose")
    if not np.isfinite(c2w).all():
        return None
    return np.linalg.inv(check_pose(c2w, pose_file, "pose"))


def check_sizes(cameras: Sequence[Camera], images: Sequence[Path], where: Path) -> None:
    """Every image's header size equals its camera's (a downscaled copy would silently misalign)."""
    for i, (cam, path) in enumerate(zip(cameras, images)):
        w, h = image_size(path)
        if (w, h) != (cam.width, cam.height):
            raise ScanError(where, f"frame {i}: {path.name} is {w}x{h} but its camera is "
                                   f"{cam.width}x{cam.height}")


def need(d: dict, key: str, where: Path, what: str):
    if not isinstance(d, dict) or key not in d:
        raise ScanError(where, f"{what}: missing '{key}'")
    return d[key]


def number(d: dict, key: str, where: Path, what: str, default: float | None = None) -> float:
    """``d[key]`` as a finite float; ``default`` where ``d`` has no ``key`` (without one: a ScanError)."""
    if default is not None and isinstance(d, dict) and key not in d:
        return default
    value = need(d, key, where, what)
    try:
        value = float(value)
    except (TypeError, ValueError):
        raise ScanError(where, f"{what}: '{key}' is not a number ({value!r})") from None
    if not np.isfinite(value):
        raise ScanError(where, f"{what}: '{key}' is not finite")
    return value


def copy_into(files, src: Path, dst: Path) -> None:
    """Copy ``src`` to ``dst`` through an :class:`~scantex.io.atomic.AtomicFiles` group."""
    import shutil

    shutil.copyfile(src, files.path(dst))


def converts(convert: Callable[[], object]) -> bool:
    """Whether a writer's conversion of a lens into its format's terms succeeds (each raises ValueError for a lens its
    format cannot hold): the writers' ``holds`` test of :meth:`PhotoSet.as_stored`."""
    try:
        convert()
    except ValueError:
        return False
    return True


def photo_suffix(photos: PhotoSet, i: int) -> str:
    """The suffix :func:`write_photo` writes photo ``i`` with: its file's, or ``.png`` for an undistorted photo."""
    return photos.images[i].suffix.lower() if photos.lenses[i] is None else ".png"


def write_photo(files, photos: PhotoSet, i: int, stem: Path) -> Path:
    """Photo ``i`` written through an :class:`~scantex.io.atomic.AtomicFiles` group as ``stem`` plus
    :func:`photo_suffix`; returns the path. The file is copied as it is, unless the photo is undistorted when read
    (:attr:`PhotoSet.lenses`, which a writer's :meth:`PhotoSet.as_stored` keeps where its format cannot hold the
    lens): then its pinhole view, as a PNG."""
    dst = stem.with_name(stem.name + photo_suffix(photos, i))
    if photos.lenses[i] is None:
        copy_into(files, photos.images[i], dst)
        return dst
    from PIL import Image

    Image.fromarray(np.ascontiguousarray(photos.load_image(i))).save(files.path(dst), format="PNG")
    return dst


def write_depth(files, photos: PhotoSet, i: int, stem: Path, *, floats: bool) -> Path:
    """Photo ``i``'s depth map written through an :class:`~scantex.io.atomic.AtomicFiles` group as ``stem`` plus a
    suffix; returns the path. The file is copied as it is where a reader takes it so: an integer map in
    millimetres (kept as a ``.png`` only when it is one), or a float map in metres where the format reads ``floats``.
    Any other map (a float map for a format without floats, integers in other units) is written as what every
    format reads: a uint16 PNG of millimetres, 0 where there is no measurement or the depth is beyond 65.535 m. A map
    of a lens of its own (:attr:`PhotoSet.depth_warps`), or of a photo undistorted when read (:attr:`PhotoSet.lenses`),
    is written resampled into its photo's pinhole view, as every format reads a map."""
    src = photos.depths[i]
    stored = photos.stored_depth(i)
    millimetres = stored.dtype.kind in "ui" and photos.depth_scale == DEPTH_SCALE_MM
    as_is = photos.depth_warps[i] is None and photos.lenses[i] is None and ((stored.dtype.kind == "f" and floats) or (
        millimetres and (floats or src.suffix.lower() == ".png")))
    if as_is:
        dst = stem.with_name(stem.name + src.suffix.lower())
        copy_into(files, src, dst)
        return dst
    from PIL import Image

    mm = np.round(photos.load_depth(i).astype(np.float64) * 1000.0)
    mm[~(mm <= np.iinfo(np.uint16).max) | ~(mm > 0)] = 0  # NaN, too far, or rounded to nothing: no measurement
    dst = stem.with_name(stem.name + ".png")
    Image.fromarray(mm.astype(np.uint16)).save(files.path(dst), format="PNG")
    return dst
