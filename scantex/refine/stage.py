"""The refinement stage as the pipeline calls it: train the ViT on the scan's own views, refine views of
the field's colour, and return a colour function that fuses them back for the bake.

1. Targets: the training views' renders of the input texture brought to the canonical appearance by
   their chart's inverse transform; holes, excluded faces and silhouettes carry no target. The ground
   truth is never looked at.
2. The refiner is trained on them (:func:`scantex.refine.train.fit_refiner`).
3. Views of the base colour (what :func:`~scantex.pipeline.enhance.mesh_only_colour` gives: the
   field's canonical colour, hole fill) are rendered from the training cameras ``view_scale`` times finer,
   about one pixel per output texel, refined, optionally denoised, and fused back
   (:func:`scantex.refine.fusion.fuse_views`).
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import torch

from scantex.atlas.bake import SurfaceColour
from scantex.refine.config import RefineConfig
from scantex.refine.correspond import Correspondence, correspond, partners
from scantex.refine.fusion import ViewResiduals, edge_confidence, fuse_views, occlusion_edges
from scantex.refine.pretext import smooth_fill
from scantex.refine.train import RefinerData, fit_refiner
from scantex.refine.vit import refine_tiled
from scantex.scan import Scan
from scantex.views.raycast import RayCaster, cast_gbuffer

log = logging.getLogger(__name__)

Update = Callable[[int, int], None]

#: points per call of the base colour function (bounded memory)
CHUNK = 65536


@dataclass(frozen=True, eq=False)
class Refined:
    """What the stage made: the colour to bake, and facts for the metrics."""

    colour: SurfaceColour
    report: dict = field(default_factory=dict)


def canonical_targets(tv, fitted, charts: np.ndarray, device, canonical: bool = True) -> RefinerData:
    """The training views' input renders, in the canonical appearance when ``canonical`` (the base colour
    is the field's) or as they are (the base colour is the input's own), with cross-view pairs."""
    train = np.asarray(tv.views.train)
    images = tv.views.images[train].astype(np.float32)  # [N, H, W, 3]
    valid = tv.valid[train]
    if canonical and fitted.appearance is not None:
        fid = tv.face_id[train][valid]
        canon = fitted.appearance.canonical(torch.as_tensor(images[valid], device=device),
                                            torch.as_tensor(charts[fid], device=device))
        images[valid] = canon.clamp(0, 1).cpu().numpy()
    images[~valid] = 0
    pairs = []
    if len(train) > 1:
        best = partners(tv.face_id[train], valid, int(tv.face_id.max()) + 1)
        for a, b in enumerate(best):
            pixels, mask = correspond(tv.views.cameras[train[a]], tv.depth[train[a]], valid[a],
                                      tv.views.cameras[train[b]], tv.depth[train[b]], valid[b])
            pairs.append(Correspondence(a, int(b), pixels, mask))
    return RefinerData(torch.as_tensor(images, device=device).permute(0, 3, 1, 2).contiguous(),
                       torch.as_tensor(valid, device=device)[:, None], tuple(pairs))


def pick_views(face_id: np.ndarray, valid: np.ndarray, max_views: int) -> list[int]:
    """Greedy choice of at most ``max_views`` views, each adding the most faces not yet seen."""
    seen_by = [set(np.unique(f[v]).tolist()) for f, v in zip(face_id, valid)]
    covered: set[int] = set()
    chosen: list[int] = []
    while len(chosen) < min(max_views, len(seen_by)):
        gain = [-1 if i in chosen else len(s - covered) for i, s in enumerate(seen_by)]
        best = int(np.argmax(gain))
        if gain[best] <= 0 and chosen:
            break
        chosen.append(best)
        covered |= seen_by[best]
    return chosen


def refine_colour(scan: Scan, fitted, tv, caster: RayCaster, base_colour: SurfaceColour, config: RefineConfig,
                  device, update: Update, *, fill: np.ndarray, charts: np.ndarray, seed: int = 0,
                  canonical: bool = True) -> Refined:
    """Train the refiner on the scan's views and return the colour of the refined, fused views.

    Args:
        scan: the scan.
        fitted: the trained field (:class:`scantex.field.train.FittedField`), for its appearance.
        tv: the rendered training views (:class:`scantex.pipeline.enhance.TrainingViews`).
        caster: the scan's BVH.
        base_colour: the colour the refined views are rendered from, and where none sees a texel.
        config: the stage's settings.
        device: torch device.
        update: progress ``(done, total)`` over training steps and refined views.
        fill: ``(F,) bool`` faces whose base colour is a fill (holes): flagged to the refiner.
        charts: ``(F,)`` input chart of every face.
        seed: random seed.
        canonical: the targets in the field's canonical appearance (the base colour is the field's);
            ``False`` when the base colour keeps the input's own appearance (``bake.source = "input"``),
            so that the refiner never learns an appearance shift to paint onto the base.
    """
    times: dict[str, float] = {}
    t = time.perf_counter()
    data = canonical_targets(tv, fitted, charts, device, canonical)
    times["targets"] = time.perf_counter() - t

    train = np.asarray(tv.views.train)
    chosen = pick_views(tv.face_id[train], tv.valid[train], config.max_views)
    total = config.steps + len(chosen)
    fitted_refiner = fit_refiner(data, config, device=device, seed=seed, progress=lambda d, _: update(d, total))
    times["train"] = fitted_refiner.seconds

    t = time.perf_counter()
    cameras, bases, hits, known, depths, usable = [], [], [], [], [], []
    normals_of_face = scan.face_normals
    for i in chosen:
        cam = tv.views.cameras[train[i]].scaled(config.view_scale)
        g = cast_gbuffer(caster, cam)
        hit = g.mask
        fid = g.face_id[hit]
        bary = g.bary[hit]
        points = g.points(scan.positions, scan.faces)[hit]
        rgb = np.zeros((cam.height, cam.width, 3), np.float32)
        values = np.empty((len(fid), 3), np.float32)
        for s in range(0, len(fid), CHUNK):
            e = s + CHUNK
            values[s:e] = base_colour(points[s:e], normals_of_face[fid[s:e]], fid[s:e], bary[s:e])
        rgb[hit] = values
        cameras.append(cam)
        bases.append(rgb)
        hits.append(hit)
        known.append(hit & ~fill[np.where(hit, g.face_id, 0)])
        depths.append(np.where(hit, g.depth, np.inf).astype(np.float32))
        usable.append(occlusion_edges(g.depth, hit))
    times["render"] = time.perf_counter() - t

    t = time.perf_counter()
    residuals = []
    denoiser = None
    model = fitted_refiner.model
    for k, (rgb, hit, have) in enumerate(zip(bases, hits, known)):
        # pixels that see nothing get the smooth fill; holes keep the base's fill, flagged as such
        x = smooth_fill(torch.as_tensor(rgb, device=device).permute(2, 0, 1)[None],
                        torch.as_tensor(hit, device=device)[None, None])
        have = torch.as_tensor(have, device=device)[None, None]
        with torch.no_grad():
            refined = refine_tiled(model, torch.cat([x, (~have).to(x.dtype)], dim=1), fitted_refiner.crop)
        refined = refined.clamp(0, 1)
        residuals.append(refined[0].permute(1, 2, 0).cpu().numpy() - rgb)
        update(config.steps + k + 1, total)
    times["infer"] = time.perf_counter() - t

    if config.diffusion:
        t = time.perf_counter()
        denoiser = _denoise(residuals, bases, usable, config, device, seed)
        times["diffusion"] = time.perf_counter() - t

    confidence = [edge_confidence(use, ramp=config.patch / 2) for use in usable]
    for r, use in zip(residuals, usable):
        r[~use] = 0
    views = ViewResiduals(tuple(cameras), np.stack(residuals), np.stack(depths), np.stack(confidence))
    report = {"views_refined": len(cameras), "view_size": [cameras[0].width, cameras[0].height] if cameras else None,
              "train_views": len(train), "cross_view_pairs": len(data.pairs), "steps": config.steps,
              "final_loss": float(np.mean(fitted_refiner.losses[-20:])),
              "mean_abs_change": float(np.mean([np.abs(r[u]).mean() for r, u in zip(residuals, usable) if u.any()]))
              if cameras else 0.0,
              "seconds": {k: round(v, 2) for k, v in times.items()}}
    if denoiser is not None:
        report["diffusion_final_loss"] = float(np.mean(denoiser.losses[-20:]))
    return Refined(fuse_views(views, base_colour), report)


def _denoise(residuals: list[np.ndarray], bases: list[np.ndarray], usable: list[np.ndarray], config: RefineConfig,
             device, seed: int):
    """Denoise the refined views in place (as residuals over ``bases``) with a diffusion model trained on
    them: the refined views are the cleanest images of this scan at this scale that the pipeline has."""
    import dataclasses

    from scantex.refine.diffusion import DiffusionConfig, fit_denoiser

    refined = torch.as_tensor(np.stack([b + r for b, r in zip(bases, residuals)]),
                              device=device).permute(0, 3, 1, 2).clamp(0, 1)
    masks = torch.as_tensor(np.stack(usable), device=device)[:, None]
    dc = dataclasses.replace(DiffusionConfig(), steps=config.diffusion_steps, strength=config.diffusion_strength)
    denoiser = fit_denoiser(refined, masks, dc, device=device, seed=seed)
    out = denoiser.denoise(refined, config.diffusion_strength, seed=seed)
    for k in range(len(residuals)):
        residuals[k] = out[k].permute(1, 2, 0).cpu().numpy() - bases[k]
    return denoiser
