"""Seam blending after a bake, and moving a texture onto a new UV layout.

Along a seam the same 3D points are stored twice, once in each chart. :func:`blend_seams` levels the two
copies (on seams that are no sharp crease: there the two sides are two surfaces): at every point of a seam edge it measures the colour on both sides (just inside each chart),
and moves the texels of each side towards their mean. Texels within ``core_texels`` of the seam (the ones
bilinear filtering reads at the seam) move all the way, so both sides end equal; the shift then falls
off linearly to nothing at ``band_texels``, so texture detail is kept and no step appears inside the
chart. Gutters are padded again afterwards from the blended texels.

The atlas is processed in strips of rows (texel map and offsets for one strip at a time), so memory
beyond the two images is the gutter padding's, not the 2.7 GB of whole-atlas float64 offsets an 8192^2
atlas would take.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np

from scantex.atlas.padding import fill_gutters
from scantex.atlas.seams import SeamEdges, SeamSides, seam_edges, seam_sides, uv_shells
from scantex.atlas.texelmap import texel_strips, uv_to_pixel
from scantex.scan import Scan
from scantex.threads import side_by_side
from scantex.views.raycast import PAIR_THREADS, interpolate
from scantex.views.render import sample_texture, to_uint8

if TYPE_CHECKING:
    from scantex.atlas.bake import AtlasLayout

log = logging.getLogger(__name__)

#: candidate texels examined per batch of seam edges (bounds memory on large atlases)
CANDIDATES_PER_BATCH = 500_000


def blend_seams(scan: Scan, *, band_texels: float = 3.0, core_texels: float = 1.5, inset_texels: float = 1.0,
                edges: SeamEdges | None = None, max_crease_deg: float = 60.0,
                layouts: Sequence[AtlasLayout | None] | None = None) -> Scan:
    """The same scan with seam-blended material images (see the module docstring).

    Args:
        scan: a textured scan.
        band_texels: texels farther than this from a seam keep their colour.
        core_texels: texels within this distance of a seam take the mean of both sides fully.
        inset_texels: how far inside each chart the two sides are read.
        edges: the seam edges (default: all of :func:`scantex.atlas.seams.seam_edges`).
        max_crease_deg: seams on a sharper crease are left alone, as seam levelling leaves them: where a
            wall meets the floor the colour changes for real, and blending it would bleed each surface's
            colour onto the other over the band (on a coarse atlas, centimetres; 180 blends every seam).
        layouts: the bake's :class:`~scantex.atlas.bake.AtlasLayout` of each material (its texel map and
            gutter padding, reused; the same result as without them).
    """
    if band_texels <= 0:
        raise ValueError(f"band_texels must be positive, got {band_texels}")
    edges = seam_edges(scan) if edges is None else edges
    if max_crease_deg < 180:
        edges = edges.smooth(scan.face_normals, max_crease_deg)
    if not scan.is_textured or len(edges) == 0:
        return scan
    core = min(core_texels, 0.999 * band_texels)
    shells = uv_shells(scan)
    tri_uv = scan.triangle_uvs
    mats = scan.face_materials
    out_images = [m.image for m in scan.materials]
    for m, material in enumerate(scan.materials):
        image = material.image
        own = np.flatnonzero(mats[edges.faces.ravel()] == m)
        if image is None or own.size == 0:
            continue
        H, W = image.shape[:2]
        edge_id, side = own // 2, own % 2
        f = edges.faces[edge_id, side]
        g = edges.faces[edge_id, 1 - side]
        cf = edges.corners[edge_id, side]
        cg = edges.corners[edge_id, 1 - side]
        seg = uv_to_pixel(np.stack([tri_uv[f, cf[:, 0]], tri_uv[f, cf[:, 1]]], axis=1), W, H)  # [n, 2, 2]
        lo = np.floor(seg.min(axis=1) - band_texels).astype(np.int64)
        hi = np.ceil(seg.max(axis=1) + band_texels).astype(np.int64)
        # each side's segment and inward step, once: a side's band holds a few dozen texels that read it
        mine, theirs = seam_sides(scan, f, cf, inset_texels), seam_sides(scan, g, cg, inset_texels)
        side_shell = shells[f]
        # an edge inside a chart (an old layout's seam, its colour step baked into the new one: both sides hold
        # it at the same texture coordinates): each side moves only the texels on its own face's side of the
        # edge, the side its third corner is on
        inner = (np.stack([tri_uv[f, cf[:, 0]], tri_uv[f, cf[:, 1]]], axis=1)
                 == np.stack([tri_uv[g, cg[:, 0]], tri_uv[g, cg[:, 1]]], axis=1)).all(axis=(1, 2))
        third = uv_to_pixel(tri_uv[f, 3 - cf[:, 0] - cf[:, 1]], W, H)
        d = seg[:, 1] - seg[:, 0]
        facing = np.sign(d[:, 0] * (third[:, 1] - seg[:, 0, 1]) - d[:, 1] * (third[:, 0] - seg[:, 0, 0]))
        facing[~inner] = 0  # 0: every texel of the side's chart within the band, as across a seam between charts
        scale = 1.0 / 255.0 if image.dtype == np.uint8 else 1.0
        new = image.copy()
        covered = np.zeros((H, W), bool)
        layout = layouts[m] if layouts is not None and m < len(layouts) else None
        if layout is not None and layout.shape != (H, W):
            layout = None  # not this image's bake
        # the atlas in strips of rows: each strip's texel map and offsets, and the edges whose band reaches it
        strips = (((y0, strip.face_id) for y0, strip in texel_strips(tri_uv, W, H, np.flatnonzero(mats == m)))
                  if layout is None else
                  layout.rows())

        def blend_strip(strip: tuple[int, np.ndarray]) -> int:
            """Blend atlas rows ``y0 ..`` of ``face_id``; the texels moved."""
            y0, face_id = strip
            y1 = y0 + face_id.shape[0]
            covered[y0:y1] = face_id >= 0
            texel_shell = np.where(face_id >= 0, shells[np.maximum(face_id, 0)], -1)
            at, offset, weight, strongest = _strip_offsets(
                scan, texel_shell, y0, W, side_shell, seg, mine, theirs, lo, hi, band_texels, core, facing)
            touched = weight > 0  # only these change
            at, offset, weight, strongest = at[touched], offset[touched], weight[touched], strongest[touched]
            rgb = image[y0:y1].reshape(-1, image.shape[2])[at, :3].astype(np.float64) * scale
            rgb += offset / weight[:, None] * strongest[:, None]
            new[y0:y1].reshape(-1, image.shape[2])[at, :3] = (to_uint8(rgb) if image.dtype == np.uint8
                                                               else rgb.astype(image.dtype))
            return int(at.size)

        # with the bake's layout, the strips side by side (each reads the image and writes its own rows of the
        # copy; the bolster's blending 0.85 -> 0.65 s); without it, one at a time: each strip's texel map is
        # made as it comes, and side_by_side would hold them all
        moved = sum(side_by_side(blend_strip, strips, PAIR_THREADS) if layout is not None else map(blend_strip, strips))
        fill_gutters(new[..., :3], covered, layout.sources if layout is not None else None)  # from the blended texels
        out_images[m] = new
        log.debug("blended %d seam sides in material %d (%d texels moved)", len(f), m, moved)
    materials = tuple(mat.with_image(img) if img is not None else mat for mat, img in zip(scan.materials, out_images))
    return scan.replace(materials=materials)


def _strip_offsets(scan: Scan, texel_shell: np.ndarray, y0: int, W: int, side_shell: np.ndarray, seg: np.ndarray,
                   mine: SeamSides, theirs: SeamSides, lo: np.ndarray, hi: np.ndarray, band_texels: float,
                   core: float, facing: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The seam sides' pull on the texels of atlas rows ``y0 .. y0 + h`` (``texel_shell (h, W)``: the
    shell each texel shows, -1 for none; ``side_shell (N,)`` each side's shell; ``mine`` and ``theirs``
    each side's segment as its own face and the other side's face hold it): ``(at (n,), offsets (n, 3),
    weights (n,), strongest (n,))``, the summed weighted offsets, summed weights and strongest weight of
    the ``n`` texels reached, ``at`` their indices in the strip's rows flattened, increasing. ``facing
    (N,)``: for a side whose edge lies inside one chart, the sign of the side of its segment its texels are on
    (0: any). Candidate texels are each seam side's bounding box within ``band_texels``, cut to the strip's
    rows, examined ``CANDIDATES_PER_BATCH`` at a time; the sums are kept for the texels reached only (a few
    per cent of a strip: dense sums over every texel of it took a third of the blending)."""
    h = texel_shell.shape[0]
    y1 = y0 + h
    rows = np.flatnonzero((hi[:, 1] >= y0) & (lo[:, 1] <= y1 - 1))  # the sides whose band reaches the strip
    lo_y = np.maximum(lo[rows, 1], y0)
    count_x = np.maximum(hi[rows, 0] - lo[rows, 0] + 1, 0)
    count_y = np.maximum(np.minimum(hi[rows, 1], y1 - 1) - lo_y + 1, 0)
    per = count_x * count_y
    cum = np.cumsum(per)
    start = 0
    batches = []  # each batch's (texel, weight, weighted offset)
    while start < len(rows):
        done_before = cum[start - 1] if start else 0
        end = max(int(np.searchsorted(cum, done_before + CANDIDATES_PER_BATCH, side="right")), start + 1)
        b = np.arange(start, end)
        start = end
        n_c = per[b]
        j = np.repeat(b, n_c)  # index into rows
        k = np.arange(n_c.sum()) - np.repeat(np.cumsum(n_c) - n_c, n_c)
        x = lo[rows[j], 0] + k % np.maximum(count_x[j], 1)
        y = lo_y[j] + k // np.maximum(count_x[j], 1)
        e = rows[j]
        inside = (x >= 0) & (x < W) & (y >= y0) & (y < y1)
        e, x, y = e[inside], x[inside], y[inside]
        same_chart = texel_shell[y - y0, x] == side_shell[e]
        e, x, y = e[same_chart], x[same_chart], y[same_chart]
        # the texel's distance from its side's segment, and where along it the nearest point is
        ax, ay = seg[e, 0, 0], seg[e, 0, 1]
        dx, dy = seg[e, 1, 0] - ax, seg[e, 1, 1] - ay
        if facing.any():
            own_side = (facing[e] == 0) | (np.sign(dx * (y - ay) - dy * (x - ax)) == facing[e])
            e, x, y, ax, ay, dx, dy = (a[own_side] for a in (e, x, y, ax, ay, dx, dy))
        length2 = dx * dx + dy * dy
        t = np.clip(np.divide((x - ax) * dx + (y - ay) * dy, length2, out=np.zeros(len(e)), where=length2 > 0),
                    0.0, 1.0)
        ex, ey = x - (ax + t * dx), y - (ay + t * dy)
        w = np.clip((band_texels - np.sqrt(ex * ex + ey * ey)) / (band_texels - core), 0.0, 1.0)
        keep = w > 0
        e, x, y, t, w = e[keep], x[keep], y[keep], t[keep], w[keep]
        if e.size == 0:
            continue
        delta = 0.5 * (theirs.colours(scan, e, t) - mine.colours(scan, e, t)).astype(np.float64)
        batches.append(((y - y0) * W + x, w, delta))
    if not batches:
        empty = np.zeros(0)
        return np.zeros(0, np.int64), np.zeros((0, 3)), empty, empty
    at = np.unique(np.concatenate([flat for flat, _, _ in batches]))
    offset = np.zeros((3, len(at)), np.float64)
    weight = np.zeros(len(at), np.float64)
    strongest = np.zeros(len(at), np.float64)
    for flat, w, delta in batches:  # each batch's sums added in turn, as the texels' own sums
        slot = np.searchsorted(at, flat)
        for c in range(3):
            offset[c] += np.bincount(slot, w * delta[:, c], len(at))
        weight += np.bincount(slot, w, len(at))
        np.maximum.at(strongest, slot, w)
    return at, offset.T, weight, strongest


def transfer_texture(source: Scan, target: Scan, size: int) -> Scan:
    """``target`` (same geometry, new UV layout) with ``source``'s texture baked into its layout.

    Each target texel shows the source texture at the same surface point (same face, same barycentrics).
    """
    from scantex.atlas.bake import bake

    if source.n_faces != target.n_faces:
        raise ValueError(f"source has {source.n_faces} faces, target {target.n_faces}: not the same mesh")
    src_uv = source.triangle_uvs

    def colour(points, normals, faces, bary):
        uv = interpolate(faces, bary, src_uv)
        rgb = np.zeros((len(faces), 3), np.float32)
        mat = source.face_materials[faces]
        for m, material in enumerate(source.materials):
            sel = np.flatnonzero(mat == m)
            if sel.size and material.image is not None:
                rgb[sel] = sample_texture(material.image, uv[sel])[:, :3]
        return rgb

    images = bake(target, colour, size=size)
    return target.replace(materials=tuple(m.with_image(i) if i is not None else m
                                          for m, i in zip(target.materials, images)))
