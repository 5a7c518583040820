"""Texture metrics: atlas-space scores where two layouts match, renders against a reference, and the
atlas's own properties (texel density per chart, coverage, seam visibility).

Render scores are the ones that mean something to a user: an atlas can differ from the truth's in its
gutters and still look identical on the model. Atlas-space scores are offered where both scans share a
UV layout (an enhanced scan and its input or ground truth), over covered texels only.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import math

import numpy as np

from scantex.arrays import uv_areas
from scantex.atlas.holes import visible_holes
from scantex.atlas.seams import seam_edges, seam_visibility, uv_shells
from scantex.atlas.texelmap import covered_texels
from scantex.metrics.image import mse, psnr, ssim
from scantex.metrics.views import PSNR_CAP_DB
from scantex.scan import Scan
from scantex.views.camera import Camera
from scantex.views.raycast import RayCaster
from scantex.views.render import render, sample_texture

#: reference view: camera -> (image (H, W, 3) float32 in [0, 1], mask (H, W) bool of pixels to score)
Reference = Callable[[Camera], tuple[np.ndarray, np.ndarray]]


def kept_faces(a: Scan, b: Scan) -> np.ndarray | None:
    """``(F,) bool``: the faces both scans map to the same UVs in the same material; ``None`` when their faces or
    materials do not correspond. A kept layout keeps all of them but the few its input gave no texture space
    (charted apart in free atlas space)."""
    if not (a.has_uvs and b.has_uvs and a.n_faces == b.n_faces and len(a.materials) == len(b.materials)):
        return None
    return (a.face_materials == b.face_materials) & (a.uvs[a.face_uvs] == b.uvs[b.face_uvs]).all(axis=(1, 2))


def atlas_scores(test: Scan, reference: Scan) -> dict:
    """MSE, PSNR and SSIM of ``test``'s atlases against ``reference``'s, over the texels the faces both map alike
    cover (:func:`kept_faces`: a kept layout's faces but the few charted apart), faces of no area left out.

    Compared at the reference's resolution: ``test``'s atlas is read at the reference's texel centres
    with the renderer's own bilinear lookup, so a smaller atlas is judged as a viewer would show it.
    Materials without an image on either side are skipped. ``faces``: the faces scored, of ``faces_total``.

    Raises:
        ValueError: no face is mapped alike (another layout): texel-by-texel scores are then meaningless; use
            render scores.
    """
    kept = kept_faces(test, reference)
    if kept is None or not kept.any():
        raise ValueError("atlas-space scores need the same UV layout on both scans")
    # a face of no area shows none of its texels: the bathroom's 3,869 such faces hold 8 % of its covered texels,
    # black in the input and filled in the output, and made an unseen change score 15 dB
    kept = kept & (reference.face_areas > 0)
    tri_uv = reference.triangle_uvs
    totals = {"mse": 0.0, "ssim": 0.0, "texels": 0}
    for m, (mt, mr) in enumerate(zip(test.materials, reference.materials)):
        faces = np.flatnonzero((reference.face_materials == m) & kept)
        if mt.image is None or mr.image is None or faces.size == 0:
            continue
        H, W = mr.image.shape[:2]
        covered = covered_texels(tri_uv, W, H, faces)
        ref = mr.image[..., :3].astype(np.float32) / 255.0
        if mt.image.shape[:2] == (H, W):
            img = mt.image[..., :3].astype(np.float32) / 255.0
        else:
            ys, xs = np.mgrid[0:H, 0:W]
            uv = np.stack([(xs.ravel() + 0.5) / W, 1.0 - (ys.ravel() + 0.5) / H], axis=1)
            img = sample_texture(mt.image, uv)[:, :3].reshape(H, W, 3)
        n = int(covered.sum())
        if n == 0:
            continue
        totals["mse"] += mse(img, ref, covered) * n
        totals["ssim"] += ssim(img, ref, covered) * n
        totals["texels"] += n
    n = totals["texels"]
    faces = {"faces": int(kept.sum()), "faces_total": int(kept.size)}
    if n == 0:
        return {"mse": float("nan"), "psnr": float("nan"), "ssim": float("nan"), "texels": 0, **faces}
    e = totals["mse"] / n
    return {"mse": e, "psnr": float("inf") if e == 0 else float(10 * np.log10(1 / e)),
            "ssim": totals["ssim"] / n, "texels": n, **faces}


def chart_texel_density(scan: Scan, unit_m: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """Texels per centimetre of every chart: ``(density (C,), area_m2 (C,))``.

    A chart's density is ``sqrt(texel area / surface area in cm²)``: the side of a texel, inverted.
    ``unit_m`` is the length of one scan unit in metres (1 for the metre-scaled exports of phone apps).
    Charts without an image get density 0.
    """
    charts = uv_shells(scan)
    C = int(charts.max()) + 1
    area_cm2 = scan.face_areas * (unit_m * 100.0) ** 2
    texels = np.zeros(scan.n_faces)
    if scan.has_uvs:
        uv_area = uv_areas(scan.triangle_uvs)
        size = np.array([m.image.shape[0] * m.image.shape[1] if m.image is not None else 0
                         for m in scan.materials], np.float64)
        texels = uv_area * size[scan.face_materials]
    chart_texels = np.bincount(charts, texels, C)
    chart_area = np.bincount(charts, area_cm2, C)
    density = np.sqrt(np.divide(chart_texels, chart_area, out=np.zeros(C), where=chart_area > 0))
    return density, chart_area / 1e4


def texel_density(scan: Scan, unit_m: float = 1.0) -> dict:
    """Summary of :func:`chart_texel_density` in texels per cm: area-weighted mean and median, and the spread, over
    the charts of some surface area (a chart of faces of no area has no density: the bathroom's made its median
    0); ``charts`` counts them all."""
    density, area = chart_texel_density(scan, unit_m)
    some = area > 0
    if not some.any():
        return {"px_per_cm_mean": 0.0, "px_per_cm_median": 0.0, "px_per_cm_min": 0.0, "px_per_cm_max": 0.0,
                "charts": len(density)}
    density, area = density[some], area[some]
    order = np.argsort(density)
    half = np.searchsorted(np.cumsum(area[order]), 0.5 * area.sum())  # half the surface has a density at most this
    return {"px_per_cm_mean": float(np.average(density, weights=area)),
            "px_per_cm_median": float(density[order[min(half, len(order) - 1)]]),
            "px_per_cm_min": float(density.min()), "px_per_cm_max": float(density.max()),
            "charts": len(some)}


def coverage(scan: Scan) -> dict:
    """How much of the atlas the charts use, and how much of the surface has colour.

    ``atlas_used``: summed UV triangle area over the atlas area (overlapping charts count twice, so it
    can pass 1); ``textured_area_share``: surface area not left black; ``hole_faces``: the faces left black
    (see :func:`scantex.atlas.holes.visible_holes`).
    """
    area = scan.face_areas
    holes = visible_holes(scan)
    out = {"textured_area_share": float(1.0 - area[holes].sum() / max(area.sum(), 1e-300)),
           "hole_faces": int(holes.sum())}
    if scan.has_uvs:
        uv_area = uv_areas(scan.triangle_uvs)
        used = [m for m in range(len(scan.materials)) if scan.materials[m].image is not None]
        out["atlas_used"] = float(uv_area.sum() / max(len(used), 1))
    return out


def texture_summary(scan: Scan, unit_m: float = 1.0, visibility: float | None = None) -> dict:
    """The atlas's own properties: charts, seams and how visible they are (``visibility``: its
    :func:`seam_visibility` when already measured), texel density, coverage."""
    edges = seam_edges(scan)
    visibility = seam_visibility(scan, edges) if visibility is None else visibility
    return {"charts": int(uv_shells(scan).max()) + 1, "seam_edges": len(edges),
            "seam_visibility": round(visibility, 3),
            "texel_density": texel_density(scan, unit_m), "coverage": coverage(scan),
            "atlas_sizes": [list(m.image.shape[:2]) if m.image is not None else None for m in scan.materials],
            # what shades the surface besides the colour, which scantex passes through (scantex.scan.TextureMap)
            "vertex_normals": scan.normals is not None,
            "other_maps": scan.map_kinds}


def render_reference(scan: Scan, supersample: int = 2) -> Reference:
    """Renders of ``scan`` as the reference (e.g. a ground truth), scored where it covers pixels fully."""
    caster = RayCaster(scan.positions, scan.faces)

    def reference(camera: Camera):
        image, alpha = render(scan, camera, caster, supersample=supersample)
        return image, alpha >= 0.999

    return reference


def render_scores(reference: Reference, scans: dict[str, Scan], cameras: Sequence[Camera],
                  supersample: int = 2) -> dict:
    """PSNR / SSIM / MSE over ``cameras`` of each scan's unlit renders against ``reference``.

    Unlike :func:`scantex.metrics.views.score_views`, each scan is ray-cast on its own, so the scans
    may differ in geometry; a pixel counts where the reference's mask says so (a scan that does not
    cover it there is scored against its black background).

    ``mse`` and ``ssim`` are means over the views; ``psnr`` is that of the mean MSE (infinite only when every
    view is identical), ``psnr_mean_of_views`` the mean of the views' PSNRs, each capped at ``PSNR_CAP_DB``:
    a view that does not see where two textures differ is identical, and one such view made the plain mean
    infinite ("identical" for textures that differ).
    """
    casters = {name: RayCaster(s.positions, s.faces) for name, s in scans.items()}
    out: dict[str, dict[str, list]] = {name: {"psnr": [], "ssim": [], "mse": []} for name in scans}
    for cam in cameras:
        ref, mask = reference(cam)
        if not mask.any():
            continue
        for name, scan in scans.items():
            img, _ = render(scan, cam, casters[name], supersample=supersample)
            out[name]["psnr"].append(min(psnr(img, ref, mask), PSNR_CAP_DB))
            out[name]["ssim"].append(ssim(img, ref, mask))
            out[name]["mse"].append(mse(img, ref, mask))
    result = {}
    for name, d in out.items():
        r = {k: float(np.mean(v)) if v else float("nan") for k, v in d.items()}
        r["psnr_mean_of_views"] = r["psnr"]
        r["psnr"] = 10 * math.log10(1 / r["mse"]) if r["mse"] > 0 else math.inf if d["mse"] else math.nan
        result[name] = r | {"views": len(d["psnr"])}
    return result
