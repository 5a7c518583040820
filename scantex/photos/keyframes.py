"""Keyframes: a capture's repeated views thinned to the sharpest of each.

A capture recorded as video (a scanning app's every frame, ScanNet's 30 frames a second) holds many photos taken
from nearly one place looking nearly one way: they add nothing to the texture that one of them does not, and cost
time and memory in proportion (the real apartment's photos four times over: the same held-out score in 5-6x the
time and 2.5x the memory, bench/RESULTS.md "photo memory"). Two photos *repeat* each other when their cameras'
centres lie within :data:`REPEAT_DISTANCE` of the nearer one's viewing distance (the median depth of the
surface it sees) and their optical axes within :data:`REPEAT_ANGLE_DEG`: then each point both see is seen from
within about 2 degrees, at about the same resolution, and the two frame nearly the same part of the scene.
:func:`keyframes` keeps the sharpest photo of each such neighbourhood (the photos taken sharpest first, each
kept unless a kept one repeats it), so a shaken frame gives way to a steady neighbour; a photo that sees none
of the mesh repeats nothing.

``photos.keyframes`` auto applies it from :data:`KEYFRAMES_FROM` photos, before the held-out split (a held-out
frame then has no training frame that repeats it, and its score says what the texture does between views); the
real captures here are keyframes already (the apartment's 219: 9 repeat another) and are left as they are. There
:func:`held_apart` moves a held-out photo that a training photo repeats to the nearest photo in the capture that
nothing repeats: the apartment's split held out 16 and 66 beside their repeats 17 and 65.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Sequence

import numpy as np

from scantex.photos.photoset import PhotoSet

log = logging.getLogger(__name__)

#: ``photos.keyframes`` auto: a capture of this many photos or more is thinned of its repeated views
KEYFRAMES_FROM = 300
#: two photos repeat each other within this share of the nearer one's viewing distance ...
REPEAT_DISTANCE = 0.03
#: ... and this angle between their optical axes
REPEAT_ANGLE_DEG = 3.0
#: the ray cast that measures a photo's viewing distance: this many pixels across
DISTANCE_PX = 48


def viewing_distances(photos: PhotoSet, indices: Sequence[int], caster,
                      update: Callable[[int], None] | None = None) -> np.ndarray:
    """Per photo of ``indices``, the median depth of the surface its camera sees (NaN where it sees none), from
    a ray cast :data:`DISTANCE_PX` pixels across; ``update(k)`` before photo ``k``."""
    from scantex.views.raycast import cast_gbuffer

    out = np.full(len(indices), np.nan)
    for k, i in enumerate(indices):
        if update:
            update(k)
        cam = photos.cameras[i]
        g = cast_gbuffer(caster, cam.scaled(min(1.0, DISTANCE_PX / cam.width)))
        if g.mask.any():
            out[k] = float(np.median(g.depth[g.mask]))
    return out


def sharpness(photos: PhotoSet, i: int) -> float:
    """Photo ``i``'s sharpness: the variance of the Laplacian of its grey at a quarter of its size (a JPEG is
    decoded at that size). Compared only between photos of one view, where the scene is the same."""
    from scipy import ndimage

    from scantex.io.images import open_image

    with open_image(photos.images[i], "photo") as im:
        width = max(1, im.width // 4)
        im.draft("L", (width, max(1, im.height // 4)))
        im = im.convert("L")
        if im.width >= 2 * width:  # decoded whole (not a JPEG): box-reduced to the quarter
            im = im.reduce(im.width // width)
        grey = np.asarray(im, np.float32) / np.float32(255.0)
    return float(ndimage.laplace(ndimage.gaussian_filter(grey, 0.5)).var())


def repeats(photos: PhotoSet, indices: Sequence[int], distances: np.ndarray) -> list[set[int]]:
    """Per photo of ``indices`` (by position), the positions of the others that repeat its view."""
    from scipy.spatial import cKDTree

    centres = np.array([photos.cameras[i].center for i in indices])
    axes = np.array([photos.cameras[i].R[2] for i in indices])
    finite = np.isfinite(distances)
    out: list[set[int]] = [set() for _ in indices]
    if finite.sum() < 2:
        return out
    cos_limit = np.cos(np.radians(REPEAT_ANGLE_DEG))
    radii = np.where(finite, REPEAT_DISTANCE * np.nan_to_num(distances), 0.0)
    # each photo's own radius (a pair within the nearer one's is within both): a far view's wide radius does not
    # make every photo near every other
    for a, found in enumerate(cKDTree(centres).query_ball_point(centres, radii)):
        for b in found:
            if b <= a or not (finite[a] and finite[b]):
                continue
            if (np.linalg.norm(centres[a] - centres[b]) < REPEAT_DISTANCE * min(distances[a], distances[b])
                    and float(axes[a] @ axes[b]) > cos_limit):
                out[a].add(b)
                out[b].add(a)
    return out


def keyframes(photos: PhotoSet, indices: Sequence[int], caster,
              update: Callable[[int, int], None] | None = None) -> tuple[list[int], list[dict]]:
    """``(kept, repeated)``: the photos of ``indices`` kept (in their order), and per photo given way
    ``{"photo", "repeats"}`` (the kept photo whose view it repeats), by the rule in the module docstring.
    ``update(done, total)`` counts the photos cast, then those decoded for their sharpness (a video-rate capture's
    thousands of photos take a minute)."""
    indices = [int(i) for i in indices]
    n = len(indices)
    near = repeats(photos, indices, viewing_distances(photos, indices, caster,
                                                      update and (lambda k: update(k, 2 * n))))
    candidates = [k for k in range(n) if near[k]]
    scores = {}
    for done, k in enumerate(candidates):
        if update:
            update(n + done, n + len(candidates))
        scores[k] = sharpness(photos, indices[k])
    if update:
        update(n + len(candidates), n + len(candidates))
    kept: set[int] = set(range(len(indices))) - set(candidates)
    repeated = []
    for k in sorted(candidates, key=lambda k: (-scores[k], k)):
        partner = min((j for j in near[k] if j in kept), key=lambda j: -scores[j], default=None)
        if partner is None:
            kept.add(k)
        else:
            repeated.append({"photo": indices[k], "repeats": indices[partner]})
    return [indices[k] for k in sorted(kept)], sorted(repeated, key=lambda d: d["photo"])


def held_apart(photos: PhotoSet, train: np.ndarray, held: np.ndarray, caster) -> tuple[np.ndarray, np.ndarray]:
    """``(train, held)`` with each held-out photo that another photo repeats swapped for the nearest photo in the
    capture's order that nothing repeats (left where it is when there is none), so that every held-out photo scores
    a view the texture was not made from again."""
    indices = sorted(int(i) for i in (*train, *held))
    near = repeats(photos, indices, viewing_distances(photos, indices, caster))
    position = {i: k for k, i in enumerate(indices)}
    chosen = {int(i) for i in held}
    for h in sorted(chosen):
        if not near[position[h]]:
            continue
        alone = [i for i in indices if i not in chosen and not near[position[i]]]
        if alone:
            instead = min(alone, key=lambda i: (abs(i - h), i))
            chosen = (chosen - {h}) | {instead}
            log.info("photo %d held out instead of photo %d, whose view photo %d repeats", instead, h,
                     indices[min(near[position[h]])])
    held = np.array(sorted(chosen), dtype=np.asarray(held).dtype)
    return np.array([i for i in indices if i not in chosen], dtype=held.dtype), held
