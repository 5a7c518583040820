"""Photos taken through a distorting lens, seen as pinhole images.

A capture straight out of structure from motion (COLMAP's ``SIMPLE_RADIAL`` and ``OPENCV`` models, a nerfstudio
``transforms.json`` with ``k1``, MVE's and VisualSfM's radial terms) stores the photos as the lens drew them.
scantex's cameras are pinholes; a distortion that moves pixels by more than ``max_distortion_px`` is undone
when a photo is read, as ``colmap image_undistorter`` and texrecon's scene do ahead of texturing:

- The pinhole camera keeps the photo's size and principal point; its focal lengths are the photo's scaled so
  that the undistorted view reaches the photo's nearest edge and no further: no pixel of it without a source
  (COLMAP's default ``blank_pixels 0``), the other edges' last few pixels left out where the lens or its principal
  point is not symmetric. A barrel lens (``k1 < 0``) gets a shorter focal length and keeps its edges' middles; a
  pincushion one a longer.
- Each pixel of the pinhole view takes the photo's colour where the lens drew it (bilinear), the distortion
  model evaluated forward (VisualSfM's, an inverse model, solved per point). A depth map of the photo's view is
  resampled the same way, nearest (no depth averaged across an edge); one of a depth camera registered to the
  photo's (:attr:`PhotoSet.depth_warps`), a pinhole of its own, through that camera alone.
- A fisheye (``projection`` equidistant or equisolid) is undone the same way; where its view is wider than a
  pinhole of half its focal length keeps (150 degrees and more across), the pinhole view stops there and the
  photo's edges are cropped.
- A model that folds the view (its mapping's Jacobian not positive somewhere in the photo: coefficients fitted
  beyond the calibrated field) is refused, as is one that needs a focal length over 3 times the photo's.

Why not OpenCV's ``initUndistortRectifyMap`` and ``remap``: they are the one piece scantex would take from OpenCV,
whose wheel is larger than the rest of scantex's dependencies; the forward model is :meth:`Distortion.distort`, the
sampling ``scipy.ndimage.map_coordinates`` (a compiled twin where numba is installed).
"""

from __future__ import annotations

import functools
import logging
from dataclasses import dataclass

import numpy as np

from scantex.errors import ScanError
from scantex.photos.photoset import Distortion, nearest_at_shares
from scantex.views.camera import Camera

log = logging.getLogger(__name__)

#: the range of focal-length scales searched for the pinhole view: a lens needing a longer one is refused; one that
#: would need a shorter one (a fisheye of 150 degrees: its edges' middles at a pinhole's 3.7 focal lengths) gets the
#: shortest, its view cropped (no wider, or its middle would keep less than half the photo's resolution)
SCALE_RANGE = (0.5, 3.0)


@dataclass(frozen=True, eq=False)
class Lens:
    """How a stored photo maps onto its camera's pinhole view (:attr:`PhotoSet.lenses`).

    Attributes:
        photo_K: ``(3, 3)`` intrinsics of the photo as stored, with ``distortion`` applied to its normalised
            coordinates.
        distortion: the lens's distortion (OpenCV's model, :class:`Distortion`).
        K: ``(3, 3)`` the pinhole view's intrinsics when the photos were read (a focal length refined later takes
            the undistorted photo along, as it takes any photo).
        size: ``(width, height)`` of the photo and of its pinhole view.
    """

    photo_K: np.ndarray
    distortion: Distortion
    K: np.ndarray
    size: tuple[int, int]

    def source_pixels(self, size: tuple[int, int], source_size: tuple[int, int] | None = None,
                      rows: slice = slice(None)) -> tuple[np.ndarray, np.ndarray]:
        """``(x, y)``, ``(h, w) float64`` each: where each pixel of the pinhole view at ``size`` (``(w, h)``,
        covering the view of :attr:`K`) falls in the stored image at ``source_size`` (default ``size``; covering
        the view of :attr:`photo_K`), in that image's pixels (``(0, 0)`` the centre of its top-left pixel);
        ``rows``: of those rows only."""
        source_size = size if source_size is None else source_size
        (W, H), (w, h) = self.size, size
        u = (np.arange(w) + 0.5) * (W / w) - 0.5  # the view's pixels at the photo's size
        v = (np.arange(h)[rows] + 0.5) * (H / h) - 0.5
        x, y = normalised(self.K, u[None, :], v[:, None])
        xd, yd = self.distortion.distort(*np.broadcast_arrays(x, y))
        us, vs = pixels(self.photo_K, xd, yd)
        return (us + 0.5) * (source_size[0] / W) - 0.5, (vs + 0.5) * (source_size[1] / H) - 0.5


def lens_summary(lenses) -> dict | None:
    """``{"photos", "models", "focal_scale": [min, max]}`` of the photos undistorted when read (``lenses``:
    :attr:`PhotoSet.lenses`): how many, through which models, their pinhole views' focal lengths over the photos';
    ``None`` when none is."""
    used = [lens for lens in lenses if lens is not None]
    if not used:
        return None
    scales = [float(lens.K[0, 0] / lens.photo_K[0, 0]) for lens in used]
    return {"photos": len(used), "models": sorted({lens.distortion.model for lens in used}),
            "focal_scale": [round(min(scales), 4), round(max(scales), 4)]}


def normalised(K: np.ndarray, u, v) -> tuple[np.ndarray, np.ndarray]:
    """Normalised camera coordinates ``(X/Z, Y/Z)`` of pixels ``u, v`` through ``K`` (skew included)."""
    y = (v - K[1, 2]) / K[1, 1]
    return (u - K[0, 2] - K[0, 1] * y) / K[0, 0], y


def pixels(K: np.ndarray, x, y) -> tuple[np.ndarray, np.ndarray]:
    """Pixels of normalised coordinates ``x, y`` through ``K``: :func:`normalised`'s inverse."""
    return K[0, 0] * x + K[0, 1] * y + K[0, 2], K[1, 1] * y + K[1, 2]


def pinhole_lens(camera: Camera, distortion: Distortion, where, what: str) -> Lens:
    """The :class:`Lens` that undoes ``distortion`` of the photo ``camera`` describes (``camera.K``: its stored
    intrinsics); the pinhole view's K as the module docstring says.

    Raises:
        ScanError: the model folds the photo's view, or needs a focal length beyond :data:`SCALE_RANGE`'s longest.
    """
    K0, size = np.asarray(camera.K, np.float64), (int(camera.width), int(camera.height))

    def fits(scale: float) -> bool:
        lens = Lens(K0, distortion, _scaled(K0, scale), size)
        return _border_inside(lens)

    lo, hi = SCALE_RANGE
    if not fits(hi):
        raise ScanError(where, f"{what}: lens distortion ({distortion.model}) leaves no pinhole view inside the "
                               f"photo: undistort the photos with the tool that calibrated the lens")
    if fits(lo):
        hi = lo
        log.info("%s: %s: the lens (%s) draws a wider view than a pinhole of half its focal length keeps: the "
                 "photo's edges are cropped", where, what, distortion.model)
    for _ in range(40 if hi > lo else 0):  # bisection on the focal-length scale: the border just inside the photo
        mid = 0.5 * (lo + hi)
        lo, hi = (lo, mid) if fits(mid) else (mid, hi)
    lens = Lens(K0, distortion, _scaled(K0, hi), size)
    _check_unfolded(lens, where, what)
    return lens


def _scaled(K: np.ndarray, scale: float) -> np.ndarray:
    out = np.array(K, np.float64)
    out[:2, :2] *= scale
    return out


def _border_inside(lens: Lens, samples: int = 257) -> bool:
    """Whether every point of the pinhole view's border (its outermost pixel centres) falls inside the photo's
    pixel centres, where bilinear sampling has all four neighbours."""
    W, H = lens.size
    t = np.linspace(0.0, 1.0, samples)
    u = np.concatenate([t * (W - 1), t * (W - 1), np.zeros(samples), np.full(samples, W - 1.0)])
    v = np.concatenate([np.zeros(samples), np.full(samples, H - 1.0), t * (H - 1), t * (H - 1)])
    xd, yd = lens.distortion.distort(*normalised(lens.K, u, v))
    us, vs = pixels(lens.photo_K, xd, yd)
    margin = 1e-3  # the border is sampled: a thousandth of a pixel keeps the points between samples inside too
    return bool((us >= margin).all() and (us <= W - 1 - margin).all() and (vs >= margin).all()
                and (vs <= H - 1 - margin).all())


def _check_unfolded(lens: Lens, where, what: str) -> None:
    """Refuse a model that folds the pinhole view over (its coefficients fitted beyond the calibrated field): the
    Jacobian of the view's normalised coordinates -> the photo's not positive (under a ten-thousandth of a
    pinhole's, 1) somewhere on a 49 x 49 grid over the view."""
    W, H = lens.size
    u, v = np.meshgrid(np.linspace(0, W - 1, 49), np.linspace(0, H - 1, 49))
    x, y = normalised(lens.K, u, v)
    eps = 1e-6
    (xa, ya), (xb, yb) = lens.distortion.distort(x + eps, y), lens.distortion.distort(x - eps, y)
    (xc, yc), (xe, ye) = lens.distortion.distort(x, y + eps), lens.distortion.distort(x, y - eps)
    det = (xa - xb) * (yc - ye) - (ya - yb) * (xc - xe)
    # against the pinhole's own (a fisheye squeezes its edges to a few hundredths and is no fold)
    if not (det > 1e-4 * (2 * eps) ** 2).all():
        raise ScanError(where, f"{what}: lens distortion ({lens.distortion.model}) folds the photo's view over "
                               f"(its coefficients do not describe a lens there): undistort the photos with the "
                               f"tool that calibrated the lens")


def _source_pixels(lens: Lens, size: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """:meth:`Lens.source_pixels` as float32 at the photo's size, kept for the last two lenses (the photos of one
    camera model share theirs; a 12-megapixel photo's take 96 MB)."""
    return _cached_source_pixels(tuple(lens.photo_K.ravel()), lens.distortion, tuple(lens.K.ravel()), lens.size,
                                 size)


@functools.lru_cache(maxsize=2)
def _cached_source_pixels(photo_K: tuple, distortion: Distortion, K: tuple, lens_size: tuple[int, int],
                          size: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    lens = Lens(np.reshape(photo_K, (3, 3)), distortion, np.reshape(K, (3, 3)), lens_size)
    x, y = np.empty((size[1], size[0]), np.float32), np.empty((size[1], size[0]), np.float32)
    for start in range(0, size[1], 256):  # in blocks of rows: the float64 terms of a 12-megapixel map would take 1 GB
        rows = slice(start, start + 256)
        x[rows], y[rows] = lens.source_pixels(size, rows=rows)
    return x, y


def undistort_image(image: np.ndarray, lens: Lens) -> np.ndarray:
    """``(H, W, C) uint8`` photo as stored -> the same size of its pinhole view (bilinear, rounded). Compiled
    (:mod:`scantex.jit`: 0.1 s for 12 megapixels against 1 s in ``map_coordinates``, which it runs where numba is
    missing; the two agree to a level)."""
    from scantex import jit

    h, w = image.shape[:2]
    x, y = _source_pixels(lens, (w, h))
    kernel = jit.compiled(_undistort_kernel)
    if kernel is not None and image.dtype == np.uint8:
        out = np.empty_like(image)
        kernel(np.ascontiguousarray(image), x, y, out)
        return out
    return undistort_image_reference(image, x, y)


def undistort_image_reference(image: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """:func:`undistort_image`'s numpy twin: each channel sampled at ``(x, y)`` by ``map_coordinates`` (order 1, the
    border extended)."""
    from scipy.ndimage import map_coordinates

    out = np.empty(x.shape + image.shape[2:], image.dtype)
    for c in range(image.shape[2]):
        out[..., c] = map_coordinates(image[..., c], [y, x], order=1, mode="nearest")
    return out


def _undistort_kernel(image, x, y, out):
    """:func:`undistort_image`'s kernel: ``image (H, W, C) uint8`` at ``x, y (h, w)`` (clamped to its pixel centres)
    into ``out (h, w, C) uint8``, bilinear, rounded half up."""
    H, W, C = image.shape
    for r in range(x.shape[0]):
        for c in range(x.shape[1]):
            px = min(max(np.float64(x[r, c]), 0.0), W - 1.0)
            py = min(max(np.float64(y[r, c]), 0.0), H - 1.0)
            x0 = min(int(px), max(W - 2, 0))
            y0 = min(int(py), max(H - 2, 0))
            x1 = min(x0 + 1, W - 1)
            y1 = min(y0 + 1, H - 1)
            fx = px - x0
            fy = py - y0
            for k in range(C):
                top = image[y0, x0, k] * (1.0 - fx) + image[y0, x1, k] * fx
                bottom = image[y1, x0, k] * (1.0 - fx) + image[y1, x1, k] * fx
                out[r, c, k] = np.uint8(min(top * (1.0 - fy) + bottom * fy + 0.5, 255.0))


def undistort_depth(depth: np.ndarray, lens: Lens, warp: np.ndarray | None = None) -> np.ndarray:
    """``(h, w) float32`` depth map of the stored photo's view -> its pinhole view at the map's size, nearest; NaN
    where no depth falls. With ``warp`` (:attr:`PhotoSet.depth_warps`), the map is a depth camera's registered to
    the photo's, a pinhole of its own: each pixel of the view goes to it along its ray, through no colour lens."""
    h, w = depth.shape
    if warp is None:
        x, y = lens.source_pixels((w, h), lens.size)  # the photo's pixels, through its lens
    else:  # the view's rays as the photo's pinhole K would draw them: what the warp's K_photo stands for
        (W, H) = lens.size
        u = (np.arange(w) + 0.5) * (W / w) - 0.5
        v = (np.arange(h) + 0.5) * (H / h) - 0.5
        x, y = pixels(lens.photo_K, *np.broadcast_arrays(*normalised(lens.K, u[None, :], v[:, None])))
    sx, sy = (x + 0.5) / lens.size[0], (y + 0.5) / lens.size[1]  # shares of the photo
    if warp is not None:
        sx, sy = warp[0, 0] * sx + warp[0, 1] * sy + warp[0, 2], warp[1, 0] * sx + warp[1, 1] * sy + warp[1, 2]
    return nearest_at_shares(depth, sx, sy)
