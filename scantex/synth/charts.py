"""A capture app's UV atlas, imitated: many ragged charts, packed shuffled, some turned by 90°.

Each panel's grid is cut into rectangles of cells by random guillotine cuts; the borders are then made
ragged by a smooth random displacement, as the charts of real scans are. Every chart is projected onto
its panel's plane (no distortion) and the charts are packed on shelves by height, so neighbours on the
wall land far apart in the atlas. Vertices on a chart border get one UV per chart: those are the seams.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from scantex.synth.mesh import PanelMesh
from scantex.synth.procedural import Panel
from scantex.uv.pack import shelves

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Unwrap:
    """How the synthetic capture app cuts and packs its atlas.

    Attributes:
        n_charts: charts over the whole scene (fewer where panels or the atlas are too small for them).
        min_cells: the smallest side of a chart's rectangle before its borders are made ragged, in cells.
        gutter_texels: empty texels kept on each side of a chart in the scan's atlas.
        rotate_share: share of the charts packed turned by 90°.
        ragged_cells: how far, in cells, chart borders wander from straight lines.
    """

    n_charts: int = 80
    min_cells: int = 4
    gutter_texels: int = 3
    rotate_share: float = 0.3
    ragged_cells: float = 1.5


@dataclass(frozen=True, eq=False)
class ChartLayout:
    """UVs of a scene's charts packed into one atlas.

    Attributes:
        uvs: ``(T, 2) float64`` texture coordinates, one per (chart, vertex) pair.
        face_uvs: ``(F, 3) int64`` indices into ``uvs``.
        chart_of_face: ``(F,) int64`` chart id per face.
        texels_per_metre: scale of the packing at the atlas size it was packed for.
    """

    uvs: np.ndarray
    face_uvs: np.ndarray
    chart_of_face: np.ndarray
    texels_per_metre: float


def split_charts(mesh: PanelMesh, panels: tuple[Panel, ...], n_charts: int, unwrap: Unwrap,
                 rng: np.random.Generator) -> np.ndarray:
    """``(F,) int64`` chart id of every face: about ``n_charts`` connected charts over the scene."""
    total = sum(p.area for p in panels)
    chart_of_face = np.empty(len(mesh.faces), dtype=np.int64)
    next_id = 0
    for k, panel in enumerate(panels):
        wanted = max(1, round(n_charts * panel.area / total))
        labels = _ragged(_guillotine(panel.cells, wanted, unwrap.min_cells, rng), unwrap.ragged_cells, rng)
        sel = np.flatnonzero(mesh.panel_of_face == k)
        cell = mesh.cell_of_face[sel]
        chart_of_face[sel] = next_id + labels[cell[:, 0], cell[:, 1]]
        next_id += int(labels.max()) + 1
    return chart_of_face


def _guillotine(cells: tuple[int, int], wanted: int, min_cells: int, rng: np.random.Generator) -> np.ndarray:
    """``(nu, nv)`` labels of ``wanted`` rectangles (fewer if they would get thinner than ``min_cells``)."""
    rects = [(0, 0, cells[0], cells[1])]
    while len(rects) < wanted:
        splittable = [r for r in rects if max(r[2] - r[0], r[3] - r[1]) >= 2 * min_cells]
        if not splittable:
            break
        areas = np.array([(r[2] - r[0]) * (r[3] - r[1]) for r in splittable], dtype=np.float64)
        i0, j0, i1, j1 = splittable[rng.choice(len(splittable), p=areas / areas.sum())]
        rects.remove((i0, j0, i1, j1))
        if i1 - i0 >= j1 - j0:
            cut = int(rng.integers(i0 + min_cells, i1 - min_cells + 1))
            rects += [(i0, j0, cut, j1), (cut, j0, i1, j1)]
        else:
            cut = int(rng.integers(j0 + min_cells, j1 - min_cells + 1))
            rects += [(i0, j0, i1, cut), (i0, cut, i1, j1)]
    labels = np.empty(cells, dtype=np.int64)
    for n, (i0, j0, i1, j1) in enumerate(rects):
        labels[i0:i1, j0:j1] = n
    return labels


def _ragged(labels: np.ndarray, amplitude: float, rng: np.random.Generator) -> np.ndarray:
    """Wavy chart borders: look labels up at smoothly displaced cells, then keep every chart connected."""
    nu, nv = labels.shape
    shift = [ndimage.gaussian_filter(rng.standard_normal((nu, nv)), 3.0, mode="wrap") for _ in range(2)]
    shift = [np.rint(amplitude * s / max(s.std(), 1e-12)).astype(np.int64) for s in shift]
    ii, jj = np.meshgrid(np.arange(nu), np.arange(nv), indexing="ij")
    moved = labels[np.clip(ii + shift[0], 0, nu - 1), np.clip(jj + shift[1], 0, nv - 1)]
    # a chart split in pieces keeps its largest piece; the cells of the others join a neighbour
    for k in np.unique(moved):
        pieces, n = ndimage.label(moved == k)
        if n > 1:
            largest = 1 + np.argmax(np.bincount(pieces.ravel())[1:])
            moved[(pieces > 0) & (pieces != largest)] = -1
    while (moved < 0).any():
        for axis, step in ((0, 1), (0, -1), (1, 1), (1, -1)):
            neighbour = np.roll(moved, step, axis=axis)
            edge = [slice(None)] * 2
            edge[axis] = 0 if step == 1 else -1
            neighbour[tuple(edge)] = -1  # no wrapping around the panel
            take = (moved < 0) & (neighbour >= 0)
            moved[take] = neighbour[take]
    return np.unique(moved, return_inverse=True)[1].reshape(nu, nv)


def pack_charts(mesh: PanelMesh, panels: tuple[Panel, ...], chart_of_face: np.ndarray, atlas_size: int,
                unwrap: Unwrap, rng: np.random.Generator) -> ChartLayout:
    """Project every chart onto its panel and shelf-pack the charts into an ``atlas_size``² atlas."""
    F, V = len(mesh.faces), len(mesh.positions)
    n = int(chart_of_face.max()) + 1
    panel_of_chart = np.zeros(n, dtype=np.int64)
    panel_of_chart[chart_of_face] = mesh.panel_of_face

    # one UV per (chart, vertex) pair used by a face of that chart
    keys = chart_of_face[:, None] * V + mesh.faces  # [F, 3]
    unique_keys, inverse = np.unique(keys, return_inverse=True)
    chart, vertex = unique_keys // V, unique_keys % V
    plane = np.empty((len(unique_keys), 2))
    for k, panel in enumerate(panels):
        sel = panel_of_chart[chart] == k
        plane[sel] = panel.plane_coordinates(mesh.positions[vertex[sel]])
    lo = np.full((n, 2), np.inf)
    hi = np.full((n, 2), -np.inf)
    np.minimum.at(lo, chart, plane)
    np.maximum.at(hi, chart, plane)
    extent = hi - lo  # [n, 2] metres
    local = plane - lo[chart]

    rotated = rng.random(n) < unwrap.rotate_share
    # a quarter turn (x, y) -> (h - y, x): a rotation, so no chart is mirrored
    r = rotated[chart]
    local = np.where(r[:, None], np.stack([extent[chart, 1] - local[:, 1], local[:, 0]], axis=1), local)
    extent = np.where(rotated[:, None], extent[:, ::-1], extent)

    order_seed = rng.permutation(n)
    scale, corner = _shelf_pack(extent, atlas_size, unwrap.gutter_texels, order_seed)
    g = unwrap.gutter_texels
    # pixel-edge coordinates (u * N, down from the top); the chart's y axis points up in the texture
    x = corner[chart, 0] + g + local[:, 0] * scale
    y_down = corner[chart, 1] + g + (extent[chart, 1] - local[:, 1]) * scale
    uvs = np.stack([x / atlas_size, 1.0 - y_down / atlas_size], axis=1)
    log.debug("packed %d charts at %.1f texels/m into %d²", n, scale, atlas_size)
    return ChartLayout(uvs, inverse.reshape(F, 3), chart_of_face, scale)


def _shelf_pack(extent: np.ndarray, size: int, gutter: int, order_seed: np.ndarray) -> tuple[float, np.ndarray]:
    """The largest scale (texels per metre) at which boxes of ``extent (n, 2)`` metres fit on shelves.

    Boxes go tallest first; ``order_seed`` (a permutation) breaks ties, so the order follows neither
    the charts' ids nor their places on the wall. Returns the scale and ``(n, 2)`` top-left box corners
    in texels.
    """
    scale = size / np.sqrt(extent.prod(axis=1).sum())  # every texel used: an upper bound
    for _ in range(400):
        boxes = np.ceil(extent * scale).astype(np.int64) + 2 * gutter  # [n, 2] (width, height)
        order = order_seed[np.argsort(-boxes[order_seed, 1], kind="stable")]
        corner = shelves(boxes, order, size)
        if corner is not None and boxes[:, 0].max() <= size:
            return scale, corner
        scale *= 0.98
    raise ValueError(f"{len(extent)} charts do not fit a {size}² atlas with {gutter}-texel gutters")
