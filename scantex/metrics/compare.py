"""Comparing two scans: what ``scantex compare A B`` reports.

Geometry (counts, volume, Hausdorff and mean point-to-mesh distances both ways), each atlas's own
properties, atlas-space scores where the layouts match, and render scores: against photos when a
cameras file with images is given, else ``B``'s renders against ``A``'s at views planned on ``A``.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from scantex.errors import ScanError
from scantex.metrics.geometry import geometry_metrics
from scantex.metrics.texture import atlas_scores, kept_faces, render_reference, render_scores, \
    texture_summary
from scantex.scan import Scan
from scantex.views.camera import Camera
from scantex.views.raycast import RayCaster
from scantex.views.render import render


def photo_files(path: str | Path) -> list[Path]:
    """The image files a ``cameras.json`` names (for the inputs an output may not replace); none where the file
    cannot be read (:func:`read_photos` says why)."""
    from scantex.photos.files import load_frames_file

    try:
        path, _, frames = load_frames_file(Path(path), "cameras.json")
        return [path.parent / str(f["image"]) for f in frames]
    except (ScanError, KeyError, TypeError):
        return []


def read_photos(path: str | Path) -> list[tuple[Camera, np.ndarray]]:
    """Cameras and their images from a ``cameras.json`` (``frames[i] = {image, width, height, K,
    world_to_camera}``, image paths relative to the file): ``[(camera, (H, W, 3) float32 in [0, 1])]``.

    Raises:
        ScanError: the file is missing or malformed, an image is missing, or its size is not the camera's.
    """
    from scantex.io.images import read_image

    path = Path(path)
    if not path.is_file():
        raise ScanError(path, "cameras file not found")
    from scantex.photos.conventions import check_intrinsics, check_pose
    from scantex.photos.files import load_frames_file

    path, _, frames = load_frames_file(path, "cameras.json")
    try:
        pairs = []
        for i, f in enumerate(frames):
            K = np.asarray(f["K"], dtype=np.float64)
            if K.shape != (3, 3):
                raise ValueError(f"frame {i}: K has shape {K.shape}")
            width, height = check_intrinsics(K, f["width"], f["height"], path, f"frame {i}")
            w2c = check_pose(f["world_to_camera"], path, f"frame {i}")
            pairs.append((Camera(K, w2c, width, height), str(f["image"])))
    except (KeyError, TypeError, ValueError, OverflowError) as e:
        detail = (str(e).strip().splitlines() or [""])[0][:80]
        raise ScanError(path, f"not a cameras file with frames of image, width, height, K, world_to_camera "
                              f"({type(e).__name__}: {detail})") from None
    photos = []
    for cam, name in pairs:
        image = read_image(path.parent / name)
        if image.shape[:2] != (cam.height, cam.width):
            raise ScanError(path.parent / name, f"image is {image.shape[1]}x{image.shape[0]}, its camera says "
                                                f"{cam.width}x{cam.height}")
        photos.append((cam, image.astype(np.float32) / 255.0))
    return photos


def photo_reference(photos: list[tuple[Camera, np.ndarray]], scan: Scan, supersample: int = 2):
    """The photos as the reference, scored where ``scan`` fully covers the pixel (not the background)."""
    caster = RayCaster(scan.positions, scan.faces)
    by_camera = {id(cam): image for cam, image in photos}

    def reference(camera: Camera):
        _, alpha = render(scan, camera, caster, supersample=supersample)
        return by_camera[id(camera)], alpha >= 0.999

    return reference


def compare(a: Scan, b: Scan, *, photos: list[tuple[Camera, np.ndarray]] | None = None, n_views: int = 8,
            width: int = 320, height: int = 240, samples: int = 100_000, seed: int = 0) -> dict:
    """Geometry and texture metrics of ``b`` against ``a``; JSON-ready.

    Args:
        a: the reference scan (e.g. the input, or a ground truth).
        b: the scan compared with it (e.g. the enhanced output).
        photos: cameras with real images (see :func:`read_photos`): both scans' renders are then scored
            against them; without, ``b``'s renders are scored against ``a``'s at ``n_views`` views planned
            on ``a`` (how close ``b`` looks to ``a``, not which is better).
        n_views, width, height: the planned views when there are no photos.
        samples: random surface points per direction for the distances.
        seed: seeds the samples and the views.

    Returns:
        ``{"geometry", "texture": {"a", "b"}, "atlas", "renders"}``.
    """
    out: dict = {"geometry": geometry_metrics(a, b, samples=samples, seed=seed),
                 "texture": {"a": texture_summary(a), "b": texture_summary(b)}}
    if not (a.is_textured and b.is_textured):
        out["atlas"] = {"skipped": "a scan has no texture atlas"}
    elif (kept := kept_faces(a, b)) is not None and kept.any():
        out["atlas"] = atlas_scores(b, a)
    else:
        out["atlas"] = {"skipped": "the UV layouts differ; see the render scores"}
    if photos:
        cameras = [cam for cam, _ in photos]
        scores = render_scores(photo_reference(photos, a), {"a": a, "b": b}, cameras)
        out["renders"] = {"reference": "photos", **scores}
    else:
        from scantex.scan import up_axis
        from scantex.views.planning import plan_views

        cameras = plan_views(a, n_views, width=width, height=height, fov_deg=60.0, up=up_axis(a), seed=seed)
        scores = render_scores(render_reference(a), {"b": b}, cameras)
        out["renders"] = {"reference": "renders of a", **scores}
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
        for side in "ab":
            lines.append(f"renders of {side} vs photos ({r[side]['views']} views): PSNR {_db(r[side]['psnr'])}, "
                         f"SSIM {r[side]['ssim']:.3f}")
    else:
        lines.append(f"renders of b vs renders of a ({r['b']['views']} views): PSNR {_db(r['b']['psnr'])}, "
                     f"SSIM {r['b']['ssim']:.3f}")
    return "\n".join(lines)


def _db(value: float) -> str:
    return "inf (identical)" if math.isinf(value) else f"{value:.2f} dB"
