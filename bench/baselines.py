"""Classical baselines for texture enhancement, each an honest implementation of a standard technique.

Every baseline returns a :class:`Scan` with the input's geometry and UV layout untouched and new
(possibly larger) atlases, so it is scored exactly like scantex's output:

- :func:`bicubic`: the atlas upscaled with Pillow's bicubic filter (what "raise the resolution" means
  without learning).
- :func:`inpaint_and_blend`: holes (faces left black) filled by biharmonic inpainting in the atlas
  (scikit-image), then every UV seam levelled: texels near a seam move towards the mean of the two sides
  with a Gaussian fall-off, so the two lookups of the same 3D points meet.
- :func:`backproject`: the input's own renders from several views averaged back into the atlas: per
  texel, the mean colour of the views that see its 3D point unoccluded (G-buffer depth test).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import numpy as np
from PIL import Image

from scantex.atlas.holes import BLACK_LEVEL, untextured_faces
from scantex.atlas.inpaint import grow_faces
from scantex.atlas.padding import pad_gutters
from scantex.atlas.seams import seam_edges, uv_shells
from scantex.atlas.texelmap import texel_map, uv_to_pixel
from scantex.scan import Scan
from scantex.views.camera import Camera
from scantex.views.raycast import RayCaster
from scantex.views.render import sample_texture, to_uint8


def _with_images(scan: Scan, images: Sequence[np.ndarray | None], tag: str) -> Scan:
    materials = tuple(m if img is None else dataclasses.replace(m, image=img, image_name=f"{tag}_{m.name}.png")
                      for m, img in zip(scan.materials, images))
    return scan.replace(materials=materials, source=None)


def _float(image: np.ndarray) -> np.ndarray:
    return image[..., :3].astype(np.float32) / 255.0


# -- bicubic ----------------------------------------------------------------------------------------


def bicubic(scan: Scan, factor: int = 2) -> Scan:
    """Every atlas ``factor`` times larger, bicubic (Pillow)."""
    images = []
    for m in scan.materials:
        if m.image is None:
            images.append(None)
            continue
        H, W = m.image.shape[:2]
        images.append(np.asarray(Image.fromarray(m.image[..., :3]).resize((W * factor, H * factor), Image.BICUBIC)))
    return _with_images(scan, images, "bicubic")


# -- inpainting + seam blending ---------------------------------------------------------------------


def inpaint_holes(scan: Scan) -> Scan:
    """Fill the texels of untextured faces by biharmonic inpainting (scikit-image) in each atlas.

    The mask is the texels of untextured faces and every black texel inside a chart, grown by one texel
    (JPEG leaves dark fringes). Gutters are first padded from the nearest chart texel, so a hole at a
    chart's border is filled from the chart, not from the black around it.
    """
    from scipy.ndimage import binary_dilation

    from scantex.deps import require

    inpaint_biharmonic = require("skimage.restoration", "the inpainting baseline").inpaint_biharmonic

    holes = untextured_faces(scan)
    images = []
    for m, material in enumerate(scan.materials):
        faces = np.flatnonzero(scan.face_materials == m)
        if material.image is None or faces.size == 0 or not holes[faces].any():
            images.append(material.image)
            continue
        H, W = material.image.shape[:2]
        tmap = texel_map(scan.triangle_uvs, W, H, faces)
        covered = tmap.mask
        # the hole faces' texels, and every black texel (faces at a hole's rim are partly black too)
        black = material.image[..., :3].max(axis=2) <= BLACK_LEVEL
        mask = covered & (holes[np.where(covered, tmap.face_id, 0)] | black)
        mask = binary_dilation(mask, iterations=1) & covered
        image = pad_gutters(_float(material.image), covered & ~mask)
        filled = inpaint_biharmonic(image, mask, channel_axis=-1)
        images.append(to_uint8(pad_gutters(filled, covered)))
    return _with_images(scan, images, "inpainted")


def blend_seams(scan: Scan, sigma_texels: float = 1.5, reach_texels: float = 4.0) -> Scan:
    """Level every UV seam: each texel within ``reach_texels`` of a seam edge moves by
    ``g(d) * (mean of the two sides - own side)`` at its place along the edge, ``g(d) = exp(-d² / 2σ²)``,
    ``d`` its distance to the edge in texels. Both sides then meet at their mean on the seam.
    """
    edges = seam_edges(scan)
    if len(edges) == 0 or not scan.is_textured:
        return scan
    images = []
    tri_uv = scan.triangle_uvs  # [F, 3, 2]
    chart_of_face = uv_shells(scan)
    for m, material in enumerate(scan.materials):
        faces = np.flatnonzero(scan.face_materials == m)
        if material.image is None or faces.size == 0:
            images.append(material.image)
            continue
        H, W = material.image.shape[:2]
        tmap = texel_map(tri_uv, W, H, faces)
        covered = tmap.mask
        chart = np.where(covered, chart_of_face[np.where(covered, tmap.face_id, 0)], -1)
        image = _float(material.image)
        shift = np.zeros((H, W, 3), np.float64)
        weight = np.zeros((H, W), np.float64)
        pix = uv_to_pixel(tri_uv, W, H)  # [F, 3, 2] texel coordinates of the corners
        for (fa, fb), (ca, cb) in zip(edges.faces, edges.corners):
            if scan.face_materials[fa] != m or scan.face_materials[fb] != m:
                continue  # a seam between atlases: each side is levelled within its own atlas only
            for own, oc, other, xc in ((fa, ca, fb, cb), (fb, cb, fa, ca)):
                p0, p1 = pix[own, oc[0]], pix[own, oc[1]]
                q0, q1 = pix[other, xc[0]], pix[other, xc[1]]
                lo = np.floor(np.minimum(p0, p1) - reach_texels).astype(int)
                hi = np.ceil(np.maximum(p0, p1) + reach_texels).astype(int)
                ys, xs = np.mgrid[max(lo[1], 0):min(hi[1], H - 1) + 1, max(lo[0], 0):min(hi[0], W - 1) + 1]
                ys, xs = ys.ravel(), xs.ravel()
                keep = chart[ys, xs] == chart_of_face[own]  # this side's chart only, not a neighbour in the atlas
                ys, xs = ys[keep], xs[keep]
                if ys.size == 0:
                    continue
                e = p1 - p0
                length2 = float(e @ e)
                if length2 == 0:
                    continue
                rel = np.stack([xs, ys], axis=1) - p0
                t = np.clip(rel @ e / length2, 0.0, 1.0)
                d = np.linalg.norm(rel - t[:, None] * e, axis=1)
                near = d <= reach_texels
                # only texels on this side of the seam: those the own face's chart holds
                near &= _same_chart_side(rel, e, pix[own, 3 - oc[0] - oc[1]] - p0)
                if not near.any():
                    continue
                ys, xs, t, d = ys[near], xs[near], t[near], d[near]
                own_colour = _inset_lookup(material.image, p0, p1, pix[own, 3 - oc[0] - oc[1]], t, W, H)
                other_colour = _inset_lookup(material.image, q0, q1, pix[other, 3 - xc[0] - xc[1]], t, W, H)
                g = np.exp(-d**2 / (2 * sigma_texels**2))
                np.add.at(shift, (ys, xs), g[:, None] * (0.5 * (other_colour - own_colour)))
                np.add.at(weight, (ys, xs), g)
        blended = image + shift / np.maximum(weight, 1.0)[..., None]
        images.append(to_uint8(pad_gutters(np.clip(blended, 0, 1), covered)))
    return _with_images(scan, images, "blended")


def _same_chart_side(rel: np.ndarray, edge: np.ndarray, third: np.ndarray) -> np.ndarray:
    """Texels on the same side of the edge line as the face's third corner (or on it)."""
    cross = rel[:, 0] * edge[1] - rel[:, 1] * edge[0]
    side = third[0] * edge[1] - third[1] * edge[0]
    return cross * np.sign(side) >= -0.5 * np.sqrt(edge @ edge)


def _inset_lookup(image: np.ndarray, p0, p1, third, t: np.ndarray, W: int, H: int) -> np.ndarray:
    """Colours ``(N, 3)`` at ``p0 + t (p1 - p0)`` (texel coordinates) moved one texel into the face."""
    e = p1 - p0
    normal = np.array([-e[1], e[0]]) / max(np.linalg.norm(e), 1e-12)
    height = float((third - p0) @ normal)
    step = np.sign(height) * min(1.0, 0.5 * abs(height))
    pts = p0 + t[:, None] * e + normal * step  # texel coordinates
    uv = np.stack([(pts[:, 0] + 0.5) / W, 1.0 - (pts[:, 1] + 0.5) / H], axis=1)
    return sample_texture(image, uv)[:, :3].astype(np.float64)


def inpaint_and_blend(scan: Scan) -> Scan:
    """:func:`inpaint_holes`, then :func:`blend_seams`."""
    out = blend_seams(inpaint_holes(scan))
    return _with_images(out, [m.image for m in out.materials], "inpaint_blend")


# -- multi-view back-projection -----------------------------------------------------------------------


def backproject(scan: Scan, cameras: Sequence[Camera], *, factor: int = 2, supersample: int = 2,
                depth_tolerance: float = 0.01, chunk: int = 1 << 18) -> Scan:
    """Average the input's own renders at ``cameras`` back into an atlas ``factor`` times larger.

    The renders are the ones scantex trains on (unlit, supersampled, with per-pixel validity: pixels
    that see a hole or a silhouette do not count). Each texel's 3D point is projected into every view;
    a view counts when the point is in front of it and the G-buffer depth there matches (no occluder);
    its colour is read bilinearly from the valid pixels around. Texels no view sees keep the input
    texture's colour (so holes stay black: no view saw colour there).
    """
    from scantex.pipeline.enhance import render_training_views

    caster = RayCaster(scan.positions, scan.faces)
    usable = ~grow_faces(scan, untextured_faces(scan), rings=1)
    tv = render_training_views(scan, list(cameras), usable, supersample, caster, 0.0, 0, lambda done, total: None)
    corners = scan.triangles
    images = []
    for m, material in enumerate(scan.materials):
        faces = np.flatnonzero(scan.face_materials == m)
        if material.image is None or faces.size == 0:
            images.append(material.image)
            continue
        H, W = material.image.shape[0] * factor, material.image.shape[1] * factor
        tmap = texel_map(scan.triangle_uvs, W, H, faces)
        covered = tmap.mask
        points = tmap.points(corners)  # [N, 3] in row-major order of the covered texels
        ys, xs = np.nonzero(covered)
        uv = np.stack([(xs + 0.5) / W, 1.0 - (ys + 0.5) / H], axis=1)
        colour = sample_texture(material.image, uv)[:, :3].astype(np.float64)  # the fallback
        total = np.zeros((len(points), 3))
        count = np.zeros(len(points))
        for s in range(0, len(points), chunk):
            sl = slice(s, s + chunk)
            for i, cam in enumerate(tv.views.cameras):
                c, w = _view_colour(points[sl], cam, tv.views.images[i], tv.depth[i], tv.valid[i], depth_tolerance)
                total[sl] += c * w[:, None]
                count[sl] += w
        seen = count > 0
        colour[seen] = total[seen] / count[seen, None]
        image = np.zeros((H, W, 3), np.float32)
        image[ys, xs] = colour
        images.append(to_uint8(pad_gutters(image, covered)))
    return _with_images(scan, images, "backprojected")


def _view_colour(points: np.ndarray, camera: Camera, image: np.ndarray, depth: np.ndarray, valid: np.ndarray,
                 tolerance: float) -> tuple[np.ndarray, np.ndarray]:
    """Bilinear colour ``(N, 3)`` of ``points`` in one view and its weight ``(N,)``: the bilinear weights of
    the valid, depth-consistent pixels around each projection (0 where the view does not see the point)."""
    H, W = depth.shape
    pix, z = camera.project(points)
    x, y = pix[:, 0], pix[:, 1]
    ok = (z > 0) & (x > -1) & (y > -1) & (x < W) & (y < H)
    x0, y0 = np.floor(x), np.floor(y)
    fx, fy = x - x0, y - y0
    rgb = np.zeros((len(points), 3))
    weight = np.zeros(len(points))
    for dx, dy, w in ((0, 0, (1 - fx) * (1 - fy)), (1, 0, fx * (1 - fy)), (0, 1, (1 - fx) * fy), (1, 1, fx * fy)):
        px = (x0 + dx).astype(np.int64)
        py = (y0 + dy).astype(np.int64)
        inside = ok & (px >= 0) & (py >= 0) & (px < W) & (py < H)
        pxc, pyc = np.clip(px, 0, W - 1), np.clip(py, 0, H - 1)
        good = inside & valid[pyc, pxc] & (np.abs(depth[pyc, pxc] - z) < tolerance * np.maximum(z, 1e-9))
        w = np.where(good, w, 0.0)
        rgb += w[:, None] * image[pyc, pxc]
        weight += w
    seen = weight > 1e-6
    rgb[seen] /= weight[seen, None]
    # a view counts once per texel, however many of its pixels contributed
    return rgb, seen.astype(np.float64)


def best_view_projective(scan: Scan, photos, views, *, size: int = 0) -> Scan:
    """Classical photo texturing on the input's own UV layout: per texel, the photo that sees it best
    (frontal, close, sharp, unoccluded; the same visibility test as scantex, a near-hard choice:
    softmax temperature 0.02, 1 px feather), each photo levelled to the input texture's colours first
    (a per-channel gain and offset fitted on the pixels where it sees the mesh: the global colour
    adjustment of classical texture mappers), then every UV seam levelled (:func:`blend_seams`).
    Texels no photo sees keep the input's colour.

    Args:
        photos: the :class:`~scantex.photos.PhotoSet` (full-resolution images).
        views: the training photos' :class:`~scantex.photos.training.PhotoView` (working resolution).
    """
    from scantex.views.render import render_gbuffer

    caster = RayCaster(scan.positions, scan.faces)
    gains = []
    for view in views:
        from scantex.views.raycast import cast_gbuffer

        g = cast_gbuffer(caster, view.camera, scan.face_normals)
        reference = render_gbuffer(scan, g)
        mask = view.valid & g.mask
        gain, offset = np.ones(3), np.zeros(3)
        for c in range(3):
            x, y = view.image[..., c][mask], reference[..., c][mask]
            if x.size > 16 and np.var(x) > 1e-8:
                gain[c] = np.cov(x, y, bias=True)[0, 1] / np.var(x)
                offset[c] = y.mean() - gain[c] * x.mean()
        gains.append((gain, offset))
    G = np.array([g for g, _ in gains], np.float32)
    O = np.array([o for _, o in gains], np.float32)

    def level(rgb, group):
        return rgb * G[group] + O[group]

    return blend_seams(_with_images(scan, _best_view_bake(scan, photos, views, level, size), "bestview"))


def _best_view_bake(scan: Scan, photos, views, canonicalise, size: int) -> tuple:
    """The atlases of a near-hard best-view choice per texel (softmax temperature 0.02, 1 px feather), each
    photo's colours through ``canonicalise`` (``None``: as they are); texels no photo sees keep the scan's."""
    from scantex.atlas.bake import bake
    from scantex.photos.texturing import ProjectiveSettings, projective_colour
    from scantex.views.render import shade_hits

    def input_colour(points, normals, face_ids, bary):
        return shade_hits(scan, face_ids, bary) if scan.is_textured else np.full((len(points), 3), 0.5, np.float32)

    colour, _ = projective_colour(photos, views, range(len(views)), canonicalise, input_colour,
                                  ProjectiveSettings(temperature=0.02, feather_px=1.0))
    return bake(scan, colour, size=size)


def app_style_bake(scan: Scan, photos, views, *, size: int = 0) -> Scan:
    """What a capture app exports, as ``../shared/data``'s app-style inputs were made: per texel the photo
    that sees it best, as it is (no exposure levelling, no seam blending), baked on the scan's own UV layout
    at ``size``; texels no photo sees keep the scan's colour."""
    return _with_images(scan, _best_view_bake(scan, photos, views, None, size), "app")
