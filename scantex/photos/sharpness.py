"""Each photo's fine detail against the photos that see the same surface: shaken or out-of-focus frames named.

A handheld capture has frames smeared by the hand's motion. Photo mode blends every photo that sees a point
nearly alike (the held-out photos' own poses, a few pixels off, favour that), so three shaken photos of nine
smear the whole texture sideways, visibly softer than the input's best view per texel, at the same held-out
score (the bolster's 9-photo draws, ``bench/bench_few_photos.py --motion-blur 21``: +0.99 dB over the input
either way; bench/RESULTS.md, "shaken photos"). Such photos are found here and, when they are many
(``photos.blurred``, :data:`LEAVE_OUT_SHARE`), left out: the texture is then as sharp as the sharp photos
(+0.75 dB). Softened instead (``photos.blurred`` soften: their colour and coverage blended with the others', their
fine detail giving way to the sharp photos', ``ProjectiveSettings.soft_photos``), it is as sharp, and scores the
same or a little less (+0.76 dB here; 0.13 dB under leaving them out where they were smeared by 15 working
pixels, more than the bands' split).

One number a photo says how sharp it is, but a photo's own detail says more of what it shows (a printed
cushion, a white wall) than of its focus. Two photos compared at the same surface points say it directly: at
each of photo ``k``'s textured pixels (:data:`TEXTURED`: a blank wall's finest detail is its photo's noise, which
an over-exposed photo has clipped away) and its four neighbours (unprojected with its G-buffer depth), the grey
image's second difference along the photo's rows, and along its columns, divided by the brightness there
(exposure cancels), is measured in ``k`` and, carried through the mesh, in photo ``l``, whose pixels are read
bilinearly at those five surface points. Half the log of their mean squares' ratio is ``log d_l - log d_k``
(``d``: a photo's detail along that axis), a row for each photo and each of its most overlapping partners
(:func:`pair_rows`). A photo is judged by the median of its rows against its partners (:func:`relative_detail`:
a pair whose few textured points mislead moves it little), along its weaker axis (a shaken photo is smeared
along the hand's motion, and a texture's detail may lie mostly across it), and one under :data:`BLURRED` (30 %
of its partners' detail) is called blurred.

Reading ``l`` between its pixels softens it a little, and ``k``'s own pixels are read as they are; a photo
further from the surface resolves less of it and would measure softer for it: a pair is measured on the coarser
photo's pixels only (where ``l``'s footprint on the surface is larger than ``k``'s by more than :data:`COARSER`,
only as ``(l, k)``).
"""

from __future__ import annotations

from collections.abc import Collection, Sequence

import numpy as np

from scantex.photos.training import PhotoView

#: a photo whose detail along its weaker axis is under exp(BLURRED) of its partners' is called blurred: 0.30.
#: Measured (bench/RESULTS.md "shaken photos"): the sharp photos of real captures at -0.94 and above (the
#: bolster's, the facade's, a real apartment's 197 Kinect frames and three 12-frame parts of it), the synthetic
#: demo wall's at -0.46; photos smeared sideways by 7 working pixels at -1.43 and below; one pale photo of a
#: blank wall in a synthetic room at -1.35
BLURRED = -1.2
#: ``photos.blurred`` auto leaves the blurred photos out when they are this share of the training photos or more:
#: one smeared photo of nine, blended in, softened a real capture's texture only slightly and left out cost it
#: 0.44 dB (the photos beside it painted what it saw from further off); three of nine smeared the bolster's texture
#: visibly, and left out it was as sharp as the photos, 0.24 dB lower
LEAVE_OUT_SHARE = 0.25
#: each photo compared with the photos that see the most of the faces it sees, this many
NEIGHBOURS = 8
#: pixels of each photo (with their four neighbours) looked up in its partners, at most
POINTS = 6000
#: the share of a photo's sampled pixels measured: those of the most contrast over a Gaussian of TEXTURE_PX
TEXTURED, TEXTURE_PX = 0.3, 3.0
#: a photo is judged from this many pairs at least
MIN_PAIRS = 2
#: and against the photos not named blurred (:func:`blurred_photos`' second look) from this many: a median of two
#: is their mean, and one misleading pair moves it (a synthetic room's photo, left with two pairs, one of them far
#: off, measured 0.22 of its partners' detail, with the third 0.75)
SHARP_PAIRS = 3
#: a pair's row needs this many points that both see, neither dark nor clipped
MIN_POINTS = 150
#: a pair is measured on the pixels of photo ``k`` unless photo ``l``'s are coarser there by more than this
#: (its pixel's footprint on the surface larger)
COARSER = 1.25
#: a pixel's four neighbours must lie on the same surface: their depth within this share of its own
DEPTH_STEP = 0.02
_STEPS = ((0, 1), (0, -1), (1, 0), (-1, 0))  # (dy, dx): along the rows, then the columns


def pair_rows(views: Sequence[PhotoView], shared: np.ndarray | None = None, depth_tolerance: float = 0.02,
              seed: int = 0) -> np.ndarray:
    """``(n, 5)``: a row ``(k, l, log d_l - log d_k along k's rows, the same along its columns, weight)`` for each
    photo ``k`` and each of its :data:`NEIGHBOURS` most-overlapping partners ``l`` that it measures against (``d``:
    a photo's fine detail at the surface points both see). ``shared``: :func:`photo_overlaps` of the views."""
    from scantex.photos.texturing import _seen_in, photo_overlaps, view_points
    from scantex.threads import side_by_side

    P = len(views)
    shared = photo_overlaps(views) if shared is None else shared
    greys = list(side_by_side(_grey, views))  # float16: a room's 219 views hold 135 MB of them, not 270
    rng = np.random.default_rng(seed)
    picks = [_drawn(candidates, rng) for candidates in side_by_side(_candidates, views)]  # drawn in photo order

    def rows_of(k: int) -> list[tuple[int, int, float, float, float]]:
        """Photo ``k``'s rows ``(k, l, log d_l - log d_k along k's rows, the same along its columns, weight)``."""
        view, (ys, xs) = views[k], picks[k]
        if len(ys) < MIN_POINTS:
            return []
        grey = greys[k].astype(np.float32)
        ys, xs = _textured(grey, ys, xs)
        centre = view_points(view, xs, ys)
        around = [view_points(view, xs + dx, ys + dy) for dy, dx in _STEPS]
        own = grey[ys, xs]
        # second differences along the rows (the first two steps) and along the columns (the last two)
        own_second = [grey[ys + dy, xs + dx] + grey[ys - dy, xs - dx] - 2 * own for dy, dx in _STEPS[::2]]
        partners = [l for l in np.argsort(-shared[k], kind="stable") if l != k and shared[k, l] >= 1]
        out = []
        for l in sorted(partners[:NEIGHBOURS]):
            u = views[l]
            pix, z = u.camera.project(centre)
            seen, _, _ = _seen_in(u.valid, u.depth, pix, z, depth_tolerance)
            if len(seen) < MIN_POINTS:
                continue
            # measured on the coarser photo's pixels: a photo further from the surface is not called soft for it
            # (the pair's other direction measures it where this photo is the coarser)
            coarser = np.median(z[seen] / u.camera.K[0, 0]) / np.median(view.depth[ys[seen], xs[seen]]
                                                                        / view.camera.K[0, 0])
            if coarser > COARSER:
                continue
            other_grey = greys[l].astype(np.float32)
            theirs = _bilinear(other_grey, pix[seen])
            read = [_bilinear(other_grey, u.camera.project(points[seen])[0]) for points in around]
            second = [read[0] + read[1] - 2 * theirs, read[2] + read[3] - 2 * theirs]
            a, b = own[seen], theirs
            good = (a > 0.03) & (a < 0.97) & (b > 0.03) & (b < 0.97)
            if good.sum() < MIN_POINTS:
                continue
            ratios = []
            for mine, other in zip(own_second, second):
                mine = np.mean(np.square(mine[seen][good] / a[good]))
                other = np.mean(np.square(other[good] / b[good]))
                ratios.append(0.5 * float(np.log(other / mine)) if mine > 0 and other > 0 else np.nan)
            if np.isfinite(ratios).all():
                out.append((k, int(l), *ratios, float(np.sqrt(good.sum()))))
        return out

    rows = [row for photo in side_by_side(rows_of, range(P)) for row in photo]
    return np.array(rows, np.float64).reshape(-1, 5)


def relative_detail(P: int, rows: np.ndarray, blurred: Collection[int] = ()) -> np.ndarray:
    """``(P, 2)`` each photo's ``log d`` against its partners', along each axis: the median over the pairs it is in
    (a pair whose few textured points mislead moves a median little), ``nan`` with fewer than
    :data:`MIN_PAIRS`. ``blurred``: photos (positions in the views) not taken as partners, where a photo has
    :data:`SHARP_PAIRS` pairs with the others (its median over all its pairs where not)."""
    out = np.full((P, 2), np.nan)
    gone = np.isin(rows[:, :2], list(blurred))

    def signed(as_k: np.ndarray, as_l: np.ndarray) -> np.ndarray:
        """The rows' log ratios seen from photo ``p``: the pairs where it is ``k`` negated."""
        return np.r_[-rows[as_k, 2:4].reshape(-1, 2), rows[as_l, 2:4].reshape(-1, 2)]

    for p in range(P):
        k, l = rows[:, 0] == p, rows[:, 1] == p
        mine = signed(k & ~gone[:, 1], l & ~gone[:, 0])
        if len(mine) < SHARP_PAIRS:
            mine = signed(k, l)
        if len(mine) >= MIN_PAIRS:
            out[p] = np.median(mine, axis=0)
    return out


def blurred_photos(views: Sequence[PhotoView]) -> list[dict]:
    """The views whose detail along their weaker axis is under :data:`BLURRED` of their partners': ``{"photo":
    index, "detail": the share of their partners' detail}`` each, the least detailed first.

    The photos named are then left out of the others' partners and every photo judged again, until no other is
    named: where a third of the photos are shaken, a shaken photo's median over its partners is taken partly
    against shaken ones, and passes (a real capture's part with three of nine photos smeared by 15 working pixels:
    the third measured 0.31 of its partners' detail, against the sharp ones alone 0.20)."""
    rows = pair_rows(views)
    named: set[int] = set()
    while True:
        # a shaken photo is smeared along the hand's motion: its weaker axis says it
        relative = relative_detail(len(views), rows, named).min(axis=1)
        found = {k for k in range(len(views)) if np.isfinite(relative[k]) and relative[k] < BLURRED}
        if found <= named:
            break
        named |= found
    found = sorted((float(relative[k]), int(views[k].index)) for k in named)
    return [{"photo": i, "detail": round(float(np.exp(r)), 2)} for r, i in found]


def _textured(grey: np.ndarray, ys: np.ndarray, xs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The pixels among ``(ys, xs)`` where the surface has texture: the grey's contrast over the Gaussian of
    :data:`TEXTURE_PX` about them in the top :data:`TEXTURED` share. A blank wall's finest detail is its photo's
    noise, which an over-exposed photo has clipped away; a smear of a few pixels lowers that contrast far less than
    the finest detail."""
    from scipy import ndimage

    contrast = ndimage.gaussian_gradient_magnitude(grey, TEXTURE_PX)[ys, xs]
    keep = contrast >= np.quantile(contrast, 1 - TEXTURED) if len(contrast) else np.zeros(0, bool)
    return ys[keep], xs[keep]


def _grey(view: PhotoView) -> np.ndarray:
    """``(H, W) float16`` luma of the view's image."""
    return (view.image @ np.array([0.299, 0.587, 0.114], np.float32)).astype(np.float16)


def _candidates(view: PhotoView) -> tuple[np.ndarray, np.ndarray]:
    """The view's usable pixels whose four neighbours are usable on the same surface."""
    ok = view.valid.copy()
    ok[[0, -1], :] = False
    ok[:, [0, -1]] = False
    depth = view.depth
    for dy, dx in _STEPS:
        near = np.roll(view.valid, (-dy, -dx), axis=(0, 1))
        step = np.abs(np.roll(depth, (-dy, -dx), axis=(0, 1)) - depth)
        ok &= near & (step < DEPTH_STEP * depth)
    return np.nonzero(ok)


def _drawn(candidates: tuple[np.ndarray, np.ndarray], rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Up to :data:`POINTS` of the ``(ys, xs)`` candidates, drawn at random."""
    ys, xs = candidates
    if len(ys) > POINTS:
        keep = rng.choice(len(ys), POINTS, replace=False)
        ys, xs = ys[keep], xs[keep]
    return ys, xs


def _bilinear(grey: np.ndarray, pix: np.ndarray) -> np.ndarray:
    """The grey image read bilinearly at pixels ``pix (n, 2)`` (clamped to the image)."""
    from scipy.ndimage import map_coordinates

    return map_coordinates(grey, [pix[:, 1], pix[:, 0]], order=1, mode="nearest")
