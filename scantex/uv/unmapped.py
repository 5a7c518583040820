"""Atlas space for the faces an input layout leaves without any: the rest of the layout kept as it is.

Some exporters give the faces no photo saw no texture space at all: OpenMVS's façade puts all three UV
corners of 42 such faces on one point of the atlas, whose one texel every one of them shows. A hole fill
cannot colour them (there is no texel of theirs to write), so they showed that texel's colour: flat grey
triangles on the output where the input had black ones. :func:`chart_unmapped_faces` lays each such face
flat as a triangle chart of its own, at the layout's texel density (its UV area over its 3D area), in a
free cell of its material's atlas (a gutter from every chart), and leaves every other face's UVs
untouched; the bake then fills the new charts as the holes they are.
"""

from __future__ import annotations

import logging

import numpy as np

from scantex.arrays import unique_rows, uv_areas
from scantex.atlas.holes import unmapped_faces, whole_tiles
from scantex.atlas.texelmap import uv_to_pixel
from scantex.scan import Scan
from scantex.uv.param import flat_triangles

log = logging.getLogger(__name__)

#: a new chart's longest side, in texels, at most (a face larger than that at the layout's density is
#: shrunk: it is a hole, filled smoothly, and needs few texels)
MAX_CHART_TEXELS = 32


def chart_unmapped_faces(scan: Scan, gutter_texels: int = 4) -> tuple[Scan, dict | None]:
    """``scan`` with a triangle chart of its own for every face :func:`unmapped_faces` finds (and whose 3D
    triangle has an area), in free space of its material's atlas, and a report (``None`` when no face is
    unmapped). Faces that find no free cell keep their UVs (the report counts them). Positions, faces and
    every other face's UVs are unchanged."""
    if not scan.is_textured:
        return scan, None
    scan, wrapped = wrap_whole_tiles(scan)
    unmapped = unmapped_faces(scan) & (scan.face_areas > 0)
    if not unmapped.any():
        return scan, ({"faces": 0, "charted": 0, "left": 0, "wrapped": wrapped} if wrapped else None)
    new_uvs, new_face_uvs = [scan.uvs], scan.face_uvs.copy()
    charted, left = 0, 0
    next_uv = len(scan.uvs)
    for m, material in enumerate(scan.materials):
        faces = np.flatnonzero(unmapped & (scan.face_materials == m))
        if material.image is None or faces.size == 0:
            left += faces.size
            continue
        H, W = material.image.shape[:2]
        mapped = np.flatnonzero(~unmapped & (scan.face_materials == m))
        density = _texels_per_metre(scan, mapped, W, H)
        corners = flat_triangles(scan.positions[scan.faces[faces]]) * density  # [n, 3, 2] texels, from (0, 0)
        side = corners.max(axis=(1, 2))
        corners *= np.minimum(1.0, MAX_CHART_TEXELS / np.maximum(side, 1e-12))[:, None, None]
        corners *= np.maximum(1.0, 2.0 / np.maximum(corners.max(axis=(1, 2)), 1e-12))[:, None, None]
        cell = int(np.ceil(corners.max())) + 2 * gutter_texels + 1
        free = _free_cells(scan, mapped, W, H, cell)
        take = min(len(free), faces.size)
        left += faces.size - take
        origin = free[:take, ::-1] * cell + gutter_texels + 0.5  # [take, 2] x, y: a gutter inside each cell
        pixel = corners[:take] + origin[:, None, :]  # [take, 3, 2]
        new_uvs.append(np.stack([pixel[..., 0] / W, 1.0 - pixel[..., 1] / H], axis=-1).reshape(-1, 2))
        new_face_uvs[faces[:take]] = next_uv + np.arange(3 * take).reshape(take, 3)
        next_uv += 3 * take
        charted += take
    if charted == 0:
        return scan, {"faces": int(unmapped.sum()), "charted": 0, "left": int(left), "wrapped": wrapped}
    log.info("gave %d unmapped faces a chart of their own (%d left as they were)", charted, left)
    out = scan.replace(uvs=np.concatenate(new_uvs).astype(scan.uvs.dtype), face_uvs=new_face_uvs)
    return out, {"faces": int(unmapped.sum()), "charted": int(charted), "left": int(left), "wrapped": wrapped}


def wrap_whole_tiles(scan: Scan) -> tuple[Scan, int]:
    """``scan`` with every face whose UV triangle lies inside one whole tile of the plane other than the atlas's
    own, ``[k, k + 1] x [l, l + 1]``, moved into ``[0, 1]^2`` by ``(-k, -l)``, and how many faces moved. A
    texture repeats outside ``[0, 1]`` (glTF's default, and every OBJ viewer's), so such a face shows the
    same texels there; read as lying outside the atlas, it would be taken for a face without texture space,
    and a layout shifted whole by one tile lost its whole texture. Faces across a tile's border (a texture
    repeated over them) keep their UVs."""
    tile, move = whole_tiles(scan.triangle_uvs)
    if not move.any():
        return scan, 0
    faces = np.flatnonzero(move)
    # a UV vertex that faces in several tiles share becomes one per tile: new vertices for the moved corners
    corners = scan.face_uvs[faces].ravel()
    tiles = np.repeat(tile[faces], 3, axis=0)
    keys, inverse = unique_rows(np.column_stack([corners, tiles]), return_inverse=True)  # (UV vertex, tile)
    face_uvs = scan.face_uvs.copy()
    face_uvs[faces] = len(scan.uvs) + inverse.reshape(-1, 3)
    shifted = scan.uvs[keys[:, 0].astype(np.int64)] - keys[:, 1:]
    uvs = np.concatenate([scan.uvs, shifted]).astype(scan.uvs.dtype)
    log.info("moved %d faces whose UVs lie in one whole tile outside [0, 1] into the atlas (the texture "
             "repeats there)", faces.size)
    return scan.replace(uvs=uvs, face_uvs=face_uvs), int(faces.size)


def _texels_per_metre(scan: Scan, faces: np.ndarray, W: int, H: int) -> float:
    """The layout's texel density over ``faces``: sqrt of their UV area in texels over their 3D area (1000 a
    metre when they have none)."""
    if faces.size == 0:
        return 1000.0
    uv_area = uv_areas(scan.triangle_uvs[faces] * [W, H]).sum()
    area = scan.face_areas[faces].sum()
    return float(np.sqrt(uv_area / area)) if area > 0 and uv_area > 0 else 1000.0


def _free_cells(scan: Scan, mapped: np.ndarray, W: int, H: int, cell: int) -> np.ndarray:
    """``(k, 2)`` (row, column) of the ``cell``-texel cells of the atlas that no face of ``mapped`` reaches with
    its UV bounding box, in reading order (a chart sits a gutter inside its cell: a cell no face's texels reach
    keeps it that far from all)."""
    rows, cols = H // cell, W // cell
    if rows == 0 or cols == 0:
        return np.zeros((0, 2), np.int64)
    pixel = uv_to_pixel(scan.triangle_uvs[mapped], W, H)  # [n, 3, 2] x, y
    low = np.floor((pixel.min(axis=1) - 1) / cell).astype(np.int64)  # a texel reaches half a texel past a corner
    high = np.floor((pixel.max(axis=1) + 1) / cell).astype(np.int64)
    c0, r0 = np.clip(low[:, 0], 0, cols), np.clip(low[:, 1], 0, rows)
    c1, r1 = np.clip(high[:, 0], -1, cols - 1), np.clip(high[:, 1], -1, rows - 1)
    keep = (c0 <= c1) & (r0 <= r1)
    c0, r0, c1, r1 = c0[keep], r0[keep], c1[keep], r1[keep]
    # every box's cells counted at once: its corners in a difference table, summed along both axes
    table = np.zeros((rows + 1, cols + 1), np.int64)
    np.add.at(table, (r0, c0), 1)
    np.add.at(table, (r0, c1 + 1), -1)
    np.add.at(table, (r1 + 1, c0), -1)
    np.add.at(table, (r1 + 1, c1 + 1), 1)
    used = table.cumsum(axis=0).cumsum(axis=1)[:rows, :cols] > 0
    return np.argwhere(~used)
