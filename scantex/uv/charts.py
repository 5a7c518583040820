"""Charts before packing: which faces form each chart and where their corners lie in the chart's plane.

:class:`Charts` is the hand-off between the stages that cut and flatten the surface (``unwrap``,
``optimize``) and the packer. Coordinates are in metres on the surface (a chart scaled by its own
texel density when densities are kept), so a single scale turns every chart into texels.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from itertools import pairwise

import numpy as np

from scantex.arrays import uv_areas
from scantex.uv.param import Distortion, distortion, distortions, flat_triangles

#: how far a layout's planning has got, ``0..1`` (the UV stages call it; ``None`` reports nothing)
Progress = Callable[[float], None] | None


def span(progress: Progress, lo: float, hi: float) -> Progress:
    """``progress`` for a part of the work that runs from ``lo`` to ``hi`` of the whole."""
    if progress is None:
        return None
    return lambda done: progress(lo + (hi - lo) * min(max(done, 0.0), 1.0))


@dataclass(frozen=True, eq=False)
class Charts:
    """An unpacked UV layout.

    Attributes:
        chart_of_face: ``(F,) int64`` chart id of every face, ``0..C-1``.
        face_uvs: ``(F, 3) int64`` indices into ``uvs``; no UV index is shared by two charts.
        uvs: ``(T, 2) float64`` chart-plane coordinates in metres.
    """

    chart_of_face: np.ndarray
    face_uvs: np.ndarray
    uvs: np.ndarray

    @property
    def n_charts(self) -> int:
        return int(self.chart_of_face.max()) + 1 if len(self.chart_of_face) else 0

    def faces_of(self) -> list[np.ndarray]:
        """Face ids of every chart."""
        order = np.argsort(self.chart_of_face, kind="stable")
        bounds = np.searchsorted(self.chart_of_face[order], np.arange(self.n_charts + 1))
        return [order[a:b] for a, b in pairwise(bounds)]

    def distortions(self, triangles_3d: np.ndarray) -> list[Distortion]:
        """Distortion of every chart given the scan's ``(F, 3, 3)`` corner positions."""
        return distortions(triangles_3d, self.uvs[self.face_uvs], self.chart_of_face, self.n_charts)


def faces_apart(charts: Charts, faces: np.ndarray, triangles_3d: np.ndarray) -> Charts:
    """``charts`` with ``faces`` (``(F,) bool``) each a chart of its own, laid flat at its true edge lengths
    (``triangles_3d (F, 3, 3)``: the scan's corner positions); the other faces keep their charts and UVs."""
    idx = np.flatnonzero(faces)
    flat = flat_triangles(triangles_3d[idx])
    face_uvs = charts.face_uvs.copy()
    face_uvs[idx] = len(charts.uvs) + np.arange(3 * len(idx)).reshape(-1, 3)
    chart = charts.chart_of_face.copy()
    chart[idx] = charts.n_charts + np.arange(len(idx))
    _, chart = np.unique(chart, return_inverse=True)  # a chart all of whose faces left is gone
    return Charts(chart.astype(np.int64), face_uvs, np.concatenate([charts.uvs, flat.reshape(-1, 2)]))


#: a group of faces moved apart whose conformal map stretches it more than this (L2 stretch) moves face by face
GROUP_STRETCH = 1.1
#: groups moved apart laid flat whole: at most this many, the largest (a conformal map takes about 2 ms: on a mesh
#: whose layout folds everywhere the rest move face by face)
MAX_GROUPS = 1000


def groups_apart(charts: Charts, faces: np.ndarray, positions: np.ndarray, triangles: np.ndarray) -> Charts:
    """``charts`` with the ``faces`` (``(F,) bool``) that share texels moved out group by group. A chart folded
    onto itself overlaps in two layers, of which one need move: where some of a chart's faces are mirrored
    against the rest of it, those are the fold's far layer and move; elsewhere the faces split into groups joined
    by a UV corner and all but the largest move. Each group moved becomes a chart of its own, laid flat by a
    conformal map (``positions``, ``triangles``: the welded geometry); one the map cannot lay flat moves face by
    face (:func:`faces_apart`). Faces that still share texels are found by the next check. Moving every such
    face alone made the bolster's optimised layout 157 charts, where this makes it 71."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    from scantex.uv.param import lscm

    signed = uv_areas(charts.uvs[charts.face_uvs], signed=True)
    majority = np.sign(np.bincount(charts.chart_of_face, signed, charts.n_charts))
    mirrored = faces & (np.sign(signed) == -majority[charts.chart_of_face]) & (signed != 0)
    folded = np.zeros(charts.n_charts, bool)
    folded[charts.chart_of_face[mirrored]] = True
    # in a folded chart only its mirrored faces move; in another, all its faces that share texels, in groups
    faces = np.where(folded[charts.chart_of_face], mirrored, faces)
    idx = np.flatnonzero(faces)
    if idx.size == 0:
        return charts
    corner = charts.face_uvs[idx]
    _, node = np.unique(corner.ravel(), return_inverse=True)
    link = coo_matrix((np.ones(node.size), (np.repeat(np.arange(idx.size), 3), node)),
                      shape=(idx.size, int(node.max()) + 1)).tocsr()
    _, group = connected_components(link @ link.T, directed=False)
    size = np.bincount(group)
    chart = charts.chart_of_face[idx]
    # the largest group of each chart that is not folded stays
    order = np.lexsort((-size[group], chart))
    first = np.ones(idx.size, bool)
    first[1:] = chart[order][1:] != chart[order][:-1]
    stays = np.zeros(group.max() + 1, bool)
    stays[group[order][first & ~folded[chart[order]]]] = True
    face_uvs, chart_of_face = charts.face_uvs.copy(), charts.chart_of_face.copy()
    uvs, next_chart, base = [charts.uvs], charts.n_charts, len(charts.uvs)
    alone = np.zeros(len(faces), bool)
    moving = np.flatnonzero(~stays)
    flattened = set(moving[np.argsort(-size[moving], kind="stable")][:MAX_GROUPS].tolist())
    for g in moving:
        members = idx[group == g]
        used, local = np.unique(triangles[members], return_inverse=True)
        local = local.reshape(-1, 3)
        whole = g in flattened and len(members) > 1
        flat = lscm(positions[used], local) if whole else None
        if (flat is None or not np.isfinite(flat).all() or np.ptp(flat, axis=0).min() <= 0
                or not distortion(positions[used][local], flat[local]).stretch <= GROUP_STRETCH):
            alone[members] = True  # a face alone lies flat at its true size
            continue
        face_uvs[members] = base + local
        chart_of_face[members] = next_chart
        uvs.append(flat - flat.min(axis=0))
        next_chart, base = next_chart + 1, base + len(flat)
    _, chart_of_face = np.unique(chart_of_face, return_inverse=True)  # a chart all of whose faces left is gone
    moved = Charts(chart_of_face.astype(np.int64), face_uvs, np.concatenate(uvs))
    return faces_apart(moved, alone, positions[triangles]) if alone.any() else moved


def assemble(pieces: list[tuple[np.ndarray, np.ndarray, np.ndarray]], n_faces: int) -> Charts:
    """One :class:`Charts` from per-chart pieces ``(faces (n,), corner_node (n, 3), node_uv (k, 2))``.

    ``corner_node`` indexes the piece's own ``node_uv``. Every face must appear in exactly one piece.
    """
    chart_of_face = np.full(n_faces, -1, dtype=np.int64)
    face_uvs = np.zeros((n_faces, 3), dtype=np.int64)
    uvs, base = [], 0
    for c, (faces, corner_node, node_uv) in enumerate(pieces):
        chart_of_face[faces] = c
        face_uvs[faces] = corner_node + base
        uvs.append(node_uv)
        base += len(node_uv)
    if (chart_of_face < 0).any():
        raise ValueError(f"{int((chart_of_face < 0).sum())} faces belong to no chart")
    return Charts(chart_of_face, face_uvs, np.concatenate(uvs) if uvs else np.zeros((0, 2)))


def compact(corner_key: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Renumber arbitrary ``(n, 3)`` corner keys to ``0..k-1``; returns the new ``(n, 3)`` and the
    ``(k,)`` original key of each."""
    keys, inverse = np.unique(corner_key.ravel(), return_inverse=True)
    return inverse.reshape(corner_key.shape), keys
