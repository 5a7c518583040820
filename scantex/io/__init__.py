"""Reading and writing scans without moving a vertex.

``load_scan`` reads OBJ (+MTL, several materials) itself, to keep OBJ's separate position/UV indexing,
USD (``.usdz``, ...) with Pixar's library, and everything else (GLB/glTF, PLY, STL, OFF, ...) through
trimesh with ``process=False``.
``save_scan`` writes OBJ+MTL+PNG (or JPEG), GLB or USDZ, atomically.
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from scantex.arrays import unique_rows
from scantex.errors import ScanError
from scantex.io.atomic import atomic_files
from scantex.scan import Scan

if TYPE_CHECKING:
    from scantex.io.images import TextureEncoder

log = logging.getLogger(__name__)

#: extensions read by trimesh, besides OBJ
TRIMESH_FORMATS = (".glb", ".gltf", ".ply", ".stl", ".off", ".dae", ".3mf")
#: USD, read with Pixar's library (the ``usd`` extra)
USD_FORMATS = (".usdz", ".usd", ".usda", ".usdc")
READ_FORMATS = (".obj",) + TRIMESH_FORMATS + USD_FORMATS
WRITE_FORMATS = (".obj", ".glb", ".usdz")


def load_scan(path: str | Path) -> Scan:
    """Read a mesh file into a :class:`Scan`, geometry exactly as stored.

    Raises:
        ScanError: the file is missing, unreadable, of an unsupported format, or not a usable mesh;
            the message names the file and the problem.
    """
    path = Path(path)
    if not path.exists():
        raise ScanError(path, "no such file")
    if path.is_dir():
        raise ScanError(path, "is a folder, not a mesh file")
    suffix = path.suffix.lower()
    if suffix not in READ_FORMATS:
        raise ScanError(path, f"unsupported format '{suffix or path.name}' "
                              f"(scantex reads {', '.join(READ_FORMATS)})")
    if path.stat().st_size == 0:
        raise ScanError(path, "the file is empty")
    if suffix == ".obj":
        from scantex.io.obj import read_obj

        scan = read_obj(path)
    elif suffix in USD_FORMATS:
        from scantex.io.usd import read_usd

        scan = read_usd(path)
    else:
        from scantex.io.trimesh_formats import read_with_trimesh

        scan = read_with_trimesh(path)
    _warn_defects(scan)
    return scan


def _refuse_overwriting_input(scan: Scan, path: Path, encoder: TextureEncoder | None = None) -> None:
    """Raise when writing ``path`` (its textures as ``encoder`` names them) would replace one of the files
    ``scan`` was read from."""
    if scan.source is None:
        return
    src = Path(scan.source).resolve()
    inputs = {src} | {Path(p).resolve() for p in scan.inputs}
    if src.suffix.lower() == ".obj":  # its material library and textures were read too
        inputs.add(src.with_suffix(".mtl"))
        inputs |= {src.parent / m.image_name for m in scan.materials if m.image_name}
    outputs = {path.resolve()}
    if path.suffix.lower() == ".obj":
        from scantex.io.obj import map_names, texture_names

        outputs.add(path.with_suffix(".mtl").resolve())
        outputs |= {path.parent.resolve() / n for n in texture_names(scan, path.stem, encoder) if n}
        outputs |= {path.parent.resolve() / n for names in map_names(scan, path.stem, encoder) for n in names.values()}
    clash = sorted(str(p) for p in inputs & outputs)
    if clash:
        raise ScanError(path, f"refusing to overwrite the input scan ({clash[0]})")


def _warn_defects(scan: Scan) -> None:
    """Count what scanners produce and scantex accepts: degenerate faces, non-manifold edges."""
    f = scan.faces
    repeated = (f[:, 0] == f[:, 1]) | (f[:, 1] == f[:, 2]) | (f[:, 0] == f[:, 2])
    degenerate = int((repeated | (scan.face_areas <= 0)).sum())
    g = f[~repeated]  # a repeated corner would count its own edge twice
    edges = np.sort(np.concatenate([g[:, [0, 1]], g[:, [1, 2]], g[:, [2, 0]]]), axis=1)
    _, counts = unique_rows(edges, return_counts=True)
    non_manifold = int((counts > 2).sum())
    if degenerate or non_manifold:
        log.warning("%s: %d degenerate faces and %d non-manifold edges (kept as they are)",
                    scan.source, degenerate, non_manifold)


def save_scan(scan: Scan, path: str | Path, *, encoder: TextureEncoder | None = None) -> list[Path]:
    """Write ``scan`` to ``path`` (``.obj`` with MTL and textures beside it, ``.glb``, or ``.usdz``).

    All files appear at once (written to temporary names, then renamed); the scan's own source files
    are never overwritten. ``encoder`` (:class:`scantex.io.images.TextureEncoder`) says how colour textures
    are written (default: PNG, lossless; or JPEG); passing the same one to several saves of one scan encodes
    each texture once.

    Returns:
        the files written.
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in WRITE_FORMATS:
        raise ScanError(path, f"cannot write '{suffix}' (scantex writes {', '.join(WRITE_FORMATS)})")
    _refuse_overwriting_input(scan, path, encoder)
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_files() as files:
        if suffix == ".obj":
            from scantex.io.obj import write_obj

            write_obj(scan, path, files, encoder)
        elif suffix == ".usdz":
            from scantex.io.usd import write_usdz

            write_usdz(scan, path, files, encoder)
        else:
            from scantex.io.trimesh_formats import write_glb

            write_glb(scan, path, files, encoder)
    return [final for _, final in files._pending]
