"""Projective texturing's per-point blend, compiled (numba): every photo's sample of a point and their blend in
one pass over the points.

:func:`scantex.photos.texturing.projective_colour` blends, for each surface point, the samples of the photos
that see it. In numpy that is some forty passes over the samples a photo (projection, visibility, view
quality, four bilinear corners, colour transform, feather, then the softmax and the weighted sums): on one
core, 4.6-6.0 s for the bolster's 2.8 M texels from 12 photos. This module does the same arithmetic point
by point, a point's samples held in small buffers, in 0.41-0.52x that time (``bench/bench_blend.py``), with the
numpy path as its slow, obviously correct twin (``tests/photos/test_compiled.py`` compares them). The kernel is
compiled by :func:`scantex.jit.compiled` on first use (about 4 s) and cached beside this file; where numba is
missing, the numpy path runs (:func:`available` says which).

The kernel releases the interpreter lock: chunks of points blend on threads side by side.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

log = logging.getLogger(__name__)

#: robust rounds that find what most photos' coarse bands say of a point (two bands' ``detail_consistency``)
DETAIL_ROUNDS = 3


def _blend(local, unit, face_ids, seen_faces, rotation_t, translation, intrinsics_t, to_view, centre, focal,
           log_sharpness, fine_weight, photo_group, pixel_start, widths, heights, pixels, coarse, view_start,
           view_widths, view_heights, depth, feather, inverse, offset, gain, depth_tolerance, temperature,
           detail_temperature, detail_gain, detail_consistency, clip_level, overshoot, consistency, rounds, without,
           censors, canonical, out, total, alpha, tally):
    """The kernel (compiled by :func:`_kernel`): :func:`blend`'s arguments unpacked, its outputs filled in."""
    n, P = len(local), len(rotation_t)
    bands = len(coarse) > 0
    quality = np.empty(P, np.float64)
    reach_of = np.empty(P, np.float64)  # each sample's feather weight
    weight = np.empty(P, np.float64)
    base = np.empty(P, np.float64)  # each sample's weight in the coarse band's (or the one band's) blend
    # each sample's colour (canonical and as recorded) and clipping: [0] the photo's, [1] its coarse band's
    rgbs = np.empty((2, P, 3), np.float64)
    raws = np.empty((2, P, 3), np.float64)
    clips = np.empty((2, P), np.bool_)
    group = np.empty(P, np.int64)
    fine_of = np.empty(P, np.float64)  # each sample's photo's factor on its weight in the fine band's blend
    for i in range(n):
        f = face_ids[i]
        m = 0  # samples of point i
        for p in range(P):
            if p == without or (seen_faces.shape[0] > 0 and not seen_faces[f, p]):
                continue
            # the point in the camera's frame, its pixel at the sampling resolution and at the working one
            cx = cy = cz = 0.0
            for k in range(3):
                cx += local[i, k] * rotation_t[p, k, 0]
                cy += local[i, k] * rotation_t[p, k, 1]
                cz += local[i, k] * rotation_t[p, k, 2]
            cx += translation[p, 0]
            cy += translation[p, 1]
            cz += translation[p, 2]
            if not cz > 0:
                continue
            hx = cx * intrinsics_t[p, 0, 0] + cy * intrinsics_t[p, 1, 0] + cz * intrinsics_t[p, 2, 0]
            hy = cx * intrinsics_t[p, 0, 1] + cy * intrinsics_t[p, 1, 1] + cz * intrinsics_t[p, 2, 1]
            hz = cx * intrinsics_t[p, 0, 2] + cy * intrinsics_t[p, 1, 2] + cz * intrinsics_t[p, 2, 2]
            fx, fy = hx / hz, hy / hz
            vx = np.rint(fx * to_view[p, 0, 0] + fy * to_view[p, 0, 1] + to_view[p, 0, 2])
            vy = np.rint(fx * to_view[p, 1, 0] + fy * to_view[p, 1, 1] + to_view[p, 1, 2])
            w, h = view_widths[p], view_heights[p]
            if not (vx >= 0 and vx < w and vy >= 0 and vy < h):
                continue
            at = view_start[p] + int(vy) * w + int(vx)
            if not abs(depth[at] - cz) < depth_tolerance * cz:  # an unusable pixel's depth is not positive
                continue
            # view quality: log cos(angle) + log(pixels per metre) + log(relative sharpness)
            dx, dy, dz = local[i, 0] - centre[p, 0], local[i, 1] - centre[p, 1], local[i, 2] - centre[p, 2]
            distance = np.sqrt(cx * cx + cy * cy + cz * cz)
            cos = abs(unit[i, 0] * dx + unit[i, 1] * dy + unit[i, 2] * dz) / distance
            quality[m] = np.log(max(cos, 1e-3) * focal[p] / cz) + log_sharpness[p]  # one log: log(a) + log(b)
            reach_of[m] = feather[at]
            # the photo's colour there, bilinear (and its coarse band's, with two bands)
            W, H = widths[p], heights[p]
            x = min(max(fx, 0.0), W - 1.001)
            y = min(max(fy, 0.0), H - 1.001)
            x0, y0 = int(x), int(y)
            ax, ay = x - x0, y - y0
            corner = pixel_start[p] + y0 * W + x0
            g = photo_group[p]
            group[m] = g
            fine_of[m] = fine_weight[p]
            for band in range(2 if bands else 1):  # indexed in full: a view a sample costs the loop time
                if band == 0:
                    a, b, c, d = pixels[corner], pixels[corner + 1], pixels[corner + W], pixels[corner + W + 1]
                else:
                    a, b, c, d = coarse[corner], coarse[corner + 1], coarse[corner + W], coarse[corner + W + 1]
                top = 0.0
                for k in range(3):
                    s = 8 * k
                    va, vb = float((a >> s) & 255), float((b >> s) & 255)
                    vc, vd = float((c >> s) & 255), float((d >> s) & 255)
                    upper = va + ax * (vb - va)
                    lower = vc + ax * (vd - vc)
                    raws[band, m, k] = (upper + ay * (lower - upper)) / 255.0
                    top = max(top, raws[band, m, k])
                clips[band, m] = top >= clip_level
                # brought to the canonical appearance: (rgb - offset) @ inverse
                r0 = raws[band, m, 0] - offset[g, 0]
                r1 = raws[band, m, 1] - offset[g, 1]
                r2 = raws[band, m, 2] - offset[g, 2]
                for k in range(3):
                    rgbs[band, m, k] = r0 * inverse[g, 0, k] + r1 * inverse[g, 1, k] + r2 * inverse[g, 2, k]
                if clips[band, m] and canonical:
                    # the clipped channels raised to the brightest of their canonical values
                    highest = -np.inf
                    for k in range(3):
                        if raws[band, m, k] >= clip_level:
                            highest = max(highest, rgbs[band, m, k])
                    for k in range(3):
                        if raws[band, m, k] >= clip_level:
                            rgbs[band, m, k] = max(rgbs[band, m, k], highest)
            m += 1
        tally[0] += m
        if m == 0:
            out[i, 0] = out[i, 1] = out[i, 2] = 0.0
            total[i] = 0.0
            alpha[i] = 0.0
            continue
        best, reach = -np.inf, 0.0
        low0 = low1 = low2 = 0.0
        for j in range(m):
            best = max(best, quality[j])
            reach = max(reach, reach_of[j])
        alpha[i] = reach
        out[i, 0] = out[i, 1] = out[i, 2] = 0.0
        for j in range(m):
            base[j] = reach_of[j] * np.exp((quality[j] - best) / temperature)
        # the fine band's two blends (the photos' and their coarse band's, at the detail temperature) weigh each
        # sample alike unless clipped samples give way or photo-consistency reweights: then the first sums both
        shared = bands and not consistency > 0
        for j in range(m if shared and censors else 0):
            if clips[0, j] or clips[1, j]:
                shared = False
                break
        # one band: the photos' blend. Two: their coarse band's blend at the temperature, plus the fine band's at the
        # detail temperature (by linearity, the photos' blend there less their coarse band's) times the detail gain
        for blend_pass in range(3 if bands else 1):
            if blend_pass == 2 and shared:
                break  # summed with the first
            band = 0 if blend_pass == 1 or not bands else 1
            sign = -detail_gain if blend_pass == 2 else detail_gain if blend_pass == 1 else 1.0
            rgb, clipped = rgbs[band], clips[band]
            t = temperature if blend_pass == 0 else detail_temperature
            any_clipped = False
            for j in range(m):
                if blend_pass == 0:
                    weight[j] = base[j]
                else:
                    weight[j] = reach_of[j] * np.exp((quality[j] - best) / t) * fine_of[j]
                any_clipped = any_clipped or clipped[j]
                if blend_pass > 0 and detail_consistency > 0:
                    # the fine band from photos whose coarse band agrees with what most photos' say (see below)
                    r = ((rgbs[1, j, 0] - low0) ** 2 + (rgbs[1, j, 1] - low1) ** 2 + (rgbs[1, j, 2] - low2) ** 2)
                    weight[j] *= np.exp(-r / (detail_consistency * detail_consistency))
            if any_clipped and blend_pass == 0:
                tally[1] += np.sum(clipped[:m])
            if censors and any_clipped:
                # the clipped samples give way where the unclipped ones say their photo overshot its white point
                support, s0, s1, s2 = 0.0, 0.0, 0.0, 0.0
                for j in range(m):
                    if not clipped[j]:
                        support += weight[j]
                        s0 += weight[j] * rgb[j, 0]
                        s1 += weight[j] * rgb[j, 1]
                        s2 += weight[j] * rgb[j, 2]
                if support > 0:
                    u0, u1, u2 = s0 / max(support, 1e-12), s1 / max(support, 1e-12), s2 / max(support, 1e-12)
                    for j in range(m):
                        if clipped[j]:
                            g = group[j]
                            predicted = -np.inf
                            for k in range(3):
                                predicted = max(predicted, u0 * gain[g, 0, k] + u1 * gain[g, 1, k]
                                                + u2 * gain[g, 2, k] + offset[g, k])
                            scale = min(max(1.0 - (predicted - 1.0) / overshoot, 1e-3), 1.0)
                            if scale < 0.5 and blend_pass == 0:  # the sample keeps less than half its weight
                                tally[2] += 1
                            weight[j] *= scale
            both = blend_pass == 1 and shared
            support, s0, s1, s2, c0, c1, c2 = 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
            for j in range(m):
                support += weight[j]
                s0 += weight[j] * rgb[j, 0]
                s1 += weight[j] * rgb[j, 1]
                s2 += weight[j] * rgb[j, 2]
                if both:  # the coarse band's at the same weights: the second of the fine band's blends
                    c0 += weight[j] * rgbs[1, j, 0]
                    c1 += weight[j] * rgbs[1, j, 1]
                    c2 += weight[j] * rgbs[1, j, 2]
            if blend_pass == 0:
                total[i] = support
            norm = max(support, 1e-12)
            o0, o1, o2 = s0 / norm, s1 / norm, s2 / norm
            # photo-consistency: each round reweights every sample by its distance from the last blend
            for _ in range(rounds if consistency > 0 else 0):
                inv_scale = 1.0 / (consistency * consistency)
                support, s0, s1, s2 = 0.0, 0.0, 0.0, 0.0
                for j in range(m):
                    r = (rgb[j, 0] - o0) ** 2 + (rgb[j, 1] - o1) ** 2 + (rgb[j, 2] - o2) ** 2
                    robust = weight[j] / (1.0 + inv_scale * r)
                    support += robust
                    s0 += robust * rgb[j, 0]
                    s1 += robust * rgb[j, 1]
                    s2 += robust * rgb[j, 2]
                norm = max(support, 1e-12)
                o0, o1, o2 = s0 / norm, s1 / norm, s2 / norm
            out[i, 0] += sign * o0
            out[i, 1] += sign * o1
            out[i, 2] += sign * o2
            if both:
                out[i, 0] += -detail_gain * (c0 / norm)
                out[i, 1] += -detail_gain * (c1 / norm)
                out[i, 2] += -detail_gain * (c2 / norm)
            if blend_pass == 0 and bands and detail_consistency > 0:
                # what most photos' coarse bands say: robust (Cauchy) rounds from the coarse blend, so that a photo
                # that saw an occluder or a highlight stands out from it
                low0, low1, low2 = o0, o1, o2
                inv_scale = 1.0 / (detail_consistency * detail_consistency)
                for _ in range(DETAIL_ROUNDS):
                    support, s0, s1, s2 = 0.0, 0.0, 0.0, 0.0
                    for j in range(m):
                        r = (rgbs[1, j, 0] - low0) ** 2 + (rgbs[1, j, 1] - low1) ** 2 + (rgbs[1, j, 2] - low2) ** 2
                        robust = base[j] / (1.0 + inv_scale * r)
                        support += robust
                        s0 += robust * rgbs[1, j, 0]
                        s1 += robust * rgbs[1, j, 1]
                        s2 += robust * rgbs[1, j, 2]
                    if support > 0:
                        low0, low1, low2 = s0 / support, s1 / support, s2 / support


def _kernel():
    """The compiled blend (:func:`scantex.jit.compiled`), or ``None`` where numba is missing."""
    from scantex.jit import compiled

    return compiled(_blend)


def available() -> bool:
    """Whether the compiled blend runs here (numba installed and loading)."""
    return _kernel() is not None


@dataclass(frozen=True, eq=False)
class PhotoTables:
    """The training photos as the kernel reads them: every photo's arrays end to end in one array each,
    with each photo's start, and its pose and settings stacked. ``P`` photos."""

    seen_faces: np.ndarray  # (F, P) bool: the faces photo p may see (culling), or (0, P): no culling
    rotation_t: np.ndarray  # (P, 3, 3) float64: the rotation, transposed (points are rows)
    translation: np.ndarray  # (P, 3) float64: about the capture's origin
    intrinsics_t: np.ndarray  # (P, 3, 3) float64: at the sampling resolution, transposed
    to_view: np.ndarray  # (P, 2, 3) float64: a sampling pixel to the working resolution's pixel
    centre: np.ndarray  # (P, 3) float64: the camera's centre, about the origin
    focal: np.ndarray  # (P,) float64: the sampling camera's focal length in pixels
    log_sharpness: np.ndarray  # (P,) float64
    fine_weight: np.ndarray  # (P,) float64: the photo's factor on its weight in the fine band's blend (two bands)
    group: np.ndarray  # (P,) int64: the photo's colour transform
    pixel_start: np.ndarray  # (P,) int64: where its image starts in ``pixels``
    widths: np.ndarray  # (P,) int64: sampling resolution
    heights: np.ndarray  # (P,) int64
    pixels: np.ndarray  # (sum H W,) uint32: the images packed (a pixel's RGB bytes in one word), row-major
    coarse: np.ndarray  # the same for each image's coarse band (two bands), or empty (one band)
    view_start: np.ndarray  # (P,) int64: where its working-resolution maps start
    view_widths: np.ndarray  # (P,) int64
    view_heights: np.ndarray  # (P,) int64
    depth: np.ndarray  # (sum h w,) float32: the pixels' signed depth at the working resolution (``_Source.depth``)
    feather: np.ndarray  # (sum h w,) float32
    inverse: np.ndarray  # (G, 3, 3) float64: the inverse of each transform's linear part
    offset: np.ndarray  # (G, 3) float64: each transform's offset
    gain: np.ndarray  # (G, 3, 3) float64: each transform's linear part
    canonical: bool  # whether the transforms are the photos' (else one identity: the colours as recorded, and a
    # clipped sample's channels are left as they are)


def blend(tables: PhotoTables, local: np.ndarray, unit: np.ndarray, face_ids: np.ndarray, *, depth_tolerance: float,
          temperature: float, clip_level: float, overshoot: float, consistency: float, rounds: int,
          without: int | None, censors: bool, detail_temperature: float = 0.0, detail_gain: float = 1.0,
          detail_consistency: float = 0.0) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The photos' blend at points ``local (n, 3)`` (about the capture's origin) with normals ``unit (n, 3)`` on
    faces ``face_ids (n,)``: ``(colour (n, 3) float32, total weight (n,) float32, the largest feather weight
    (n,) float32, tally (3,) int64: samples, clipped samples, clipped samples that gave way)``, as
    :func:`scantex.photos.texturing.projective_colour`'s numpy path makes them (``censors``: clipped samples
    give way where the others say their photo overshot its white point). With ``tables.coarse`` (two bands), the
    colour is the coarse band's blend at ``temperature`` plus ``detail_gain`` times the fine band's at
    ``detail_temperature``, a photo's weight there times ``exp(-(d / detail_consistency)^2)``, ``d`` its coarse
    band's distance from what most photos' coarse bands say (:data:`DETAIL_ROUNDS` robust rounds from the coarse
    blend; 0: no such weight); the total weight and the tally are the coarse band's blend's."""
    n = len(local)
    out = np.empty((n, 3), np.float64)
    total = np.empty(n, np.float64)
    alpha = np.empty(n, np.float64)
    tally = np.zeros(3, np.int64)
    t = tables
    _kernel()(np.ascontiguousarray(local, np.float64), np.ascontiguousarray(unit, np.float64),
              np.ascontiguousarray(face_ids, np.int64), t.seen_faces, t.rotation_t, t.translation, t.intrinsics_t,
              t.to_view, t.centre, t.focal, t.log_sharpness, t.fine_weight, t.group, t.pixel_start, t.widths,
              t.heights, t.pixels, t.coarse, t.view_start, t.view_widths, t.view_heights, t.depth, t.feather,
              t.inverse, t.offset, t.gain, float(depth_tolerance), float(temperature),
              float(detail_temperature or 1.0), float(detail_gain),  # read with two bands only
              float(detail_consistency), float(clip_level), float(overshoot), float(consistency), int(rounds),
              -1 if without is None else int(without), bool(censors),
              t.canonical, out, total, alpha, tally)
    return out.astype(np.float32), total.astype(np.float32), alpha.astype(np.float32), tally
