"""Comparing two scans: what ``scantex compare A B`` reports.

Geometry (counts, volume, Hausdorff and mean point-to-mesh distances both ways), each atlas's own
properties, atlas-space scores where the layouts match, and render scores: against posed photos when
they are given (read as ``enhance --photos`` reads them: :func:`scantex.photos.load_photos`), else ``B``'s
renders against ``A``'s at views planned on ``A``.
"""

from __future__ import annotations

import logging
import math
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from scantex.errors import ScanError
from scantex.metrics.geometry import geometry_metrics
from scantex.metrics.texture import atlas_scores, kept_faces, render_reference, render_scores, \
    texture_summary
from scantex.scan import Scan
from scantex.views.camera import Camera
from scantex.views.raycast import RayCaster
from scantex.views.render import render

if TYPE_CHECKING:
    from scantex.photos.photoset import PhotoSet

log = logging.getLogger(__name__)


def photo_files(photos: PhotoSet) -> list[Path]:
    """The files ``photos`` was read from (the inputs an output may not replace): its camera file or folder, its
    images and its depth maps."""
    return [photos.source, *photos.images, *(d for d in photos.depths if d is not None)]


def photo_scores(photos: PhotoSet, a: Scan, b: Scan, supersample: int = 2) -> dict:
    """:func:`render_scores` of ``a``'s and ``b``'s renders against ``photos``, on the pixels ``a`` covers fully (not
    the background): ``{"a", "b", "photos_left_out"}``. Photos that see none of ``a`` are left out, with a warning
    naming them.

    Raises:
        ScanError: naming ``photos.source``: none of the photos sees ``a``.
    """
    from scantex.photos.cameras_json import FORMAT as CAMERAS_JSON

    caster = RayCaster(a.positions, a.faces)
    index = {id(cam): i for i, cam in enumerate(photos.cameras)}
    blind: list[int] = []

    def reference(camera: Camera):
        i = index[id(camera)]
        _, alpha = render(a, camera, caster, supersample=supersample)
        mask = alpha >= 0.999
        if not mask.any():  # render_scores skips the view: its photo need not be read
            blind.append(i)
            return None, mask
        return photos.load_image(i).astype(np.float32) / 255.0, mask

    scores = render_scores(reference, {"a": a, "b": b}, photos.cameras, supersample=supersample)
    mesh = f"the mesh {Path(a.source).name}" if a.source is not None else "the mesh"
    hint = ("are its poses world-to-camera, not camera-to-world?" if photos.format == CAMERAS_JSON
            else "was the mesh moved or turned after the capture?")
    if len(blind) == len(photos):
        raise ScanError(photos.source, f"none of its {len(photos)} photos sees {mesh}: the mesh is not in the "
                                       f"cameras' frame ({hint})")
    if blind:
        names = [photos.images[i].name for i in blind]
        # camera-to-world poses read as world-to-camera still let a photo or two see the mesh (the bolster's: 1
        # of 14): most photos blind is worth the same hint as all of them
        log.warning("%s: %d of its %d photos see none of %s, left out of the scores: %s%s", photos.source,
                    len(blind), len(photos), mesh,
                    ", ".join(names[:10]) + (f" and {len(names) - 10} more" if len(names) > 10 else ""),
                    f" (most of them: {hint})" if 2 * len(blind) > len(photos) else "")
    return scores | {"photos_left_out": len(blind)}


def compare(a: Scan, b: Scan, *, photos: PhotoSet | None = None, n_views: int = 8, width: int = 320,
            height: int = 240, samples: int = 100_000, seed: int = 0) -> dict:
    """Geometry and texture metrics of ``b`` against ``a``; JSON-ready.

    Args:
        a: the reference scan (e.g. the input, or a ground truth).
        b: the scan compared with it (e.g. the enhanced output).
        photos: posed photos (:func:`scantex.photos.load_photos`): both scans' renders are then scored
            against them (:func:`photo_scores`); without, ``b``'s renders are scored against ``a``'s at
            ``n_views`` views planned on ``a`` (how close ``b`` looks to ``a``, not which is better).
        n_views, width, height: the planned views when there are no photos.
        samples: random surface points per direction for the distances.
        seed: seeds the samples and the views.

    Returns:
        ``{"geometry", "texture": {"a", "b"}, "atlas", "renders"}``.

    Raises:
        ScanError: none of the photos sees ``a``.
    """
    if photos is not None:  # first: a mesh out of the cameras' frame is refused before the distances are taken
        renders = {"reference": "photos", **photo_scores(photos, a, b)}
    else:
        from scantex.scan import up_axis
        from scantex.views.planning import plan_views

        cameras = plan_views(a, n_views, width=width, height=height, fov_deg=60.0, up=up_axis(a), seed=seed)
        renders = {"reference": "renders of a", **render_scores(render_reference(a), {"b": b}, cameras)}
    out: dict = {"geometry": geometry_metrics(a, b, samples=samples, seed=seed),
                 "texture": {"a": texture_summary(a), "b": texture_summary(b)}}
    if not (a.is_textured and b.is_textured):
        out["atlas"] = {"skipped": "a scan has no texture atlas"}
    elif (kept := kept_faces(a, b)) is not None and kept.any():
        out["atlas"] = atlas_scores(b, a)
    else:
        out["atlas"] = {"skipped": "the UV layouts differ; see the render scores"}
    out["renders"] = renders
    return out


def summary_lines(result: dict) -> str:
    """A few lines for the terminal."""
    g = result["geometry"]
    d = g["distance"]
    lines = [f"geometry: vertices {g['vertices'][0]:,} / {g['vertices'][1]:,}, faces {g['faces'][0]:,} / "
             f"{g['faces'][1]:,}, distinct positions {g['distinct_positions'][0]:,} / {g['distinct_positions'][1]:,}"
             f" ({'identical' if g['arrays_identical'] else 'triangles identical' if g['triangles_identical'] else 'different'})",
             f"distance: Hausdorff {d['hausdorff']:.6g} ({d['hausdorff_rel']:.3g} of the diagonal), mean "
             f"point-to-mesh a->b {d['mean_a_to_b']:.6g}, b->a {d['mean_b_to_a']:.6g}"
             + (f" (from every vertex and {d['samples']:,} surface points a direction: the Hausdorff distance "
                f"can only be larger)" if d.get("samples") else "")]
    for side, v in zip("ab", g["volume"]):
        lines.append(f"volume {side}: {v['volume']:.6g}" if v["volume"] is not None else f"volume {side}: {v['note']}")
    ta, tb = result["texture"]["a"], result["texture"]["b"]
    lines.append(f"seam visibility: {ta['seam_visibility']:.2f} / {tb['seam_visibility']:.2f}; texel density "
                 f"{ta['texel_density']['px_per_cm_mean']:.2f} / {tb['texel_density']['px_per_cm_mean']:.2f} px/cm")
    atlas = result["atlas"]
    if "skipped" in atlas:
        lines.append(f"atlas: skipped ({atlas['skipped']})")
    else:
        some = atlas["faces"] < atlas["faces_total"]
        lines.append(f"atlas (b vs a, {atlas['texels']:,} covered texels"
                     + (f" of {atlas['faces']:,} of the {atlas['faces_total']:,} faces: those both map alike, of "
                        f"some area" if some else "") + f"): PSNR {_db(atlas['psnr'])}, SSIM {atlas['ssim']:.3f}")
    r = result["renders"]
    if r["reference"] == "photos":
        left = r.get("photos_left_out", 0)
        unseen = f"; {left} photo{'s' if left > 1 else ''} seeing none of a left out" if left else ""
        for side in "ab":
            lines.append(f"renders of {side} vs photos ({r[side]['views']} views{unseen}): PSNR "
                         f"{_db(r[side]['psnr'])}, SSIM {r[side]['ssim']:.3f}")
    else:
        lines.append(f"renders of b vs renders of a ({r['b']['views']} views): PSNR {_db(r['b']['psnr'])}, "
                     f"SSIM {r['b']['ssim']:.3f}")
    return "\n".join(lines)


def _db(value: float) -> str:
    return "inf (identical)" if math.isinf(value) else f"{value:.2f} dB"
