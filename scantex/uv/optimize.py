"""The paper's UV optimisation: split shells that stretch too much, merge neighbours while a merged chart
stays under the threshold, so the atlas has fewer, larger charts and fewer seams.

Starting from the scan's own shells:

* **flatten again**: a shell whose L2 stretch exceeds the threshold (or that is mirrored in part, or
  overlaps itself) is first flattened again whole by a least-squares conformal map, and kept so (no new
  seam) where that passes: the app's own unwrapper often stretches charts a conformal map need not
  (57 of the facade's 73 such shells, 138 of the bathroom's 899);
* **split**: the others are replaced by normal-cone planar charts of their faces
  (:func:`scantex.uv.unwrap.planar_charts`, all at once, each shell's charts grown inside it);
* **merge**: shells are merged greedily, longest shared seam (in metres) first. The union is welded
  along the seam between the two shells only (other cuts stay cut), re-flattened by planar projection,
  else by a least-squares conformal map, and kept when it has no mirrored face, no overlap and stretch
  within the threshold (:class:`scantex.uv.merge.Merger`).

Geometry never changes; the result is a :class:`~scantex.uv.charts.Charts` for the packer.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field

import numpy as np

from scantex.arrays import uv_areas
from scantex.atlas.seams import texture_vertices, uv_shells
from scantex.scan import Scan
from scantex.uv.charts import Charts, Progress, assemble, compact, span
from scantex.uv.merge import LSCM_MAX_FACES, MergeLog, Merger, Piece
from scantex.uv.param import lscm
from scantex.uv.shells import texel_uvs
from scantex.uv.unwrap import (
    UnwrapLog,
    UnwrapOptions,
    acceptable,
    interior_edges,
    planar_charts,
)

log = logging.getLogger(__name__)


@dataclass
class OptimizeLog:
    """What the optimiser did (JSON-ready through ``as_dict``)."""

    shells_in: int = 0
    shells_reflattened: int = 0
    shells_split: int = 0
    charts_from_splits: int = 0
    merge: MergeLog = field(default_factory=MergeLog)
    fallbacks: list = field(default_factory=list)

    def as_dict(self) -> dict:
        return {**self.__dict__, "merge": self.merge.as_dict()}


def shell_pieces(scan: Scan, texture_size: int, equalise_density: bool) -> tuple[list[Piece], np.ndarray]:
    """The scan's shells as pieces in metres (texel coordinates over the shell's texel density, or over
    the median density to keep relative densities), and ``(S,)`` each shell's density in texels/m."""
    shells = uv_shells(scan)
    tex = texel_uvs(scan, texture_size)  # [F, 3, 2]
    S = int(shells.max()) + 1
    uv_area = uv_areas(tex)
    surface = np.bincount(shells, scan.face_areas, S)
    density = np.sqrt(np.divide(np.bincount(shells, uv_area, S), surface, out=np.zeros(S), where=surface > 0))
    common = float(np.median(density[density > 0])) if (density > 0).any() else 1.0
    key = texture_vertices(scan)  # the corners of a shell's faces meet at these (by value)
    order = np.argsort(shells, kind="stable")
    bounds = np.searchsorted(shells[order], np.arange(S + 1))
    pieces = []
    for s in range(S):
        faces = order[bounds[s]:bounds[s + 1]]
        corner_node, _ = compact(key[faces])
        node_uv = np.zeros((int(corner_node.max()) + 1, 2))
        node_uv[corner_node.ravel()] = tex[faces].reshape(-1, 2)
        scale = density[s] if equalise_density else common
        pieces.append(Piece(faces, corner_node, node_uv / (scale if scale > 0 else 1.0)))
    return pieces, density


def _reflattened(positions: np.ndarray, faces: np.ndarray, shell: Piece, triangles: np.ndarray,
                 threshold: float) -> Piece | None:
    """``shell`` flattened again whole by a least-squares conformal map (no new seam), or ``None`` where that
    still stretches beyond ``threshold``, mirrors a face or overlaps (the shell is split then)."""
    if len(shell.faces) > LSCM_MAX_FACES:
        return None
    node_vertex = np.zeros(len(shell.node_uv), np.int64)
    node_vertex[shell.corner_node.ravel()] = faces[shell.faces].ravel()
    try:
        uv = lscm(positions[node_vertex], shell.corner_node)
    except (RuntimeError, ValueError, np.linalg.LinAlgError):
        return None
    if not np.isfinite(uv).all() or not acceptable(triangles[shell.faces], uv[shell.corner_node], threshold):
        return None
    return Piece(shell.faces, shell.corner_node, uv)


def optimize(scan: Scan, options: UnwrapOptions | None = None, *, texture_size: int = 1024,
             equalise_density: bool = True, merge: bool = True, time_budget_s: float = 60.0,
             record: OptimizeLog | None = None, unwrap_record: UnwrapLog | None = None,
             progress: Progress = None) -> Charts:
    """Split and merge the scan's UV shells under ``options.threshold`` (see the module docstring);
    ``progress`` hears how far it has got (the merges are most of the time)."""
    if not scan.has_uvs:
        raise ValueError("optimising a UV layout needs UVs; unwrap the scan instead")
    start = time.perf_counter()
    options = options if options is not None else UnwrapOptions()
    record = record if record is not None else OptimizeLog()
    unwrap_record = unwrap_record if unwrap_record is not None else UnwrapLog()
    shells, _ = shell_pieces(scan, texture_size, equalise_density)
    record.shells_in = len(shells)
    tri3 = scan.triangles
    positions, faces = scan.welded_geometry()  # faces meet where their positions do, whatever the indices
    pairs, corners = interior_edges(faces)
    pieces: list[Piece] = []
    split: list[Piece] = []
    for k, p in enumerate(shells):
        if progress is not None:
            progress(0.05 * k / len(shells))
        if acceptable(tri3[p.faces], p.node_uv[p.corner_node], options.threshold):
            pieces.append(p)
            continue
        flat = _reflattened(positions, faces, p, tri3, options.threshold)
        if flat is not None:
            record.shells_reflattened += 1
            pieces.append(flat)
        else:
            split.append(p)
    if split:
        # every shell to split at once, growth kept inside its own shell (one pass over the mesh, not one a shell)
        shell_of = np.full(scan.n_faces, -1, np.int64)
        for k, p in enumerate(split):
            shell_of[p.faces] = k
        inside = (shell_of[pairs[:, 0]] >= 0) & (shell_of[pairs[:, 0]] == shell_of[pairs[:, 1]])
        parts = planar_charts(positions, faces, scan.face_normals, scan.face_areas, pairs[inside], options,
                              subset=np.concatenate([p.faces for p in split]), record=unwrap_record)
        record.shells_split += len(split)
        record.charts_from_splits += len(parts)
        pieces += [Piece(*part) for part in parts]
    if progress is not None:
        progress(0.05)
    if merge and len(pieces) > 1:
        merger = Merger(positions, faces, pieces, pairs, corners, options.threshold, retry=False)
        pieces = merger.run(start + time_budget_s, record.merge, span(progress, 0.05, 1.0))
        if record.merge.out_of_time:
            record.fallbacks.append(f"merging stopped at the {time_budget_s:g} s budget")
    log.info("UV optimisation: %d shells -> %d charts (%d split, %d merges of %d tried) in %.1f s",
             record.shells_in, len(pieces), record.shells_split, record.merge.merges, record.merge.attempts,
             time.perf_counter() - start)
    return assemble([(p.faces, p.corner_node, p.node_uv) for p in pieces], scan.n_faces)


def charts_distortion(scan: Scan, charts: Charts) -> list:
    """Distortion of every chart (in metres, before packing)."""
    return charts.distortions(scan.triangles)
