"""What a machine has (cores, memory) and what one enhance run of a scan needs.

The estimate decides how many scans (or tiles) a local pool runs at once and what memory a Ray task
declares, so that two big scans are not started together on a machine that cannot hold both.
It is read from the files' headers (face count, atlas size) without loading the mesh.
"""

from __future__ import annotations

import os
import re
import resource
import struct
from dataclasses import dataclass
from pathlib import Path

GiB = 1024 ** 3

#: memory of a worker before it touches a scan: Python, numpy, torch, trimesh, embree (measured 0.45 GiB)
BASE_BYTES = int(0.6 * GiB)
#: per face: geometry, BVH, adjacency, per-face arrays of the pipeline (about 1.2 GiB at 80k faces with
#: a 2048² output, 1.4 GiB in the default preset; most of it is the fixed part)
BYTES_PER_FACE = 3000
#: per output texel: texel map (face id, barycentrics), points, float colours, the uint8 atlas, seam blending
BYTES_PER_TEXEL = 60
#: photo mode, per pixel of a photo's working view: its image, depth, face ids, barycentrics, masks
PHOTO_BYTES_PER_WORKING_PIXEL = 30
#: photo mode, per full-size pixel: a photo's samples, packed, held at most at its own size
PHOTO_BYTES_PER_PIXEL = 4


@dataclass(frozen=True)
class Machine:
    """The resources a local pool may use."""

    cores: int
    """CPU cores this process may run on"""
    memory: int
    """bytes of memory available now (MemAvailable)"""


def machine() -> Machine:
    """The cores this process may use and the memory available now."""
    try:
        cores = len(os.sched_getaffinity(0))
    except AttributeError:  # not Linux
        cores = os.cpu_count() or 1
    return Machine(cores=max(1, cores), memory=available_memory())


def available_memory() -> int:
    """``MemAvailable`` from ``/proc/meminfo`` (bytes); physical memory where that is unknown."""
    try:
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemAvailable:"):
                return int(line.split()[1]) * 1024
    except OSError:
        pass
    try:
        return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (ValueError, OSError, AttributeError):
        return 8 * GiB


def peak_memory() -> int:
    """Peak resident memory of this process and its finished children, bytes (Linux reports KiB)."""
    own = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    children = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
    return max(own, children) * 1024


def estimate_memory(n_faces: int, output_texels: int) -> int:
    """Bytes one enhance run needs for a scan of ``n_faces`` faces baked into ``output_texels`` texels."""
    return int(BASE_BYTES + BYTES_PER_FACE * n_faces + BYTES_PER_TEXEL * output_texels)


def photo_memory(photos, max_side: int) -> int:
    """Bytes photo mode holds for ``photos`` (a :class:`scantex.photos.PhotoSet`) at working size ``max_side``:
    ``PHOTO_BYTES_PER_WORKING_PIXEL`` a working pixel and, at most, ``PHOTO_BYTES_PER_PIXEL`` a full-size one."""
    total = 0.0
    for cam in photos.cameras:
        pixels = cam.width * cam.height
        scale = min(1.0, max_side / max(cam.width, cam.height))
        total += PHOTO_BYTES_PER_WORKING_PIXEL * pixels * scale * scale + PHOTO_BYTES_PER_PIXEL * pixels
    return int(total)


@dataclass(frozen=True)
class Footprint:
    """What a scan file holds, as far as memory goes, read from headers only."""

    faces: int
    """triangles (estimated from the file size where the format does not say)"""
    atlas_texels: int
    """texels of the input atlas(es)"""

    def output_texels(self, texture_size: int = 0) -> int:
        """Texels of the baked atlas: ``texture_size``², or twice the input per side (at most 8192)."""
        if texture_size:
            return texture_size * texture_size
        side = min(2 * int(self.atlas_texels ** 0.5), 8192) if self.atlas_texels else 1024
        return side * side

    def memory(self, texture_size: int = 0) -> int:
        return estimate_memory(self.faces, self.output_texels(texture_size))


def footprint(path: str | Path) -> Footprint:
    """Faces and atlas size of a mesh file, cheaply: OBJ (counts ``f`` lines, reads the MTL's image
    headers), PLY (its header); other formats from the file size. Never raises: an unreadable file gets
    a size-based guess (the run itself reports what is wrong with it)."""
    path = Path(path)
    try:
        suffix = path.suffix.lower()
        if suffix == ".obj":
            return _obj_footprint(path)
        if suffix == ".ply":
            return Footprint(_ply_faces(path), 0)
        return Footprint(max(1, path.stat().st_size // 40), 2048 * 2048)
    except (OSError, ValueError, struct.error):
        try:
            size = path.stat().st_size
        except OSError:
            size = 0
        return Footprint(max(1, size // 40), 2048 * 2048)


def _obj_footprint(path: Path) -> Footprint:
    faces, libraries = 0, []
    with open(path, "rb") as f:
        tail = b"\n"
        while chunk := f.read(1 << 24):
            text = tail + chunk
            faces += text.count(b"\nf ")
            tail = text[-2:]  # a "\nf " split across chunks is counted once: the tail holds at most 2 bytes
            if not libraries:
                libraries = re.findall(rb"^mtllib\s+(.+?)\s*$", text, flags=re.M)
        # polygons with more corners are triangulated; most scans are triangles already
    texels = 0
    for lib in libraries:
        mtl = path.parent / lib.decode("utf-8", "replace")
        if not mtl.exists():
            continue
        for image in re.findall(r"^\s*map_Kd\s+(?:-\S+\s+\S+\s+)*(.+?)\s*$", mtl.read_text(errors="replace"),
                                flags=re.M):
            texels += _image_texels(mtl.parent / image)
    return Footprint(max(faces, 1), texels)


def _image_texels(path: Path) -> int:
    from PIL import Image

    try:
        with Image.open(path) as im:  # reads the header only
            w, h = im.size
        return w * h
    except (OSError, ValueError):
        return 0


def _ply_faces(path: Path) -> int:
    with open(path, "rb") as f:
        for _ in range(200):
            line = f.readline()
            if not line or line.strip() == b"end_header":
                break
            parts = line.split()
            if parts[:2] == [b"element", b"face"]:
                return int(parts[2])
    return max(1, path.stat().st_size // 40)
