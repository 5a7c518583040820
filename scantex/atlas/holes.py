"""Faces the input texture leaves without colour: black untextured faces and out-of-atlas UVs.

Capture apps paint faces no photo saw pure black. Such faces must not teach the field "black"; they
are masked out of the loss and the field fills them from their surroundings. Black that is dark content
(a black tyre in shadow: its darkest texels spread over the black levels, amid dark texture) is no hole:
filled, it would turn into flat, lighter patches (:func:`dark_content`).
"""

from __future__ import annotations

import numpy as np
from scipy import sparse
from scipy.sparse.csgraph import connected_components

from scantex import jit
from scantex.arrays import read_only, unique_rows, uv_areas
from scantex.scan import Scan
from scantex.views.render import sample_texture

#: colours at or below this (0-255) in every channel count as "no colour" (JPEG leaves a little noise)
BLACK_LEVEL = 6

#: black faces that are not pure black are a hole only where the surface around them is brighter than this
#: (0-255, the median of the neighbouring faces' brightest channel): black inside dark surroundings is dark
#: content (a black tyre in shadow), which a fill would lighten into flat patches (see :func:`dark_content`)
DARK_SURROUND = 24

#: colours at or below this (0-255) in every channel are pure black: an app's untextured texels, through JPEG
PURE_BLACK_LEVEL = 1


def untextured_faces(scan: Scan) -> np.ndarray:
    """``(F,) bool``: faces whose texture is black at their centre and near their corners (an app's black, not
    dark content: :func:`dark_content`), whose UVs lie entirely outside the atlas, or whose UV triangle has no
    area. All False for untextured scans. Computed once per scan (:meth:`Scan.texture_memo`); read-only."""
    return _black_faces(scan)[0]


def visible_holes(scan: Scan) -> np.ndarray:
    """``(F,) bool``: :func:`untextured_faces` of some area, the holes a viewer can see (a capture app's mesh
    holds faces of no area: the bathroom's 3,869, black in its atlas, counted as holes that never show)."""
    return untextured_faces(scan) & (scan.face_areas > 0)


def _black_faces(scan: Scan) -> tuple[np.ndarray, np.ndarray]:
    """``(holes (F,), partly (F,))``: :func:`untextured_faces` and :func:`partly_untextured_faces`, dark content
    left out of both (:func:`dark_content`). Computed once per scan; read-only."""
    def find() -> tuple[np.ndarray, np.ndarray]:
        if not scan.is_textured:
            return read_only(np.zeros(scan.n_faces, bool)), read_only(np.zeros(scan.n_faces, bool))
        unmapped = unmapped_faces(scan)
        black = _black_all_over(scan) & ~unmapped
        black_probes, pure_probes = _black_probes(scan)
        partly = (black_probes > 0) & ~black & ~unmapped
        dark = dark_content(scan, black, partly, black_probes, pure_probes)
        return read_only(unmapped | (black & ~dark)), read_only(partly & ~dark)

    return scan.texture_memo("black_faces", find)


def dark_content(scan: Scan, holes: np.ndarray, partly: np.ndarray, black_probes: np.ndarray,
                 pure_probes: np.ndarray) -> np.ndarray:
    """``(F,) bool``: the faces of ``holes`` (black all over) and ``partly`` (black in part) that are dark
    content rather than texture an app left black. The black faces are grouped into regions (faces sharing a
    position). A region is an app's black where at least half its black probes (``black_probes``, ``(F,)``
    counts) read pure black (``pure_probes``): where an app's photos did not reach, its atlas is pure black
    even through JPEG (the 3D Scanner App bathroom's hole regions and an app-style bake's: all of their
    probes), while a dark texture's darkest texels spread over the black levels (a Polycam scan's black tyres:
    at most 17 % a region, the bathroom's shadows none). It is one too where it holds a face black all over
    and the faces around it are lit: the median of their brightest channel (at 7 points a face) at least
    :data:`DARK_SURROUND` (an app whose black is not pure: a Polycam scan's unseen rug border, amid 26-112
    levels; the tyres' shadowed rubber lies amid 10-19). Every other region is dark content. A region with no
    face around it (a black fragment on its own) counts as lit."""
    black = holes | partly
    dark = np.zeros(scan.n_faces, bool)
    if not black.any() or not scan.is_textured:
        return dark
    corners = scan.welded[scan.faces]  # [F, 3] positions, so that regions cross the UV seams
    V = int(corners.max()) + 1
    idx = np.flatnonzero(black)
    # regions: black faces and their positions, one graph
    graph = sparse.coo_matrix((np.ones(3 * idx.size), (np.repeat(np.arange(idx.size), 3), corners[idx].ravel())),
                              shape=(idx.size, V)).tocsr()
    n, label = connected_components(sparse.bmat([[None, graph], [graph.T, None]]), directed=False)
    region_of_face = label[:idx.size]
    region_of_position = np.full(V, -1)
    touched = np.zeros(V, bool)
    touched[corners[idx].ravel()] = True
    region_of_position[touched] = label[idx.size:][touched]
    # the faces around each region: the others that share a position with it (a face counted once a region)
    around = np.flatnonzero(~black & touched[corners].any(axis=1))
    pairs = unique_rows(np.stack([np.repeat(around, 3), region_of_position[corners[around]].ravel()], axis=1))
    pairs = pairs[pairs[:, 1] >= 0]
    surround = np.full(n, np.inf)  # no face around: lit
    if len(pairs):
        values = _face_levels(scan, np.unique(pairs[:, 0]))[pairs[:, 0]]
        order = np.lexsort((values, pairs[:, 1]))
        region, values = pairs[order, 1], values[order]
        starts = np.flatnonzero(np.r_[True, region[1:] != region[:-1]])
        counts = np.diff(np.r_[starts, len(region)])
        surround[region[starts]] = 0.5 * (values[starts + (counts - 1) // 2] + values[starts + counts // 2])
    has_hole = np.zeros(n, bool)
    has_hole[region_of_face[holes[idx]]] = True
    pure_share = (np.bincount(region_of_face, pure_probes[idx], minlength=n)
                  / np.maximum(np.bincount(region_of_face, black_probes[idx], minlength=n), 1))
    app_black = (pure_share >= 0.5) | (has_hole & (surround >= DARK_SURROUND))
    dark[idx] = ~app_black[region_of_face]
    return dark


def _face_levels(scan: Scan, faces: np.ndarray) -> np.ndarray:
    """``(F,) float``: the median over 7 points of each of ``faces`` of its texture's brightest channel (0-255;
    0 for the other faces)."""
    weights = np.array([[1, 1, 1], [3, 1, 1], [1, 3, 1], [1, 1, 3], [2, 2, 1], [1, 2, 2], [2, 1, 2]], np.float64)
    weights /= weights.sum(axis=1, keepdims=True)
    level = np.zeros(scan.n_faces)
    for m, material in enumerate(scan.materials):
        sel = faces[scan.face_materials[faces] == m]
        if material.image is None or sel.size == 0:
            continue
        points = np.matmul(weights, scan.triangle_uvs[sel])  # [n, 7, 2]
        rgb = sample_texture(material.image, points.reshape(-1, 2)).reshape(len(sel), len(weights), -1)[..., :3]
        level[sel] = np.median(rgb.max(axis=2), axis=1) * 255.0
    return level


def unmapped_faces(scan: Scan) -> np.ndarray:
    """``(F,) bool``: faces whose UVs lie entirely outside the atlas (but inside no one whole tile of the plane:
    :func:`whole_tiles`), or whose UV triangle has no area."""
    uv = scan.triangle_uvs  # [F, 3, 2]
    outside = ((uv < 0) | (uv > 1)).any(axis=2).all(axis=1) & ~whole_tiles(uv)[1]
    return (uv_areas(uv) < 0.5e-14) | outside


def whole_tiles(uv: np.ndarray, eps: float = 1e-6) -> tuple[np.ndarray, np.ndarray]:
    """``(tile (F, 2), off (F,) bool)`` of UV triangles ``uv (F, 3, 2)``: the whole tile ``[k, k + 1] x [l, l + 1]``
    of the plane each one's centre lies in, and whether the triangle lies inside it and it is not the atlas's
    own. A texture repeats outside ``[0, 1]`` (glTF's default and every OBJ viewer's): such a face shows the
    texels of its triangle moved by ``(-k, -l)`` (:func:`scantex.uv.unmapped.wrap_whole_tiles`)."""
    tile = np.floor(uv.mean(axis=1))
    local = uv - tile[:, None, :]
    off = (tile != 0).any(axis=1) & ((local >= -eps) & (local <= 1 + eps)).all(axis=(1, 2))
    return tile, off


def _black_all_over(scan: Scan) -> np.ndarray:
    """``(F,) bool``: faces whose texture is black at their centre and near their corners."""
    black = np.zeros(scan.n_faces, bool)
    uv = scan.triangle_uvs  # [F, 3, 2]
    centre = uv.mean(axis=1, keepdims=True)
    probes = np.concatenate([centre, centre + 0.7 * (uv - centre)], axis=1)  # [F, 4, 2]
    for m, material in enumerate(scan.materials):
        sel = np.flatnonzero(scan.face_materials == m)
        if material.image is None or sel.size == 0:
            continue
        rgb = sample_texture(material.image, probes[sel].reshape(-1, 2)).reshape(len(sel), 4, -1)[..., :3]
        black[sel] = rgb.max(axis=(1, 2)) * 255.0 <= BLACK_LEVEL
    return black


#: probes per face edge for :func:`partly_untextured_faces` (a triangular grid of (n+1)(n+2)/2 points)
PARTIAL_PROBES = 6


def _black_texels(image, level, pure_level, out):
    """The compiled twin of :func:`_black_probes`' masks: ``out (H, W, 2)``, channel 0 255 where every channel
    of the 8-bit ``image (H, W, >= 3)`` is at most ``level``, channel 1 where it is at most ``pure_level``."""
    for y in range(image.shape[0]):
        for x in range(image.shape[1]):
            brightest = max(image[y, x, 0], image[y, x, 1], image[y, x, 2])
            out[y, x, 0] = 255 if brightest <= level else 0
            out[y, x, 1] = 255 if brightest <= pure_level else 0


def partly_untextured_faces(scan: Scan, holes: np.ndarray | None = None) -> np.ndarray:
    """``(F,) bool``: faces that are not :func:`untextured_faces` (``holes``, when given) but whose texture is
    black somewhere inside (an app's black, not dark content: :func:`dark_content`). Computed once per scan;
    read-only.

    A capture app leaves black where no photo reached: a face on the edge of that region is partly black,
    and its black part is kept as the input's colour where nothing else covers it (black specks on a
    room's walls)."""
    partly = _black_faces(scan)[1]
    return partly if holes is None else partly & ~holes


def _black_probes(scan: Scan, *, chunk: int = 65536) -> tuple[np.ndarray, np.ndarray]:
    """``(black (F,), pure (F,)) int``: how many of each face's probes read black texels only (at most
    :data:`BLACK_LEVEL`), and how many pure black ones (at most :data:`PURE_BLACK_LEVEL`). Probes a triangular
    grid of points drawn 10 % towards the face's centre (a UV triangle's own border reads the atlas's gutter);
    a probe reads four texels."""
    black_count = np.zeros(scan.n_faces, np.int64)
    pure_count = np.zeros(scan.n_faces, np.int64)
    n = PARTIAL_PROBES
    grid = np.array([(i / n, j / n) for i in range(n + 1) for j in range(n + 1 - i)])
    weights = np.stack([1 - grid[:, 0] - grid[:, 1], grid[:, 0], grid[:, 1]], axis=1)
    weights = 0.9 * weights + 0.1 / 3
    uv = scan.triangle_uvs  # [F, 3, 2]
    for m, material in enumerate(scan.materials):
        sel = np.flatnonzero(scan.face_materials == m)
        if material.image is None or sel.size == 0:
            continue
        image = material.image
        scale = 1 if image.dtype == np.uint8 else 1 / 255.0
        # two channels to look up: 255 where a texel is black, and where it is pure black
        masks = np.empty((*image.shape[:2], 2), np.uint8)
        kernel = jit.compiled(_black_texels) if image.dtype == np.uint8 else None
        if kernel is not None:  # one compiled pass (an 8192^2 atlas: about 0.1 s, where numpy took 0.6 s)
            kernel(image, BLACK_LEVEL, PURE_BLACK_LEVEL, masks)
        else:
            brightest = np.maximum(np.maximum(image[..., 0], image[..., 1]), image[..., 2])
            masks[..., 0] = (brightest <= BLACK_LEVEL * scale).astype(np.uint8) * np.uint8(255)
            masks[..., 1] = (brightest <= PURE_BLACK_LEVEL * scale).astype(np.uint8) * np.uint8(255)
        per = max(1, chunk // len(grid))
        for s in range(0, sel.size, per):
            f = sel[s:s + per]
            probes = np.matmul(weights, uv[f])  # [f, P, 2]
            read = sample_texture(masks, probes.reshape(-1, 2)).reshape(len(f), len(grid), 2) > 0.999
            black_count[f] = read[..., 0].sum(axis=1)
            pure_count[f] = read[..., 1].sum(axis=1)
    return black_count, pure_count
