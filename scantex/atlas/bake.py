"""Baking: the colour of every covered texel from a function of the surface point, then gutters.

The geometry and the UV layout are the scan's own; only the texture images are new.
"""

from __future__ import annotations

import contextlib
import dataclasses
from collections import deque
from collections.abc import Callable, Iterator
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np

from scantex.arrays import uv_areas
from scantex.atlas.padding import fill_gutters, gutter_sources, pad_gutters
from scantex.atlas.texelmap import covered_texels, rasterised_cheaply, texel_map, texel_strips
from scantex.scan import Scan
from scantex.views.raycast import interpolate
from scantex.views.render import to_uint8

#: colour of surface points: (points (N, 3), unit normals (N, 3), face ids (N,), barycentrics (N, 2))
#: -> rgb (N, 3) in [0, 1]
SurfaceColour = Callable[[np.ndarray, np.ndarray, np.ndarray, np.ndarray], np.ndarray]


@dataclass(frozen=True, eq=False)
class AtlasLayout:
    """What a bake found out about one material's atlas, for a pass over the same atlas after it
    (:func:`scantex.uv.blend.blend_seams`) to reuse instead of rasterising the UVs and padding's distance
    transform again."""

    strips: tuple[np.ndarray, ...]
    """the face each texel shows (-1 where no triangle covers it), a ``(rows, W) int32`` strip of rows at a time,
    top to bottom: the strips the bake drew, kept as they are (one atlas-sized array filled from them took 0.3-1.8 s
    of the bathroom's 8192^2 bake, most of it the operating system handing over fresh memory)"""
    sources: np.ndarray | None
    """:func:`scantex.atlas.padding.gutter_sources` of the covered texels (``None``: no gutters)"""

    @property
    def shape(self) -> tuple[int, int]:
        """The atlas's ``(H, W)``."""
        return sum(s.shape[0] for s in self.strips), (self.strips[0].shape[1] if self.strips else 0)

    def rows(self) -> Iterator[tuple[int, np.ndarray]]:
        """``(y0, face_id)`` of each strip, top to bottom."""
        y0 = 0
        for strip in self.strips:
            yield y0, strip
            y0 += strip.shape[0]


def output_size(scan: Scan, material: int, requested: int = 0, cap: int = 8192, scale: int = 2) -> tuple[int, int]:
    """Atlas size for a material: ``requested`` square, or ``scale`` times the input atlas (at most ``cap``;
    never below the input's own size)."""
    if requested:
        return requested, requested
    image = scan.materials[material].image
    if image is None:
        return 1024, 1024
    H, W = image.shape[:2]
    return max(H, min(scale * H, cap)), max(W, min(scale * W, cap))


def bake(scan: Scan, colour: SurfaceColour, *, size: int = 0, scale: int = 2, chunk: int = 65536,
         progress: Callable[[int, int], None] | None = None,
         layouts: list[AtlasLayout | None] | None = None, workers: int = 1,
         only: np.ndarray | None = None) -> tuple[np.ndarray, ...]:
    """New ``(H, W, 3) uint8`` images, one per material (``None`` for materials without UVs/faces).

    Each is ``size`` square, or ``scale`` times its input atlas (:func:`output_size`). At ``scale`` 1 on
    the input's own UVs every texel centre is an input texel centre, so a colour that returns the
    input's texture unchanged bakes the input's texels exactly.

    Every texel some triangle covers gets ``colour`` at its surface point; the rest are filled from the
    nearest covered texel (gutter padding).

    The atlas is streamed in strips of rows (:func:`scantex.atlas.texelmap.texel_strips`): texel map,
    surface points and colours exist for one strip and one chunk at a time, so memory beyond the output
    image is the padding's distance transform (0.5 GB at 8192^2), not the ~100 bytes a texel (6-7 GB at
    8192^2) of the whole atlas's texel map, points, colours and float image. ``colour`` is called with
    the same chunks of covered texels, in the same order (row-major), as :func:`bake_reference` calls it,
    so the result is the same byte for byte.
    ``progress`` gets ``(done, total)`` texels; ``total`` is estimated from the UV area until the end.
    ``layouts``: if given, receives each material's :class:`AtlasLayout` (``None`` where no image is made),
    for seam blending (8 bytes a texel more, held: 0.13 GB at 4096^2).
    ``workers`` > 1 colours that many chunks at once, in threads (``colour`` must then allow calls from
    several threads at once; numpy releases the interpreter lock in its array work). The texels are the
    same, as each chunk's colours depend on that chunk alone; at most twice ``workers`` chunks are held.
    ``only``: ``(F,) bool``, the faces to colour (``None``: all); the texels of the others are gutter, filled
    from the nearest coloured texel. Away from the faces left out, the coloured texels are those of a full
    bake to one 8-bit level (a strip's texel map starts at another row: barycentrics agree to 1e-7).
    """
    tri_uv = scan.triangle_uvs
    corners = scan.triangles
    normals = scan.face_normals
    plans = _plans(scan, size, scale, only)
    total = sum(_estimated_texels(tri_uv[p[0]], p[1], p[2]) for p in plans if p is not None)
    images, done = [], 0

    def coloured(f: np.ndarray, b: np.ndarray) -> np.ndarray:
        rgb = colour(interpolate(f, b, corners), np.take(normals, f, axis=0), f, b)
        return to_uint8(np.asarray(rgb, dtype=np.float32))

    # the gutters' nearest-texel map depends on the layout alone, not on the colours: with cores to spare it is
    # found on a thread of its own while the texels are coloured (the distance transform releases the interpreter
    # lock; the texel map is drawn a second time for its mask, which the compiled rasteriser makes cheap), instead
    # of after them on one core (the bolster's 2048^2 atlas: 0.44 s)
    ahead = workers > 1 and rasterised_cheaply()
    with (ThreadPoolExecutor(workers) if workers > 1 else contextlib.nullcontext() as pool,
          ThreadPoolExecutor(1) if ahead else contextlib.nullcontext() as gutters):
        for plan in plans:
            if plan is None:
                images.append(None)
                if layouts is not None:
                    layouts.append(None)
                continue
            faces, H, W = plan
            padding = gutters.submit(_layout_gutter_sources, tri_uv, W, H, faces) if ahead else None
            image = np.zeros((H * W, 3), np.uint8)
            covered = np.zeros(H * W, bool)
            face_strips: list[np.ndarray] | None = [] if layouts is not None else None
            # covered texels of the strips so far not yet coloured: (flat texel index, face, barycentrics)
            flat, fid, bary = np.zeros(0, np.int64), np.zeros(0, np.int32), np.zeros((0, 2), np.float32)
            pending: deque = deque()  # (texels, the future of their colours), oldest first

            def store(idx: np.ndarray, rgb: np.ndarray) -> None:
                nonlocal done, total
                image[idx] = rgb
                covered[idx] = True
                done += len(idx)
                total = max(total, done)
                if progress:
                    progress(done, total)

            def emit(idx: np.ndarray, f: np.ndarray, b: np.ndarray, keep: int) -> None:
                """Colour texels ``idx`` (None: none), then store finished chunks until ``keep`` are left."""
                if idx is not None and pool is None:
                    store(idx, coloured(f, b))
                elif idx is not None:
                    pending.append((idx, pool.submit(coloured, f, b)))
                while len(pending) > keep:
                    first, future = pending.popleft()
                    store(first, future.result())

            for y0, strip in texel_strips(tri_uv, W, H, faces):
                if face_strips is not None:
                    face_strips.append(strip.face_id)
                hit = np.flatnonzero(strip.mask.reshape(-1))
                flat = np.concatenate([flat, hit + y0 * W])
                fid = np.concatenate([fid, strip.face_id.reshape(-1)[hit]])
                bary = np.concatenate([bary, strip.bary.reshape(-1, 2)[hit]])
                whole = len(flat) // chunk * chunk
                for s in range(0, whole, chunk):
                    emit(flat[s:s + chunk], fid[s:s + chunk], bary[s:s + chunk], keep=2 * workers - 1)
                flat, fid, bary = flat[whole:], fid[whole:], bary[whole:]
            if len(flat):
                emit(flat, fid, bary, keep=2 * workers - 1)
            emit(None, None, None, keep=0)
            image, covered = image.reshape(H, W, 3), covered.reshape(H, W)
            sources = gutter_sources(covered) if padding is None else padding.result()
            fill_gutters(image, covered, sources)
            images.append(image)
            if layouts is not None:
                layouts.append(AtlasLayout(tuple(face_strips), sources))
            del sources  # the layout keeps it, or it goes now
    if progress and done < total:
        progress(done, done)  # the estimate was high (overlapping UVs): end at 100 %
    return tuple(images)


def _layout_gutter_sources(tri_uv: np.ndarray, W: int, H: int, faces: np.ndarray) -> np.ndarray | None:
    """:func:`gutter_sources` of the texels that ``faces`` cover in a ``W`` x ``H`` atlas (the mask a bake's strips
    mark, drawn by the same rasteriser)."""
    return gutter_sources(covered_texels(tri_uv, W, H, faces))


def bake_reference(scan: Scan, colour: SurfaceColour, *, size: int = 0, scale: int = 2,
                   chunk: int = 65536) -> tuple[np.ndarray, ...]:
    """Slow, plainly correct twin of :func:`bake`: the whole atlas's texel map, points and colours at
    once (~100 bytes a texel: 6-7 GB at 8192^2; for tests)."""
    corners = scan.triangles
    normals = scan.face_normals
    images = []
    for plan in _plans(scan, size, scale):
        if plan is None:
            images.append(None)
            continue
        faces, H, W = plan
        tmap = texel_map(scan.triangle_uvs, W, H, faces)
        covered = tmap.mask
        points = tmap.points(corners)
        face_of_texel = tmap.face_id[covered]
        bary = tmap.bary[covered]
        rgb = np.zeros((len(points), 3), np.float32)
        for s in range(0, len(points), chunk):
            e = min(s + chunk, len(points))
            rgb[s:e] = colour(points[s:e], normals[face_of_texel[s:e]], face_of_texel[s:e], bary[s:e])
        image = np.zeros((H, W, 3), np.float32)
        image[covered] = rgb
        images.append(to_uint8(pad_gutters(image, covered)))
    return tuple(images)


def _plans(scan: Scan, size: int, scale: int = 2, only: np.ndarray | None = None
           ) -> list[tuple[np.ndarray, int, int] | None]:
    """Per material: its faces (of ``only``, when given) and atlas height and width, or ``None`` when it has
    no faces."""
    plans = []
    for m in range(len(scan.materials)):
        faces = np.flatnonzero((scan.face_materials == m) & (True if only is None else only))
        plans.append((faces, *output_size(scan, m, size, scale=scale)) if faces.size else None)
    return plans


def _estimated_texels(tri_uv: np.ndarray, H: int, W: int) -> int:
    """Texels the triangles ``(F, 3, 2)`` cover, from their UV area (exact but for overlaps and edges)."""
    area = uv_areas(tri_uv).sum()
    return max(1, min(H * W, int(round(area * H * W))))


#: the share of an atlas that a fresh layout's charts are expected to use, when choosing the size to lay it out
#: at (:func:`texture_from_vertex_colours`)
LAYOUT_SHARE = 0.25


#: a base colour channel below this is kept out of the texture (white as before): dividing by it would blow up
MIN_BASE_COLOUR = 0.05


def with_base_colours_of(result: Scan, source: Scan) -> Scan:
    """``result`` (the input's texels baked: each texel the input's times its material's base colour, ``Kd`` /
    ``baseColorFactor``) with each textured material's base colour ``source``'s again and its texture divided by
    it, so that every viewer shows the result as it showed the input. The formats multiply the texture by the
    base colour, and some viewers do, while others (Blender's OBJ import) show the texture alone: a scan
    exported from Blender (``Kd 0.8``) had come out 20 % darker there, its texture times 0.8 under ``Kd 1``.
    Unchanged where the materials do not correspond one to one, or where a base colour is white or nearly
    black."""
    if len(result.materials) != len(source.materials):
        return result
    materials = []
    for mine, theirs in zip(result.materials, source.materials):
        kd = np.asarray(theirs.diffuse[:3], np.float64)
        if mine.image is None or theirs.image is None or (kd == 1).all() or (kd < MIN_BASE_COLOUR).any() \
                or mine.image.dtype != np.uint8 or mine.image.ndim != 3:
            materials.append(mine)
            continue
        image = mine.image.copy()
        image[..., :3] = np.clip(np.rint(image[..., :3] / kd), 0, 255).astype(np.uint8)
        materials.append(dataclasses.replace(mine, image=image, diffuse=(*theirs.diffuse[:3], mine.diffuse[3])))
    return result.replace(materials=tuple(materials))


def texture_from_vertex_colours(scan: Scan, size: int = 2048, *, texels_per_vertex: float = 0.0,
                                time_budget_s: float = 60.0) -> Scan:
    """``scan``'s vertex colours as a texture: UVs unwrapped afresh and a square atlas baked from the colours
    interpolated over each face. Positions and faces are the same arrays.

    The atlas is ``size`` square, doubled (up to 8192) until its charts hold ``texels_per_vertex`` texels for
    every distinct position: a noisy fused surface unwraps into many small charts whose gutters leave a small
    share of the atlas to texels (a fused apartment of 105,796 vertices: 11 % of 2048^2, 4 texels a vertex).
    The layout is made at the size its charts are expected to need (``LAYOUT_SHARE`` of it used), so that
    gutters made for a small atlas do not waste a large one: a fused apartment of 108,048 vertices laid out at
    2048² used 8 % of it and was baked at 8192² (4.6 GB); laid out at 4096², its charts use about 30 %.

    A fused RGB-D mesh (Open3D, KinectFusion, ScanNet) carries its colour per vertex. As a texture it serves
    as any capture app's atlas does: the texels mesh-only mode keeps, and in photo mode the reference the
    photos' colours are brought to, the colour where no photo reaches, and texture edges for the alignment
    check. Vertices black in all three channels are taken as uncoloured (what a fusion leaves where no frame
    saw the surface) and get the harmonic fill of the colours around them first: interpolated over a face
    towards a black corner, they would draw dark rims that the texture's hole fill (black faces) misses."""
    from scantex.atlas.inpaint import harmonic_vertex_colours
    from scantex.uv.plan import plan_uvs
    from scantex.views.render import shade_hits

    if scan.vertex_colors is None:
        raise ValueError("the scan has no vertex colours")
    rgba = scan.vertex_colors
    uncoloured = ~rgba[:, :3].any(axis=1)
    if uncoloured.any() and not uncoloured.all():
        rgb = harmonic_vertex_colours(scan, ~uncoloured, rgba[:, :3].astype(np.float64))
        rgba = np.column_stack([np.clip(np.round(rgb), 0, 255), rgba[:, 3]]).astype(np.uint8)
        scan = scan.replace(vertex_colors=rgba)
    positions = int(scan.welded.max()) + 1 if scan.n_vertices else 0
    while size < 8192 and LAYOUT_SHARE * size * size < texels_per_vertex * positions:
        size *= 2
    planned = plan_uvs(scan, "unwrap", texture_size=size, time_budget_s=time_budget_s).scan
    used = float(uv_areas(planned.triangle_uvs).sum())  # the charts' share of the atlas
    while size < 8192 and used * size * size < texels_per_vertex * positions:
        size *= 2

    def colour(points, normals, face_ids, bary):
        return shade_hits(scan, face_ids, bary)

    (image,) = bake(planned, colour, size=size)
    # white base colour: a texture is multiplied by it, and an untextured mesh's default is grey
    material = dataclasses.replace(planned.materials[0], image=image, image_name="vertex_colours.png",
                                   diffuse=(1.0, 1.0, 1.0, 1.0))
    return planned.replace(materials=(material,), face_materials=np.zeros(planned.n_faces, np.int32))
