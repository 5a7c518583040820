"""What a capture app does to a texture: a lower resolution, blur, exposure jumps, JPEG, and holes.

Applied to the ground-truth atlas in this order, as in a capture: the keyframes are blurred, each
chart is textured from a keyframe with its own exposure and white balance, the atlas is stored as
JPEG, and faces no keyframe saw are left black.
"""

from __future__ import annotations

import io
import logging
from dataclasses import dataclass

import numpy as np
from PIL import Image
from scipy import ndimage

from scantex.atlas.texelmap import TexelMap
from scantex.synth.texture import nearest_covered
from scantex.views.render import to_uint8

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Degradation:
    """How far the synthetic scan's texture falls short of the ground truth.

    Attributes:
        blur_sigma: Gaussian blur, in texels of the scan's atlas.
        gain_spread: per-chart exposure gain, drawn uniformly from 1 ± this.
        white_balance_spread: per-chart, per-channel gain on top of the exposure, from 1 ± this.
        offset_spread: per-chart, per-channel black-level offset, from ± this (colours in [0, 1]).
        jpeg_quality: Pillow JPEG quality the atlas is stored at; ``None`` for no compression.
        hole_share: share of the surface area left untextured (pure black).
        hole_clusters: number of blobs the untextured faces come in.
    """

    blur_sigma: float = 1.0
    gain_spread: float = 0.15
    white_balance_spread: float = 0.05
    offset_spread: float = 0.015
    jpeg_quality: int | None = 50
    hole_share: float = 0.03
    hole_clusters: int = 4


def pick_holes(positions: np.ndarray, faces: np.ndarray, share: float, clusters: int,
               rng: np.random.Generator) -> np.ndarray:
    """Sorted ids ``(K,) int64`` of faces forming ``clusters`` irregular blobs of ``share`` of the area.

    Each blob grows from a random face, taking faces in order of their distance to it, where the
    distance is stretched by a random smooth function of the direction: blobs, not discs.
    """
    if share <= 0 or clusters <= 0:
        return np.zeros(0, dtype=np.int64)
    tri = positions[faces]
    centre = tri.mean(axis=1)
    cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    area = 0.5 * np.linalg.norm(cross, axis=1)
    normal = cross / np.maximum(2 * area, 1e-20)[:, None]
    holes = np.zeros(len(faces), dtype=bool)
    budget = share * area.sum() / clusters
    for _ in range(clusters):
        seed = rng.choice(len(faces), p=area / area.sum())
        n = normal[seed]
        t1 = np.cross(n, [0.0, 0.0, 1.0] if abs(n[2]) < 0.9 else [1.0, 0.0, 0.0])
        t1 /= np.linalg.norm(t1)
        t2 = np.cross(n, t1)
        d = centre - centre[seed]
        angle = np.arctan2(d @ t2, d @ t1)
        harmonics = rng.normal(0.0, 0.25, (3, 2))
        shape = 1.0 + sum(a * np.cos((k + 2) * angle) + b * np.sin((k + 2) * angle)
                          for k, (a, b) in enumerate(harmonics))
        order = np.argsort(np.linalg.norm(d, axis=1) / np.maximum(shape, 0.3))
        taken = order[:np.searchsorted(np.cumsum(area[order]), budget) + 1]
        holes[taken] = True
    return np.flatnonzero(holes)


def degrade_atlas(ground_truth: np.ndarray, texels: TexelMap, chart_of_face: np.ndarray, hole_faces: np.ndarray,
                  gutter_texels: int, degradation: Degradation, rng: np.random.Generator) -> np.ndarray:
    """The scan's atlas made from the ground truth's.

    Args:
        ground_truth: ``(G, G, 3) float32`` ground-truth atlas in [0, 1], gutters filled; ``G`` a multiple of
            the scan atlas size.
        texels: texel map of the scan's ``(N, N)`` atlas (same UVs).
        chart_of_face: ``(F,)`` chart id per face.
        hole_faces: ``(K,)`` faces left untextured.
        gutter_texels: how far around each chart the colours reach, in scan texels.
        degradation: what to do.
        rng: draws the per-chart exposures.

    Returns:
        ``(N, N, 3) uint8`` atlas.
    """
    N = texels.shape[0]
    G = ground_truth.shape[0]
    if G % N:
        raise ValueError(f"the ground-truth atlas ({G}²) must be a whole multiple of the scan's ({N}²)")
    f = G // N
    # area average: each scan texel is the mean of the albedo over its footprint
    image = ground_truth.reshape(N, f, N, f, 3).mean(axis=(1, 3))
    (rows, cols), within = nearest_covered(texels.mask, gutter_texels)
    image = image[rows, cols]
    if degradation.blur_sigma > 0:
        image = ndimage.gaussian_filter(image, (degradation.blur_sigma, degradation.blur_sigma, 0), mode="nearest")

    n_charts = int(chart_of_face.max()) + 1
    spread = degradation.white_balance_spread
    gain = (1 + rng.uniform(-degradation.gain_spread, degradation.gain_spread, (n_charts, 1))) \
        * (1 + rng.uniform(-spread, spread, (n_charts, 3)))
    offset = rng.uniform(-degradation.offset_spread, degradation.offset_spread, (n_charts, 3))
    face_of_texel = texels.face_id[rows, cols]  # the nearest covered texel's face, for gutter texels too
    chart = chart_of_face[face_of_texel]
    image = image * gain[chart].astype(np.float32) + offset[chart].astype(np.float32)
    image[~within] = 0
    atlas = to_uint8(image)

    if degradation.jpeg_quality is not None:
        buffer = io.BytesIO()
        Image.fromarray(atlas).save(buffer, format="JPEG", quality=degradation.jpeg_quality)
        atlas = np.asarray(Image.open(io.BytesIO(buffer.getvalue())).convert("RGB")).copy()
    # after the JPEG round trip, so that holes are pure black as apps leave them
    hole = np.zeros(len(chart_of_face), dtype=bool)
    hole[hole_faces] = True
    atlas[within & hole[face_of_texel]] = 0
    log.debug("degraded atlas %d²: exposure gains %.2f..%.2f over %d charts", N, gain.min(), gain.max(), n_charts)
    return atlas
