"""Greedy chart merging under a stretch threshold, longest shared seam first.

Two neighbouring charts are welded along the seam between them only (their other cuts stay cut) and kept
merged when the result has no mirrored face, no overlap and L2 stretch within the threshold. Small unions
are flattened again (planar projection first, a least-squares conformal map when that fails); where one
chart is large, it keeps its layout and the other is placed around their shared nodes (flattening a large
chart again for every sliver joining it took up to seconds a try: the refined facade's 175,000 faces ran out
of time after about 190 of its 590 merges).

With ``retry`` off (UV optimisation), two charts that failed to merge are not tried again once either has
grown: a union that contains a failed one rarely passes when flattened afresh (more surface, more curvature),
and retrying every neighbour of a growing chart, each try a sparse conformal solve over the union, made the
merges quadratic: ``--uv optimize`` on the facade's app-style mesh stopped at its 60 s budget after 117 merges
of 406 tries and 258 charts; with the failures remembered it finishes in 36 s, 33 charts (327 merges of 375).
"""

from __future__ import annotations

import heapq
import time
from dataclasses import dataclass

import numpy as np

from scantex.arrays import unique_rows
from scantex.uv.charts import Progress
from scantex.uv.param import lscm, overlap_counts, planar_projection, stretch_of_sums, stretch_sums

#: unions larger than this are not tried with LSCM (a sparse solve per attempt costs seconds there)
LSCM_MAX_FACES = 30_000
#: unwrapping's merges: a chart this large keeps its layout when a smaller one joins it
#: (:meth:`Merger._absorbed`): flattening the whole union again costs a projection, a rasterisation and often
#: a sparse solve over all its faces
ABSORB_FACES = 256


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
    absorbed: int = 0
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
        absorb_faces: when given, a chart of at least this many faces keeps its layout when a smaller one
            joins it (:meth:`_absorbed`); otherwise every union is flattened afresh.
        retry: whether two charts that failed to merge are tried again once either has grown (see the module
            docstring). Unwrapping's slivers do: a sliver placed around a grown chart's new nodes may fit
            where it did not before.
    """

    def __init__(self, positions: np.ndarray, faces: np.ndarray, pieces: list[Piece], pairs: np.ndarray,
                 corners: np.ndarray, threshold: float, small_faces: int | None = None,
                 absorb_faces: int | None = None, retry: bool = True):
        from scantex.uv.unwrap import OVERLAP_TOLERANCE, acceptable

        self._acceptable, self._tolerance = acceptable, OVERLAP_TOLERANCE
        self.positions, self.faces = positions, faces
        self.threshold, self.small_faces, self.absorb_faces = threshold, small_faces, absorb_faces
        self._layouts: dict[int, tuple] = {}
        self.retry = retry
        self._failed: dict[int, set[int]] = {}  # each chart's partners it failed to merge with (retry off)
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
        ca, cb = self.chart[self.pairs[:, 0]], self.chart[self.pairs[:, 1]]
        # each chart's edges to other charts, ascending (a merge looks at its two charts' edges, not all)
        between = np.flatnonzero(ca != cb)
        side = np.concatenate([ca[between], cb[between]])
        order = np.argsort(side, kind="stable")
        edges = np.concatenate([between, between])[order]
        cuts = np.searchsorted(side[order], np.arange(len(pieces) + 1))
        self._edges: dict[int, np.ndarray] = {c: np.sort(edges[cuts[c]:cuts[c + 1]]) for c in self.pieces}
        self._push(ca, cb, self.length)

    def _push(self, a: np.ndarray, b: np.ndarray, length: np.ndarray) -> None:
        between = a != b
        lo, hi = np.minimum(a, b)[between], np.maximum(a, b)[between]
        if lo.size == 0:
            return
        keys, inverse = unique_rows(np.stack([lo, hi], 1), return_inverse=True)
        total = np.bincount(inverse.ravel(), length[between], len(keys))
        for (x, y), t in zip(keys.tolist(), total.tolist()):
            if y in self._failed.get(x, ()):
                continue  # these two failed before, each then smaller (see the module docstring)
            if self.small_faces is None or min(self.size[x], self.size[y]) < self.small_faces:
                heapq.heappush(self.heap, (-t, x, y))

    def _union(self, a: int, b: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Charts ``a`` and ``b`` welded along their seam: faces (``a``'s, then ``b``'s), ``(n, 3)`` corner
        nodes, ``(k,)`` node vertices, the welded node of each of their nodes (``a``'s, then ``b``'s), and the
        nodes the seam welds."""
        from scipy.sparse import coo_matrix
        from scipy.sparse.csgraph import connected_components

        pa, pb = self.pieces[a], self.pieces[b]
        na = len(pa.node_uv)
        faces = np.concatenate([pa.faces, pb.faces])
        cn = np.concatenate([pa.corner_node, pb.corner_node + na])
        n_nodes = na + len(pb.node_uv)
        node_vertex = np.zeros(n_nodes, dtype=np.int64)
        node_vertex[cn.ravel()] = self.faces[faces].ravel()
        e = self._seam(a, b)
        links = []
        for side in range(2):
            f = self.pairs[e, side]
            row = self.row[f] + np.where(self.chart[f] == b, len(pa.faces), 0)
            links.append(cn[row[:, None], self.corners[e, side]].ravel())  # both end points of each edge
        # the seam's nodes joined into groups; each group becomes its lowest node, and nodes are numbered in
        # that order (the numbering connected components over all nodes would give)
        welded, ends = np.unique(np.concatenate(links), return_inverse=True)
        half = len(links[0])
        graph = coo_matrix((np.ones(half), (ends[:half], ends[half:])), shape=(len(welded),) * 2)
        _, group = connected_components(graph, directed=False)
        lowest = np.full(group.max() + 1 if group.size else 0, n_nodes, dtype=np.int64)
        np.minimum.at(lowest, group, welded)
        root = np.arange(n_nodes)
        root[welded] = lowest[group]
        node_of = (np.cumsum(root == np.arange(n_nodes)) - 1)[root]
        vertex = np.zeros(int(node_of.max()) + 1, dtype=np.int64)
        vertex[node_of] = node_vertex  # welded nodes are at one vertex
        return faces, node_of[cn], vertex, node_of, welded

    def _seam(self, a: int, b: int) -> np.ndarray:
        """The interior edges between charts ``a`` and ``b``, ascending."""
        e = self._edges[a] if len(self._edges[a]) <= len(self._edges[b]) else self._edges[b]
        ca, cb = self.chart[self.pairs[e, 0]], self.chart[self.pairs[e, 1]]
        return e[((ca == a) & (cb == b)) | ((ca == b) & (cb == a))]

    def try_merge(self, a: int, b: int, record: MergeLog) -> bool:
        faces, corner_node, vertex, node_of, welded = self._union(a, b)
        points = self.positions[vertex]
        layout = None
        if self._absorbs(a, b, node_of, welded):
            absorbed = self._absorbed(a, b, corner_node, points, node_of)
            if absorbed is None:
                return False
            (uv, layout), how = absorbed, "absorbed"
        else:
            uv, how = self._flattened(points, corner_node)
            if uv is None:
                return False
        c = self.next_id
        self.next_id += 1
        del self.pieces[a], self.pieces[b], self.size[a], self.size[b]
        for gone in (a, b):
            self._layouts.pop(gone, None)
        self.pieces[c] = Piece(faces, corner_node, uv)
        if layout is not None:
            self._layouts[c] = layout
        self.size[c] = len(faces)
        self.chart[faces] = c
        self.row[faces] = np.arange(len(faces))
        record.merges += 1
        setattr(record, how, getattr(record, how) + 1)
        inherited = (self._failed.pop(a, set()) | self._failed.pop(b, set())) - {a, b}
        for y in inherited:  # the union keeps its parts' failures
            self._failed[y] -= {a, b}
            self._failed[y].add(c)
        if inherited:
            self._failed[c] = inherited
        near = np.union1d(self._edges.pop(a), self._edges.pop(b))
        ca, cb = self.chart[self.pairs[near, 0]], self.chart[self.pairs[near, 1]]
        touch = (ca == c) != (cb == c)
        self._edges[c] = near[touch]
        self._push(ca[touch], cb[touch], self.length[near[touch]])
        return True

    def _flattened(self, points: np.ndarray, corner_node: np.ndarray) -> tuple[np.ndarray | None, str]:
        """The union flattened afresh (its plane, else a least-squares conformal map) and how, or ``None``
        where neither is within the threshold without mirrored faces or overlaps."""
        tri3 = points[corner_node]
        cand = planar_projection(points, corner_node)
        if self._acceptable(tri3, cand[corner_node], self.threshold):
            return cand, "planar"
        if len(corner_node) > LSCM_MAX_FACES:
            return None, ""
        try:
            cand = lscm(points, corner_node)
        except (RuntimeError, ValueError, np.linalg.LinAlgError):
            return None, ""
        if np.isfinite(cand).all() and self._acceptable(tri3, cand[corner_node], self.threshold):
            return cand, "lscm"
        return None, ""

    def _layout(self, c: int) -> tuple[np.ndarray, bool, np.ndarray]:
        """Chart ``c``'s :func:`scantex.uv.param.stretch_sums`, whether it mirrors a face, and its faces' UV
        bounding boxes ``(n, 2, 2)`` (lower, upper corner); kept while its layout stands."""
        got = self._layouts.get(c)
        if got is None:
            p = self.pieces[c]
            tri_uv = p.node_uv[p.corner_node]
            sums, signed = stretch_sums(self.positions[self.faces[p.faces]], tri_uv)
            got = self._layouts[c] = (sums, bool((signed * _orientation(sums) < 0).any()),
                                      np.stack([tri_uv.min(axis=1), tri_uv.max(axis=1)], axis=1))
        return got

    def _absorbs(self, a: int, b: int, node_of: np.ndarray, welded: np.ndarray) -> bool:
        """Whether the union of ``a`` and ``b`` keeps the larger chart's layout (:meth:`_absorbed`): it is large
        (``absorb_faces``) and the seam joins none of its own nodes (which would close one of its cuts: the
        union is flattened afresh then)."""
        if self.absorb_faces is None or max(self.size[a], self.size[b]) < self.absorb_faces:
            return False
        na = len(self.pieces[a].node_uv)
        joined = welded[(welded < na) == (self.size[a] >= self.size[b])]  # the larger chart's nodes on the seam
        return np.unique(node_of[joined]).size == joined.size

    def _absorbed(self, a: int, b: int, corner_node: np.ndarray, points: np.ndarray, node_of: np.ndarray
                  ) -> tuple[np.ndarray, tuple] | None:
        """The union's node UVs with the larger chart's layout kept as it is and the smaller one's nodes placed
        around the nodes they now share (a least-squares conformal map pinned there), and the union's
        :meth:`_layout`; ``None`` where that is no chart: the larger chart mirrors a face, the smaller one
        shares fewer than two nodes with it, or the union mirrors a face, stretches beyond the threshold or
        overlaps itself where the smaller chart lies."""
        big = a if self.size[a] >= self.size[b] else b
        sums_big, mirrored, boxes_big = self._layout(big)
        if mirrored:
            return None
        na = len(self.pieces[a].node_uv)
        big_nodes = node_of[:na] if big == a else node_of[na:]
        uv = np.full((len(points), 2), np.nan)
        uv[big_nodes] = self.pieces[big].node_uv
        rows = np.arange(self.size[a], len(corner_node)) if big == a else np.arange(self.size[a])
        tris = corner_node[rows]
        nodes = np.unique(tris)
        pinned = nodes[np.isfinite(uv[nodes, 0])]
        if pinned.size < 2:
            return None
        if pinned.size < nodes.size:
            mirror = np.array([_orientation(sums_big), 1.0])  # the conformal map keeps faces' winding
            try:
                placed = lscm(points, tris, pins=(pinned, uv[pinned] * mirror)) * mirror
            except (RuntimeError, ValueError, np.linalg.LinAlgError):
                return None
            free = np.setdiff1d(nodes, pinned)
            uv[free] = placed[free]
        tri_uv = uv[tris]
        if not np.isfinite(tri_uv).all():
            return None
        sums, signed = stretch_sums(points[tris], tri_uv)
        sums = sums_big + sums
        orientation = _orientation(sums)
        if (orientation != _orientation(sums_big) or (signed * orientation < 0).any()
                or not stretch_of_sums(sums) <= self.threshold):
            return None
        # the larger chart passed this test when it was made: an overlap it lacked involves the smaller chart's
        # faces, so only the faces around those are rasterised, on the grid (and at the resolution) the whole
        # union would be
        lo, hi = tri_uv.reshape(-1, 2).min(axis=0), tri_uv.reshape(-1, 2).max(axis=0)
        near = np.flatnonzero((boxes_big[:, 1] >= lo).all(axis=1) & (boxes_big[:, 0] <= hi).all(axis=1))
        piece = self.pieces[big]
        texels = np.clip(8 * len(corner_node), 2048, 200_000)
        overlapped, _ = overlap_counts(np.concatenate([piece.node_uv[piece.corner_node[near]], tri_uv]),
                                       np.minimum(boxes_big[:, 0].min(axis=0), lo), np.sqrt(texels / sums[1]))
        if overlapped > self._tolerance * texels:
            return None
        boxes = np.stack([tri_uv.min(axis=1), tri_uv.max(axis=1)], axis=1)
        boxes = np.concatenate([boxes_big, boxes] if big == a else [boxes, boxes_big])
        return uv, (sums, False, boxes)

    def run(self, deadline: float, record: MergeLog, progress: Progress = None) -> list[Piece]:
        """Merge until no pair is left or ``deadline`` (``time.perf_counter()``) passes; the charts.
        ``progress`` hears the share of queued pairs settled, or of the time to the deadline used where that
        is further (a merge queues its union's pairs: the queue's length is only an estimate)."""
        start, popped, shown = time.perf_counter(), 0, 0.0
        while self.heap:
            now = time.perf_counter()
            if now > deadline:
                record.out_of_time = True
                break
            if progress is not None:  # never backwards: a merge lengthens the queue
                shown = max(shown, popped / (popped + len(self.heap)), (now - start) / max(deadline - start, 1e-9))
                progress(shown)
            _, a, b = heapq.heappop(self.heap)
            popped += 1
            if a not in self.pieces or b not in self.pieces:
                continue  # one of them was merged since this pair was queued
            record.attempts += 1
            if not self.try_merge(a, b, record) and not self.retry:
                self._failed.setdefault(a, set()).add(b)
                self._failed.setdefault(b, set()).add(a)
        return list(self.pieces.values())


def _orientation(sums: np.ndarray) -> float:
    """The side a chart faces in UV from its :func:`scantex.uv.param.stretch_sums`, as
    :func:`scantex.uv.param.distortions` takes it: +1 or -1 by its signed area (+1 without any)."""
    return -1.0 if sums[3] < 0 else 1.0
