"""Each photo's tone curve levelled against the others' (photo mode's closed-form colour transforms).

A camera's auto-exposure does not scale a photo's colours by one gain: its tone curve keeps a near-white
wall near white while the mid-tones and shadows move. Two photos of a room's corner, measured at the surface
points both see (flat parts only: the poses' few pixels of error and the ratio of an edge's two sides say
nothing of exposure), differ by a ratio of 1.29 in their shadows and 1.00 at the wall (a real Kinect
apartment, frames 182 and 183); a gain fitted to their median ratio, 1.15, lifts that photo's white wall by
15 %, and the wall is drawn with an exposure step where the photo's frame ends.

A power law models it: photo ``k`` records ``y = g_k x ** gamma_k`` of the true colour ``x`` (the gain per
channel, its white balance; the gamma the camera's, one a photo; white at 1 kept). Between photos ``k`` and
``l``, ``log y_l`` is then a line in ``log y_k`` of slope ``gamma_l / gamma_k``: measured by a total least
squares line (both photos' colours are noisy alike) through their flat, unclipped shared points (each point's
mean log over its channels), with a robust trim, and solved for every photo's ``log gamma`` at once by least
squares, weighted by the points and the spread of their brightness (a wall of one colour says nothing of a
slope), with the photos' mean ``log gamma`` held at 0 and a pull of each towards 0. Each photo's pixels are
then brought to the common curve, ``y ** (1 / gamma_k)`` (a table of 256 entries; white stays white, so a
clipped pixel stays clipped), before its gains are fitted and its colours are blended
(:func:`scantex.photos.texturing.fit_photo_transforms`, :class:`scantex.photos.photoset.PhotoSet` ``tones``).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import numpy as np

from scantex.photos.training import PhotoView

#: a pair's line is fitted again without its points this many robust deviations off it, this many times
TRIM_SIGMAS, TRIM_ROUNDS = 3.0, 3
#: the pull of each photo's log gamma towards 0, as a share of the mean weight (squared) a photo's pairs give it:
#: 0.1 let a synthetic wall's photos (gains and black offsets, no tone curve) take gammas of 0.96-1.05 and cost
#: it 0.13 dB; 1 halved a real apartment's gain from levelling (bench/RESULTS.md "photo tones")
PRIOR = 0.3
#: each photo's slope measured against the photos that share the most of its surface, this many (a room's photo
#: overlaps dozens)
NEIGHBOURS = 8
#: flat usable pixels of each photo looked up in its neighbours, at most
POINTS = 2000
#: the gammas kept within these
GAMMA_RANGE = (0.5, 2.0)


def fit_photo_tones(views: Sequence[PhotoView], blur_px: float = 0.5, min_pixels: int = 100,
                    flat_gradient: float = 0.01) -> np.ndarray:
    """``(P,)`` each photo's gamma against the photos' common tone curve (1 where nothing measures it).

    Args:
        views: the photos at a working resolution (their G-buffers say which pixels see the surface).
        blur_px: the Gaussian each view's image is blurred by first (as the gains' fit blurs it).
        min_pixels: the fewest flat, unclipped shared points a pair's slope is measured from.
        flat_gradient: a pixel is flat where the grey image's gradient (a Gaussian derivative of 1 pixel) is
            below this, per pixel.
    """
    from scipy import ndimage, sparse
    from scipy.sparse.linalg import lsqr

    from scantex.photos.texturing import _photo_pairs
    from scantex.threads import side_by_side

    P = len(views)
    blurred = list(side_by_side(
        lambda view: np.stack([ndimage.gaussian_filter(view.image[..., c], blur_px) for c in range(3)], -1), views))
    flat = [ndimage.gaussian_gradient_magnitude(image.mean(axis=2), 1.0) < flat_gradient for image in blurred]
    pairs = _photo_pairs(views, blurred, min_pixels, lambda a, b: _log_slope(a, b, min_pixels), usable=flat,
                         neighbours=NEIGHBOURS, per_photo=POINTS)
    gammas = np.ones(P)
    pairs = [pair for pair in pairs if pair[3] > 0]
    if not pairs:
        return gammas
    k = np.array([pair[0] for pair in pairs])
    l = np.array([pair[1] for pair in pairs])
    slope = np.array([pair[2] for pair in pairs])
    w = np.array([pair[3] for pair in pairs])
    n, r = len(w), np.arange(len(w))
    # unknowns: log gamma per photo; rows: log gamma_l - log gamma_k = log slope; the photos' mean held at 0; each
    # photo pulled towards 0 by PRIOR of the mean weight (squared) its rows give a photo
    prior = np.sqrt(PRIOR * (w ** 2).sum() * 2 / P)
    A = sparse.vstack([
        sparse.csr_matrix((np.r_[w, -w], (np.r_[r, r], np.r_[l, k])), shape=(n, P)),
        sparse.csr_matrix(np.full((1, P), 100.0 * w.sum() / P)),
        prior * sparse.identity(P, format="csr")]).tocsr()
    solution = lsqr(A, np.r_[w * slope, 0.0, np.zeros(P)], atol=1e-10, btol=1e-10)[0]
    return np.clip(np.exp(solution), *GAMMA_RANGE)


def _log_slope(a: np.ndarray, b: np.ndarray, min_pixels: int) -> tuple[float, float] | None:
    """``(log slope, weight)`` of the line of ``log b`` in ``log a`` (points ``(n, 3)``, each its channels' mean
    log: the gains' log is then an offset, the slope the gammas' ratio), weight ``sqrt(points kept) x`` their
    spread in ``log a``; ``None`` where too few points are neither dark nor clipped."""
    good = ((a > 0.03) & (a < 0.97) & (b > 0.03) & (b < 0.97)).all(axis=1)
    if good.sum() < min_pixels:
        return None
    x, y = np.log(a[good]).mean(axis=1), np.log(b[good]).mean(axis=1)
    keep = np.ones(len(x), bool)
    for _ in range(TRIM_ROUNDS):
        slope, mx, my = _principal_line(x[keep], y[keep])
        residual = (y - my) - slope * (x - mx)
        keep = np.abs(residual) <= TRIM_SIGMAS * 1.4826 * np.median(np.abs(residual[keep])) + 1e-6
    if keep.sum() < min_pixels or not 0 < slope < np.inf:
        return None
    return float(np.log(slope)), float(np.sqrt(keep.sum()) * x[keep].std())


def _principal_line(x: np.ndarray, y: np.ndarray) -> tuple[float, float, float]:
    """``(slope, mean x, mean y)`` of the total least squares line through the points (its principal axis)."""
    mx, my = x.mean(), y.mean()
    sxx, syy, sxy = ((x - mx) ** 2).mean(), ((y - my) ** 2).mean(), ((x - mx) * (y - my)).mean()
    # the principal axis's slope, in closed form (sxy = 0: the larger spread's axis)
    if abs(sxy) < 1e-12:
        return (0.0 if sxx >= syy else np.inf), mx, my
    return float((syy - sxx + np.sqrt((syy - sxx) ** 2 + 4 * sxy ** 2)) / (2 * sxy)), mx, my


def tone_table(gamma: float | np.ndarray) -> np.ndarray:
    """``(256, 3) uint8``: a photo's 8-bit values on its curve of ``gamma`` (one, or one a channel ``(3,)``),
    brought to the common curve (``y ** (1 / gamma)``, rounded; 0 and 255 kept)."""
    y = np.arange(256, dtype=np.float64)[:, None] / 255.0
    exponent = 1.0 / np.broadcast_to(np.asarray(gamma, np.float64), (3,))[None, :]
    return np.clip(np.round(255.0 * y ** exponent), 0, 255).astype(np.uint8)


def toned(image: np.ndarray, gamma: float | np.ndarray) -> np.ndarray:
    """``image`` brought to the common tone curve: ``(h, w, 3)`` uint8 through :func:`tone_table`, float in
    [0, 1] by the power itself. The table is looked up compiled (:mod:`scantex.jit`: a 1920x1080 photo in a few
    milliseconds, where numpy's three gathers took about 19; photo mode tones each photo each time it is read),
    or in numpy where numba is missing."""
    if image.dtype == np.uint8:
        from scantex import jit

        table = tone_table(gamma)
        kernel = jit.compiled(_toned_kernel)
        if kernel is None or image.ndim != 3 or image.shape[2] < 3:
            return np.stack([table[image[..., c], c] for c in range(3)], axis=-1)
        source = np.ascontiguousarray(image).view()
        source.flags.writeable = False  # one type for the kernel, whether the photo came from the cache or not
        out = np.empty((*image.shape[:2], 3), np.uint8)
        kernel(source, table, out)
        return out
    return np.power(np.clip(image, 0, 1), (1.0 / np.asarray(gamma, np.float32)).astype(np.float32))


def _toned_kernel(image, table, out):
    """:func:`toned`'s lookup, pixel by pixel: ``out (h, w, 3)`` the ``table (256, 3)`` entries of ``image``'s first
    three channels."""
    for y in range(image.shape[0]):
        for x in range(image.shape[1]):
            for c in range(3):
                out[y, x, c] = table[image[y, x, c], c]


def toned_view(view: PhotoView, gamma: float | np.ndarray) -> PhotoView:
    """``view`` with its pixels brought to the common tone curve (its maps shared)."""
    return dataclasses.replace(view, pixels=toned(view.pixels, gamma))
