"""What colour the bake gives each surface point: the colour sources of mesh-only mode.

Two sources, chosen by ``bake.source``:

- ``"input"`` (the default): **the input's own texels, levelled and denoised**. The input atlas is the
  best evidence there is of the surface's colour: a field fitted to renders of it at a ray per several
  texels is blurrier than it, and switching between the two draws patches. So every valid texel keeps
  the input's colour, changed only by

  1. the local seam levelling of :func:`scantex.atlas.levelling.seam_offsets`: a smooth additive
     offset per chart, interpolated from its UV vertices, that makes both sides of every seam agree
     (it cannot put an edge anywhere but on a seam, where it removes one);
  2. denoising against the field: the residual ``r = input - field`` (the field seen through the
     chart's appearance transform, i.e. its prediction of the input) is split into a low-frequency
     part, its mean over every vertex's faces interpolated over the surface, which is kept (the input's
     own low frequencies stay the input's: no patch of the field gets in), and the rest, of which the
     part smaller than ``noise_threshold`` is removed (clipped in magnitude): compression and sensor
     noise go, detail stronger than the noise stays.

  Holes (untextured faces) get a harmonic interpolation over the mesh of the colours around them; the
  ring of faces around a hole (whose lookups bleed into it), and every face black in part, keeps its own
  texels but where they are black, or darker than ``FADE_SHARE`` of the fill near black texels (an app's
  fade into its black).

- ``"field"``: the paper's bake: the field's canonical colour on every taught face (optionally mixed
  with ``detail`` of the input), the canonical input where no training ray reached, hole fill as above.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable

import numpy as np

from scantex import jit
from scantex.atlas.bake import SurfaceColour
from scantex.atlas.inpaint import harmonic_vertex_colours
from scantex.scan import Scan
from scantex.views.raycast import interpolate
from scantex.views.render import shade_hits

log = logging.getLogger(__name__)

#: barycentric sample points per face (centre, and inside each corner): for vertex means of a residual (here, and
#: photo mode's fallback offsets)
FACE_SAMPLES = np.array([[1 / 3, 1 / 3], [1 / 6, 1 / 6], [2 / 3, 1 / 6], [1 / 6, 2 / 3]], np.float32)
#: points per call of a colour function (bounded memory)
CHUNK = 65536
#: a denoising threshold below half an 8-bit step cannot change a stored texel: denoising is then skipped
NOISE_FLOOR = 0.5 / 255


def denoising_matters(noise: float, denoise: float) -> bool:
    """Whether removing residuals up to ``denoise`` times the atlas's ``noise`` level can change a
    stored (8-bit) texel; when it cannot, the field has nothing to do in the default bake."""
    return denoise * noise >= NOISE_FLOOR


def estimate_noise(image: np.ndarray, mask: np.ndarray | None = None, *, max_tiles: int = 64,
                   tile: int = 256) -> float:
    """Standard deviation (0-1 scale) of the noise in ``image (H, W, C)``, robustly.

    Immerkær's Laplacian-difference operator (zero on planes and linear ramps, 6 sigma on white noise)
    on the luminance, its median absolute value over ``mask (H, W)`` (texels inside charts, away from
    their borders) taken as the noise's (Donoho's MAD estimate): edges and texture are a minority of
    texels and do not move a median. Large images are read in at most ``max_tiles`` tiles of ``tile``²
    texels spread over the covered area (an 8192² atlas in a fraction of a second).
    """
    from scipy import ndimage

    H, W = image.shape[:2]
    mask = np.ones((H, W), bool) if mask is None else mask
    ty, tx = max(1, H // tile), max(1, W // tile)
    th, tw = H // ty, W // tx
    cover = mask[:ty * th, :tx * tw].reshape(ty, th, tx, tw).mean(axis=(1, 3))
    candidates = np.flatnonzero(cover.ravel() > 0.5)
    if candidates.size == 0:
        candidates = np.flatnonzero(cover.ravel() > 0)
    if candidates.size > max_tiles:
        candidates = candidates[np.linspace(0, candidates.size - 1, max_tiles).round().astype(int)]
    kernel = np.array([[1, -2, 1], [-2, 4, -2], [1, -2, 1]], np.float32)
    weights = np.array([0.299, 0.587, 0.114], np.float32)
    responses = []
    for k in candidates:
        y, x = divmod(int(k), tx)
        ys, xs = slice(y * th, (y + 1) * th), slice(x * tw, (x + 1) * tw)
        img = image[ys, xs].astype(np.float32) / (255.0 if image.dtype == np.uint8 else 1.0)
        lum = img[..., :3] @ weights if img.ndim == 3 else img
        response = np.abs(ndimage.convolve(lum, kernel, mode="nearest"))
        inside = ndimage.binary_erosion(mask[ys, xs], iterations=2)
        responses.append(response[inside])
    values = np.concatenate(responses) if responses else np.zeros(0)
    if values.size == 0:
        return 0.0
    return float(np.median(values) / 0.6745 / 6.0)


def atlas_noise(scan: Scan, exclude: np.ndarray | None = None) -> float:
    """The input atlases' noise level (:func:`estimate_noise` over the texels their faces cover,
    ``exclude`` faces left out), weighted by covered texels; 0 for an untextured scan."""
    from scantex.atlas.texelmap import texel_map

    total, weight = 0.0, 0
    for m, material in enumerate(scan.materials):
        if material.image is None or not scan.has_uvs:
            continue
        faces = np.flatnonzero((scan.face_materials == m) & (True if exclude is None else ~exclude))
        if faces.size == 0:
            continue
        H, W = material.image.shape[:2]
        # a quarter-resolution texel map is enough to say which texels are inside charts
        h, w = max(1, H // 4), max(1, W // 4)
        covered = texel_map(scan.triangle_uvs, w, h, faces).mask
        mask = np.repeat(np.repeat(covered, 4, axis=0), 4, axis=1)[:H, :W]
        mask = np.pad(mask, ((0, H - mask.shape[0]), (0, W - mask.shape[1])))
        n = int(mask.sum())
        if n:
            total += estimate_noise(material.image, mask) * n
            weight += n
    return total / weight if weight else 0.0


#: input texels up to this many 8-bit levels above the black level blend from the hole fill into their own colour
DARK_RAMP = 24.0
#: a hole fill's seed vertex whose lookup is more than this share black texels seeds nothing (its neighbours do);
#: below it, a uniformly dark texture (13-17 levels count as 0.5-0.7 black on the ramp) still seeds its own colour
MAX_BLACK_SHARE = 0.9


def _with_hole_fill(scan: Scan, base: SurfaceColour, fill: np.ndarray, ring: np.ndarray | None = None,
                    offset: Callable[[np.ndarray, np.ndarray], np.ndarray] | None = None,
                    reads_texels: bool = True) -> SurfaceColour:
    """``base`` outside the ``fill`` faces; inside, a harmonic interpolation over the mesh of ``base``'s
    colours at the vertices around them (read through a non-fill face each).

    ``ring``: ``(F,) bool`` fill faces that have texels of their own (the ring around a hole, kept out of
    training and of the fill's seeds because lookups near the hole read its black texels, and faces black in
    part): there each point keeps ``base`` but where the input's texels are black, which take the fill
    (blending in over ``DARK_RAMP`` levels; see :func:`_dark_texels`).
    On a coarse mesh a ring face is a large part of the surface, whose own texture the fill would replace
    by a smooth gradient (a patch the input does not have).

    ``offset(face_ids, bary) -> (n, 3)``: what ``base`` adds to every texel it looks up, black ones too (the
    seam levelling's offsets). A seed is the colour of its non-black texels, the lookup less its black share,
    renormalised; an offset left in the lookup would be renormalised with it, multiplied by ``1 / (1 - share)``
    (a real apartment's glass rim, its lookups 85 % black, took a levelling offset of +0.1 as +0.7: cyan).
    ``reads_texels``: False where ``base`` is not a lookup of the input's texels (the field's colour): its
    seeds are taken as they are."""
    outside = np.flatnonzero(~fill)
    corner_face = np.full(scan.n_vertices, -1)
    corner_slot = np.zeros(scan.n_vertices, int)
    for k in range(3):
        corner_face[scan.faces[outside, k]] = outside
        corner_slot[scan.faces[outside, k]] = k
    known = corner_face >= 0
    vertex_rgb = np.zeros((scan.n_vertices, 3))
    idx = np.flatnonzero(known)
    corner_bary = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]], np.float32)
    normals = scan.face_normals
    darkness = _dark_texels(scan)
    near_black = _near_black(scan)
    filling = bool(fill.any())
    renormalise = filling and reads_texels
    for s in range(0, idx.size, CHUNK):
        v = idx[s:s + CHUNK]
        f, b = corner_face[v], corner_bary[corner_slot[v]]
        rgb = base(scan.positions[v], normals[f], f, b)
        if renormalise:
            # a vertex beside a hole reads its black texels too (the bilinear lookup at a chart's corner): the
            # colour of the others, or nothing where they are nearly all of it (a real apartment's fill of its
            # unseen upper walls had a dark drip below every such vertex)
            share, dark = darkness(f, b, offset)
            rgb = (rgb - dark) / np.maximum(1.0 - share, 1e-6)
            known[v[share[:, 0] > MAX_BLACK_SHARE]] = False
        vertex_rgb[v] = rgb
    if filling:
        # a fill cut off from every seed (a fused scan's loose fragment, floating off the surface it belongs to
        # and seen cleanly by no photo) takes the colour of the surfaces nearest to it in space, not the scan's
        # mean colour: a real apartment's dark cabinets were dotted with light grey where their floaters were
        vertex_rgb = harmonic_vertex_colours(scan, known, vertex_rgb, nearest=True)

    def colour(points, normals, face_ids, bary):
        rgb = np.empty((len(face_ids), 3), np.float32)
        hole = fill[face_ids]
        if (~hole).any():
            rgb[~hole] = base(points[~hole], normals[~hole], face_ids[~hole], bary[~hole])
        if hole.any():
            corners = vertex_rgb[scan.faces[face_ids[hole]]]  # [n, 3, 3]
            b = bary[hole].astype(np.float64)
            w = np.stack([1 - b[:, 0] - b[:, 1], b[:, 0], b[:, 1]], axis=1)
            rgb[hole] = np.einsum("nk,nkc->nc", w, corners)
            own = np.flatnonzero(hole)[ring[face_ids[hole]]] if ring is not None else np.zeros(0, np.intp)
            if own.size:
                f, b = face_ids[own], bary[own]
                share, dark = darkness(f, b, offset)
                filled = rgb[own]
                kept = np.clip(base(points[own], normals[own], f, b) - dark + share * filled, 0, 1)
                rgb[own] = _faded_into(kept, filled, near_black(f, b))
        return rgb

    return colour


#: a texel of a hole's ring darker than this share of the hole fill's brightness at its point, near the
#: black, is taken for the app's fade into its black (see :func:`_faded_into`)
FADE_SHARE = 0.7
#: how far an app's fade reaches from its black, in texels (Polycam's 2048² atlases: some 20)
FADE_TEXELS = 24


def _faded_into(kept: np.ndarray, filled: np.ndarray, near: np.ndarray) -> np.ndarray:
    """Ring texels ``kept (n, 3)`` blended towards the hole fill ``filled (n, 3)`` at the same points where they
    are darker than ``FADE_SHARE`` of it (brightest channel) and near the black (``near (n,)``: 1 beside black
    texels, 0 from ``FADE_TEXELS`` away): fully where they are black, not at all from that share up or that
    far. An app fades its atlas into its black over the texels around what it did not see (Polycam: levels
    falling from the surface's own to 0 over some 20 texels); kept as they were, those texels drew a dark,
    jagged rim along the hole's faces where the fill begins. A ring texel as bright as the fill, a dark
    surface whose fill is as dark (the fill's seeds are its own colours), and the dark detail of a large ring
    face away from its hole are kept."""
    level = FADE_SHARE * np.maximum(filled.max(axis=1), 1e-6)
    w = (np.clip(1.0 - kept.max(axis=1) / level, 0.0, 1.0) * near)[:, None]
    return (kept + w * (filled - kept)).astype(kept.dtype)


def _near_black(scan: Scan):
    """A lookup ``(face_ids, bary) -> (N,)`` in [0, 1]: how near the input's black texels (``BLACK_LEVEL``) a
    surface point lies, falling from 1 beside them to 0 at ``FADE_TEXELS``: twice the black share of the square
    that far around it, read from a quarter-resolution table made at the first call (an 8192² atlas: 2048², a
    box filter)."""
    lookup = _texel_lookup(scan, _near_table, 1)
    return lambda face_ids, bary: lookup(face_ids, bary)[:, 0]


def _near_table(image: np.ndarray) -> np.ndarray:
    """:func:`_near_black`'s ``(H // 4, W // 4, 1)`` table of ``image``."""
    from scipy.ndimage import uniform_filter

    from scantex.atlas.holes import BLACK_LEVEL

    H, W = image.shape[:2]
    kernel = jit.compiled(_black_blocks) if image.dtype == np.uint8 and H >= 4 and W >= 4 else None
    if kernel is not None:  # one compiled pass (an 8192² atlas: 0.05 s, numpy's 0.7 s)
        quarter = np.empty((H // 4, W // 4), np.float32)
        kernel(image, BLACK_LEVEL, quarter)
    else:
        level = BLACK_LEVEL if image.dtype == np.uint8 else BLACK_LEVEL / 255.0
        # the channels' maximum pairwise (numpy's max over a row of three is many times slower)
        black = np.maximum(np.maximum(image[..., 0], image[..., 1]), image[..., 2]) <= level
        h, w = max(1, H // 4), max(1, W // 4)
        quarter = black.astype(np.float32) if H < 4 or W < 4 else \
            black[:4 * h, :4 * w].reshape(h, 4, w, 4).sum(axis=(1, 3), dtype=np.uint8) / np.float32(16)
    reach = FADE_TEXELS * max(quarter.shape) / max(H, W)  # in the table's texels
    size = 2 * max(1, int(round(reach))) + 1
    return np.clip(2.0 * uniform_filter(quarter, size, mode="wrap"), 0, 1)[..., None]


def _texel_lookup(scan: Scan, make: Callable[[np.ndarray], np.ndarray], channels: int):
    """A lookup ``(face_ids, bary) -> (N, channels) float32``: the bilinear lookup, at surface points, of a table
    ``make(image)`` of each textured material's atlas (0-1 for an 8-bit table), made at the first call that
    needs it; zeros on materials without a texture. The bake colours chunks in threads: the first to need a
    table makes it."""
    from scantex.views.render import hit_uvs, sample_texture

    tables: dict[int, np.ndarray] = {}
    making = threading.Lock()

    def table(m: int) -> np.ndarray:
        with making:
            if m not in tables:
                tables[m] = make(scan.materials[m].image)
        return tables[m]

    def lookup(face_ids: np.ndarray, bary: np.ndarray) -> np.ndarray:
        out = np.zeros((len(face_ids), channels), np.float32)
        uv = hit_uvs(scan, face_ids, bary)
        materials = scan.face_materials[face_ids]
        for m, material in enumerate(scan.materials):
            sel = np.flatnonzero(materials == m)
            if material.image is not None and sel.size:
                out[sel] = sample_texture(table(m), uv[sel])
        return out

    return lookup


def _black_blocks(image, level, out):
    """The compiled twin of :func:`_near_table`'s quarter-resolution counts: ``out (H // 4, W // 4)`` the share of
    each 4x4 block of the 8-bit ``image (H, W, >= 3)`` whose channels are all at most ``level``."""
    for by in range(out.shape[0]):
        for bx in range(out.shape[1]):
            count = 0
            for y in range(4 * by, 4 * by + 4):
                for x in range(4 * bx, 4 * bx + 4):
                    if max(max(image[y, x, 0], image[y, x, 1]), image[y, x, 2]) <= level:
                        count += 1
            out[by, bx] = np.float32(count) / np.float32(16)


def _dark_texels(scan: Scan):
    """A lookup ``(face_ids, bary) -> (share (N, 1), dark (N, 3))`` of the input's black texels at surface
    points: each texel counts as black by ``w`` = 1 at ``BLACK_LEVEL`` and below, falling to 0 over
    ``DARK_RAMP`` levels (JPEG leaves a little noise on an app's black); ``share`` is the bilinear lookup of
    ``w`` and ``dark`` that of ``w`` times the texel's colour. ``base - dark + share * fill`` is then the
    lookup of an atlas whose black texels were replaced by the fill: no dark rim where bilinear lookups mix
    a black texel with a coloured one. The tables (4 bytes a texel) are made at the first call."""
    lookup = _texel_lookup(scan, _dark_texel_table, 4)
    diffuse = np.asarray([m.diffuse[:3] for m in scan.materials], np.float32)

    def darkness(face_ids: np.ndarray, bary: np.ndarray, offset=None) -> tuple[np.ndarray, np.ndarray]:
        """``offset(face_ids, bary)``, when given, is what a colour adds to every texel it looks up: ``dark``
        then includes the black texels' share of it."""
        looked = lookup(face_ids, bary)  # 0-1
        share = looked[:, :1]
        dark = looked[:, 1:] * diffuse[scan.face_materials[face_ids]]
        if offset is not None:
            dark += share * np.asarray(offset(face_ids, bary), np.float32)
        return share, dark

    return darkness


def _dark_texel_table(image: np.ndarray) -> np.ndarray:
    """:func:`_dark_texels`' ``(H, W, 4) uint8`` table of ``image``: ``w`` times 255, and ``w`` times the texel."""
    from scantex.atlas.holes import BLACK_LEVEL

    out = np.empty((*image.shape[:2], 4), np.uint8)
    kernel = jit.compiled(_dark_table) if image.dtype == np.uint8 else None
    if kernel is not None:  # one compiled pass (an 8192^2 atlas: about 0.2 s, where numpy took 1-2 s)
        kernel(image, out, BLACK_LEVEL, np.float32(BLACK_LEVEL + DARK_RAMP), np.float32(DARK_RAMP))
        return out

    def weighted(levels: np.ndarray) -> np.ndarray:
        """``(..., 4)`` table entries of texels ``levels (..., 3)`` in 8-bit levels (float32)."""
        # the channels' maximum pairwise: numpy's max over a row of three is many times slower
        brightest = np.maximum(np.maximum(levels[..., 0], levels[..., 1]), levels[..., 2])[..., None]
        w = np.clip((BLACK_LEVEL + DARK_RAMP - brightest) / DARK_RAMP, 0, 1)
        # in 8-bit levels: w * 255, and w times the texel (at most BLACK_LEVEL + DARK_RAMP levels)
        return np.concatenate([np.rint(w * 255), np.rint(w * levels)], axis=-1)

    for r in range(0, image.shape[0], 512):  # a band of rows at a time: bounded memory on 8192² atlases
        band = out[r:r + 512]
        if image.dtype != np.uint8:
            band[:] = weighted(image[r:r + 512, :, :3].astype(np.float32) * 255.0)
            continue
        # 8-bit texels: w is 1 at BLACK_LEVEL and below (the entry is the texel itself) and 0 from the ramp's
        # end (the entry is 0), both exactly; only the few texels on the ramp take arithmetic (an 8192² atlas:
        # 3.4 -> 1.3 s, the same table)
        levels = image[r:r + 512, :, :3]
        brightest = np.maximum(np.maximum(levels[..., 0], levels[..., 1]), levels[..., 2])
        black = (brightest <= BLACK_LEVEL).view(np.uint8)
        np.multiply(black, 255, out=band[..., 0])
        np.multiply(levels, black[..., None], out=band[..., 1:])
        ramp = np.flatnonzero((brightest > BLACK_LEVEL) & (brightest < BLACK_LEVEL + DARK_RAMP))
        if ramp.size:
            band.reshape(-1, 4)[ramp] = weighted(levels.reshape(-1, 3)[ramp].astype(np.float32))
    return out


def _dark_table(image, out, black_level, ramp_end, ramp):
    """The compiled twin of :func:`_dark_texel_table` for an 8-bit ``image (H, W, >= 3)``: ``out (H, W, 4)`` the
    texel itself behind 255 at ``black_level`` and below, zeros from ``ramp_end`` up, and between them ``w`` = (ramp_end
    - brightest) / ramp times 255 and times the texel, rounded, in float32 as the numpy table computes them."""
    H, W = image.shape[0], image.shape[1]
    for y in range(H):
        for x in range(W):
            r, g, b = image[y, x, 0], image[y, x, 1], image[y, x, 2]
            brightest = max(max(r, g), b)
            if brightest <= black_level:
                out[y, x, 0] = 255
                out[y, x, 1] = r
                out[y, x, 2] = g
                out[y, x, 3] = b
            elif np.float32(brightest) < ramp_end:
                w = min(max((ramp_end - np.float32(brightest)) / ramp, np.float32(0.0)), np.float32(1.0))
                out[y, x, 0] = np.uint8(np.rint(w * np.float32(255.0)))
                out[y, x, 1] = np.uint8(np.rint(w * np.float32(r)))
                out[y, x, 2] = np.uint8(np.rint(w * np.float32(g)))
                out[y, x, 3] = np.uint8(np.rint(w * np.float32(b)))
            else:
                out[y, x, 0] = out[y, x, 1] = out[y, x, 2] = out[y, x, 3] = 0


def field_colour(scan: Scan, fitted, fill: np.ndarray, taught: np.ndarray, charts: np.ndarray, device, *,
                 detail: float = 0.0) -> SurfaceColour:
    """The paper's bake (``bake.source = "field"``).

    - taught faces: the field's canonical colour, mixed with ``detail`` of the input's own colour brought
      to the canonical appearance by its chart's inverse transform (``field + detail * (input - field)``);
    - faces no training ray reached but the input textures: that canonical input colour (a hash grid is
      noise where nothing taught it);
    - ``fill`` faces (holes and their border): a harmonic interpolation over the mesh of the colours
      around them.
    """
    import torch

    use_input = fitted.appearance is not None and scan.is_textured

    def base(points, normals, face_ids, bary):
        rgb = fitted.surface_colour(points, normals, device)
        if not use_input:
            return rgb
        weight = np.where(taught[face_ids], detail, 1.0)[:, None]
        sel = np.flatnonzero(weight[:, 0] > 0)
        if sel.size:
            observed = shade_hits(scan, face_ids[sel], bary[sel])
            canon = fitted.appearance.canonical(torch.as_tensor(observed, device=device),
                                                torch.as_tensor(charts[face_ids[sel]], device=device))
            rgb[sel] = np.clip(rgb[sel] + weight[sel] * (canon.cpu().numpy() - rgb[sel]), 0, 1)
        return rgb

    return _with_hole_fill(scan, base, fill, reads_texels=False)


def field_prediction(fitted, charts: np.ndarray, device):
    """The field's prediction of the *input's* colour at surface points: its canonical colour seen
    through the point's chart's appearance transform (what it was trained to match)."""
    import torch

    def predict(points, normals, face_ids):
        rgb = fitted.surface_colour(points, normals, device)
        if fitted.appearance is None:
            return rgb
        with torch.no_grad():
            seen = fitted.appearance(torch.as_tensor(rgb, device=device),
                                     torch.as_tensor(charts[face_ids], device=device))
        return seen.cpu().numpy().astype(np.float32)

    return predict


def residual_vertex_means(scan: Scan, predict, usable: np.ndarray) -> np.ndarray:
    """``(V, 3)`` mean of ``input - prediction`` over sample points of each vertex's ``usable`` faces
    (0 at vertices with none): the low-frequency part of the residual, interpolated over faces."""
    faces = np.flatnonzero(usable)
    V = scan.n_vertices
    sums = np.zeros((V, 3))
    counts = np.zeros(V)
    if faces.size == 0:
        return sums
    normals = scan.face_normals
    S = len(FACE_SAMPLES)
    per_chunk = max(1, CHUNK // S)
    for s in range(0, faces.size, per_chunk):
        f = np.repeat(faces[s:s + per_chunk], S)
        bary = np.tile(FACE_SAMPLES, (len(f) // S, 1))
        points = interpolate(f, bary, scan.triangles)
        r = shade_hits(scan, f, bary) - predict(points, normals[f], f)
        face_mean = r.reshape(-1, S, 3).mean(axis=1)  # [n, 3]
        corner = scan.faces[faces[s:s + per_chunk]]
        for k in range(3):
            np.add.at(sums, corner[:, k], face_mean)
            np.add.at(counts, corner[:, k], 1.0)
    return np.divide(sums, counts[:, None], out=np.zeros_like(sums), where=counts[:, None] > 0)


def levelled_input_colour(scan: Scan, offsets: np.ndarray, fill: np.ndarray, *, fitted=None,
                          taught: np.ndarray | None = None, charts: np.ndarray | None = None, device=None,
                          noise_threshold: float = 0.0) -> SurfaceColour:
    """The input's texels, levelled and denoised (``bake.source = "input"``; see the module docstring).

    Args:
        scan: the textured input scan.
        offsets: ``(T, 3)`` additive offset per UV vertex (:func:`scantex.atlas.levelling.seam_offsets`).
        fill: ``(F,) bool`` faces given the harmonic hole fill.
        fitted: the trained field (for denoising; ``None``: no denoising).
        taught: ``(F,) bool`` faces the field was taught on (only there is it trusted).
        charts: ``(F,)`` appearance group of every face.
        noise_threshold: residual magnitude (0-1 RGB) up to which a difference from the field counts as
            noise and is removed; 0 keeps the input's high frequencies exactly.
    """
    corner_offsets = offsets[scan.face_uvs].astype(np.float32)  # [F, 3, 3]
    denoise = fitted is not None and noise_threshold > 0 and taught is not None and taught.any()
    if denoise:
        predict = field_prediction(fitted, charts, device)
        usable = taught & ~fill
        low = residual_vertex_means(scan, predict, usable).astype(np.float32)
        corner_low = low[scan.faces]  # [F, 3, 3]

    def base(points, normals, face_ids, bary):
        observed = shade_hits(scan, face_ids, bary)
        rgb = observed + interpolate(face_ids, bary, corner_offsets)
        if denoise:
            sel = np.flatnonzero(usable[face_ids])
            if sel.size:
                f, b = face_ids[sel], bary[sel]
                high = observed[sel] - predict(points[sel], normals[sel], f) - interpolate(f, b, corner_low)
                size = np.linalg.norm(high, axis=1, keepdims=True)
                # the part of the high-frequency residual within the noise level is noise: remove it
                rgb[sel] -= high * np.minimum(1.0, noise_threshold / np.maximum(size, 1e-12))
        return np.clip(rgb, 0, 1)

    from scantex.atlas.holes import partly_untextured_faces, untextured_faces

    # faces black in part keep their own texels and take the fill where those are black, as a hole's ring does
    holes = untextured_faces(scan)
    partly = partly_untextured_faces(scan, holes) & ~fill
    return _with_hole_fill(scan, base, fill | partly, ring=(fill & ~holes) | partly,
                           offset=lambda face_ids, bary: interpolate(face_ids, bary, corner_offsets))
