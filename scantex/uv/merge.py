"""Greedy chart merging under a stretch threshold, longest shared seam first.

Two neighbouring charts are welded along the seam between them only (their other cuts stay cut),
flattened again (planar projection first, a least-squares conformal map when that fails) and kept merged
when the result has no mirrored face, no overlap and L2 stretch within the threshold.
"""

from __future__ import annotations

import heapq
import time
from dataclasses import dataclass

import numpy as np

from scantex.arrays import unique_rows
from scantex.uv.charts import compact
from scantex.uv.param import lscm, planar_projection

#: unions larger than this are not tried with LSCM (a sparse solve per attempt costs seconds there)
LSCM_MAX_FACES = 30_000


@dataclass
class Piece:
    """One chart while charts are being cut and merged.

    Attributes:
        faces: ``(n,)`` face ids.
        corner_node: ``(n, 3)`` indices into ``node_uv``.
        node_uv: ``(k, 2)`` chart-plane coordinates in metres.
    """

    faces: np.ndarray
    corner_node: np.ndarray
    node_uv: np.ndarray


@dataclass
class MergeLog:
    """What the merger did (JSON-ready through ``as_dict``)."""

    attempts: int = 0
    merges: int = 0
    planar: int = 0
    lscm: int = 0
    out_of_time: bool = False

    def as_dict(self) -> dict:
        return dict(self.__dict__)


class Merger:
    """Greedy merging of charts; see the module docstring.

    Args:
        positions, faces: the mesh.
        face_normals: ``(F, 3)`` unit normals (unused faces may be anything).
        pieces: the charts to start from; every face in exactly one.
        pairs, corners: interior edges (:func:`scantex.uv.unwrap.interior_edges`).
        threshold: largest stretch a merged chart may have.
        small_faces: when given, only pairs with a chart of fewer faces than this are tried (absorbing
            slivers and outlier faces into their neighbours).
    """

    def __init__(self, positions: np.ndarray, faces: np.ndarray, pieces: list[Piece], pairs: np.ndarray,
                 corners: np.ndarray, threshold: float, small_faces: int | None = None):
        from scantex.uv.unwrap import acceptable

        self._acceptable = acceptable
        self.positions, self.faces = positions, faces
        self.threshold, self.small_faces = threshold, small_faces
        self.pieces: dict[int, Piece] = dict(enumerate(pieces))
        F = len(faces)
        self.chart = np.full(F, -1, dtype=np.int64)
        self.row = np.zeros(F, dtype=np.int64)
        for c, p in self.pieces.items():
            self.chart[p.faces] = c
            self.row[p.faces] = np.arange(len(p.faces))
        keep = (self.chart[pairs[:, 0]] >= 0) & (self.chart[pairs[:, 1]] >= 0)
        self.pairs, self.corners = pairs[keep], corners[keep]
        p0 = positions[faces[self.pairs[:, 0], self.corners[:, 0, 0]]]
        p1 = positions[faces[self.pairs[:, 0], self.corners[:, 0, 1]]]
        self.length = np.linalg.norm(p1 - p0, axis=1)
        self.size = {c: len(p.faces) for c, p in self.pieces.items()}
        self.next_id = len(pieces)
        self.heap: list[tuple[float, int, int]] = []
        self._push(self.chart[self.pairs[:, 0]], self.chart[self.pairs[:, 1]], self.length)

    def _push(self, a: np.ndarray, b: np.ndarray, length: np.ndarray) -> None:
        between = a != b
        lo, hi = np.minimum(a, b)[between], np.maximum(a, b)[between]
        if lo.size == 0:
            return
        keys, inverse = unique_rows(np.stack([lo, hi], 1), return_inverse=True)
        total = np.bincount(inverse.ravel(), length[between], len(keys))
        for (x, y), t in zip(keys.tolist(), total.tolist()):
            if self.small_faces is None or min(self.size[x], self.size[y]) < self.small_faces:
                heapq.heappush(self.heap, (-t, x, y))

    def _union(self, a: int, b: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Faces, welded ``(n, 3)`` corner nodes and ``(k,)`` node vertices of charts ``a`` and ``b``."""
        from scipy.sparse import coo_matrix
        from scipy.sparse.csgraph import connected_components

        pa, pb = self.pieces[a], self.pieces[b]
        na = len(pa.node_uv)
        faces = np.concatenate([pa.faces, pb.faces])
        cn = np.concatenate([pa.corner_node, pb.corner_node + na])
        n_nodes = na + len(pb.node_uv)
        node_vertex = np.zeros(n_nodes, dtype=np.int64)
        node_vertex[cn.ravel()] = self.faces[faces].ravel()
        ca, cb = self.chart[self.pairs[:, 0]], self.chart[self.pairs[:, 1]]
        e = np.flatnonzero(((ca == a) & (cb == b)) | ((ca == b) & (cb == a)))
        links = []
        for side in range(2):
            f = self.pairs[e, side]
            row = self.row[f] + np.where(self.chart[f] == b, len(pa.faces), 0)
            links.append(cn[row[:, None], self.corners[e, side]])  # [e, 2] nodes of both end points
        i, j = links[0].ravel(), links[1].ravel()
        graph = coo_matrix((np.ones(i.size), (i, j)), shape=(n_nodes, n_nodes))
        _, label = connected_components(graph, directed=False)
        corner_node, keys = compact(label[cn])
        first = np.zeros(len(keys), dtype=np.int64)
        first[corner_node.ravel()] = cn.ravel()
        return faces, corner_node, node_vertex[first]

    def try_merge(self, a: int, b: int, record: MergeLog) -> bool:
        faces, corner_node, vertex = self._union(a, b)
        points = self.positions[vertex]
        tri3 = points[corner_node]
        uv, how = None, ""
        cand = planar_projection(points, corner_node)
        if self._acceptable(tri3, cand[corner_node], self.threshold):
            uv, how = cand, "planar"
        elif len(faces) <= LSCM_MAX_FACES:
            try:
                cand = lscm(points, corner_node)
            except (RuntimeError, ValueError, np.linalg.LinAlgError):
                cand = None
            if cand is not None and np.isfinite(cand).all() and self._acceptable(tri3, cand[corner_node],
                                                                                  self.threshold):
                uv, how = cand, "lscm"
        if uv is None:
            return False
        c = self.next_id
        self.next_id += 1
        del self.pieces[a], self.pieces[b], self.size[a], self.size[b]
        self.pieces[c] = Piece(faces, corner_node, uv)
        self.size[c] = len(faces)
        self.chart[faces] = c
        self.row[faces] = np.arange(len(faces))
        record.merges += 1
        setattr(record, how, getattr(record, how) + 1)
        ca, cb = self.chart[self.pairs[:, 0]], self.chart[self.pairs[:, 1]]
        touch = (ca == c) != (cb == c)
        self._push(ca[touch], cb[touch], self.length[touch])
        return True

    def run(self, deadline: float, record: MergeLog) -> list[Piece]:
        """Merge until no pair is left or ``deadline`` (``time.perf_counter()``) passes; the charts."""
        while self.heap:
            if time.perf_counter() > deadline:
                record.out_of_time = True
                break
            _, a, b = heapq.heappop(self.heap)
            if a not in self.pieces or b not in self.pieces:
                continue  # one of them was merged since this pair was queued
            record.attempts += 1
            self.try_merge(a, b, record)
        return list(self.pieces.values())
