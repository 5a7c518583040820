"""The UV plan: keep the scan's layout, optimise its shells, or unwrap afresh; then pack one atlas.

:func:`plan_uvs` is the stage's entry point. Whatever the mode, ``positions`` and ``faces`` are the very
same arrays as the input's; only ``uvs``, ``face_uvs``, ``face_materials`` and ``materials`` change.

A new layout gets one material holding one square ``texture_size``² atlas whose image is all zeros
(``(S, S, 3) uint8``): a placeholder of the right size for :func:`scantex.atlas.bake.bake` (pass
``size=texture_size``) or :func:`scantex.uv.blend.transfer_texture` to fill.
"""

from __future__ import annotations

import dataclasses
import logging
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from scantex.scan import Material, Scan
from scantex.uv.charts import Charts, faces_apart, groups_apart, span
from scantex.uv.optimize import OptimizeLog, charts_distortion, optimize
from scantex.uv.pack import pack
from scantex.uv.param import overlapped_faces
from scantex.uv.shells import stats, summarise
from scantex.uv.unwrap import UnwrapLog, UnwrapOptions, unwrap

log = logging.getLogger(__name__)

MODES = ("keep", "optimize", "unwrap")
#: packings tried while faces share texels (the first moves them a group at a time, the others one by one)
MAX_REPACKS = 4


@dataclass(frozen=True, eq=False)
class UVPlan:
    """The scan with its planned UV layout, and what planning did.

    Attributes:
        scan: same ``positions`` and ``faces`` objects as the input; new ``uvs``, ``face_uvs``,
            ``face_materials`` and ``materials`` unless the layout was kept.
        report: JSON-ready: mode, shells and seam edges before and after, stretch and texel density
            (px/cm) statistics before and after, time taken, and what fell back to what.
    """

    scan: Scan
    report: dict


def _default_size(scan: Scan) -> int:
    sides = [max(m.image.shape[:2]) for m in scan.materials if m.image is not None]
    return int(max(sides)) if sides else 1024


def _atlas_material(scan: Scan, size: int) -> Material:
    """The new layout's one material: the input's when it has one, without its other maps (a normal or an
    occlusion map is drawn in the old layout, and scantex bakes colour only)."""
    image = np.zeros((size, size, 3), np.uint8)
    if len(scan.materials) == 1:
        return dataclasses.replace(scan.materials[0], image=image, maps={})
    return Material("atlas", image, diffuse=scan.materials[0].diffuse, image_name="atlas.png")


def _summary(scan: Scan, size: int) -> dict | None:
    s = summarise(scan, size)
    return None if s is None else s.as_dict()


def plan_uvs(scan: Scan, mode: str = "keep", *, threshold: float = 1.1, texture_size: int = 0,
             time_budget_s: float = 60.0, equalise_density: bool = True, seed: int = 0,
             gutter_texels: int = 4, max_angle_deg: float = 50.0, use_xatlas: bool = True,
             chart_unmapped: bool = True, progress: Callable[[int, int], None] | None = None) -> UVPlan:
    """Plan the texture layout of ``scan``.

    Args:
        scan: the input scan, with or without UVs.
        mode: ``"keep"`` the input layout; ``"optimize"`` it (split shells over ``threshold``, merge
            neighbours while under it, repack); ``"unwrap"`` afresh (planar charts plus xatlas for the
            curved leftovers). A scan without UVs is unwrapped whatever the mode (noted in the report).
        threshold: largest L2 stretch of a chart (1 = no distortion; 1.1 allows about 10 %).
        texture_size: side of the new square atlas in texels; 0 = the largest input image, else 1024.
        time_budget_s: wall-clock budget for merging (optimize) or for xatlas (unwrap); when it runs
            out the work done so far is used and the report says so.
        equalise_density: give every chart the same texels per metre (optimize; unwrap always does).
        seed: reserved for randomised tie-breaking; the planner is deterministic today.
        gutter_texels: empty texels kept around each chart in the atlas.
        max_angle_deg: widest normal cone of a planar chart.
        use_xatlas: hand the curved leftovers of an unwrap to xatlas (in a subprocess).
        chart_unmapped: keep: give the faces the input layout leaves no texture space (every UV corner on one
            point, or outside the atlas) a small chart each in free atlas space
            (:func:`scantex.uv.unmapped.chart_unmapped_faces`), every other face's UVs kept.
        progress: hears ``(done, 100)``: the percentage of the planning done (optimize's merges and unwrap's
            xatlas charting are most of it; packing the last 5 %).
    """
    if mode not in MODES:
        raise ValueError(f"mode must be one of {', '.join(MODES)}, got {mode!r}")
    if threshold < 1.0:
        raise ValueError(f"threshold is a stretch (>= 1, 1 = no distortion), got {threshold}")
    if texture_size < 0 or gutter_texels < 0:
        raise ValueError("texture_size and gutter_texels must not be negative")
    del seed
    start = time.perf_counter()
    size = int(texture_size) or _default_size(scan)
    report: dict = {"mode": mode, "threshold": threshold, "texture_size": size,
                    "equalise_density": equalise_density, "fallbacks": []}
    report["before"] = _summary(scan, size)
    if not scan.has_uvs and mode != "unwrap":
        report["fallbacks"].append(f"the scan has no UVs: {mode} fell back to unwrap")
        mode = "unwrap"
    report["mode_used"] = mode
    if mode == "keep":
        report["after"] = report["before"]
        kept = scan
        if chart_unmapped:
            from scantex.uv.unmapped import chart_unmapped_faces

            kept, unmapped = chart_unmapped_faces(scan, gutter_texels)
            if unmapped is not None:
                report["unmapped"] = unmapped
        report["time_s"] = time.perf_counter() - start
        if progress is not None:
            progress(100, 100)
        return UVPlan(kept, report)

    said = -1

    def percent(done: float) -> None:
        """``progress`` in whole percent, each said once."""
        nonlocal said
        value = min(99, int(100 * done))
        if value > said:
            said = value
            progress(value, 100)

    charting = span(percent if progress is not None else None, 0.0, 0.95)
    options = UnwrapOptions(threshold=threshold, max_angle_deg=max_angle_deg, xatlas=use_xatlas)
    unwrap_log = UnwrapLog()
    if mode == "optimize":
        optimize_log = OptimizeLog()
        charts = optimize(scan, options, texture_size=size, equalise_density=equalise_density,
                          time_budget_s=time_budget_s, record=optimize_log, unwrap_record=unwrap_log,
                          progress=charting)
        report["optimize"] = optimize_log.as_dict()
        report["fallbacks"] += optimize_log.fallbacks
    else:
        # on the distinct positions: a mesh that repeats a position per face (STL, some glTF and OBJ writers)
        # would otherwise have no edge two faces share, and every face would be a chart of its own
        positions, faces = scan.welded_geometry()
        charts = unwrap(positions, faces, options, time_budget_s=time_budget_s, record=unwrap_log,
                        progress=charting)
    report["unwrap"] = unwrap_log.as_dict()
    report["fallbacks"] += unwrap_log.fallbacks
    planned = _packed_scan(scan, charts, size, gutter_texels, report)
    report["after"] = _summary(planned, size)
    report["time_s"] = time.perf_counter() - start
    if progress is not None:
        progress(100, 100)
    log.info("UV plan (%s): %s -> %s shells in %.1f s", mode,
             report["before"]["shells"] if report["before"] else "-", report["after"]["shells"], report["time_s"])
    return UVPlan(planned, report)


def _packed_scan(scan: Scan, charts: Charts, size: int, gutter: int, report: dict) -> Scan:
    atlas = pack(charts, size, gutter)
    report["faces_apart"] = 0
    for attempt in range(MAX_REPACKS):
        # a chart folded onto itself (a merge, a flattening that passed its coarser overlap test) gives two
        # surfaces the same texels: its faces that share one on the atlas's own grid move to charts of their own,
        # first a group at a time (all but the largest group of each chart), then, if some still share, one by one
        shared = overlapped_faces(atlas.uvs[atlas.face_uvs] * size, size)
        if not shared.any():
            break
        charts = (groups_apart(charts, shared, *scan.welded_geometry()) if attempt == 0 else
                  faces_apart(charts, shared, scan.triangles))
        report["faces_apart"] += int(shared.sum())
        atlas = pack(charts, size, gutter)
    if report["faces_apart"]:
        log.info("UV plan: %d faces shared texels with others: moved to charts of their own (all but the largest "
                 "group of each chart)", report["faces_apart"])
    d = charts_distortion(scan, charts)
    report["chart_stretch"] = stats([x.stretch for x in d])
    report["texels_per_metre"] = atlas.texels_per_metre
    report["atlas_utilisation"] = atlas.utilisation
    report["images"] = f"zero placeholders ({size}, {size}, 3) uint8; bake(size={size}) fills them"
    dropped = scan.map_kinds
    if dropped:
        report["maps_left_out"] = dropped
        log.warning("%s: the input's %s maps are left out: they are drawn in the input's UV layout, not the new "
                    "one (--uv keep, the default, keeps them)", scan.source or "the scan",
                    " and ".join(k.replace("_", "-") for k in dropped))
    return scan.with_texture(atlas.uvs, atlas.face_uvs, (_atlas_material(scan, size),),
                             np.zeros(scan.n_faces, dtype=np.int32))
