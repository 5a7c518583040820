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

With photos (photo mode), what concerns the whole capture is done once, before the tiles, on the whole scan:
the alignment check, the split into training and held-out photos, each training photo's pose refinement
against the input texture (``photos.refine_poses`` ``input``: a photo seen by two tiles has one pose in both),
and for each training photo one ray cast at its working size, which says the tiles it sees, the pixels where
another tile's surface is in front (``PhotoSet.hidden``: a tile does not have its neighbours' geometry, and
would take their colours for its own) and whether its depth map is of its view (``PhotoSet.depth_factors``: a
tile sees too little of a photo to judge it). Each tile is textured from the training photos that see it and
holds nothing out; its photos are levelled onto the input texture's appearance, which all tiles share. The
held-out photos score the fused result, input against output, as ``enhance`` scores its own.

An untextured scan has no layout to share: one is made for the whole scan before the tiles. A scan with vertex
colours (a fused RGB-D mesh) has them baked into a texture first, as ``enhance`` does, and is then tiled as a
textured scan. A bare mesh with photos is unwrapped whole at the atlas size its photos call for (``enhance``'s
rule, from the photos' pixels per centimetre measured by the same ray casts), and each tile textures its part of
that layout from the photos, as an untiled run textures a bare mesh (its poses refined among the tile's photos,
``consensus``, as an untiled run of fewer than 50 photos does).

The output is the input's geometry, bit for bit, and its UV layout (or the one made for it), with the fused atlas.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import socket
import time
import traceback
from dataclasses import dataclass, field

import numpy as np

from scantex.errors import ScanError
from scantex.photos.photoset import PhotoSet
from scantex.pipeline.config import EnhanceConfig, TilingConfig
from scantex.scale.executors import Job, LocalPool, WorkerLost
from scantex.scale.resources import GiB, estimate_memory, machine, peak_memory, photo_memory
from scantex.scan import Scan, up_axis

log = logging.getLogger(__name__)


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

    def holds(self) -> np.ndarray:
        """``(T, F) bool``: whether each tile holds each face (its cell's and its overlaps')."""
        holds = np.zeros((len(self.faces), len(self.home)), bool)
        for t, faces in enumerate(self.faces):
            holds[t, faces] = True
        return holds

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
    shared (the tile bakes into the same layout). The materials' other maps stay with the whole scan: a
    tile's job changes colour only."""
    used, inverse = np.unique(scan.faces[faces], return_inverse=True)
    materials = scan.materials
    if any(m.maps for m in materials):
        materials = tuple(dataclasses.replace(m, maps={}) for m in materials)
    sub = dict(positions=scan.positions[used], faces=inverse.reshape(-1, 3),
               face_materials=scan.face_materials[faces], materials=materials, source=scan.source, up=scan.up)
    if scan.has_uvs:
        sub.update(uvs=scan.uvs, face_uvs=scan.face_uvs[faces])
    if scan.vertex_colors is not None:
        sub["vertex_colors"] = scan.vertex_colors[used]
    if scan.face_colors is not None:
        sub["face_colors"] = scan.face_colors[faces]
    return Scan(**sub)


@dataclass(frozen=True, eq=False)
class TilePhotos:
    """Photo mode over tiles: what is done once for the whole capture (see the module docstring).

    Attributes:
        photos: the capture, its training photos' poses refined when the run refines them.
        train: the training photos' indices (into ``photos``).
        held_out: the held-out photos' indices: they score the fused result.
        per_tile: per tile, the training photos that see it.
        hidden: per tile, ``{photo: packed (h, w) mask}`` of the pixels another tile's surface takes
            (:func:`numpy.packbits` of the rows; photos without any are left out).
        depth_factors: ``{photo: factor}``, each training photo's depth map judged against the whole scan
            (:func:`scantex.photos.training.depth_factor`; 0: not of its view, set aside).
        pose_mode: the pose refinement applied (``off``, ``input``; ``consensus`` is left to each tile).
        corrections: the training photos' pose corrections (``input`` mode).
        alignment: the alignment check's report (``None`` when it was skipped).
        px_per_cm: how finely the training photos resolve the surface (:func:`scantex.pipeline.enhance.photo_density`'s
            measure, from the ray casts of :func:`tiles_seen`).
        left_out: the photos left out as not showing what their cameras see
            (:func:`scantex.photos.matching.leave_out_mismatched`).
        repeated: the photos given way to a sharper one whose view they repeat (``photos.keyframes``).
    """

    photos: PhotoSet
    train: np.ndarray
    held_out: np.ndarray
    per_tile: list[np.ndarray]
    hidden: list[dict]
    depth_factors: dict
    pose_mode: str
    corrections: list
    alignment: object | None
    px_per_cm: float = 0.0
    left_out: list = field(default_factory=list)
    repeated: list = field(default_factory=list)

    def for_tile(self, tile: int) -> PhotoSet | None:
        """Tile ``tile``'s training photos, their pixels that other tiles hide masked (``None``: no photo sees
        it, the tile keeps the input's texels)."""
        if not len(self.per_tile[tile]):
            return None
        masks = []
        for i in self.per_tile[tile]:
            packed = self.hidden[tile].get(int(i))
            masks.append(None if packed is None else
                         np.unpackbits(packed[0], axis=1, count=packed[1]).astype(bool))
        subset = self.photos.subset(self.per_tile[tile])
        # a map judged not of its photo's view is set aside (no factor); a photo without a map has none either
        factors = tuple(self.depth_factors.get(int(i)) for i in self.per_tile[tile])
        depths = tuple(None if f is None else d for f, d in zip(factors, subset.depths))
        return dataclasses.replace(subset, hidden=tuple(masks), depths=depths, depth_factors=factors,
                                   numbers=tuple(int(i) for i in self.per_tile[tile]))

    def tile_config(self, config: EnhanceConfig) -> EnhanceConfig:
        """``config`` as each tile applies it: nothing held out, no alignment check, the poses as refined here, the
        fine detail, the depth gaps and the photo pairs chosen for the whole capture (a tile sees a part of its
        photos)."""
        from scantex.pipeline.enhance import depth_gaps_mode, detail_mode, pairs_mode

        n = len(self.photos)
        return config.override(photos__holdout=0, photos__check_alignment=False, photos__final="training",
                               photos__refine_poses="consensus" if self.pose_mode == "consensus" else "off",
                               photos__detail=detail_mode(config.photos.detail, n),
                               photos__depth_gaps=depth_gaps_mode(config.photos.depth_gaps, n),
                               photos__pairs=pairs_mode(config.photos.pairs, n))


def photos_for_tiles(scan: Scan, plan: TilePlan, photos: PhotoSet, config: EnhanceConfig, caster,
                     update=None) -> TilePhotos:
    """The whole capture's part of tiled photo mode (see the module docstring): the alignment check (refuses
    a mesh out of the cameras' frame), the held-out split less the photos that do not show what their cameras see,
    the input-texture pose refinement, and which training photos see each tile."""
    from functools import partial

    from scantex.photos.poses import refine_poses
    from scantex.pipeline.enhance import checked_split, pose_refinement_mode
    from scantex.views.render import shade_hits

    pc = config.photos
    report, train, held, left_out, repeated = checked_split(scan, photos, pc, caster, config.seed)
    mode = pose_refinement_mode(pc.refine_poses, scan, len(photos))
    corrections: list = []
    # the stage's progress counts the training photos refined (input mode), then each one cast
    steps = 2 * len(train) if mode == "input" else len(train)
    if mode == "input":
        photos, corrections = refine_poses(scan, photos, train, partial(shade_hits, scan), caster,
                                           update=update and (lambda done, total: update(done, steps)))
    first = steps - len(train)
    per_tile, hidden, factors, density = tiles_seen(scan, plan, photos, train, caster, pc.max_side,
                                                    pc.depth_tolerance,
                                                    update and (lambda done, total: update(first + done, steps)))
    log.info("photos per tile: %s", [len(p) for p in per_tile])
    return TilePhotos(photos, train, held, per_tile, hidden, factors, mode, corrections, report, density, left_out,
                      repeated)


def tiles_seen(scan: Scan, plan: TilePlan, photos: PhotoSet, indices, caster, max_side: int,
               depth_tolerance: float = 0.05, update=None) -> tuple[list[np.ndarray], list[dict], dict, float]:
    """Per tile, the photos of ``indices`` that see any of its faces; in each, the pixels another tile's
    surface takes (``{photo: (packed rows, width)}``); each photo's depth map judged against the whole
    scan (see :class:`TilePhotos`); and how finely the photos resolve the surface (the median over the photos of
    their surface pixels' median full-resolution pixels per centimetre): each photo ray-cast against the whole
    scan at its working size (``max_side``), the nearest surface at each pixel's centre. ``update(done, total)``:
    progress, in photos."""
    from scipy import ndimage

    from scantex.photos.training import depth_factor, resize_depth, working_camera
    from scantex.pipeline.enhance import photo_px_per_cm
    from scantex.views.raycast import cast_gbuffer

    holds = plan.holds()
    seen: list[list[int]] = [[] for _ in range(len(plan))]
    hidden: list[dict] = [{} for _ in range(len(plan))]
    factors: dict = {}
    densities = []  # each photo's pixels per centimetre on the surface
    for k, i in enumerate(indices):
        if update:
            update(k, len(indices))
        g = cast_gbuffer(caster, working_camera(photos.cameras[int(i)], max_side))
        face_id = g.face_id
        hit = face_id >= 0
        if hit.any():
            densities.append(photo_px_per_cm(photos.cameras[int(i)], g.depth[hit]))
        measured = photos.load_depth(int(i))
        if measured is not None:  # judged where the whole scan's surface is smooth, as prepare_photo judges it
            clean = ndimage.binary_erosion(hit, iterations=2) & np.isfinite(g.depth)
            factors[int(i)] = depth_factor(resize_depth(measured, *face_id.shape[::-1]), g.depth, clean,
                                           depth_tolerance, photos.depths[int(i)])
        for t in np.flatnonzero(holds[:, np.unique(face_id[hit])].any(axis=1)):
            seen[t].append(int(i))
            other = hit & ~holds[t, np.where(hit, face_id, 0)]
            if other.any():
                hidden[t][int(i)] = (np.packbits(other, axis=1), other.shape[1])
    if update:
        update(len(indices), len(indices))
    density = float(np.median(densities)) if densities else 0.0
    return [np.array(s, np.int64) for s in seen], hidden, factors, density


def enhance_tile(index: int, sub: Scan, config: dict, threads: int, photos: PhotoSet | None = None) -> dict:
    """Enhance one tile (a worker's job; never raises): its atlas images and what it cost. ``photos``: the
    training photos that see it (photo mode; ``config`` as :meth:`TilePhotos.tile_config` makes it)."""
    t0 = time.perf_counter()
    try:
        import torch

        from scantex.pipeline.enhance import enhance

        torch.set_num_threads(threads)
        result = enhance(sub, EnhanceConfig.from_dict(config).override(threads=threads), photos=photos)
        m = result.metrics
        return {"index": index, "images": tuple(mat.image for mat in result.scan.materials),
                "base_colours": tuple(tuple(mat.diffuse[:3]) for mat in result.scan.materials),
                "uv_identical": bool(np.array_equal(result.scan.uvs, sub.uvs)
                                     and np.array_equal(result.scan.face_uvs, sub.face_uvs)),
                "faces": sub.n_faces, "seconds": round(time.perf_counter() - t0, 2), "host": socket.gethostname(),
                "peak_memory_gib": round(peak_memory() / GiB, 3),
                "held_out_vs_input": m.get("held_out_vs_input", {}).get("enhanced"),
                "photos": len(photos) if photos is not None else 0,
                # the photos it named blurred, by their number in the capture
                "blurred": [{**d, "photo": photos.number(d["photo"])}
                            for d in m.get("photos", {}).get("blurred", [])] if photos is not None else []}
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

    The atlas is fused a strip of texel rows at a time (:func:`scantex.atlas.texelmap.texel_strips`), one tile's
    colours at a time, into an 8-bit image: the whole atlas's texel map, points, every tile's colours and a float
    image at once were 4 GB at 8192² (a real apartment of 800,000 faces in 4 tiles, whose driver then peaked
    above the untiled run). The gains need every tile's colours on the overlaps, so ``harmonize`` takes the
    whole map.
    """
    from scantex.atlas.padding import fill_gutters
    from scantex.atlas.texelmap import texel_map, texel_strips
    from scantex.views.render import to_uint8

    corners = scan.triangles
    T = len(plan)
    holds_face = plan.holds()
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
        gains = np.ones((T, 3))
        if harmonize and T > 1:
            gains = _tile_gains_on(scan, plan, [img[m] for img in tile_images], texel_map(scan.triangle_uvs, W, H,
                                                                                          faces), holds_face)
        # 8-bit from the start: the gutters copy their nearest covered texel, which commutes with the rounding
        image = np.zeros((H, W, 3), np.uint8)
        covered_all = np.zeros((H, W), bool)
        for y0, strip in texel_strips(scan.triangle_uvs, W, H, faces):
            covered = strip.mask
            if not covered.any():
                continue
            rows = slice(y0, y0 + covered.shape[0])
            image[rows][covered] = to_uint8(_fuse_texels(plan, [img[m] for img in tile_images], strip, y0, corners,
                                                         holds_face, gains))
            covered_all[rows] = covered
        if covered_all.any() and not covered_all.all():
            fill_gutters(image, covered_all)
        fused_images.append(image)
        gains_all.append(gains)
    report = {"gains": [np.round(g, 4).tolist() for g in gains_all]}
    return tuple(fused_images), report


def _tile_colours(images: list, covered: np.ndarray, y0: int = 0):
    """``colour(t, sel)``: tile ``t``'s colours (float32, 0-1) at the ``covered`` texels ``sel`` (row-major, the
    texel rows from ``y0``; 0 where the tile baked no image)."""
    ys, xs = np.nonzero(covered)
    ys += y0

    def colour(t: int, sel=slice(None)) -> np.ndarray:
        if images[t] is None:
            return np.zeros((len(ys[sel]), 3), np.float32)
        return images[t][ys[sel], xs[sel]].astype(np.float32) / 255.0

    return colour


def _tile_weight(plan: TilePlan, images: list, t: int, st: np.ndarray, face_of: np.ndarray,
                 holds_face: np.ndarray) -> np.ndarray:
    """Tile ``t``'s blending weight at texels of tile coordinates ``st`` on faces ``face_of`` (0 off its faces)."""
    if images[t] is None:
        return np.zeros(len(st))
    return np.where(holds_face[t, face_of], plan.weights(t, st), 0.0)


def _tile_gains_on(scan: Scan, plan: TilePlan, images: list, tmap, holds_face: np.ndarray) -> np.ndarray:
    """:func:`tile_gains` on the whole texel map ``tmap`` of one material."""
    covered = tmap.mask
    face_of = tmap.face_id[covered]
    st = plan.coords(tmap.points(scan.triangles))
    colour = _tile_colours(images, covered)
    T = len(plan)
    return tile_gains(plan, [colour(t) for t in range(T)],
                      [_tile_weight(plan, images, t, st, face_of, holds_face) for t in range(T)],
                      [holds_face[t, face_of] & (images[t] is not None) for t in range(T)])


def _fuse_texels(plan: TilePlan, images: list, strip, y0: int, corners: np.ndarray, holds_face: np.ndarray,
                 gains: np.ndarray) -> np.ndarray:
    """The fused colours ``(N, 3) float32`` of the covered texels of ``strip`` (atlas rows from ``y0``)."""
    covered = strip.mask
    face_of = strip.face_id[covered]
    st = plan.coords(strip.points(corners))  # [N, 2]
    colour = _tile_colours(images, covered, y0)
    total = np.zeros(len(st))
    acc = np.zeros((len(st), 3), np.float32)
    for t in range(len(plan)):
        w = _tile_weight(plan, images, t, st, face_of, holds_face)
        acc += (w[:, None] * np.clip(colour(t) * gains[t].astype(np.float32), 0, 1)).astype(np.float32)
        total += w
    # texels whose point no tile's weight reaches (a face larger than the overlap): its home tile's colour
    orphan = total <= 1e-9
    if orphan.any():
        home = plan.home[face_of[orphan]]
        idx = np.flatnonzero(orphan)
        for t in np.unique(home):
            sel = idx[home == t]
            acc[sel] = np.clip(colour(t, sel) * gains[t].astype(np.float32), 0, 1)
            total[sel] = 1.0
    return acc / total[:, None].astype(np.float32)


def enhance_tiled(scan: Scan, config: EnhanceConfig = EnhanceConfig(), tiling: TilingConfig = TilingConfig(tiles=4),
                  *, ground_truth: Scan | None = None, photos: PhotoSet | None = None, runner=None, reporter=None):
    """Enhance ``scan`` as overlapping tiles (one job each on ``runner``) and fuse them.

    Args:
        scan: the scan. A textured one keeps its UV layout, which the tiles share; an untextured one with vertex
            colours, or with ``photos``, gets a layout made for it first (see the module docstring).
        config: the enhance settings of every tile (``uv.mode`` must be ``keep`` for a textured scan).
        tiling: how many tiles, their overlap, colour levelling.
        ground_truth: the true texture on the same geometry, if known: the whole result is scored on it.
        photos: the capture's posed photos (photo mode): each tile textures itself from the training photos that
            see it, and the held-out photos score the fused result (see the module docstring).
        runner: where the tiles run (:class:`scantex.scale.executors.LocalPool` by default, or
            :class:`scantex.scale.executors.RayCluster`).
        reporter: progress (see :class:`scantex.pipeline.enhance.Reporter`).

    Returns:
        An :class:`scantex.pipeline.enhance.EnhanceResult` (its metrics hold a ``tiles`` section); the
        scan's positions and faces are the input's own arrays.
    """
    from scantex.pipeline.enhance import Reporter
    from scantex.scale.executors import check_not_bootstrapping

    check_not_bootstrapping()  # before the work a worker that re-runs the caller's script would do for nothing
    reporter = reporter or Reporter()
    if ground_truth is not None and (ground_truth.positions.shape != scan.positions.shape
                                     or ground_truth.faces.shape != scan.faces.shape):
        raise ScanError(ground_truth.source, "the ground truth does not have the scan's geometry")
    timings: dict[str, float] = {}
    extra: dict = {}  # metrics of the layout made for an untextured scan
    if scan.is_textured and config.uv.mode != "keep":
        raise ScanError(scan.source, f"tiled enhancement keeps the input's UV layout; uv.mode '{config.uv.mode}' "
                                     "is not supported with tiles")
    # the tiles share one layout: the faces the input's gives no texture space are charted once, for the whole
    # scan, as enhance charts them; no tile may chart faces into free space of its own
    if scan.is_textured and config.uv.chart_unmapped:
        from scantex.uv.unmapped import chart_unmapped_faces

        scan, unmapped = chart_unmapped_faces(scan)
        if unmapped is not None:
            extra["uv"] = {"unmapped": unmapped}
    config = config.override(uv__chart_unmapped=False)
    if not scan.is_textured and scan.vertex_colors is not None:
        scan, config, extra = _textured_from_vertex_colours(scan, config, photos is not None, reporter, timings)
    elif not scan.is_textured and photos is None:
        raise ScanError(scan.source, "has no texture or vertex colours to enhance in tiles; give the capture's posed "
                                     "photos (--photos) to texture it from them")
    n = tiling.count(scan.n_faces)
    runner = runner or LocalPool()
    t = time.perf_counter()
    plan = plan_tiles(scan, n, tiling.overlap)
    timings["tiling"] = time.perf_counter() - t
    log.info("%d tiles (%d x %d), faces per tile %s", n, *plan.grid, [len(f) for f in plan.faces])
    caster, shared = None, None
    if photos is not None:
        from scantex.views.raycast import RayCaster

        t = time.perf_counter()
        caster = RayCaster(scan.positions, scan.faces)
        with reporter.stage("reading photos (the whole capture)") as update:
            shared = photos_for_tiles(scan, plan, photos, config, caster, update)
        timings["photos"] = time.perf_counter() - t
    if not scan.is_textured:  # a bare mesh with photos: one layout for the whole scan, which every tile bakes into
        scan, config, extra = _laid_out_for_photos(scan, config, shared.px_per_cm, reporter, timings)
    subs = [tile_scan(scan, f) for f in plan.faces]

    t = time.perf_counter()
    with reporter.stage(f"enhancing {n} tiles ({runner.name})") as update:
        outputs = run_tiles(scan, plan, subs, config, runner, update, shared)
    timings["tiles"] = time.perf_counter() - t
    result = assemble_tiles(scan, plan, outputs, config, tiling, runner.name, timings,
                            ground_truth=ground_truth, reporter=reporter, photos=shared, caster=caster)
    for key, value in extra.items():
        result.metrics.setdefault(key, {}).update(value)
    return result


def _textured_from_vertex_colours(scan: Scan, config: EnhanceConfig, with_photos: bool, reporter,
                                  timings: dict) -> tuple[Scan, EnhanceConfig, dict]:
    """An untextured scan's vertex colours as a texture the tiles share, made and treated as ``enhance`` makes
    and treats it (not levelled; its seams not blended in mesh-only mode): the scan, the tiles' settings, and
    the metrics saying so."""
    from scantex.pipeline.enhance import vertex_colour_texture, vertex_texture_note

    t = time.perf_counter()
    textured = vertex_colour_texture(scan, reporter)
    timings["vertex_colours"] = time.perf_counter() - t
    blends = config.uv.blend_seams and with_photos
    config = config.override(bake__levelling=False, uv__mode="keep", uv__blend_seams=blends)
    return textured, config, {"input": {"texture": vertex_texture_note(textured.materials[0].image.shape[0], blends)}}


def _laid_out_for_photos(scan: Scan, config: EnhanceConfig, px_per_cm: float, reporter,
                         timings: dict) -> tuple[Scan, EnhanceConfig, dict]:
    """A bare mesh unwrapped whole for its photos (see the module docstring): the scan with the new layout and
    no texture, the tiles' settings (that layout kept, baked at its size), and the layout's metrics."""
    from scantex.pipeline.enhance import untextured_atlas_size
    from scantex.uv import plan_uvs

    uc = config.uv
    size = config.bake.texture_size or untextured_atlas_size(scan, px_per_cm)
    t = time.perf_counter()
    with reporter.stage("UV layout (unwrap, the whole scan)") as update:
        planned = plan_uvs(scan, "unwrap", threshold=uc.threshold, texture_size=size,
                           time_budget_s=uc.time_budget_s, progress=update)
    timings["uv"] = time.perf_counter() - t
    bare = planned.scan.replace(materials=tuple(dataclasses.replace(m, image=None) for m in planned.scan.materials))
    return bare, config.override(bake__texture_size=size, uv__mode="keep"), {"uv": {"mode": "unwrap",
                                                                                     **planned.report}}


def run_tiles(scan: Scan, plan: TilePlan, subs: list[Scan], config: EnhanceConfig, runner, update=None,
              photos: TilePhotos | None = None) -> list[dict]:
    """Enhance every tile ``subs[k]`` as a job on ``runner`` (with the training photos that see it, in photo
    mode); their outputs (see :func:`enhance_tile`) in tile order. Raises :class:`ScanError` naming the first
    tile that failed."""
    n = len(subs)
    cores = machine().cores
    workers = getattr(runner, "workers", None) or cores
    threads = max(1, cores // min(workers, n)) if isinstance(runner, LocalPool) else max(1, config.threads or 1)
    cfg = (photos.tile_config(config) if photos is not None else config).to_dict()
    texels = sum(int(np.prod(m.image.shape[:2])) for m in scan.materials if m.image is not None)
    out_texels = (config.bake.texture_size ** 2) if config.bake.texture_size else min(4 * texels, 8192 ** 2)
    tile_photos = [photos.for_tile(k) if photos is not None else None for k in range(n)]
    jobs = [Job(f"tile {k}", enhance_tile, (k, sub, cfg, threads, tile_photos[k]),
                memory=estimate_memory(sub.n_faces, out_texels)
                + (photo_memory(tile_photos[k], config.photos.max_side) if tile_photos[k] is not None else 0),
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
                   executor: str, timings: dict, *, ground_truth: Scan | None = None, reporter=None,
                   photos: TilePhotos | None = None, caster=None):
    """Fuse the tiles' outputs into the whole scan's result and measure it (see :func:`enhance_tiled`;
    ``photos``: photo mode's shared part, whose held-out photos score the result)."""
    from scantex.pipeline.enhance import EnhanceResult, Reporter
    from scantex.views.raycast import RayCaster

    reporter = reporter or Reporter()
    timings = dict(timings)
    n = len(outputs)
    if not all(o["uv_identical"] for o in outputs):
        raise ScanError(scan.source, "a tile's enhance changed the UV layout; tiles can only be fused in a shared one")

    t = time.perf_counter()
    with reporter.stage("fusing the tiles") as update:
        images, fuse_report = fuse_tiles(scan, plan, [o["images"] for o in outputs], tiling.harmonize)
        for o in outputs:  # a full atlas each, fused: let go (the caller's list holds the same dicts)
            del o["images"]
        # each texture under the base colour its tiles' textures were made for (see with_base_colours_of)
        base = outputs[0].get("base_colours") or [(1.0, 1.0, 1.0)] * len(images)
        materials = tuple(m if img is None else dataclasses.replace(
            m, image=img, image_name=f"enhanced_{m.name}.png", diffuse=(*base[k], m.diffuse[3]))
            for k, (m, img) in enumerate(zip(scan.materials, images)))
        fused = scan.replace(materials=materials, source=None)
        if config.uv.blend_seams:
            from scantex.uv import blend_seams

            fused = blend_seams(fused, band_texels=config.uv.band_texels)
        update(1, 1)
    timings["fuse"] = time.perf_counter() - t

    t = time.perf_counter()
    caster = caster or RayCaster(scan.positions, scan.faces)
    comparisons: dict = {}
    shown: list = []
    with reporter.stage("measuring") as update:
        views, metrics = measure_whole(scan, fused, ground_truth, config, caster,
                                       photos=photos.photos if photos is not None else None, renders=shown)
        if photos is not None:
            metrics.update(tiled_photo_metrics(scan, fused, ground_truth, photos, config, caster, comparisons))
            metrics["photos"]["blurred"] = tiled_blurred(outputs)
        update(1, 1)
    timings["metrics"] = time.perf_counter() - t
    metrics["tiles"] = {
        "count": n, "grid": list(plan.grid), "overlap": tiling.overlap, "harmonize": tiling.harmonize,
        "executor": executor, "threads_per_tile": outputs[0]["threads"], **fuse_report,
        "per_tile": [{k: o.get(k) for k in ("faces", "photos", "seconds", "peak_memory_gib", "host",
                                            "held_out_vs_input")}
                     for o in outputs]}
    metrics["timings_s"] = {k: round(v, 2) for k, v in timings.items()}
    metrics["timings_s"]["total"] = round(sum(timings.values()), 2)
    comparisons = {f"held_out_photo_{i:03d}": im for i, im in comparisons.items()}
    return EnhanceResult(fused, metrics, config, views, comparisons, input_scan=scan, ground_truth=ground_truth,
                         renders=shown)


def tiled_texturing(pc, n_photos: int) -> dict:
    """How every tile coloured its texels (the settings; each tile's own report stays with it): the mode, and the
    two bands' settings where ``photos.detail`` (auto: by the capture's ``n_photos``) asks for them, as a whole
    run's ``photos.texturing`` gives them."""
    from scantex.photos.texturing import ProjectiveSettings, detail_report
    from scantex.pipeline.enhance import detail_settings

    if pc.texturing != "projective":
        return {"mode": pc.texturing}
    return {"mode": pc.texturing, **detail_report(ProjectiveSettings(**detail_settings(pc.detail, n_photos)))}


def tiled_blurred(outputs: list[dict]) -> list[dict]:
    """The photos the tiles named blurred (:func:`scantex.pipeline.enhance.judge_detail`: each tile judges the
    training photos that see it against one another, and treats them by their share there): each photo once, with
    the least detail a tile measured, ``left_out`` or ``softened`` where a tile did so, and the tiles that named it;
    the least detailed first."""
    named: dict[int, dict] = {}
    for o in outputs:
        for d in o.get("blurred", []):
            entry = named.setdefault(d["photo"], {**d, "tiles": []})
            entry["detail"] = min(entry["detail"], d["detail"])
            entry["left_out"] = entry["left_out"] or d["left_out"]
            entry["softened"] = entry.get("softened", False) or d.get("softened", False)
            entry["tiles"].append(o["index"])
    return sorted(named.values(), key=lambda d: (d["detail"], d["photo"]))


def tiled_photo_metrics(scan: Scan, enhanced: Scan, ground_truth: Scan | None, photos: TilePhotos,
                        config: EnhanceConfig, caster, images: dict | None = None) -> dict:
    """Photo mode's metrics of a tiled run, in ``enhance``'s shape: what the photos gave, and the input and the
    fused result scored on the held-out photos (``images`` receives a photo | input | result image each)."""
    from scantex.atlas.holes import untextured_faces
    from scantex.metrics.views import score_views
    from scantex.photos.training import prepare_photos, score_photos
    from scantex.pipeline.enhance import alignment_metrics, visibility_settings

    pc = config.photos
    out: dict = {"photos": {
        "source": str(photos.photos.source), "format": photos.photos.format, "total": len(photos.photos),
        "train": photos.train.tolist(), "held_out": photos.held_out.tolist(),
        "per_tile": [len(p) for p in photos.per_tile],
        "pose_refinement": photos.pose_mode, "pose_corrections": [c.to_dict() for c in photos.corrections],
        "alignment": alignment_metrics(photos.alignment), "left_out": photos.left_out, "repeated": photos.repeated,
        "final_texture": {"photos": len(photos.train), "mode": "training", "setting": pc.final,
                          "note": "tiles write the texture the held-out photos score: the training photos'"},
        "texturing": tiled_texturing(pc, len(photos.photos)),
    }}
    if len(photos.held_out):
        held = prepare_photos(scan, photos.photos, photos.held_out, caster, pc.max_side,
                              visibility_settings(pc, len(photos.photos)))
        both = {"input": scan, "enhanced": enhanced}
        out["held_out_photos"] = score_photos(both, held, caster, images=images, align=photos.pose_mode != "off")
        if ground_truth is not None:
            out["held_out_photos_vs_ground_truth"] = score_views(ground_truth, both, [v.camera for v in held], caster,
                                                                 untextured_faces(scan))
    return out


def measure_whole(scan: Scan, enhanced: Scan, ground_truth: Scan | None, config: EnhanceConfig, caster=None,
                  photos: PhotoSet | None = None, renders: list | None = None):
    """Views of the whole scan planned as ``enhance`` plans them (same seed, so the same held-out
    cameras), and the result's metrics on them: geometry identity, seam visibility, held-out scores. With
    ``photos`` (photo mode) as an untiled photo-mode run plans and renders them: no views added for coverage,
    and only the held-out ones rendered (nothing trains on the others). ``renders``: if given, receives the
    held-out views' renders as scored (:func:`scantex.metrics.views.score_views`), for the report."""
    from scantex.atlas.holes import untextured_faces, visible_holes
    from scantex.atlas.seams import seam_visibility
    from scantex.metrics.geometry import geometry_metrics
    from scantex.metrics.views import score_views
    from scantex.pipeline.enhance import (fill_held_out, held_out_rendered_when_scored, render_training_views,
                                          views_teach)
    from scantex.views.planning import add_views_for_coverage, plan_views
    from scantex.views.raycast import RayCaster

    vc = config.views
    caster = caster or RayCaster(scan.positions, scan.faces)
    up = up_axis(scan, vc.up)
    cameras = plan_views(scan, vc.n_views, mode=vc.mode, width=vc.width, height=vc.height, fov_deg=vc.fov_deg,
                         seed=config.seed, up=up, caster=caster)
    trains_on_views = views_teach(scan, config, photos)
    if vc.adaptive and trains_on_views:
        cameras = add_views_for_coverage(scan, cameras, min_views=2, max_new=max(2, vc.n_views // 4), up=up,
                                         seed=config.seed, caster=caster)
    holes = untextured_faces(scan)
    views = render_training_views(scan, cameras, np.ones(scan.n_faces, bool), vc.supersample, caster,
                                  vc.test_fraction, config.seed, lambda done, total: None,
                                  render_train=trains_on_views,
                                  render_test=not held_out_rendered_when_scored(scan, trains_on_views))
    metrics: dict = {
        "geometry": geometry_metrics(scan, enhanced),
        "input": {"vertices": scan.n_vertices, "faces": scan.n_faces, "textured": scan.is_textured,
                  "hole_faces": int(visible_holes(scan).sum())},
        "views": {"total": len(views.views), "test": len(views.views.test)},
        "seam_visibility": {"input": round(seam_visibility(scan), 3), "enhanced": round(seam_visibility(enhanced), 3)},
    }
    test = [views.views.cameras[i] for i in views.views.test]
    scored: list[dict] = []
    if ground_truth is not None:
        metrics["held_out_vs_ground_truth"] = score_views(ground_truth, {"input": scan, "enhanced": enhanced}, test,
                                                          caster, holes, renders=renders, reference_name="ground truth",
                                                          scored=scored)
    elif scan.is_textured:  # how faithfully the result reproduces the input, where the input has colour
        metrics["held_out_vs_input"] = score_views(scan, {"enhanced": enhanced}, test, caster, holes, renders=renders,
                                                   reference_name="input", scored=scored, pooled=True)
    fill_held_out(views.views, scored)
    return views, metrics
