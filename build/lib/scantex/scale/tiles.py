"""One huge scan as overlapping spatial tiles, each enhanced as its own job, fused in the shared atlas.

The surface is cut along its two main directions (principal axes of the face centroids) into a grid of
cells holding about equal numbers of faces; each tile is a cell grown by ``overlap`` of its size on
every inner side. Every tile is enhanced on its own (``enhance`` is a black box here: it returns the
tile's geometry with an atlas baked in the input's own UV layout), on a local process pool or as Ray
tasks. The tiles' atlases are then fused texel by texel in that shared layout: a texel's weight in a
tile is a smoothstep ramp of its 3D surface point's position across each overlap (the weights of the
tiles sum to 1 everywhere, and each falls to 0, with zero slope, at its tile's edge), so there is no
line where one tile ends. Before fusing, each tile's overall colour can be levelled (a per-channel gain
fitted on the overlaps: each tile's field chose its own canonical exposure, the mean over its charts); off by
default, as it measured no better.

The output is the input's geometry, bit for bit, and its UV layout, with the fused atlas.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import socket
import time
import traceback
from dataclasses import dataclass

import numpy as np

from scantex.errors import ScanError
from scantex.pipeline.config import EnhanceConfig
from scantex.scale.executors import Job, LocalPool, WorkerLost
from scantex.scale.resources import GiB, estimate_memory, machine, peak_memory
from scantex.scan import Scan

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class TilingConfig:
    tiles: int = 0
    """tiles to cut the surface into (0: automatic, one per max_faces faces; 1: no tiling)"""
    max_faces: int = 1_000_000
    """automatic tiling: the most faces one tile should hold"""
    overlap: float = 0.15
    """overlap of neighbouring tiles on each side of their border, as a share of a tile's size"""
    harmonize: bool = False
    """level each tile's overall colour with a per-channel gain fitted on the overlaps before fusing (off: it
    cost 0.12 dB on the toy wall and did not change the steps at the borders; bench/bench_tiles.py)"""

    def count(self, n_faces: int) -> int:
        """The number of tiles for a scan of ``n_faces`` faces."""
        return self.tiles if self.tiles > 0 else max(1, math.ceil(n_faces / self.max_faces))


@dataclass(frozen=True, eq=False)
class TilePlan:
    """How a scan is cut into tiles.

    Attributes:
        origin: ``(3,)`` the centroid the tile coordinates are measured from.
        axes: ``(2, 3)`` unit vectors of the surface's two main directions.
        grid: ``(nx, ny)`` cells along the first and second axis.
        cells: per tile ``(s0, s1, t0, t1)``, its cell in tile coordinates (``±inf`` on the outer sides).
        margins: ``(2,)`` half-width of the overlap across borders along each axis (tile coordinates).
        faces: per tile, ``(n,) int64`` the faces it holds (centroid inside the grown cell).
        home: ``(F,) int32`` the tile whose cell holds each face's centroid.
    """

    origin: np.ndarray
    axes: np.ndarray
    grid: tuple[int, int]
    cells: np.ndarray
    margins: np.ndarray
    faces: list[np.ndarray]
    home: np.ndarray

    def __len__(self) -> int:
        return len(self.faces)

    def coords(self, points: np.ndarray) -> np.ndarray:
        """``(N, 3)`` points -> ``(N, 2)`` tile coordinates."""
        return (points - self.origin) @ self.axes.T

    def weights(self, tile: int, st: np.ndarray) -> np.ndarray:
        """``(N,)`` blending weight of ``tile`` at tile coordinates ``st (N, 2)``: 1 inside its cell away
        from borders, a smoothstep across each inner border (the neighbour's weight is 1 minus it)."""
        s0, s1, t0, t1 = self.cells[tile]
        w = np.ones(len(st))
        for lo, hi, m, x in ((s0, s1, self.margins[0], st[:, 0]), (t0, t1, self.margins[1], st[:, 1])):
            if np.isfinite(lo):
                w *= smoothstep((x - (lo - m)) / (2 * m))
            if np.isfinite(hi):
                w *= 1.0 - smoothstep((x - (hi - m)) / (2 * m))
        return w


def smoothstep(x: np.ndarray) -> np.ndarray:
    """``3x² - 2x³`` on ``[0, 1]``, clamped: ``s(x) + s(1 - x) = 1``, zero slope at both ends."""
    x = np.clip(x, 0.0, 1.0)
    return x * x * (3.0 - 2.0 * x)


def grid_shape(n: int, extent: tuple[float, float]) -> tuple[int, int]:
    """The factorisation ``nx * ny = n`` whose cells are closest to square on a surface of ``extent``."""
    best = None
    for nx in range(1, n + 1):
        if n % nx:
            continue
        ny = n // nx
        cost = abs(math.log(max(extent[0], 1e-12) / nx) - math.log(max(extent[1], 1e-12) / ny))
        if best is None or cost < best[0]:
            best = (cost, (nx, ny))
    return best[1]


def plan_tiles(scan: Scan, n: int, overlap: float = 0.15) -> TilePlan:
    """Cut ``scan`` into ``n`` overlapping tiles with about equal face counts (see the module docstring)."""
    if n < 1:
        raise ValueError(f"the number of tiles must be at least 1, got {n}")
    centroids = scan.triangles.mean(axis=1)  # [F, 3]
    areas = scan.face_areas
    origin = np.average(centroids, axis=0, weights=areas + 1e-30)
    centred = centroids - origin
    cov = (centred * (areas + 1e-30)[:, None]).T @ centred
    _, vectors = np.linalg.eigh(cov)
    axes = vectors[:, ::-1][:, :2].T.copy()  # the two largest directions, [2, 3]
    st = centred @ axes.T  # [F, 2]
    extent = np.ptp(st, axis=0)
    nx, ny = grid_shape(n, (float(extent[0]), float(extent[1])))
    # k-d cut at face-count quantiles: slabs along the first axis, cells along the second within each
    s_cuts = np.quantile(st[:, 0], np.linspace(0, 1, nx + 1)[1:-1]) if nx > 1 else np.array([])
    s_edges = np.concatenate([[-np.inf], s_cuts, [np.inf]])
    cells, home = [], np.zeros(len(st), np.int32)
    for i in range(nx):
        in_slab = (st[:, 0] >= s_edges[i]) & (st[:, 0] < s_edges[i + 1])
        t = st[in_slab, 1]
        t_cuts = np.quantile(t, np.linspace(0, 1, ny + 1)[1:-1]) if ny > 1 and t.size else np.array([])
        t_edges = np.concatenate([[-np.inf], t_cuts, [np.inf]])
        for j in range(ny):
            cell = (s_edges[i], s_edges[i + 1], t_edges[j], t_edges[j + 1])
            home[in_slab & (st[:, 1] >= cell[2]) & (st[:, 1] < cell[3])] = len(cells)
            cells.append(cell)
    cells = np.array(cells, np.float64)
    # overlap: a share of the smallest cell's size along each axis (finite cells only)
    sizes = []
    for a, b, ext, k in ((0, 1, extent[0], nx), (2, 3, extent[1], ny)):
        width = cells[:, b] - cells[:, a]
        finite = width[np.isfinite(width)]
        sizes.append(finite.min() if finite.size else ext / k)
    margins = overlap * np.array(sizes, np.float64)
    plan = TilePlan(origin, axes, (nx, ny), cells, np.maximum(margins, 1e-12), [], home)
    faces = []
    for k, (s0, s1, t0, t1) in enumerate(cells):
        m0, m1 = plan.margins
        inside = ((st[:, 0] >= s0 - m0) & (st[:, 0] < s1 + m0) & (st[:, 1] >= t0 - m1) & (st[:, 1] < t1 + m1))
        faces.append(np.flatnonzero(inside | (home == k)))
    return TilePlan(origin, axes, (nx, ny), cells, plan.margins, faces, home)


def tile_scan(scan: Scan, faces: np.ndarray) -> Scan:
    """The part of ``scan`` made of ``faces``: their vertices re-indexed, the UVs, materials and atlases
    shared (the tile bakes into the same layout)."""
    used, inverse = np.unique(scan.faces[faces], return_inverse=True)
    sub = dict(positions=scan.positions[used], faces=inverse.reshape(-1, 3),
               face_materials=scan.face_materials[faces], materials=scan.materials, source=scan.source)
    if scan.has_uvs:
        sub.update(uvs=scan.uvs, face_uvs=scan.face_uvs[faces])
    if scan.vertex_colors is not None:
        sub["vertex_colors"] = scan.vertex_colors[used]
    if scan.face_colors is not None:
        sub["face_colors"] = scan.face_colors[faces]
    return Scan(**sub)


def enhance_tile(index: int, sub: Scan, config: dict, threads: int) -> dict:
    """Enhance one tile (a worker's job; never raises): its atlas images and what it cost."""
    t0 = time.perf_counter()
    try:
        import torch

        from scantex.pipeline.enhance import enhance

        torch.set_num_threads(threads)
        result = enhance(sub, EnhanceConfig.from_dict(config).override(threads=threads))
        m = result.metrics
        return {"index": index, "images": tuple(mat.image for mat in result.scan.materials),
                "uv_identical": bool(np.array_equal(result.scan.uvs, sub.uvs)
                                     and np.array_equal(result.scan.face_uvs, sub.face_uvs)),
                "faces": sub.n_faces, "seconds": round(time.perf_counter() - t0, 2), "host": socket.gethostname(),
                "peak_memory_gib": round(peak_memory() / GiB, 3),
                "held_out_vs_input": m.get("held_out_vs_input", {}).get("enhanced")}
    except ScanError as e:
        return {"index": index, "error": str(e)}
    except Exception as e:
        return {"index": index, "error": f"internal error: {type(e).__name__}: {e}".splitlines()[0],
                "traceback": traceback.format_exc()}


def tile_gains(plan: TilePlan, colours: list[np.ndarray], weights: list[np.ndarray], holds: list[np.ndarray]
               ) -> np.ndarray:
    """``(T, 3)`` per-tile per-channel gains that make the tiles agree on their overlaps.

    ``colours[t]``: ``(N, 3)`` tile ``t``'s colour at every covered texel; ``weights[t]``: ``(N,)`` its
    blending weights; ``holds[t]``: ``(N,) bool`` texels of faces it holds. For every pair of tiles that
    share texels, ``log g_t - log g_u = log mean_u - log mean_t`` (means over the shared texels), weighted
    by the square root of their count; the gains' geometric mean (weighted by each tile's texels) is 1.
    """
    T = len(colours)
    rows, rhs, wts = [], [], []
    share = np.array([float(((w > 0) & h).sum()) for w, h in zip(weights, holds)])
    for t in range(T):
        for u in range(t + 1, T):
            both = holds[t] & holds[u] & (weights[t] > 0) & (weights[u] > 0)
            n = int(both.sum())
            if n < 16:
                continue
            mt = colours[t][both].mean(axis=0)
            mu = colours[u][both].mean(axis=0)
            row = np.zeros(T)
            row[t], row[u] = 1.0, -1.0
            rows.append(row)
            rhs.append(np.log(np.maximum(mu, 1e-3)) - np.log(np.maximum(mt, 1e-3)))
            wts.append(math.sqrt(n))
    if not rows:
        return np.ones((T, 3))
    A = np.array(rows) * np.array(wts)[:, None]
    b = np.array(rhs) * np.array(wts)[:, None]
    anchor = share / max(share.sum(), 1.0)
    big = 1e3 * max(wts)
    A = np.vstack([A, big * anchor])
    b = np.vstack([b, np.zeros((1, 3))])
    x, *_ = np.linalg.lstsq(A, b, rcond=None)
    return np.exp(x)


def fuse_tiles(scan: Scan, plan: TilePlan, tile_images: list[tuple], harmonize: bool = False
               ) -> tuple[tuple[np.ndarray | None, ...], dict]:
    """Fuse the tiles' atlases into one per material (see the module docstring).

    Args:
        scan: the whole scan (its UV layout is every tile's).
        plan: the tiling.
        tile_images: per tile, its ``(H, W, 3) uint8`` image per material (``None`` where it has no faces
            of that material).
        harmonize: level the tiles' colours first (:func:`tile_gains`).

    Returns:
        ``(images, report)``: one fused ``(H, W, 3) uint8`` image per material (``None`` for materials
        no tile baked), gutters padded; the report holds the gains per tile.
    """
    from scantex.atlas.padding import pad_gutters
    from scantex.atlas.texelmap import texel_map
    from scantex.views.render import to_uint8

    corners = scan.triangles
    T = len(plan)
    holds_face = np.zeros((T, scan.n_faces), bool)
    for t, f in enumerate(plan.faces):
        holds_face[t, f] = True
    fused_images, gains_all = [], []
    for m in range(len(scan.materials)):
        sizes = {img[m].shape[:2] for img in tile_images if img[m] is not None}
        faces = np.flatnonzero(scan.face_materials == m)
        if not sizes or faces.size == 0:
            fused_images.append(None)
            continue
        if len(sizes) > 1:
            raise ValueError(f"the tiles baked material {m} at different sizes: {sorted(sizes)}")
        (H, W), = sizes
        tmap = texel_map(scan.triangle_uvs, W, H, faces)
        covered = tmap.mask
        face_of = tmap.face_id[covered]
        st = plan.coords(tmap.points(corners))  # [N, 2]
        colours, weights, holds = [], [], []
        for t in range(T):
            image = tile_images[t][m]
            hold = holds_face[t, face_of]
            w = np.where(hold, plan.weights(t, st), 0.0) if image is not None else np.zeros(len(st))
            colours.append(image[covered].astype(np.float32) / 255.0 if image is not None
                           else np.zeros((len(st), 3), np.float32))
            weights.append(w)
            holds.append(hold & (image is not None))
        gains = tile_gains(plan, colours, weights, holds) if harmonize and T > 1 else np.ones((T, 3))
        total = np.zeros(len(st))
        acc = np.zeros((len(st), 3), np.float32)
        for t in range(T):
            acc += (weights[t][:, None] * np.clip(colours[t] * gains[t].astype(np.float32), 0, 1)).astype(np.float32)
            total += weights[t]
        # texels whose point no tile's weight reaches (a face larger than the overlap): its home tile's colour
        orphan = total <= 1e-9
        if orphan.any():
            home = plan.home[face_of[orphan]]
            idx = np.flatnonzero(orphan)
            for t in np.unique(home):
                sel = idx[home == t]
                acc[sel] = np.clip(colours[t][sel] * gains[t].astype(np.float32), 0, 1)
                total[sel] = 1.0
        image = np.zeros((H, W, 3), np.float32)
        image[covered] = acc / total[:, None].astype(np.float32)
        fused_images.append(to_uint8(pad_gutters(image, covered)))
        gains_all.append(gains)
    report = {"gains": [np.round(g, 4).tolist() for g in gains_all]}
    return tuple(fused_images), report


def enhance_tiled(scan: Scan, config: EnhanceConfig = EnhanceConfig(), tiling: TilingConfig = TilingConfig(tiles=4),
                  *, ground_truth: Scan | None = None, runner=None, reporter=None):
    """Enhance ``scan`` as overlapping tiles (one job each on ``runner``) and fuse them.

    Args:
        scan: a textured scan with UVs (the tiles share its UV layout, which is kept).
        config: the enhance settings of every tile (``uv.mode`` must be ``keep``).
        tiling: how many tiles, their overlap, colour levelling.
        ground_truth: the true texture on the same geometry, if known: the whole result is scored on it.
        runner: where the tiles run (:class:`scantex.scale.executors.LocalPool` by default, or
            :class:`scantex.scale.executors.RayCluster`).
        reporter: progress (see :class:`scantex.pipeline.enhance.Reporter`).

    Returns:
        An :class:`scantex.pipeline.enhance.EnhanceResult` (its metrics hold a ``tiles`` section); the
        scan's positions and faces are the input's own arrays.
    """
    from scantex.pipeline.enhance import Reporter

    reporter = reporter or Reporter()
    if ground_truth is not None and (ground_truth.positions.shape != scan.positions.shape
                                     or ground_truth.faces.shape != scan.faces.shape):
        raise ScanError(ground_truth.source, "the ground truth does not have the scan's geometry")
    if not scan.is_textured:
        raise ScanError(scan.source, "tiled enhancement needs a textured scan with UVs (the tiles share its layout)")
    if config.uv.mode != "keep":
        raise ScanError(scan.source, f"tiled enhancement keeps the input's UV layout; uv.mode '{config.uv.mode}' "
                                     "is not supported with tiles")
    n = tiling.count(scan.n_faces)
    runner = runner or LocalPool()
    timings: dict[str, float] = {}
    t = time.perf_counter()
    plan = plan_tiles(scan, n, tiling.overlap)
    subs = [tile_scan(scan, f) for f in plan.faces]
    timings["tiling"] = time.perf_counter() - t
    log.info("%d tiles (%d x %d), faces per tile %s", n, *plan.grid, [len(f) for f in plan.faces])

    t = time.perf_counter()
    with reporter.stage(f"enhancing {n} tiles ({runner.name})") as update:
        outputs = run_tiles(scan, plan, subs, config, runner, update)
    timings["tiles"] = time.perf_counter() - t
    return assemble_tiles(scan, plan, outputs, config, tiling, runner.name, timings,
                          ground_truth=ground_truth, reporter=reporter)


def run_tiles(scan: Scan, plan: TilePlan, subs: list[Scan], config: EnhanceConfig, runner, update=None
              ) -> list[dict]:
    """Enhance every tile ``subs[k]`` as a job on ``runner``; their outputs (see :func:`enhance_tile`) in
    tile order. Raises :class:`ScanError` naming the first tile that failed."""
    n = len(subs)
    cores = machine().cores
    workers = getattr(runner, "workers", None) or cores
    threads = max(1, cores // min(workers, n)) if isinstance(runner, LocalPool) else max(1, config.threads or 1)
    cfg = config.to_dict()
    texels = sum(int(np.prod(m.image.shape[:2])) for m in scan.materials if m.image is not None)
    out_texels = (config.bake.texture_size ** 2) if config.bake.texture_size else min(4 * texels, 8192 ** 2)
    jobs = [Job(f"tile {k}", enhance_tile, (k, sub, cfg, threads), memory=estimate_memory(sub.n_faces, out_texels),
                cpus=threads, gpus=1.0 if config.device == "cuda" else 0.0) for k, sub in enumerate(subs)]
    outputs: list[dict | None] = [None] * n
    if update:
        update(0, n)
    for done, (job, out) in enumerate(runner.run(jobs), 1):
        if isinstance(out, WorkerLost):
            out = {"index": job.args[0], "error": out.message}
        if "error" in out:
            raise ScanError(scan.source, f"tile {out['index']} of {n} failed: {out['error']}")
        outputs[out["index"]] = {**out, "threads": threads}
        if update:
            update(done, n)
    return outputs


def assemble_tiles(scan: Scan, plan: TilePlan, outputs: list[dict], config: EnhanceConfig, tiling: TilingConfig,
                   executor: str, timings: dict, *, ground_truth: Scan | None = None, reporter=None):
    """Fuse the tiles' outputs into the whole scan's result and measure it (see :func:`enhance_tiled`)."""
    from scantex.pipeline.enhance import EnhanceResult, Reporter

    reporter = reporter or Reporter()
    timings = dict(timings)
    n = len(outputs)
    if not all(o["uv_identical"] for o in outputs):
        raise ScanError(scan.source, "a tile's enhance changed the UV layout; tiles can only be fused in a shared one")

    t = time.perf_counter()
    with reporter.stage("fusing the tiles") as update:
        images, fuse_report = fuse_tiles(scan, plan, [o["images"] for o in outputs], tiling.harmonize)
        materials = tuple(m if img is None else dataclasses.replace(
            m, image=img, image_name=f"enhanced_{m.name}.png", diffuse=(1.0, 1.0, 1.0, m.diffuse[3]))
            for m, img in zip(scan.materials, images))
        fused = scan.replace(materials=materials, source=None)
        if config.uv.blend_seams:
            from scantex.uv import blend_seams

            fused = blend_seams(fused, band_texels=config.uv.band_texels)
        update(1, 1)
    timings["fuse"] = time.perf_counter() - t

    t = time.perf_counter()
    with reporter.stage("measuring") as update:
        views, metrics = measure_whole(scan, fused, ground_truth, config)
        update(1, 1)
    timings["metrics"] = time.perf_counter() - t
    metrics["tiles"] = {
        "count": n, "grid": list(plan.grid), "overlap": tiling.overlap, "harmonize": tiling.harmonize,
        "executor": executor, "threads_per_tile": outputs[0]["threads"], **fuse_report,
        "per_tile": [{k: o[k] for k in ("faces", "seconds", "peak_memory_gib", "host", "held_out_vs_input")}
                     for o in outputs]}
    metrics["timings_s"] = {k: round(v, 2) for k, v in timings.items()}
    metrics["timings_s"]["total"] = round(sum(timings.values()), 2)
    return EnhanceResult(fused, metrics, config, views, input_scan=scan, ground_truth=ground_truth)


def measure_whole(scan: Scan, enhanced: Scan, ground_truth: Scan | None, config: EnhanceConfig):
    """Views of the whole scan planned as ``enhance`` plans them (same seed, so the same held-out
    cameras), and the result's metrics on them: geometry identity, seam visibility, held-out scores."""
    from scantex.atlas.holes import untextured_faces
    from scantex.atlas.seams import seam_visibility
    from scantex.metrics.geometry import geometry_metrics
    from scantex.metrics.views import score_views
    from scantex.pipeline.enhance import render_training_views, up_axis
    from scantex.views.planning import add_views_for_coverage, plan_views
    from scantex.views.raycast import RayCaster
    from scantex.views.render import render

    vc = config.views
    caster = RayCaster(scan.positions, scan.faces)
    up = up_axis(scan, vc.up)
    cameras = plan_views(scan, vc.n_views, mode=vc.mode, width=vc.width, height=vc.height, fov_deg=vc.fov_deg,
                         seed=config.seed, up=up, caster=caster)
    if vc.adaptive:
        cameras = add_views_for_coverage(scan, cameras, min_views=2, max_new=max(2, vc.n_views // 4), up=up,
                                         seed=config.seed, caster=caster)
    holes = untextured_faces(scan)
    views = render_training_views(scan, cameras, np.ones(scan.n_faces, bool), vc.supersample, caster,
                                  vc.test_fraction, config.seed, lambda done, total: None)
    metrics: dict = {
        "geometry": geometry_metrics(scan, enhanced),
        "input": {"vertices": scan.n_vertices, "faces": scan.n_faces, "hole_faces": int(holes.sum())},
        "views": {"total": len(views.views), "test": len(views.views.test)},
        "seam_visibility": {"input": round(seam_visibility(scan), 3), "enhanced": round(seam_visibility(enhanced), 3)},
    }
    test = [views.views.cameras[i] for i in views.views.test]
    if ground_truth is not None:
        metrics["held_out_vs_ground_truth"] = score_views(
            lambda cam: render(ground_truth, cam, caster, supersample=2), {"input": scan, "enhanced": enhanced},
            test, caster, holes)
    else:
        metrics["held_out_vs_input"] = score_views(
            lambda cam: render(scan, cam, caster, supersample=2), {"enhanced": enhanced}, test, caster, holes)
    return views, metrics
