"""Scoring renders of scans at held-out views against reference renders (ground truth or photos)."""

from __future__ import annotations

from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from scantex.metrics.image import psnr, ssim
from scantex.scan import Scan
from scantex.views.camera import Camera
from scantex.views.raycast import PAIR_THREADS, RayCaster, cast_gbuffer
from scantex.views.render import render_scans

#: the key a reference scan is rendered under, beside the scored scans (no name of theirs can equal it)
_REFERENCE = object()
#: a view's PSNR where the images are identical (infinite): a mean over views with one such view would be
#: infinite too, hiding the others' errors (and ``Infinity`` is not JSON)
PSNR_CAP_DB = 100.0
#: rays a pixel side when views are scored (box-filtered): the scores are robust to a texel's aliasing
SCORE_SUPERSAMPLE = 2


def score_views(reference: Callable[[Camera], tuple[np.ndarray, np.ndarray]] | Scan, scans: dict[str, Scan],
                cameras: list[Camera], caster: RayCaster, hole_faces: np.ndarray,
                supersample: int = SCORE_SUPERSAMPLE, *, renders: list | None = None,
                reference_name: str = "reference", scored: list | None = None, pooled: bool = False) -> dict:
    """PSNR / SSIM / MSE of each scan's renders against ``reference`` renders at ``cameras``.

    ``reference`` is a function giving a camera's ``(image, alpha)``, or a scan of the same geometry (a
    ground truth): that one is rendered with ``scans`` from the same rays, as ``render(reference, cam,
    caster, supersample=supersample)`` would render it, with one ray cast fewer per camera.

    Pixels count where the reference fully covers them; a view whose images are identical scores
    ``PSNR_CAP_DB``; ``hole_psnr`` is over pixels whose surface is one of ``hole_faces`` (what the input left
    black), ``psnr_outside_holes`` that of all the views' other pixels together (a result's fidelity to the input
    where the input had colour); ``patches`` is the share of pixels where the scan has a low-frequency edge the
    reference lacks (:mod:`scantex.metrics.patches`).

    Returns:
        ``{name: {"psnr", "ssim", "mse", "patches", ["hole_psnr", "psnr_outside_holes"], "per_view": {"psnr":
        [...], "ssim": [...], "patches": [...]}}}``: means over the views, and each view's own PSNR, SSIM and
        patch share in the order of ``cameras`` (the report shows them next to each view).

    ``pooled``: ``psnr`` is that of the views' mean MSE (``psnr_mean_of_views`` the mean of their PSNRs): a
    result against the input it was made from leaves some views unchanged, which score ``PSNR_CAP_DB`` each and
    would make the mean of the views' PSNRs mean little (100, 100 and 23.5 dB: 74.5).

    ``renders``: if given, receives one dict a camera, in order: each scan's render (and a reference
    scan's, as ``reference_name``) before its supersamples are averaged, ``uint8`` (see
    :func:`scantex.views.render.render_scans`'s ``fine``): the report shows these. ``scored``: if given,
    receives one dict a camera, in order: each scan's ``(image, alpha)`` as scored (and a reference scan's, as
    ``reference_name``), as :func:`scantex.views.render.render` gives them.
    """
    from scantex.metrics.patches import patch_score

    truth = reference if isinstance(reference, Scan) else None

    def score(cam: Camera) -> tuple[dict[str, tuple[dict[str, float], np.ndarray | None]], dict | None, dict]:
        """Each scan's scores at ``cam`` and its squared errors over hole pixels (``None``: none), the fine
        renders (``None`` unless ``renders`` is given), and the renders as scored."""
        fine = {} if renders is not None else None
        if truth is None:
            ref, ref_alpha = reference(cam)
            images = shown = render_scans(scans, cam, caster, supersample=supersample, fine=fine)
        else:
            shown = render_scans({**scans, _REFERENCE: truth}, cam, caster, supersample=supersample, fine=fine)
            ref, ref_alpha = shown.pop(_REFERENCE)
            images = {**shown, reference_name: (ref, ref_alpha)}
            if fine is not None:
                fine[reference_name] = fine.pop(_REFERENCE)
        mask = ref_alpha >= 0.999
        g = cast_gbuffer(caster, cam)
        holes = mask & (g.face_id >= 0) & hole_faces[np.where(g.face_id >= 0, g.face_id, 0)]
        outside = mask & ~holes
        return {name: ({"psnr": min(psnr(img, ref, mask), PSNR_CAP_DB), "ssim": ssim(img, ref, mask),
                        "mse": float(((img - ref) ** 2)[mask].mean()), "patches": patch_score(img, ref, mask)},
                       ((img - ref) ** 2)[holes] if holes.any() else None,
                       (float(((img - ref) ** 2)[outside].sum()), int(outside.sum()) * img.shape[-1]))
                for name, (img, _) in shown.items()}, fine, images

    # the views side by side: Embree and numpy release the interpreter lock (SSIM's filtering does not)
    with ThreadPoolExecutor(PAIR_THREADS) as pool:
        per_view, fine_renders, scored_renders = zip(*pool.map(score, cameras)) if cameras else ((), (), ())
    if renders is not None:
        renders.extend(fine_renders)
    if scored is not None:
        scored.extend(scored_renders)
    out: dict[str, dict] = {name: {"psnr": [], "ssim": [], "mse": [], "patches": []} for name in scans}
    hole_pixels = {name: [] for name in scans}
    outside = {name: [0.0, 0] for name in scans}  # squared errors and values over the pixels of no hole
    for view_scores in per_view:
        for name, (values, hole_errors, (errors, count)) in view_scores.items():
            for k, v in values.items():
                out[name][k].append(v)
            if hole_errors is not None:
                hole_pixels[name].append(hole_errors)
            outside[name][0] += errors
            outside[name][1] += count
    result = {}
    for name in scans:
        r = {k: float(np.mean(v)) for k, v in out[name].items() if v}
        if pooled and "mse" in r:
            r["psnr_mean_of_views"] = r["psnr"]
            r["psnr"] = _capped_psnr(r["mse"])
        r["per_view"] = {k: [float(x) for x in out[name][k]] for k in ("psnr", "ssim", "patches")}
        if hole_pixels[name]:
            r["hole_psnr"] = _capped_psnr(float(np.concatenate(hole_pixels[name]).mean()))
            r["psnr_outside_holes"] = _capped_psnr(outside[name][0] / max(outside[name][1], 1))
        result[name] = r
    return result


def _capped_psnr(mse: float) -> float:
    """PSNR (dB, peak 1) of a mean squared error, at most :data:`PSNR_CAP_DB` (identical images)."""
    return float(min(10 * np.log10(1 / mse), PSNR_CAP_DB)) if mse > 0 else PSNR_CAP_DB
