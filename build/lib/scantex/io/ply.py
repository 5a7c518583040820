"""Checks on a PLY file before trimesh reads it: trimesh accepts header counts that lie, truncated bodies,
faces of 0 to 2 corners and out-of-range indices and returns *other* geometry (a ``-1`` index in an
ASCII PLY with texture coordinates gains a vertex and shifts every face by one). scantex refuses such
files, and checks what trimesh returns against what the header and body say.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from scantex.errors import ScanError

SIZES = {"char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1", "short": "i2", "int16": "i2",
         "ushort": "u2", "uint16": "u2", "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
         "float": "f4", "float32": "f4", "double": "f8", "float64": "f8"}


@dataclass
class Element:
    name: str
    count: int
    #: ``(name, type)`` of scalars, ``(name, (count type, item type))`` of lists
    properties: list = field(default_factory=list)


@dataclass
class PlyInfo:
    """What a checked PLY file holds."""

    vertices: int
    triangles: int
    texture: str | None
    binary: bool


def check_ply(path: Path) -> PlyInfo:
    """Parse ``path``'s header and check its body against it.

    Raises:
        ScanError: a malformed header, counts that do not match the body (truncated, or data beyond
            them), faces with fewer than 3 corners, or vertex indices outside the vertex list.
    """
    data = path.read_bytes()
    end = data.find(b"end_header")
    if not data.startswith(b"ply") or end < 0:
        raise ScanError(path, "not a PLY file (no 'ply' ... 'end_header' header)")
    nl = data.find(b"\n", end)
    body = data[nl + 1:] if nl >= 0 else b""
    header = data[:end].decode("ascii", errors="replace").splitlines()
    fmt, texture, elements = None, None, []
    for line in header[1:]:
        words = line.split()
        if not words:
            continue
        try:
            if words[0] == "format":
                fmt = words[1]
            elif words[0] in ("comment", "obj_info"):
                if len(words) > 2 and words[1].lower() == "texturefile":
                    texture = line.split(None, 2)[2].strip()
            elif words[0] == "element":
                count = int(words[2])
                if count < 0:
                    raise ValueError
                elements.append(Element(words[1], count))
            elif words[0] == "property":
                if words[1] == "list":
                    prop = (words[4], (SIZES[words[2]], SIZES[words[3]]))
                else:
                    prop = (words[2], SIZES[words[1]])
                elements[-1].properties.append(prop)
        except (IndexError, ValueError, KeyError):
            raise ScanError(path, f"malformed PLY header line '{line.strip()[:60]}'") from None
    if fmt not in ("ascii", "binary_little_endian", "binary_big_endian"):
        raise ScanError(path, f"unknown PLY format '{fmt}'")
    by_name = {e.name: e for e in elements}
    if "vertex" not in by_name or "face" not in by_name:
        raise ScanError(path, "the PLY file has no vertex or no face element")
    nv = by_name["vertex"].count
    if fmt == "ascii":
        triangles = _check_ascii(path, body, elements, nv)
    else:
        triangles = _check_binary(path, body, elements, nv, "<" if fmt.endswith("little_endian") else ">")
    return PlyInfo(nv, triangles, texture, fmt != "ascii")


def _face_list(element: Element) -> int | None:
    """Index of the face element's vertex index list among its properties."""
    for i, (name, kind) in enumerate(element.properties):
        if isinstance(kind, tuple) and name in ("vertex_indices", "vertex_index"):
            return i
    return None


def _check_corners(path: Path, face: int, n: int, indices, nv: int) -> None:
    if n < 3:
        raise ScanError(path, f"face {face + 1} has {n} corners (a face needs at least 3)")
    for i in indices:
        if not 0 <= i < nv:
            raise ScanError(path, f"face {face + 1} refers to vertex {i}, the file has {nv} vertices "
                                  "(PLY indices start at 0)")


def _check_ascii(path: Path, body: bytes, elements: list[Element], nv: int) -> int:
    lines = [ln for ln in body.decode("ascii", errors="replace").splitlines() if ln.strip()]
    row, triangles = 0, 0
    for e in elements:
        if row + e.count > len(lines):
            raise ScanError(path, f"the header says {e.count} {e.name} rows, the file has "
                                  f"{max(0, len(lines) - row)}: truncated, or the header's counts are wrong")
        lst = _face_list(e) if e.name == "face" else None
        for k in range(e.count):
            words = lines[row + k].split()
            try:
                values, pos = [], 0
                for name, kind in e.properties:
                    if isinstance(kind, tuple):
                        n = int(words[pos])
                        if n < 0:
                            raise ValueError
                        values.append([int(float(w)) for w in words[pos + 1:pos + 1 + n]])
                        if len(values[-1]) != n:
                            raise ValueError
                        pos += 1 + n
                    else:
                        float(words[pos])
                        values.append(None)
                        pos += 1
                if pos != len(words):
                    raise ValueError
            except (ValueError, IndexError):
                raise ScanError(path, f"{e.name} {k + 1}: '{lines[row + k].strip()[:60]}' does not match the "
                                      "header's properties (truncated, or the header's counts are wrong)") from None
            if lst is not None:
                _check_corners(path, k, len(values[lst]), values[lst], nv)
                triangles += len(values[lst]) - 2
        row += e.count
    if row != len(lines):
        raise ScanError(path, f"{len(lines) - row} rows after the last element the header declares: "
                              "the header's counts are wrong")
    return triangles


def _check_binary(path: Path, body: bytes, elements: list[Element], nv: int, order: str) -> int:
    pos, triangles = 0, 0
    for e in elements:
        scalars = all(not isinstance(kind, tuple) for _, kind in e.properties)
        if scalars:
            pos += e.count * sum(np.dtype(kind).itemsize for _, kind in e.properties)
            continue
        lst = _face_list(e) if e.name == "face" else None
        if lst is not None and len(e.properties) == 1:
            count_t, item_t = e.properties[0][1]
            stride = np.dtype(count_t).itemsize + 3 * np.dtype(item_t).itemsize
            block = body[pos:pos + e.count * stride]
            if len(block) == e.count * stride:  # the common case, all triangles: checked at numpy speed
                rec = np.frombuffer(block, dtype=np.dtype([("n", order + count_t), ("i", order + item_t, 3)]))
                if (rec["n"] == 3).all():
                    bad = np.flatnonzero(((rec["i"] < 0) | (rec["i"] >= nv)).any(axis=1))
                    if bad.size:
                        _check_corners(path, int(bad[0]), 3, rec["i"][bad[0]].tolist(), nv)
                    pos += len(block)
                    triangles += e.count
                    continue
        for k in range(e.count):  # general layout: walked one row at a time
            for i, (_, kind) in enumerate(e.properties):
                if isinstance(kind, tuple):
                    count_t, item_t = (np.dtype(order + t) for t in kind)
                    if pos + count_t.itemsize > len(body):
                        raise _truncated(path, e)
                    n = int(np.frombuffer(body, count_t, 1, pos)[0])
                    pos += count_t.itemsize
                    if n < 0 or pos + n * item_t.itemsize > len(body):
                        raise _truncated(path, e)
                    if i == lst:
                        _check_corners(path, k, n, np.frombuffer(body, item_t, n, pos).tolist(), nv)
                        triangles += n - 2
                    pos += n * item_t.itemsize
                else:
                    pos += np.dtype(kind).itemsize
    if pos > len(body):
        raise ScanError(path, f"the file ends {pos - len(body)} bytes before the data its header declares: "
                              "truncated, or the header's counts are wrong")
    if len(body) - pos > 16:  # a few bytes of padding or a newline are harmless
        raise ScanError(path, f"{len(body) - pos} bytes after the data the header declares: "
                              "the header's counts are wrong")
    return triangles


def _truncated(path: Path, e: Element) -> ScanError:
    return ScanError(path, f"the file ends inside the {e.name} data: truncated, or the header's counts are wrong")
