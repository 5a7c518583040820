"""Wavefront OBJ + MTL, read and written without touching the geometry.

trimesh's OBJ loader merges each (position, UV, normal) index triple into one vertex, so a 77k-vertex
scan comes back with more, re-indexed vertices, and its exporter writes that merged form. scantex's
contract is that positions and triangles come out exactly as they went in, so this module keeps OBJ's
separate ``v``/``vt``/``vn`` index spaces: it parses the few statements that carry geometry and texture
(``v vt vn f usemtl mtllib``) itself and writes them back in the same order, with floats written in
shortest round-trip form (``repr``), so every coordinate survives bit for bit.
"""

from __future__ import annotations

import logging
import os
import re
import warnings
from dataclasses import dataclass
from pathlib import Path, PurePosixPath

import numpy as np

from scantex.errors import ScanError
from scantex.io.images import TextureEncoder, read_image
from scantex.scan import Material, Scan, TextureMap

log = logging.getLogger(__name__)


def _floats(path: Path, rows: list[str], width: int, kind: str, line_of: list[int]) -> np.ndarray:
    """Parse ``rows`` (the text after the keyword) into ``(N, width)`` floats, extra columns dropped."""
    if not rows:
        return np.zeros((0, width))
    try:
        flat = np.array(" ".join(rows).split(), dtype=np.float64)
        if flat.size == len(rows) * width:
            return flat.reshape(-1, width)
    except ValueError:
        pass
    out = np.empty((len(rows), width))
    for i, row in enumerate(rows):  # uneven rows (vertex colours, 3-component vt) or a bad number
        parts = row.split()
        try:
            if len(parts) < width:
                raise ValueError
            out[i] = [float(p) for p in parts[:width]]
        except ValueError:
            raise ScanError(path, f"line {line_of[i]}: cannot read {kind} '{row.strip()[:60]}'") from None
    return out


def _vertex_colors(rows: list[str]) -> np.ndarray | None:
    """``v x y z r g b`` (an extension several scanners write) → ``(V, 4) uint8``, else None."""
    if not rows or len(rows[0].split()) < 6:
        return None
    try:
        rgb = np.array([r.split()[3:6] for r in rows], dtype=np.float64)
    except ValueError:
        return None
    return _colours(rgb)


def _colours(rgb: np.ndarray) -> np.ndarray:
    """Vertex colours ``(V, 3)``, 0-1 or 0-255 → ``(V, 4) uint8``."""
    if rgb.max(initial=0) > 1.0:
        rgb = rgb / 255.0
    rgba = np.concatenate([np.clip(np.rint(rgb * 255), 0, 255), np.full((len(rgb), 1), 255)], axis=1)
    return rgba.astype(np.uint8)


#: MTL texture options and how many arguments each takes (``-o``, ``-s``, ``-t`` take 1 to 3 numbers)
MAP_OPTIONS = {"-blendu": 1, "-blendv": 1, "-boost": 1, "-cc": 1, "-clamp": 1, "-imfchan": 1, "-mm": 2,
               "-texres": 1, "-bm": 1, "-type": 1, "-o": 3, "-s": 3, "-t": 3}


def map_file_name(rest: str) -> str:
    """The file name of a ``map_Kd`` statement's arguments, options before it skipped:
    ``-clamp on -s 1 1 1 -bm 0.5 texture name.png`` -> ``texture name.png`` (names may hold spaces)."""
    rest = rest.strip()
    while rest.startswith("-"):
        option, _, rest = rest.partition(" ")
        rest = rest.lstrip()
        n = MAP_OPTIONS.get(option.lower())
        if n is None:
            break  # not an option scantex knows: take the rest as the name
        variable = option.lower() in ("-o", "-s", "-t")
        for k in range(n):
            arg, _, after = rest.partition(" ")
            if variable and k > 0 and not re.fullmatch(r"[-+]?[\d.]+(?:[eE][-+]?\d+)?", arg):
                break  # -o/-s/-t take one to three numbers
            rest = after.lstrip()
    return rest


def _mtl_numbers(path: Path, line: str, rest: str, lo: int, hi: int) -> list[float]:
    try:
        values = [float(x) for x in rest.split()[:hi]]
    except ValueError:
        values = []
    if len(values) < lo or not np.isfinite(values).all():
        raise ScanError(path, f"cannot read '{line[:60]}' (expected {lo} to {hi} numbers)")
    return values


#: MTL statements of a material's other maps (the PBR extension's; ``map_Bump``/``bump`` are left alone: files
#: hold height maps and normal maps under them alike), by the kind of :attr:`scantex.scan.Material.maps`
MTL_MAPS = {"norm": "normal", "map_ke": "emissive"}
#: the statement each kind is written back as
MTL_STATEMENTS = {"normal": "norm", "emissive": "map_Ke"}


def parse_mtl(path: Path) -> dict[str, dict]:
    """Materials of an MTL file: ``{name: {"diffuse": (r, g, b, a), "map_Kd": Path | None, "maps": {kind:
    Path}}}`` (``maps``: :data:`MTL_MAPS`)."""
    try:
        text = path.read_text(encoding="utf-8-sig", errors="replace")
    except OSError as e:
        raise ScanError(path, f"cannot read material library ({e.strerror})") from None
    materials: dict[str, dict] = {}
    current = None
    for raw in text.splitlines():
        line = raw.strip()
        if not line or line.startswith("#"):
            continue
        key, rest = (line.split(None, 1) + [""])[:2]
        rest = rest.strip()
        if key == "newmtl":
            current = materials.setdefault(rest, {"diffuse": [1.0, 1.0, 1.0, 1.0], "map_Kd": None, "maps": {}})
        elif current is None:
            continue
        elif key == "Kd":
            rgb = _mtl_numbers(path, line, rest, 1, 3)
            current["diffuse"][:3] = rgb if len(rgb) == 3 else [rgb[0]] * 3  # 'Kd r': g = b = r
        elif key == "d":
            current["diffuse"][3] = _mtl_numbers(path, line, rest, 1, 1)[0]
        elif key.lower() == "map_kd":
            name = map_file_name(rest)
            current["map_Kd"] = find_texture(path.parent, name) if name else None
        elif key.lower() in MTL_MAPS:
            name = map_file_name(rest)
            if name:
                current["maps"][MTL_MAPS[key.lower()]] = find_texture(path.parent, name)
    return materials


def find_texture(folder: Path, name: str) -> Path:
    """The file an MTL's texture ``name`` means, relative to the MTL's ``folder``: as written (backslashes as
    separators, quotes around it dropped), else, where that file is not there, the same name in another
    case (an export made on a case-blind iOS, macOS or Windows disk: ``Tex.JPG`` for ``tex.jpg``), else its
    bare file name beside the MTL (an absolute path of the machine that wrote it, ``C:\\Users\\...\\tex.jpg``,
    copied along with the scan). The name as written where none of them is a file (its warning names it)."""
    name = name.strip()
    if len(name) > 1 and name[0] == name[-1] and name[0] in "\"'":
        name = name[1:-1]
    name = name.replace("\\", "/")
    written = folder / name
    if written.is_file():
        return written
    for candidate in (written, folder / PurePosixPath(name).name):
        found = _in_any_case(candidate)
        if found is not None:
            log.info("%s: texture '%s' read from %s", folder, name, found)
            return found
    return written


def _in_any_case(path: Path) -> Path | None:
    """``path`` itself, or the one file of its folder whose name differs from it only in case."""
    if path.is_file():
        return path
    try:
        matches = [e.path for e in os.scandir(path.parent) if e.name.lower() == path.name.lower() and e.is_file()]
    except OSError:
        return None
    return Path(matches[0]) if len(matches) == 1 else None


def mtllib_paths(obj_path: Path, rest: str) -> list[Path]:
    """The files of an ``mtllib`` statement: several names separated by spaces, or one name with spaces
    when a file of that whole name exists."""
    whole = obj_path.parent / rest.strip().replace("\\", "/")
    if whole.is_file() or len(rest.split()) < 2:
        return [whole]
    return [obj_path.parent / name.replace("\\", "/") for name in rest.split()]


@dataclass
class _Parsed:
    """What an OBJ file's ``v vt vn f usemtl mtllib`` statements hold, before it becomes a :class:`Scan`."""

    positions: np.ndarray
    vertex_colors: np.ndarray | None
    uvs: np.ndarray | None
    normals: np.ndarray | None
    corners: tuple  # (F, 3) position, texture coordinate and normal indices of each corner, 0-based, -1: none
    face_mat: np.ndarray  # (F,) the usemtl of each face, -1 before any
    mtllibs: list[str]
    mat_names: list[str]
    n_ngons: int = 0


def read_obj(path: str | Path) -> Scan:
    path = Path(path)
    try:
        data = path.read_bytes()
    except OSError as e:
        raise ScanError(path, f"cannot read file ({e.strerror})") from None
    if b"\x00" in data[:4096]:
        raise ScanError(path, "not a text OBJ file (binary data)")
    parsed = _parse_bulk(data)
    if parsed is None:
        parsed = _parse_lines(path, data)
    corner_v, corner_t, corner_n = parsed.corners
    if not len(corner_v):
        raise ScanError(path, "the mesh has no faces" if len(parsed.positions) else
                        "no vertices or faces: not an OBJ mesh")
    faces = np.asarray(corner_v, dtype=np.int64)
    uvs = parsed.uvs
    face_uvs = np.asarray(corner_t, dtype=np.int64) if uvs is not None else None
    if face_uvs is not None and (face_uvs < 0).any():
        # some faces have no vt: give them a UV (0, 0) of their own so indexing stays uniform
        missing = int((face_uvs < 0).any(axis=1).sum())
        log.warning("%s: %d faces have no texture coordinates", path, missing)
        uvs = np.concatenate([uvs, np.zeros((1, 2))])
        face_uvs = np.where(face_uvs < 0, len(uvs) - 1, face_uvs)
    normals = parsed.normals
    face_normals_idx = np.asarray(corner_n, dtype=np.int64) if normals is not None else None
    if face_normals_idx is not None and (face_normals_idx < 0).any():
        normals, face_normals_idx = None, None  # partial normals are of no use; shading recomputes them

    inputs = [path]
    materials, face_materials = _materials(path, parsed.mtllibs, parsed.mat_names,
                                           np.asarray(parsed.face_mat, dtype=np.int32), inputs)
    if parsed.n_ngons:
        log.info("%s: %d polygons with more than 3 corners were fan-triangulated", path, parsed.n_ngons)
    return Scan(parsed.positions, faces, uvs, face_uvs, face_materials, materials,
                vertex_colors=parsed.vertex_colors, normals=normals, face_normals_idx=face_normals_idx,
                source=path, inputs=tuple(inputs))


def _parse_lines(path: Path, data: bytes) -> _Parsed:
    """Any OBJ, line by line: polygons, relative indices, indented or CR-ended lines, and the errors, each named by
    its line (:func:`_parse_bulk` reads what scanners write, and leaves the rest to this)."""
    text = data.decode("utf-8-sig", errors="replace")  # a byte-order mark (Windows editors') is no text
    v_rows, vt_rows, vn_rows = [], [], []
    v_lines, vt_lines, vn_lines = [], [], []
    corner_v, corner_t, corner_n, face_mat = [], [], [], []
    mtllibs: list[str] = []
    mat_names: list[str] = []
    mat_index: dict[str, int] = {}
    current = -1  # faces before any usemtl use an implicit default material
    face_lines: list[tuple[str, int, int, int, int, int]] = []  # (line, number, material, v, vt, vn so far)
    for lineno, line in enumerate(text.splitlines(), start=1):
        if line[:1] in (" ", "\t"):
            line = line.lstrip()
        head = line[:3]
        if head.startswith("v ") or head.startswith("v\t"):
            v_rows.append(line[2:])
            v_lines.append(lineno)
        elif head == "vt " or head == "vt\t":
            vt_rows.append(line[3:])
            vt_lines.append(lineno)
        elif head == "vn " or head == "vn\t":
            vn_rows.append(line[3:])
            vn_lines.append(lineno)
        elif head.startswith("f ") or head.startswith("f\t"):
            face_lines.append((line, lineno, current, len(v_rows), len(vt_rows), len(vn_rows)))
        elif line.startswith("usemtl") and line[6:7] in (" ", "\t"):
            name = line[6:].strip()
            if name not in mat_index:
                mat_index[name] = len(mat_names)
                mat_names.append(name)
            current = mat_index[name]
        elif line.startswith("mtllib") and line[6:7] in (" ", "\t"):
            mtllibs.append(line[6:].strip())

    fast = _triangles_fast(face_lines)
    if fast is not None:
        corner_v, corner_t, corner_n = fast
        face_mat = [current for _, _, current, *_ in face_lines]
        n_ngons = 0
    else:
        n_ngons = _faces(path, face_lines, corner_v, corner_t, corner_n, face_mat)
    return _Parsed(positions=_floats(path, v_rows, 3, "vertex", v_lines), vertex_colors=_vertex_colors(v_rows),
                   uvs=_floats(path, vt_rows, 2, "texture coordinate", vt_lines) if vt_rows else None,
                   normals=_floats(path, vn_rows, 3, "normal", vn_lines) if vn_rows else None,
                   corners=(corner_v, corner_t, corner_n), face_mat=face_mat, mtllibs=mtllibs,
                   mat_names=mat_names, n_ngons=n_ngons)


#: the bytes the bulk reader reads: a number of a v, vt or vn line; an f line's indices (white space in both)
_NUMBER = b"0123456789+-.eE \t\r\n"
_INDICES = b"0123456789/ \t\r\n"
#: what else ends a line for the line reader (``str.splitlines``): vertical tab, form feed, file, group and record
#: separators, NEL, the line and paragraph separators (UTF-8)
_OTHER_BREAKS = (b"\x0b", b"\x0c", b"\x1c", b"\x1d", b"\x1e", b"\xc2\x85", b"\xe2\x80\xa8", b"\xe2\x80\xa9")
#: line kinds in the bulk reader
_OTHER, _V, _VT, _VN, _F = range(5)
#: lines the bulk reader parses at once: its memory beyond the file's own bytes does not grow with the file
BULK_LINES = 1 << 19


def _spaces(text: np.ndarray) -> np.ndarray:
    """Which bytes of ``text`` are white space (four comparisons: faster than a table lookup per byte)."""
    return (text == 32) | (text == 10) | (text == 9) | (text == 13)


def _starts_of(runs: np.ndarray) -> np.ndarray:
    """Where each run of True in ``runs`` starts."""
    start = np.empty(runs.size, bool)
    start[:1] = runs[:1]
    np.greater(runs[1:], runs[:-1], out=start[1:])
    return np.flatnonzero(start)


def _ramps(lengths: np.ndarray) -> np.ndarray:
    """``0 .. n-1`` for each ``n`` of ``lengths``, one after another."""
    return np.arange(lengths.sum()) - np.repeat(np.cumsum(lengths) - lengths, lengths)


def _per_segment(positions: np.ndarray, ends: np.ndarray) -> np.ndarray:
    """How many of the increasing ``positions`` fall in each segment of consecutive ones ending (exclusive) at
    ``ends`` (increasing, the first starting at 0)."""
    return np.diff(np.searchsorted(positions, ends), prepend=0)


def _parse_bulk(data: bytes) -> _Parsed | None:
    """The OBJ files scanners and apps write, read in bulk by numpy over the file's bytes: each line's kind from
    its first bytes, then each kind's numbers parsed a block of lines at a time (a 2,000,000-face scan: 10 s and
    2.0 GB line by line, 5 s and 0.6 GB so). ``None`` for anything else (polygons, relative or zero indices,
    uneven rows, indented or CR-ended lines, a number that is not plain): :func:`_parse_lines` reads those, and
    says where a file is broken."""
    skipped = 3 if data.startswith(b"\xef\xbb\xbf") else 0  # a byte-order mark (Windows editors'), no text
    buf = np.frombuffer(data, np.uint8)[skipped:]
    size = buf.size
    if size == 0 or data.count(b"\r") != data.count(b"\r\n") or any(b in data for b in _OTHER_BREAKS):
        return None  # lines that end otherwise than in "\n" (str.splitlines' line breaks: the line reader's)
    starts = np.concatenate([[0]] + [np.flatnonzero(buf[i:i + (1 << 26)] == 10) + (i + 1)  # 64 MB at a time
                                     for i in range(0, size, 1 << 26)])
    lengths = np.diff(np.append(starts, size))  # each line with its newline

    def byte(k: int) -> np.ndarray:  # the k-th byte of each line, a newline past its end
        return np.where(k < lengths, buf[np.minimum(starts + k, size - 1)], 10)

    c0, c1, c2 = byte(0), byte(1), byte(2)
    if ((c0 == 32) | (c0 == 9)).any():
        return None  # an indented line
    kind = np.full(len(starts), _OTHER, np.uint8)
    kind[(c0 == ord("v")) & ((c1 == 32) | (c1 == 9))] = _V
    after = (c2 == 32) | (c2 == 9)
    kind[(c0 == ord("v")) & (c1 == ord("t")) & after] = _VT
    kind[(c0 == ord("v")) & (c1 == ord("n")) & after] = _VN
    kind[(c0 == ord("f")) & ((c1 == 32) | (c1 == 9))] = _F

    def blocks(k: int, allowed: bytes):
        """Each block of up to BULK_LINES lines of kind ``k``: ``(lines, text, tokens)``, the lines' indices, the
        bytes from the first to the last with every other line and each line's keyword made white space (files
        write each kind together, or faces in runs between usemtl lines: a copy, and a few lines blanked), and
        the number of tokens (runs of non-space bytes) of each line; ``None`` for a block with a byte not
        ``allowed``."""
        of_kind = np.flatnonzero(kind == k)
        for b0 in range(0, len(of_kind), BULK_LINES):
            lines = of_kind[b0:b0 + BULK_LINES]
            first, last = lines[0], lines[-1]
            text = buf[starts[first]:starts[last] + lengths[last]].copy()
            others = np.flatnonzero(kind[first:last + 1] != k) + first
            if others.size:
                text[np.repeat(starts[others] - starts[first], lengths[others]) + _ramps(lengths[others])] = 32
            for j in range(1 if k in (_V, _F) else 2):
                text[starts[lines] - starts[first] + j] = 32
            if text.tobytes().translate(None, allowed):  # what is left once the allowed bytes are deleted
                yield None
                return
            yield lines, text, _per_segment(_starts_of(~_spaces(text)), starts[lines] + lengths[lines] - starts[first])

    def numbers(k: int, least: int) -> np.ndarray | None:
        """``(n, columns)`` floats of the lines of kind ``k``, all with as many numbers, ``least`` or more."""
        parts = []
        for block in blocks(k, _NUMBER):
            if block is None:
                return None
            _, text, tokens = block
            if tokens.min() < least or tokens.min() != tokens.max() or (parts and tokens[0] != parts[0].shape[1]):
                return None
            try:
                with warnings.catch_warnings():
                    warnings.simplefilter("error")
                    values = np.fromstring(text, dtype=np.float64, sep=" ")
            except (ValueError, DeprecationWarning):
                return None  # "1-2", "e", "..": not a number
            if values.size != tokens.sum():
                return None
            parts.append(values.reshape(len(tokens), -1))
        return np.concatenate(parts) if parts else np.zeros((0, least))

    v, vt, vn = numbers(_V, 3), numbers(_VT, 2), numbers(_VN, 3)
    if v is None or vt is None or vn is None:
        return None
    # each field's elements read before each line, for the faces' indices
    read = {field: np.cumsum(kind == of) for field, of in enumerate((_V, _VT, _VN))}
    corners, pattern = [], None
    for block in blocks(_F, _INDICES):
        got = None if block is None else _bulk_corners(block[1], block[2], pattern)
        if got is None:
            return None
        values, pattern = got
        for field, k in zip(np.flatnonzero(pattern), range(values.shape[2])):
            if (values[:, :, k] > read[field][block[0]][:, None]).any():
                return None  # an index past the elements read so far: line by line says where
        corners.append(values - 1)
    if not corners:
        return None
    values = np.concatenate(corners)
    fields = iter(range(values.shape[2]))
    corners = tuple(values[:, :, next(fields)] if have else np.full(values.shape[:2], -1, np.int64)
                    for have in pattern)
    # the materials and libraries: few lines, read as text
    mtllibs, mat_names, usemtl_line, usemtl_of = [], [], [], []
    for i in np.flatnonzero((kind == _OTHER) & ((c0 == ord("u")) | (c0 == ord("m")))):
        at = skipped + int(starts[i])
        line = data[at:at + int(lengths[i])].decode("utf-8", errors="replace").rstrip("\r\n")
        if line.startswith("usemtl") and line[6:7] in (" ", "\t"):
            name = line[6:].strip()
            if name not in mat_names:
                mat_names.append(name)
            usemtl_line.append(i)
            usemtl_of.append(mat_names.index(name))
        elif line.startswith("mtllib") and line[6:7] in (" ", "\t"):
            mtllibs.append(line[6:].strip())
    last = np.searchsorted(np.asarray(usemtl_line, np.int64), np.flatnonzero(kind == _F)) - 1
    face_mat = np.where(last >= 0, np.asarray(usemtl_of + [-1], np.int64)[last], -1)
    return _Parsed(positions=np.ascontiguousarray(v[:, :3]),
                   vertex_colors=_colours(v[:, 3:6]) if v.shape[1] >= 6 else None,
                   uvs=np.ascontiguousarray(vt[:, :2]) if len(vt) else None,
                   normals=np.ascontiguousarray(vn[:, :3]) if len(vn) else None,
                   corners=corners, face_mat=face_mat, mtllibs=mtllibs, mat_names=mat_names)


def _bulk_corners(text: np.ndarray, tokens: np.ndarray, pattern: list[bool] | None
                  ) -> tuple[np.ndarray, list[bool]] | None:
    """``(values (n, 3, fields), pattern)``: the indices (1-based) of :func:`_parse_bulk`'s block of face lines
    (``text``, ``tokens`` a line), each a triangle whose corners are all written alike (``v``, ``v/t``,
    ``v/t/n``, ``v//n``, with an empty field or not) as ``pattern`` says (which of v, vt, vn they hold; ``None``:
    as the first corner does), every index positive and below ``MAX_INDEX``; ``None`` otherwise."""
    n = len(tokens)
    if tokens.min() != 3 or tokens.max() != 3:
        return None  # polygons, or a face of fewer corners: line by line
    slash = text == ord("/")
    digit = ~(slash | _spaces(text))  # all that is left of the bytes allowed
    # every corner alike: as many slashes, as many numbers, "//" in all or none, no empty first field
    token_at = _starts_of(digit | slash)
    ends = np.append(token_at[1:], text.size)
    slashes = _per_segment(np.flatnonzero(slash), ends)
    numbers = _per_segment(_starts_of(digit), ends)
    doubled = _per_segment(np.flatnonzero(slash[:-1] & slash[1:]), ends)
    if (slashes.min() != slashes.max() or slashes[0] > 2 or numbers.min() != numbers.max() or numbers[0] == 0
            or doubled.min() != doubled.max() or not digit[token_at].all()):
        return None
    first = bytes(text[token_at[0]:ends[0]]).split()[0].decode()
    present = [bool(f) for f in first.split("/")] + [False] * (2 - int(slashes[0]))
    if pattern is not None and present != pattern:
        return None
    values = np.fromstring(np.where(slash, np.uint8(32), text), dtype=np.int64, sep=" ")
    if values.size != 3 * n * sum(present):
        return None
    values = values.reshape(n, 3, sum(present))
    if (values <= 0).any() or (values > MAX_INDEX).any():
        return None  # a zero index (refused), or one past int64 (clipped): line by line says where
    return values, present


def _faces(path: Path, face_lines: list, corner_v: list, corner_t: list, corner_n: list, face_mat: list) -> int:
    """Parse face lines one by one (any polygon, negative indices, missing fields) into the corner lists;
    the number of polygons with more than 3 corners (fan-triangulated) is returned."""
    n_ngons = 0
    for line, lineno, current, nv, nt, nn in face_lines:
        parts = line.split()[1:]
        if len(parts) < 3:
            raise ScanError(path, f"line {lineno}: cannot read face '{line.strip()[:60]}' "
                                  "(fewer than 3 corners: is the file truncated?)")
        try:
            ids = [p.split("/") for p in parts]
            vi = [int(p[0]) for p in ids]
            ti = [int(p[1]) if len(p) > 1 and p[1] else 0 for p in ids]
            ni = [int(p[2]) if len(p) > 2 and p[2] else 0 for p in ids]
        except ValueError:
            raise ScanError(path, f"line {lineno}: cannot read face '{line.strip()[:60]}'") from None
        # OBJ indices are 1-based; negative ones count back from the latest element. BAD marks an
        # index that points before the first element (0, or too negative): refused below
        vi = [i - 1 if i > 0 else nv + i if -nv <= i < 0 else BAD for i in vi]
        ti = [i - 1 if i > 0 else nt + i if -nt <= i < 0 else -1 if i == 0 else BAD for i in ti]
        ni = [i - 1 if i > 0 else nn + i if -nn <= i < 0 else -1 if i == 0 else BAD for i in ni]
        if BAD in vi or BAD in ti or BAD in ni:
            raise ScanError(path, f"line {lineno}: face '{line.strip()[:60]}' has an index of 0 or one "
                                  "before the first element (OBJ indices start at 1)")
        if max(vi + ti + ni) > MAX_INDEX:
            raise ScanError(path, f"line {lineno}: face index too large '{line.strip()[:60]}'")
        if len(parts) > 3:
            n_ngons += 1
        for k in range(1, len(parts) - 1):  # fan triangulation, as trimesh does
            corner_v.append((vi[0], vi[k], vi[k + 1]))
            corner_t.append((ti[0], ti[k], ti[k + 1]))
            corner_n.append((ni[0], ni[k], ni[k + 1]))
            face_mat.append(current)
    return n_ngons


def _triangles_fast(face_lines: list) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """The corner indices ``(v, vt, vn)`` (``(F, 3)`` int64, 0-based, -1 for an absent field) of face lines
    that are all triangles written alike with positive indices in range (what scanners and apps write),
    parsed in bulk; ``None`` when they are not, for :func:`_faces` to read (and refuse) line by line."""
    if not face_lines:
        return None
    joined = " ".join(line[2:] for line, *_ in face_lines)
    tokens = joined.split()
    n = len(face_lines)
    if len(tokens) != 3 * n:
        return None  # polygons, or a line with too few corners
    fields = tokens[0].split("/")
    if len(fields) > 3 or any(t.count("/") != len(fields) - 1 for t in (tokens[0], tokens[-1])):
        return None
    present = [bool(f) for f in fields]
    if not present[0] or joined.count("/") != (len(fields) - 1) * len(tokens):
        return None
    if not _DIGITS_AND_SEPARATORS.fullmatch(joined):
        return None  # a sign, a letter, a decimal point: line by line says which
    # the indices parsed in C (4x faster than numpy converting a list of strings): digits and separators alone,
    # so every number is read, and none of 19 digits or more (past int64's range, which it would not refuse)
    if _LONG_NUMBER.search(joined):
        return None
    values = np.fromstring(joined.replace("/", " "), dtype=np.int64, sep=" ")
    if values.size != 3 * n * sum(present):
        return None  # a field empty in some corners and not in others
    values = values.reshape(n, 3, sum(present))
    if (values <= 0).any():
        return None  # zero indices
    before = face_lines[0][3:]  # the elements read before the first face: where files put all of them
    last = None  # the elements read before each face, built only when an index is past ``before``
    out, k = [], 0
    for field, have in enumerate(present + [False] * (3 - len(present))):
        if not have:
            out.append(np.full((n, 3), -1, np.int64))
            continue
        idx = values[:, :, k]
        if (idx > before[field]).any():
            if last is None:
                last = np.array([[nv, nt, nn] for *_, nv, nt, nn in face_lines], dtype=np.int64)
            if (idx > last[:, field:field + 1]).any():
                return None  # an index past the elements read so far: line by line says where
        out.append(idx - 1)
        k += 1
    return out[0], out[1], out[2]


#: what bulk-parsed face lines may hold: digits, slashes and the white space numpy reads as such (str.split's other
#: white space, a no-break space, would end np.fromstring's reading early)
_DIGITS_AND_SEPARATORS = re.compile(r"[0-9/ \t]*")
#: a number of 19 digits or more: past int64's range, which ``np.fromstring`` would clip to its maximum
_LONG_NUMBER = re.compile(r"[0-9]{19}")


#: index of a face corner that points before the first element (refused once the file is read)
BAD = -(1 << 62)
#: largest index kept (beyond int64 a numpy array cannot hold it; no file has that many elements)
MAX_INDEX = (1 << 62) - 1


def _map_files(files: dict[str, Path], material: str, inputs: list[Path]) -> dict[str, TextureMap]:
    """A material's other maps (:data:`MTL_MAPS`), with their files' own bytes; one a file lost is a warning."""
    from scantex.io.images import open_image

    maps = {}
    for kind, file in files.items():
        if not file.is_file():
            log.warning("%s: %s map named by material '%s' not found: left out", file, kind, material)
            continue
        with open_image(file, f"{kind} map") as im:
            im.load()
            maps[kind] = TextureMap.of(im, file.read_bytes())
        inputs.append(file)
    return maps


def _materials(path: Path, mtllibs: list[str], names: list[str], face_mat: np.ndarray, inputs: list[Path]):
    library: dict[str, dict] = {}
    for lib in mtllibs:
        for lib_path in mtllib_paths(path, lib):
            if not lib_path.is_file():
                raise ScanError(lib_path, f"material library named by {path.name} not found")
            library.update(parse_mtl(lib_path))
            inputs.append(lib_path)
    materials = []
    images: dict[Path, np.ndarray] = {}
    for name in names:
        spec = library.get(name)
        if spec is None:
            if mtllibs:
                log.warning("%s: material '%s' is not defined in %s", path, name, ", ".join(mtllibs))
            materials.append(Material(name, diffuse=(0.7, 0.7, 0.7, 1.0)))
            continue
        image = None
        tex = spec["map_Kd"]
        if tex is not None:
            if not tex.is_file():  # apps' exports lose textures (a partial copy): keep the mesh, say so
                log.warning("%s: texture named by material '%s' not found: the material is read untextured",
                            tex, name)
                materials.append(Material(name, None, tuple(spec["diffuse"])))
                continue
            if tex not in images:
                images[tex] = read_image(tex)
                inputs.append(tex)
            image = images[tex]
        materials.append(Material(name, image, tuple(spec["diffuse"]), image_name=tex.name if tex else None,
                                  maps=_map_files(spec["maps"], name, inputs)))
    if (face_mat < 0).any():
        materials.append(Material("default", diffuse=(0.7, 0.7, 0.7, 1.0)))
        face_mat = np.where(face_mat < 0, len(materials) - 1, face_mat)
    if not materials:
        materials = [Material("default", diffuse=(0.7, 0.7, 0.7, 1.0))]
    return tuple(materials), face_mat


# -- writing ------------------------------------------------------------------------------------


def _rows(prefix: str, values: np.ndarray) -> str:
    # repr() (%r) is the shortest string that reads back to the same float64: coordinates round-trip exactly;
    # one format over all rows runs in C (twice as fast as joining each row's reprs)
    rows, width = values.shape
    return (prefix + " ".join(["%r"] * width) + "\n") * rows % tuple(values.ravel().tolist())


def texture_names(scan: Scan, stem: str, encoder: TextureEncoder | None = None) -> list[str | None]:
    """File name of each material's texture: ``stem_material.png``, or where it has a name of its own,
    that name after ``stem_`` (kept as it is when it starts with ``stem``).

    ``stem`` keeps two meshes saved in one folder from sharing (and overwriting) a texture, and a copy saved
    beside its input from being refused for the input's texture name. Names are made unique and end in
    ``.png`` (lossless), or ``.jpg`` where ``encoder`` writes the image as a JPEG.
    """
    encoder = encoder or TextureEncoder()
    names, used = [], set()
    for m in scan.materials:
        if m.image is None:
            names.append(None)
            continue
        own = Path(m.image_name).stem if m.image_name else None
        base = own if own and own.startswith(stem) else f"{stem}_{own or m.name}"
        base = re.sub(r"[^\w.-]+", "_", base)
        suffix = encoder.suffix(m.image)
        name, k = f"{base}.{suffix}", 1
        while name in used:
            name, k = f"{base}_{k}.{suffix}", k + 1
        used.add(name)
        names.append(name)
    return names


def map_names(scan: Scan, stem: str, encoder: TextureEncoder | None = None) -> list[dict[str, str]]:
    """File name of each material's other maps that MTL can name (:data:`MTL_STATEMENTS`), by kind:
    ``stem_material_kind.jpg`` (or ``.png``, as their bytes are), made unique against each other and against
    the colour textures' :func:`texture_names` (a material named ``m_normal`` has a colour texture of the name
    material ``m``'s normal map would take)."""
    taken = {name for name in texture_names(scan, stem, encoder) if name}
    names = []
    for m in scan.materials:
        own = {}
        for kind, texture in m.maps.items():
            if kind in MTL_STATEMENTS and m.image is not None:
                base = re.sub(r"[^\w.-]+", "_", f"{stem}_{m.name}_{kind}")
                name, k = f"{base}.{texture.suffix}", 1
                while name in taken:
                    name, k = f"{base}_{k}.{texture.suffix}", k + 1
                taken.add(name)
                own[kind] = name
        names.append(own)
    return names


def write_obj(scan: Scan, obj_path: Path, files, encoder: TextureEncoder | None = None) -> None:
    """Write ``scan`` as OBJ + MTL + textures (PNG, or as ``encoder`` says) next to ``obj_path``.

    Args:
        files: an :class:`~scantex.io.atomic.AtomicFiles` that hands out temporary paths.
        encoder: how the colour textures are written, and the bytes of each once encoded (default: PNG).
    """
    encoder = encoder or TextureEncoder()
    stem = obj_path.stem
    mtl_path = obj_path.with_suffix(".mtl")
    tex_names = texture_names(scan, stem, encoder)
    mat_names = [re.sub(r"\s+", "_", m.name) or f"material_{i}" for i, m in enumerate(scan.materials)]

    mtl = ["# written by scantex\n"]
    for m, name, tex, others in zip(scan.materials, mat_names, tex_names, map_names(scan, stem, encoder)):
        r, g, b, a = m.diffuse
        mtl.append(f"newmtl {name}\nKa 0 0 0\nKd {r!r} {g!r} {b!r}\nKs 0 0 0\nd {a!r}\nillum 1\n")
        if tex:
            mtl.append(f"map_Kd {tex}\n")
            files.path(obj_path.parent / tex).write_bytes(encoder.colour(m.image))
        for kind, file in others.items():  # the input's own bytes, or a PNG of them
            mtl.append(f"{MTL_STATEMENTS[kind]} {file}\n")
            files.path(obj_path.parent / file).write_bytes(m.maps[kind].file_bytes(encoder))
        mtl.append("\n")
    mtl_tmp = files.path(mtl_path)
    mtl_tmp.write_text("".join(mtl), encoding="utf-8")

    parts = [f"# written by scantex: {scan.n_vertices} vertices, {scan.n_faces} faces\n",
             f"mtllib {mtl_path.name}\n"]
    if scan.vertex_colors is not None:
        rgb = scan.vertex_colors[:, :3].astype(np.float64) / 255.0
        parts.append(_rows("v ", np.concatenate([scan.positions, rgb], axis=1)))
    else:
        parts.append(_rows("v ", scan.positions))
    if scan.uvs is not None:
        parts.append(_rows("vt ", scan.uvs))
    if scan.normals is not None:
        parts.append(_rows("vn ", scan.normals))
    corners = [scan.faces + 1]
    corner = "%d"  # v, v/vt, v//vn or v/vt/vn
    if scan.uvs is not None:
        corners.append(scan.face_uvs + 1)
        corner += "/%d"
    if scan.normals is not None:
        corners.append(scan.face_normals_idx + 1)
        corner += "/%d" if scan.uvs is not None else "//%d"
    face_format = f"f {corner} {corner} {corner}\n"
    flat = np.stack(corners, axis=-1).reshape(scan.n_faces, -1)
    # keep the file's face order: a usemtl line wherever the material changes
    fm = scan.face_materials
    change = np.flatnonzero(np.diff(fm, prepend=-1) != 0).tolist() + [scan.n_faces]
    for start, stop in zip(change[:-1], change[1:]):
        parts.append(f"usemtl {mat_names[fm[start]]}\n")
        parts.append(face_format * (stop - start) % tuple(flat[start:stop].ravel().tolist()))
    files.path(obj_path).write_text("".join(parts), encoding="utf-8")
