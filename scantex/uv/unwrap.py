"""Unwrapping a LiDAR mesh afresh, within a time budget.

xatlas alone takes minutes to hours on large near-planar scans (642 s for an 80k-face noisy wall, over
20 min for a smooth one) and segfaults on some meshes. Most of a room or facade scan is nearly planar,
so this module:

1. grows charts over edge-connected faces whose normals stay within a cone around the chart's mean
   normal (the cone follows from the stretch threshold),
2. projects each chart onto its best-fit plane, which by the cone has no flipped faces and bounded
   stretch; a chart whose projection overlaps itself (a surface that folds back) is cut in two along
   its longest axis until none does,
3. merges tiny charts (outlier faces, slivers) into a neighbour where the union still flattens within
   the threshold (:class:`scantex.uv.merge.Merger`, under half the time budget),
4. hands the leftovers (many tiny charts: curved or very rough regions) to xatlas, one region per
   process, under the remaining time budget, keeping the tiny planar charts where xatlas fails or is late.

Scans without any UVs unwrap the same way: only positions and faces are used.
"""

from __future__ import annotations

import logging
import os
import subprocess
import sys
import tempfile
import time
from collections import deque
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from itertools import pairwise

import numpy as np

from scantex.uv.charts import Charts, Progress, assemble, compact, span
from scantex.uv.param import distortion, distortions, overlap_share, overlap_shares, planar_projection, \
    planar_projections

log = logging.getLogger(__name__)

#: a chart whose rasterised UV area is covered twice on more than this share overlaps itself
OVERLAP_TOLERANCE = 0.002


@dataclass(frozen=True)
class UnwrapOptions:
    """How :func:`unwrap` cuts the surface.

    Attributes:
        threshold: largest L2 stretch a chart may have (1 = no distortion).
        max_angle_deg: widest angle between a face normal and its chart's mean normal (the threshold may
            make it narrower).
        min_chart_faces: charts with fewer faces are leftovers handed to xatlas.
        xatlas: whether to use xatlas for the leftovers at all.
        xatlas_min_faces: leftover regions smaller than this keep their planar charts.
        xatlas_max_faces: leftover regions larger than this are not handed to xatlas (its time explodes).
        workers: xatlas processes run at once.
    """

    threshold: float = 1.1
    max_angle_deg: float = 50.0
    min_chart_faces: int = 12
    xatlas: bool = True
    xatlas_min_faces: int = 8
    xatlas_max_faces: int = 20_000
    workers: int = 2


@dataclass
class UnwrapLog:
    """What happened: counts, and what fell back to what (JSON-ready through ``as_dict``)."""

    planar_charts: int = 0
    overlap_splits: int = 0
    small_merged: int = 0
    leftover_regions: int = 0
    xatlas_regions: int = 0
    xatlas_charts: int = 0
    fallbacks: list = field(default_factory=list)

    def as_dict(self) -> dict:
        return dict(self.__dict__)


def interior_edges(faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Edges shared by exactly two faces: ``(E, 2)`` face pairs and ``(E, 2, 2)`` local corners.

    ``corners[e, s]`` are face ``s``'s local corners (0..2) of the edge's lower and higher vertex id,
    so both sides list the edge in the same vertex order (the layout of :class:`SeamEdges`).
    """
    F = len(faces)
    local = np.array([[0, 1], [1, 2], [2, 0]])
    a = faces[:, local[:, 0]].ravel()
    b = faces[:, local[:, 1]].ravel()
    lo, hi = np.minimum(a, b), np.maximum(a, b)
    face = np.repeat(np.arange(F), 3)
    ca, cb = np.tile(local[:, 0], F), np.tile(local[:, 1], F)
    c_lo, c_hi = np.where(a <= b, ca, cb), np.where(a <= b, cb, ca)
    order = np.lexsort((hi, lo))
    lo, hi, face, c_lo, c_hi = lo[order], hi[order], face[order], c_lo[order], c_hi[order]
    same = (lo[1:] == lo[:-1]) & (hi[1:] == hi[:-1])
    start = np.flatnonzero(same)
    if len(start):
        prev = np.concatenate([[False], same])[start]
        nxt = np.concatenate([same, [False]])[start + 1]
        start = start[~prev & ~nxt]
    i, j = start, start + 1
    pairs = np.stack([face[i], face[j]], axis=1)
    corners = np.stack([np.stack([c_lo[i], c_hi[i]], 1), np.stack([c_lo[j], c_hi[j]], 1)], axis=1)
    return pairs, corners


def neighbours(n_faces: int, pairs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """CSR ``(indptr, indices)`` of the face adjacency given by ``pairs (E, 2)``."""
    src = np.concatenate([pairs[:, 0], pairs[:, 1]])
    dst = np.concatenate([pairs[:, 1], pairs[:, 0]])
    order = np.argsort(src, kind="stable")
    indptr = np.searchsorted(src[order], np.arange(n_faces + 1))
    return indptr, dst[order]


def cone_angle(threshold: float, max_angle_deg: float) -> float:
    """Widest normal cone (radians) whose planar projection stays under the L2 ``threshold``.

    Projecting a face tilted by θ scales one direction by cos θ: L2 stretch ``sqrt((1 + c²) / (2c))``.
    """
    t2 = threshold ** 2
    c = t2 - np.sqrt(max(t2 * t2 - 1.0, 0.0))  # root of c² - 2 t² c + 1 = 0 in (0, 1]
    return float(min(np.arccos(np.clip(c, 0.0, 1.0)), np.radians(max_angle_deg)))


def grow_charts(normals: np.ndarray, areas: np.ndarray, indptr: np.ndarray, indices: np.ndarray,
                max_angle: float, faces: np.ndarray | None = None) -> np.ndarray:
    """``(F,)`` chart labels: breadth-first growth over neighbours within ``max_angle`` of the chart's
    running area-weighted mean normal. ``faces`` restricts growth to a subset (others get -1)."""
    F = len(normals)
    label = np.full(F, -1, dtype=np.int64)
    allowed = np.ones(F, bool) if faces is None else np.isin(np.arange(F), faces)
    cos_t = float(np.cos(max_angle))
    nx, ny, nz = (normals[:, k].tolist() for k in range(3))
    w = areas.tolist()
    ptr, nb = indptr.tolist(), indices.tolist()
    lab = label  # numpy writes per face are slow; keep a Python list and copy back
    lab_list = [-1] * F
    free = [bool(x) for x in allowed]
    n_charts = 0
    seeds = np.flatnonzero(allowed)
    # largest faces seed first: they are the least noisy normals
    seeds = seeds[np.argsort(-areas[seeds], kind="stable")].tolist()
    for seed in seeds:
        if not free[seed]:
            continue
        c = n_charts
        n_charts += 1
        free[seed] = False
        lab_list[seed] = c
        ax, ay, az = nx[seed] * w[seed], ny[seed] * w[seed], nz[seed] * w[seed]
        norm = (ax * ax + ay * ay + az * az) ** 0.5 or 1.0
        mx, my, mz = ax / norm, ay / norm, az / norm
        queue = deque([seed])
        while queue:
            f = queue.popleft()
            for g in nb[ptr[f]:ptr[f + 1]]:
                if free[g] and nx[g] * mx + ny[g] * my + nz[g] * mz >= cos_t:
                    free[g] = False
                    lab_list[g] = c
                    queue.append(g)
                    ax += nx[g] * w[g]
                    ay += ny[g] * w[g]
                    az += nz[g] * w[g]
                    norm = (ax * ax + ay * ay + az * az) ** 0.5 or 1.0
                    mx, my, mz = ax / norm, ay / norm, az / norm
    lab[:] = lab_list
    return lab


def _components(faces_sel: np.ndarray, pairs: np.ndarray, n_faces: int) -> list[np.ndarray]:
    """Edge-connected components of the faces ``faces_sel``."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    inside = np.zeros(n_faces, bool)
    inside[faces_sel] = True
    keep = inside[pairs[:, 0]] & inside[pairs[:, 1]]
    local = np.full(n_faces, -1, dtype=np.int64)
    local[faces_sel] = np.arange(len(faces_sel))
    p = local[pairs[keep]]
    n = len(faces_sel)
    graph = coo_matrix((np.ones(len(p)), (p[:, 0], p[:, 1])), shape=(n, n))
    k, lab = connected_components(graph, directed=False)
    order = np.argsort(lab, kind="stable")
    bounds = np.searchsorted(lab[order], np.arange(k + 1))
    return [faces_sel[order[a:b]] for a, b in pairwise(bounds)]


def flatten_planar(positions: np.ndarray, faces: np.ndarray, chart_faces: np.ndarray,
                   threshold: float) -> tuple[np.ndarray, np.ndarray] | None:
    """Planar projection of one chart as ``(corner_node (n, 3), node_uv (k, 2))`` in metres, or ``None``
    when it flips a face, overlaps itself or stretches more than ``threshold``."""
    corner_node, vertex = compact(faces[chart_faces])
    uv = planar_projection(positions[vertex], corner_node)
    if not acceptable(positions[vertex][corner_node], uv[corner_node], threshold):
        return None
    return corner_node, uv


def flatten_planar_all(positions: np.ndarray, faces: np.ndarray, charts: list[np.ndarray],
                       threshold: float) -> list[tuple[np.ndarray, np.ndarray] | None]:
    """:func:`flatten_planar` of every chart of ``charts`` (disjoint face sets), the same results without a
    call per chart (a fused room's 29,000 small charts took 46 s one by one)."""
    if not charts:
        return []
    sizes = np.array([len(c) for c in charts])
    chart_faces = np.concatenate(charts)
    chart_of_face = np.repeat(np.arange(len(charts)), sizes)
    # each chart's own nodes, numbered chart by chart in vertex order (as compact() numbers one chart's)
    V = int(faces.max()) + 1
    keys, inverse = np.unique(chart_of_face[:, None].astype(np.int64) * V + faces[chart_faces], return_inverse=True)
    inverse = inverse.reshape(-1, 3)
    chart_of_node, vertex = keys // V, keys % V
    first_node = np.searchsorted(chart_of_node, np.arange(len(charts)))
    uv = planar_projections(positions[vertex], inverse, chart_of_face, len(charts), chart_of_node)
    triangles_3d, triangles_uv = positions[vertex][inverse], uv[inverse]
    ok = np.array([np.isfinite(d.stretch) and d.stretch <= threshold and d.flipped_share <= 0
                   for d in distortions(triangles_3d, triangles_uv, chart_of_face, len(charts))])
    flat = ok[chart_of_face]
    shares = np.zeros(len(charts))
    shares[ok] = overlap_shares(triangles_uv[flat], np.searchsorted(np.flatnonzero(ok), chart_of_face[flat]),
                                int(ok.sum()))
    ok &= shares <= OVERLAP_TOLERANCE
    ends = np.concatenate([first_node[1:], [len(keys)]])
    face_start = np.concatenate([[0], np.cumsum(sizes)])
    return [(inverse[face_start[c]:face_start[c + 1]] - first_node[c], uv[first_node[c]:ends[c]]) if ok[c] else None
            for c in range(len(charts))]


def acceptable(triangles_3d: np.ndarray, triangles_uv: np.ndarray, threshold: float) -> bool:
    """A chart may be used: no mirrored faces, stretch within ``threshold``, no overlap."""
    d = distortion(triangles_3d, triangles_uv)
    if not np.isfinite(d.stretch) or d.stretch > threshold or d.flipped_share > 0:
        return False
    return overlap_share(triangles_uv) <= OVERLAP_TOLERANCE


def _bisect(positions: np.ndarray, faces: np.ndarray, chart_faces: np.ndarray,
            pairs: np.ndarray) -> list[np.ndarray]:
    """Cut a chart in two across its longest extent (by face centroid), as connected pieces."""
    centre = positions[faces[chart_faces]].mean(axis=1)
    centred = centre - centre.mean(axis=0)
    axis = np.linalg.svd(centred, full_matrices=False)[2][0]
    t = centred @ axis
    half = t > np.median(t)
    if half.all() or not half.any():
        half = np.arange(len(t)) >= len(t) // 2
    return (_components(chart_faces[half], pairs, len(faces))
            + _components(chart_faces[~half], pairs, len(faces)))


def planar_charts(positions: np.ndarray, faces: np.ndarray, face_normals: np.ndarray, face_areas: np.ndarray,
                  pairs: np.ndarray, options: UnwrapOptions, subset: np.ndarray | None = None,
                  record: UnwrapLog | None = None) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """Normal-cone charts of all faces (or ``subset``), each flattened by planar projection.

    Returns pieces ``(faces, corner_node, node_uv)`` (see :func:`scantex.uv.charts.assemble`). A single
    face always flattens, so every face ends in some chart.
    """
    record = record if record is not None else UnwrapLog()
    indptr, indices = neighbours(len(faces), pairs)
    labels = grow_charts(face_normals, face_areas, indptr, indices,
                         cone_angle(options.threshold, options.max_angle_deg), subset)
    sel = np.flatnonzero(labels >= 0)
    order = sel[np.argsort(labels[sel], kind="stable")]
    bounds = np.searchsorted(labels[order], np.arange(int(labels.max()) + 2))
    todo = [order[a:b] for a, b in pairwise(bounds) if b > a]
    pieces = []
    while todo:  # all charts at once, then the halves of those that failed (the order of a queue)
        cut = []
        for chart, flat in zip(todo, flatten_planar_all(positions, faces, todo, options.threshold)):
            if flat is not None or len(chart) == 1:
                if flat is None:  # a single degenerate face: any layout will do
                    corner_node, vertex = compact(faces[chart])
                    flat = corner_node, planar_projection(positions[vertex], corner_node)
                pieces.append((chart, *flat))
            else:
                record.overlap_splits += 1
                cut.extend(_bisect(positions, faces, chart, pairs))
        todo = cut
    record.planar_charts += len(pieces)
    return pieces


def _run_xatlas(positions: np.ndarray, faces: np.ndarray, timeout: float) -> tuple | None:
    """xatlas in a subprocess: ``(vmapping, indices, uvs)`` or ``None`` on timeout or crash."""
    with tempfile.TemporaryDirectory(prefix="scantex-xatlas-") as tmp:
        src, dst = os.path.join(tmp, "in.npz"), os.path.join(tmp, "out.npz")
        np.savez(src, positions=positions.astype(np.float32), faces=faces.astype(np.uint32))
        try:
            done = subprocess.run([sys.executable, "-m", "scantex.uv._xatlas_worker", src, dst],
                                  timeout=max(timeout, 0.1), capture_output=True, check=False)
        except subprocess.TimeoutExpired:
            return None
        if done.returncode != 0 or not os.path.exists(dst):
            log.warning("xatlas failed (exit %d): %s", done.returncode, done.stderr.decode(errors="replace")[-300:])
            return None
        out = np.load(dst)
        return out["vmapping"], out["indices"].reshape(-1, 3), out["uvs"]


def xatlas_pieces(positions: np.ndarray, faces: np.ndarray, region: np.ndarray,
                  result: tuple) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """xatlas's charts of ``region`` (faces in input order), each rescaled to metres."""
    from scantex.atlas.seams import uv_shells
    from scantex.scan import Scan

    _, indices, uvs = result
    corner_node, vertex = compact(faces[region])
    sub = Scan(positions[vertex], corner_node, uvs.astype(np.float64), indices.astype(np.int64))
    shells = uv_shells(sub)
    pieces = []
    for s in range(int(shells.max()) + 1):
        sel = np.flatnonzero(shells == s)
        nodes, uv_index = compact(indices[sel].astype(np.int64))
        uv = uvs[uv_index].astype(np.float64)
        d = distortion(sub.positions[corner_node[sel]], uv[nodes])
        if d.uv_area > 0:
            uv = uv * np.sqrt(d.surface_area / d.uv_area)
        pieces.append((region[sel], nodes, uv))
    return pieces


def unwrap(positions: np.ndarray, faces: np.ndarray, options: UnwrapOptions | None = None, *,
           time_budget_s: float = 60.0, record: UnwrapLog | None = None, progress: Progress = None) -> Charts:
    """Charts covering every face of the mesh, each within ``options.threshold`` stretch; ``progress`` hears
    how far it has got."""
    start = time.perf_counter()
    options = options if options is not None else UnwrapOptions()
    record = record if record is not None else UnwrapLog()
    tri = positions[faces]
    cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    area2 = np.linalg.norm(cross, axis=1)
    normals = np.divide(cross, area2[:, None], out=np.zeros_like(cross), where=area2[:, None] > 0)
    pairs, corners = interior_edges(faces)
    pieces = planar_charts(positions, faces, normals, 0.5 * area2, pairs, options, record=record)
    if progress is not None:
        progress(0.2)
    if any(len(p[0]) < options.min_chart_faces for p in pieces):
        from scantex.uv.merge import ABSORB_FACES, MergeLog, Merger, Piece

        merge_log = MergeLog()
        merger = Merger(positions, faces, [Piece(*p) for p in pieces], pairs, corners, options.threshold,
                        small_faces=options.min_chart_faces, absorb_faces=ABSORB_FACES)
        merged = merger.run(start + 0.5 * time_budget_s, merge_log, span(progress, 0.2, 0.5))
        pieces = [(p.faces, p.corner_node, p.node_uv) for p in merged]
        record.small_merged = merge_log.merges
        if merge_log.out_of_time:
            record.fallbacks.append("merging small charts stopped at half the time budget")

    small = [p for p in pieces if len(p[0]) < options.min_chart_faces]
    if not small or not options.xatlas:
        return assemble(pieces, len(faces))
    from scantex.deps import has_module, missing_message

    if not has_module("xatlas"):  # optional (the `unwrap` extra): the small planar charts are a valid layout
        message = (missing_message("xatlas", f"charting {sum(len(p[0]) for p in small)} faces in curved or rough "
                                   "regions") + "; they keep their small planar charts")
        log.warning(message)
        record.fallbacks.append(message)
        return assemble(pieces, len(faces))
    keep = [p for p in pieces if len(p[0]) >= options.min_chart_faces]
    leftover = np.concatenate([p[0] for p in small])
    regions = [r for r in _components(leftover, pairs, len(faces))]
    record.leftover_regions = len(regions)
    by_face = {int(p[0][0]): p for p in small}
    owner = np.full(len(faces), -1, dtype=np.int64)
    for p in small:
        owner[p[0]] = p[0][0]

    def planar_of(region):
        return [by_face[k] for k in np.unique(owner[region]).tolist()]

    # tiny regions gain nothing from xatlas; huge ones would not finish
    fits = [options.xatlas_min_faces <= len(r) <= options.xatlas_max_faces for r in regions]
    eligible = [r for r, ok in zip(regions, fits) if ok]
    out = [p for r, ok in zip(regions, fits) if not ok for p in planar_of(r)]
    if len(regions) - len(eligible):
        record.fallbacks.append(f"{len(regions) - len(eligible)} leftover regions kept as small planar "
                                f"charts (fewer than {options.xatlas_min_faces} or more than "
                                f"{options.xatlas_max_faces} faces)")
    deadline = start + time_budget_s

    def work(region):
        left = deadline - time.perf_counter()
        if left <= 0.5:
            return region, None
        return region, _run_xatlas(positions, faces[region], left)

    # largest first, so a late small region is what misses the deadline
    eligible.sort(key=len, reverse=True)
    missed: dict[str, list[int]] = {"failed or ran out of time": [], "overlapped": []}  # region sizes
    total, done = sum(len(r) for r in eligible), 0
    with ThreadPoolExecutor(max_workers=max(1, options.workers)) as pool:
        for region, result in pool.map(work, eligible):
            done += len(region)
            if progress is not None:
                progress(0.5 + 0.5 * done / total)
            got = xatlas_pieces(positions, faces, region, result) if result is not None else None
            if got is not None and all(acceptable(tri[p[0]], p[2][p[1]], np.inf) for p in got):
                out += got
                record.xatlas_regions += 1
                record.xatlas_charts += len(got)
            else:
                out += planar_of(region)
                missed["failed or ran out of time" if got is None else "overlapped"].append(len(region))
    # one line per outcome, not per region (a fused room has thousands of such regions)
    for why, sizes in missed.items():
        if sizes:
            what = (f"a {sizes[0]}-face region" if len(sizes) == 1 else
                    f"{len(sizes)} regions of {min(sizes)}-{max(sizes)} faces ({sum(sizes)} in all)")
            record.fallbacks.append(f"xatlas on {what} {why}: kept {'its' if len(sizes) == 1 else 'their'} "
                                    "small planar charts")
    return assemble(keep + out, len(faces))
