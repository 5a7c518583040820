"""Rendering a scan from its G-buffers: unlit texture lookup (what the field fits) and a lit preview.

Colours are the texture's stored values scaled to [0, 1] (no colour management: scans store sRGB
and so does every output, so the field learns and bakes sRGB values).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from scantex.scan import Scan
from scantex.views.camera import Camera
from scantex.views.raycast import GBuffer, RayCaster, cast_gbuffer, interpolate, interpolate_indexed


def sample_texture(image: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Bilinear lookup of ``image (H, W, C)`` at ``uv (N, 2)``, repeating outside [0, 1].

    Returns ``(N, C) float32`` in [0, 1] for uint8 images (values as stored for float images).
    Compiled (:mod:`scantex.jit`: a point at a time, 5-10x faster than numpy's passes over rows of a few
    channels), or in numpy where numba is missing (the four texels gathered by flat index, ``take`` on the
    ``(H * W, C)`` image); both do :func:`sample_texture_reference`'s arithmetic, bit for bit.
    """
    from scantex import jit

    H, W = image.shape[:2]
    scale = 1.0 / 255.0 if image.dtype == np.uint8 else 1.0
    kernel = jit.compiled(_sample_kernel)
    uv = np.asarray(uv)
    if kernel is not None and uv.dtype in (np.float32, np.float64) and image.dtype in (np.uint8, np.float32,
                                                                                       np.float64):
        texels = np.ascontiguousarray(image).reshape(H * W, -1)
        out = np.empty((len(uv), texels.shape[1]), np.float32)
        # the constants in the types numpy's arithmetic takes them in (a Python number adopts the array's type)
        real, value = uv.dtype.type, np.float32 if image.dtype == np.uint8 else image.dtype.type
        kernel(texels, np.ascontiguousarray(uv), real(W), real(H), real(1), real(0.5), W, H, value(scale), out)
        return out
    x0, y0, fx, fy = _texel_corner(uv, W, H)
    x1 = x0 + 1
    x1[x1 == W] = 0
    row0 = y0 * W
    row1 = y0 + 1
    row1[row1 == H] = 0
    row1 *= W
    texels = image.reshape(H * W, -1)
    gx = 1 - fx
    top = texels.take(row0 + x0, axis=0) * gx + texels.take(row0 + x1, axis=0) * fx
    bottom = texels.take(row1 + x0, axis=0) * gx + texels.take(row1 + x1, axis=0) * fx
    return ((top * (1 - fy) + bottom * fy) * scale).astype(np.float32)


def _sample_kernel(texels, uv, width, height, one, half, W, H, scale, out):
    """:func:`sample_texture`'s kernel: ``texels (H * W, C)``, ``uv (N, 2)``; ``width``, ``height``, ``one`` and
    ``half`` the image's size, 1 and 0.5 in the uv's type, ``scale`` in the arithmetic's; ``out (N, C)`` filled
    in."""
    one32 = np.float32(1)
    for i in range(uv.shape[0]):
        x = uv[i, 0] * width - half
        y = (one - uv[i, 1]) * height - half
        left, top_row = np.floor(x), np.floor(y)
        x0, y0 = int(left) % W, int(top_row) % H
        fx, fy = np.float32(x - left), np.float32(y - top_row)
        x1 = x0 + 1 if x0 + 1 < W else 0
        y1 = y0 + 1 if y0 + 1 < H else 0
        gx, gy = one32 - fx, one32 - fy
        a, b, c, d = y0 * W + x0, y0 * W + x1, y1 * W + x0, y1 * W + x1
        for k in range(texels.shape[1]):
            top = texels[a, k] * gx + texels[b, k] * fx
            bottom = texels[c, k] * gx + texels[d, k] * fx
            out[i, k] = (top * gy + bottom * fy) * scale


def _texel_corner(uv: np.ndarray, W: int, H: int):
    """The top-left texel ``x0, y0 (N,) int64`` (wrapped) of the bilinear lookups at ``uv (N, 2)`` in a
    ``W x H`` image, and the weights ``fx, fy (N, 1) float32`` of the texels right of and below it."""
    x = uv[:, 0] * W - 0.5
    y = (1.0 - uv[:, 1]) * H - 0.5
    x0 = np.floor(x)
    y0 = np.floor(y)
    fx = (x - x0).astype(np.float32)[:, None]
    fy = (y - y0).astype(np.float32)[:, None]
    return x0.astype(np.int64) % W, y0.astype(np.int64) % H, fx, fy


def sample_texture_reference(image: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Slow, plainly written twin of :func:`sample_texture` (rows and columns indexed); for tests."""
    H, W = image.shape[:2]
    scale = 1.0 / 255.0 if image.dtype == np.uint8 else 1.0
    x0, y0, fx, fy = _texel_corner(uv, W, H)
    x1 = (x0 + 1) % W
    y1 = (y0 + 1) % H
    img = image.reshape(H, W, -1)
    top = img[y0, x0] * (1 - fx) + img[y0, x1] * fx
    bottom = img[y1, x0] * (1 - fx) + img[y1, x1] * fx
    return ((top * (1 - fy) + bottom * fy) * scale).astype(np.float32)


#: above this many materials, :func:`shade_hits` sorts its points by material once (a Matterport export's
#: hundreds made a pass over every point per material a share of the bake); below, a pass each is faster
SORT_MATERIALS = 8


def shade_hits(scan: Scan, face_id: np.ndarray, bary: np.ndarray, uv: np.ndarray | None = None) -> np.ndarray:
    """Unlit RGB ``(N, 3) float32`` of surface points given as ``face_id (N,)`` (all >= 0), ``bary (N, 2)``.

    Texture (per material) when the scan has UVs, else vertex colours, else face colours, else the
    material's base colour. ``uv``: the points' texture coordinates ``(N, 2)`` when already interpolated
    (:func:`hit_uvs`; scans that share a UV layout share them).
    """
    N = len(face_id)
    rgb = np.empty((N, 3), dtype=np.float32)
    mat_of_hit = scan.face_materials[face_id]
    if uv is None and scan.has_uvs and any(m.image is not None for m in scan.materials):
        uv = hit_uvs(scan, face_id, bary)
    sorted_out = len(scan.materials) > SORT_MATERIALS
    if sorted_out:  # each material's points from one sort, not a pass over them all per material
        order = np.argsort(mat_of_hit, kind="stable")
        bounds = np.searchsorted(mat_of_hit[order], np.arange(len(scan.materials) + 1))
    for m, material in enumerate(scan.materials):
        if sorted_out:
            sel = order[bounds[m]:bounds[m + 1]]
        else:
            sel = np.flatnonzero(mat_of_hit == m) if len(scan.materials) > 1 else np.arange(N)
        if sel.size == 0:
            continue
        base = np.asarray(material.diffuse[:3], dtype=np.float32)
        if material.image is not None and uv is not None:
            looked = sample_texture(material.image, uv if sel.size == N else uv[sel])[:, :3]
            if not (base == 1).all():  # times 1 is the identity: no pass for the usual white base
                looked = looked * base
            if sel.size == N:  # every point (one material): a copy, not a scatter by index
                rgb[:] = looked
            else:
                rgb[sel] = looked
        elif scan.vertex_colors is not None:
            corner = scan.vertex_colors[scan.faces][:, :, :3].astype(np.float32) / 255.0
            rgb[sel] = interpolate(face_id[sel], bary[sel], corner)
        elif scan.face_colors is not None:
            rgb[sel] = scan.face_colors[face_id[sel], :3].astype(np.float32) / 255.0
        else:
            rgb[sel] = base
    return rgb


def hit_uvs(scan: Scan, face_id: np.ndarray, bary: np.ndarray) -> np.ndarray:
    """``(N, 2)``: the texture coordinates of the surface points ``face_id (N,)``, ``bary (N, 2)`` (0 where
    ``face_id`` is -1, a miss)."""
    # read through face_uvs, hit by hit (gathering every face's corners at each call cost more than the lookup)
    return interpolate_indexed(face_id, bary, scan.face_uvs, scan.uvs)


def render_gbuffer(scan: Scan, gbuffer: GBuffer, background=(0.0, 0.0, 0.0)) -> np.ndarray:
    """Unlit colours ``(H, W, 3) float32`` in [0, 1] of the surface each pixel sees."""
    return shade_pixels(scan, gbuffer.face_id, gbuffer.bary, background)


def shade_pixels(scan: Scan, face_id: np.ndarray, bary: np.ndarray, background=(0.0, 0.0, 0.0),
                 uv: np.ndarray | None = None) -> np.ndarray:
    """Unlit colours ``(H, W, 3) float32`` of the surface points ``face_id (H, W)`` (-1: none, ``background``)
    and ``bary (H, W, 2)`` that an image's pixels see (``uv``: as :func:`shade_hits` takes it, for the pixels
    that see the surface, in row-major order)."""
    H, W = face_id.shape
    image = np.empty((H * W, 3), dtype=np.float32)
    image[:] = background
    fid = face_id.reshape(-1)
    hit = np.flatnonzero(fid >= 0)
    image[hit] = shade_hits(scan, fid[hit], bary.reshape(-1, 2)[hit], uv)
    return image.reshape(H, W, 3)


@dataclass(frozen=True)
class Light:
    """A directional light plus ambient, for previews.

    Attributes:
        direction_camera: ``(3,)`` direction the light travels, in camera coordinates (OpenCV axes), so
            that every view is lit from the same side: the default comes from the upper left, behind
            the viewer.
        ambient: share of the colour that is lit regardless of orientation.
    """

    direction_camera: tuple[float, float, float] = (0.4, 0.5, 1.0)
    ambient: float = 0.35


def shade_lit(albedo: np.ndarray, gbuffer: GBuffer, camera: Camera, light: Light = Light()) -> np.ndarray:
    """Lambertian shading of ``albedo (H, W, 3)`` by a directional light; two-sided."""
    d = camera.R.T @ np.asarray(light.direction_camera, dtype=np.float64)
    d /= np.linalg.norm(d)
    n = gbuffer.normal.astype(np.float64)
    # two-sided: face the normal towards the camera (scanned surfaces are seen from either side)
    view = camera.forward
    n = np.where((n @ view)[..., None] > 0, -n, n)
    lambert = np.clip(-(n @ d), 0.0, 1.0)[..., None]
    shaded = albedo * (light.ambient + (1 - light.ambient) * lambert)
    return np.where(gbuffer.mask[..., None], shaded, albedo).astype(np.float32)


def downsample(image: np.ndarray, factor: int) -> np.ndarray:
    """Box-filter ``(H*f, W*f, C)`` to ``(H, W, C)``: the sum of the ``f * f`` strided ``(H, W, C)`` views (a
    reduction over the strided axes of an ``(H, f, W, f, C)`` array is several times slower), over ``f * f``."""
    if factor == 1:
        return image
    H, W = image.shape[0] // factor, image.shape[1] // factor
    image = image[:H * factor, :W * factor].reshape(H * factor, W * factor, -1)
    total = np.zeros((H, W, image.shape[2]), image.dtype if image.dtype.kind == "f" else np.float64)  # as mean's
    for a in range(factor):
        for b in range(factor):
            total += image[a::factor, b::factor]
    return total / total.dtype.type(factor * factor)


def render(scan: Scan, camera: Camera, caster: RayCaster | None = None, *, lit: bool = False,
           supersample: int = 1, light: Light = Light(), background=(0.0, 0.0, 0.0)):
    """Render one view of a scan.

    Args:
        scan: the scan.
        camera: the view.
        caster: a prebuilt :class:`RayCaster` (built here when ``None``).
        lit: shade with ``light`` (a preview) instead of returning the unlit texture colour.
        supersample: rays per pixel along each axis (box filtered).
        background: RGB of pixels that see nothing.

    Returns:
        ``(image, alpha)``: ``(H, W, 3) float32`` in [0, 1] and ``(H, W) float32`` coverage.
    """
    return render_scans({"": scan}, camera, caster, lit=lit, supersample=supersample, light=light,
                        background=background)[""]


def render_scans(scans: dict[str, Scan], camera: Camera, caster: RayCaster | None = None, *, lit: bool = False,
                 supersample: int = 1, light: Light = Light(), background=(0.0, 0.0, 0.0),
                 fine: dict | None = None) -> dict:
    """:func:`render` of several scans that share one geometry (an input, its result, a ground truth):
    the rays are cast once. Returns ``{name: (image, alpha)}``. ``fine``: if given, receives each scan's
    image before the supersamples are averaged (``supersample`` times the camera's size, one ray a pixel:
    the render of ``camera.scaled(supersample)``), as ``uint8``."""
    first = next(iter(scans.values()))
    caster = caster or RayCaster(first.positions, first.faces)
    cam = camera.scaled(supersample) if supersample > 1 else camera
    g = cast_gbuffer(caster, cam, first.face_normals if lit else None)
    alpha = downsample(g.mask.astype(np.float32)[..., None], supersample)[..., 0]
    out = {}
    layouts: dict[tuple[int, int], np.ndarray] = {}  # the hits' UVs, once for scans sharing a UV layout
    for name, scan in scans.items():
        uv = None
        if scan.has_uvs:
            key = (id(scan.uvs), id(scan.face_uvs))
            if key not in layouts:
                fid = g.face_id.reshape(-1)
                hit = np.flatnonzero(fid >= 0)
                layouts[key] = hit_uvs(scan, fid[hit], g.bary.reshape(-1, 2)[hit])
            uv = layouts[key]
        rgb = shade_pixels(scan, g.face_id, g.bary, background, uv)
        if lit:
            rgb = shade_lit(rgb, g, cam, light)
        if fine is not None:
            fine[name] = to_uint8(rgb)
        out[name] = (downsample(rgb, supersample), alpha)
    return out


def to_uint8(image: np.ndarray) -> np.ndarray:
    """``[0, 1]`` float image to uint8 with rounding."""
    return np.clip(np.rint(np.asarray(image) * 255.0), 0, 255).astype(np.uint8)
