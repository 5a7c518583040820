"""Capture app exports as the app wrote them: a mesh file, a folder or a zip, and what is in it.

:func:`find_capture` takes what a user has after exporting a scan and finds the mesh to enhance and,
when the export holds them, the posed photos (any layout :func:`scantex.photos.detect_format` knows,
:data:`scantex.photos.load.LAYOUTS`: 3D Scanner App "All Data" ``frame_XXXXX.jpg`` + ``.json``, Polycam
``keyframes/``, nerfstudio, COLMAP, ScanNet, RGB-D frame files, ARKitScenes, MVE, Metashape, Meshroom, OpenMVS,
texrecon, ``cameras.json``):

- a **mesh file** (``textured_output.obj``, ``raw.glb``, a ``.gltf`` with its buffers, ...): that mesh;
  photos only when the app wrote its frames next to it (3D Scanner App frames or a Polycam
  ``keyframes/`` folder in the same folder);
- a **folder** (a 3D Scanner App export, an unzipped Polycam export): the mesh the apps name
  (``textured_output.obj``, ``raw.glb``, ...) or else the one mesh file of the most useful format,
  searched down to :data:`MAX_DEPTH` levels; photos in the mesh's folder, the root or one level below;
- a **zip** (Polycam's export, a zipped folder): extracted into a new temporary folder (never next
  to the input), refusing members that would land outside it (zip slip), links, and archives larger
  than ``max_bytes`` unpacked; then as a folder. The extraction is removed by :meth:`Capture.close`
  (use the capture as a context manager: the photos are read from it during the run).

Nothing in the input is changed.
"""

from __future__ import annotations

import logging
import shutil
import stat
import tempfile
import zipfile
from dataclasses import dataclass, field
from pathlib import Path, PurePosixPath

from scantex.errors import ScanError

log = logging.getLogger(__name__)

#: mesh formats in order of preference (textured and exact first)
MESH_SUFFIXES = (".obj", ".glb", ".gltf", ".usdz", ".usdc", ".usda", ".usd", ".ply", ".off", ".stl", ".dae", ".3mf")
#: file names capture apps (and Meshroom's, OpenMVS's and OpenDroneMap's texturing) give their textured mesh, preferred
#: over any other mesh in an export (OpenDroneMap's mesh in its cameras' frame first: an --align'ed project's
#: ``_geo.obj`` was moved out of it)
APP_MESH_NAMES = ("textured_output.obj", "textured_output.glb", "textured_output.usdz", "raw.glb", "mesh.glb",
                  "texturedmesh.obj", "scene_dense_mesh_refine_texture.obj", "scene_dense_mesh_refine_texture.ply",
                  "scene_dense_mesh_texture.obj", "scene_dense_mesh_texture.ply",
                  "odm_textured_model_geo_unaligned.obj", "odm_textured_model_geo.obj", "odm_textured_model.obj",
                  "model.obj", "model.glb", "scene.obj", "export.obj")
#: folders searched below the root for a mesh
MAX_DEPTH = 3
#: folders that hold no mesh worth enhancing (photos, previews, macOS zip metadata)
SKIP_FOLDERS = ("keyframes", "__MACOSX", "images", "depth", "confidence")
#: an archive unpacking to more than this is refused (bytes)
MAX_ZIP_BYTES = 16 << 30
#: ... or holding more members than this
MAX_ZIP_MEMBERS = 200_000


@dataclass
class Capture:
    """What an export holds.

    Attributes:
        source: the path the user gave (file, folder or zip).
        kind: ``"file"``, ``"folder"`` or ``"zip"``.
        mesh: the mesh file to read (inside the extraction for a zip).
        photos: the file or folder to hand to :func:`scantex.photos.load_photos`; ``None`` without photos.
        photo_format: their layout (``"3dscannerapp"``, ``"polycam"``, ...), or ``None``.
        other_meshes: further mesh files the export holds, not used.
        extracted: the temporary folder a zip was unpacked into (removed by :meth:`close`), or ``None``.
    """

    source: Path
    kind: str
    mesh: Path
    photos: Path | None = None
    photo_format: str | None = None
    other_meshes: tuple[Path, ...] = ()
    extracted: Path | None = field(default=None, repr=False)

    def describe(self) -> str:
        """One line: what was found where."""
        root = self.extracted if self.extracted is not None else (
            self.source if self.kind == "folder" else self.source.parent)

        def rel(p: Path) -> str:
            try:
                return str(p.relative_to(root))
            except ValueError:
                return str(p)

        text = f"{self.source}: {self.kind}; mesh {rel(self.mesh)}"
        text += (f"; photos {rel(self.photos)} ({self.photo_format})" if self.photos is not None
                 else "; no posed photos")
        if self.other_meshes:
            text += f"; also holds {', '.join(rel(p) for p in self.other_meshes[:4])}" + (
                f" and {len(self.other_meshes) - 4} more" if len(self.other_meshes) > 4 else "") + " (not used)"
        return text

    def shown(self, path: Path) -> Path:
        """``path`` as the user knows it: a file of a zip's extraction as a path inside the zip
        (``scan.zip/Scan 23/keyframes``), not the temporary folder it was unpacked into; other paths as they are."""
        if self.extracted is None:
            return path
        try:
            return self.source / Path(path).relative_to(self.extracted)
        except ValueError:
            return path

    def close(self) -> None:
        """Remove the zip's extraction, if any."""
        if self.extracted is not None:
            shutil.rmtree(self.extracted, ignore_errors=True)
            self.extracted = None

    def __enter__(self) -> Capture:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def find_capture(path: str | Path, *, photos: bool = True, max_bytes: int = MAX_ZIP_BYTES,
                 temp_dir: str | Path | None = None) -> Capture:
    """Find the mesh (and, with ``photos``, the posed photos) in a capture app's export.

    Args:
        path: a mesh file, an export folder, or a ``.zip`` of one.
        photos: look for posed photos.
        max_bytes: a zip that unpacks to more is refused.
        temp_dir: where a zip's temporary folder is made (default: the system's).

    Raises:
        ScanError: one line naming the path: missing, an unknown file type, no mesh inside, a zip that is
            broken, too large or holds paths outside itself.
    """
    path = Path(path)
    if not path.exists():
        raise ScanError(path, "no such file or folder")
    if path.is_file() and path.suffix.lower() == ".zip":
        extracted = extract_zip(path, max_bytes=max_bytes, temp_dir=temp_dir)
        try:
            capture = _from_folder(extracted, photos, source=path, kind="zip")
        except BaseException:
            shutil.rmtree(extracted, ignore_errors=True)
            raise
        capture.extracted = extracted
    elif path.is_dir():
        capture = _from_folder(path, photos, source=path, kind="folder")
    else:
        # a mesh file (load_scan says what is wrong with anything else)
        capture = Capture(path, "file", path)
        if photos and path.suffix.lower() in MESH_SUFFIXES:
            capture.photos, capture.photo_format = _photos_near(path.parent, app_layouts_only=True)
    log.info("%s", capture.describe())
    return capture


def _from_folder(root: Path, photos: bool, *, source: Path, kind: str) -> Capture:
    meshes = _meshes(root)
    if not meshes:
        raise ScanError(source, f"no mesh file found in it (looked for {', '.join(MESH_SUFFIXES)} "
                                f"down to {MAX_DEPTH} folders deep)")
    mesh = meshes[0]
    capture = Capture(source, kind, mesh, other_meshes=tuple(meshes[1:]))
    if photos:
        capture.photos, capture.photo_format = _photos_near(mesh.parent, root=root)
    return capture


def _meshes(root: Path) -> list[Path]:
    """Mesh files under ``root``, the one to use first: an app's own name, then the shallowest, then by
    format preference, then the largest."""
    found = []

    def walk(folder: Path, depth: int) -> None:
        try:
            entries = sorted(folder.iterdir())
        except OSError:
            return
        for entry in entries:
            if entry.name.startswith(".") or entry.is_symlink():
                continue
            if entry.is_dir():
                if depth < MAX_DEPTH and entry.name not in SKIP_FOLDERS:
                    walk(entry, depth + 1)
            elif entry.suffix.lower() in MESH_SUFFIXES and entry.is_file():
                found.append((entry, depth))

    walk(root, 0)

    def rank(item):
        p, depth = item
        name = p.name.lower()
        app = APP_MESH_NAMES.index(name) if name in APP_MESH_NAMES else len(APP_MESH_NAMES)
        flat = p.parent.name.lower().endswith("_25d")  # OpenDroneMap's 2.5D model, for its orthophoto: the 3D first
        return app, flat, depth, MESH_SUFFIXES.index(p.suffix.lower()), -p.stat().st_size, str(p)

    return [p for p, _ in sorted(found, key=rank)]


def _photos_near(folder: Path, *, root: Path | None = None, app_layouts_only: bool = False):
    """``(path, format)`` of posed photos in ``folder``, else in ``root`` or a folder just below it;
    ``(None, None)`` when there are none. ``app_layouts_only``: only the layouts capture apps write next
    to their mesh (3D Scanner App frames, Polycam keyframes, Meshroom's cache), not a stray ``cameras.json``."""
    from scantex.photos import meshroom, polycam, scannerapp
    from scantex.photos.load import detect_format

    sfm = meshroom.cache_sfm(folder)  # a mesh in Meshroom's cache: its reconstruction's cameras
    if sfm is not None:
        return sfm, meshroom.FORMAT
    candidates = [folder]
    if root is not None:
        candidates.append(root)
        try:
            candidates += sorted(p for p in root.iterdir() if p.is_dir() and not p.name.startswith(".")
                                 and p.name != "__MACOSX")
        except OSError:
            pass
    seen = set()
    for candidate in candidates:
        if candidate in seen:
            continue
        seen.add(candidate)
        if app_layouts_only:
            keyframes = polycam.keyframes_folder(candidate)
            if keyframes is not None:
                return keyframes, polycam.FORMAT
            if scannerapp.frame_files(candidate):
                return candidate, scannerapp.FORMAT
            continue
        try:
            fmt, target = detect_format(candidate)
        except ScanError:
            continue
        return target, fmt
    return None, None


def extract_zip(path: str | Path, *, max_bytes: int = MAX_ZIP_BYTES, temp_dir: str | Path | None = None) -> Path:
    """Unpack ``path`` into a new temporary folder and return it (the caller removes it).

    Refused with a :class:`ScanError` (and nothing left behind): a file that is not a zip or is
    corrupt, a member whose name is absolute or climbs out with ``..`` (zip slip), a link, more than
    :data:`MAX_ZIP_MEMBERS` members, more than ``max_bytes`` unpacked (counted while writing, so a
    header that understates a member's size does not get past it), or not enough free disk space.
    """
    path = Path(path)
    try:
        archive = zipfile.ZipFile(path)
    except (zipfile.BadZipFile, OSError) as error:
        raise ScanError(path, f"not a readable zip file ({error})") from None
    with archive:
        members = archive.infolist()
        if len(members) > MAX_ZIP_MEMBERS:
            raise ScanError(path, f"holds {len(members):,} files, more than the {MAX_ZIP_MEMBERS:,} scantex unpacks")
        declared = sum(m.file_size for m in members)
        if declared > max_bytes:
            raise ScanError(path, f"unpacks to {declared / 2**30:.1f} GiB, more than the "
                                  f"{max_bytes / 2**30:.1f} GiB allowed")
        for m in members:
            _check_member(path, m)
        target = Path(tempfile.mkdtemp(prefix="scantex-capture-", dir=temp_dir))
        try:
            free = shutil.disk_usage(target).free
            if declared > free:
                raise ScanError(path, f"unpacks to {declared / 2**30:.1f} GiB, and {target.parent} has "
                                      f"{free / 2**30:.1f} GiB free")
            written = 0
            for m in members:
                name = PurePosixPath(m.filename.replace("\\", "/"))
                out = target.joinpath(*name.parts)
                if m.is_dir():
                    out.mkdir(parents=True, exist_ok=True)
                    continue
                out.parent.mkdir(parents=True, exist_ok=True)
                with archive.open(m) as src, open(out, "wb") as dst:
                    while chunk := src.read(1 << 20):
                        written += len(chunk)
                        if written > max_bytes:
                            raise ScanError(path, f"unpacks to more than the {max_bytes / 2**30:.1f} GiB allowed")
                        dst.write(chunk)
        except ScanError:
            shutil.rmtree(target, ignore_errors=True)
            raise
        except (zipfile.BadZipFile, OSError, EOFError, RuntimeError, ValueError) as error:
            # corrupt data (CRC), encrypted members, a full disk
            shutil.rmtree(target, ignore_errors=True)
            raise ScanError(path, f"cannot unpack: {error}") from None
        except BaseException:
            shutil.rmtree(target, ignore_errors=True)
            raise
    return target


def _check_member(path: Path, member: zipfile.ZipInfo) -> None:
    name = member.filename.replace("\\", "/")
    parts = PurePosixPath(name).parts
    if name.startswith("/") or (parts and parts[0].endswith(":")) or ".." in parts or not parts:
        raise ScanError(path, f"member '{member.filename}' would be written outside the folder it is "
                              "unpacked into (refused)")
    mode = member.external_attr >> 16
    if stat.S_ISLNK(mode):
        raise ScanError(path, f"member '{member.filename}' is a symbolic link (refused)")
