"""Photos as training data: which photo pixels may teach which surface point, and held-out scoring.

A photo pixel teaches the field only where the mesh says what it sees, and only when that is certain:

- the mesh is ray cast through the photo's camera at the working resolution with ``supersample``
  sub-samples per pixel; a pixel counts when all its sub-samples hit the mesh at nearly one depth
  (no silhouette, no depth discontinuity inside the pixel);
- pixels within ``edge_margin_px`` of an occluding contour (silhouette or a relative depth jump
  between neighbours) do not count: a pose that is off by a pixel would paint the background onto
  the object's rim, or the front object onto what it hides;
- grazing pixels (surface normal more than ``max_angle_deg`` away from the ray) do not count: their
  footprint on the surface is long and smeared;
- where the capture recorded a depth map, the pixel counts only when the measured depth agrees with
  the mesh's depth within ``depth_tolerance`` (relative): a person or a door that moved between the
  LiDAR scan and the photo, or a mesh that is locally wrong, is then left out. Pixels the depth map has
  no measurement for are kept (phones drop depth on dark and shiny surfaces), but for a line of them
  narrower than ``depth_gap_px`` across a map measured almost everywhere (:data:`DENSE_DEPTH`), with
  :data:`GAP_MARGIN_PX` around it: a thin object the sensor lost, which the mesh lacks too (a lamp's
  pole, a cable), would paint a line on the wall behind it in each photo that shows it.

Held-out photos are scored by rendering a scan through their cameras and comparing it with the
photo on the pixels that pass the same test. A held-out photo's exposure is unknown to any texture,
so besides the raw score the *colour-matched* score first fits a per-channel gain and offset from the
render to the photo (least squares, 6 numbers per photo, fitted to each scan's render on its own): it
measures texture detail and alignment rather than a photo's exposure.
"""

from __future__ import annotations

import dataclasses
import logging
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np

from scantex.photos.alignment import contour_map, resized_camera
from scantex.photos.photoset import PhotoSet
from scantex.scan import Scan
from scantex.views.camera import Camera
from scantex.views.raycast import PAIR_THREADS, RayCaster, pixel_footprints

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class VisibilitySettings:
    """How strict the photo-pixel visibility test is (see the module docstring)."""

    supersample: int = 2
    edge_margin_px: int = 2
    max_angle_deg: float = 75.0
    depth_tolerance: float = 0.05
    depth_gap_px: int = 0
    """a line of missing depth narrower than this (working pixels) in a dense depth map is left out (0: kept)"""


#: a depth map measured on at least this share of the pixels that see the mesh is dense (a Kinect's, a phone's
#: LiDAR's): its narrow lines of missing depth are thin objects the sensor lost. A map reprojected from a sparser
#: camera (the bolster's: 35 % measured, in a grid of holes) tells nothing by its gaps
DENSE_DEPTH = 0.9
#: working pixels left out around such a line too (the colour photo's registration to the depth camera is off
#: by a pixel or two)
GAP_MARGIN_PX = 2


@dataclass(frozen=True, eq=False)
class PhotoView:
    """One photo at the working resolution with what the mesh says each pixel sees.

    Attributes:
        index: the photo's index in its :class:`PhotoSet`.
        camera: its camera for the working resolution.
        pixels: the photo box-filtered down to the working resolution, ``(H, W, 3) uint8`` as read (a quarter
            of the memory of its colours in float: a room's two hundred views of 640x480 hold 0.5 GB less), or
            ``float32`` in [0, 1] for a view made from others' pixels (:func:`halved`); ``None`` once
            :meth:`sampled` (the texture made, what teaches it is no longer held). Read it as :attr:`image`.
        face_id: ``(H, W) int32`` face at the pixel centre, -1 for none; ``None`` once :meth:`sampled`.
        depth: ``(H, W) float32`` mean depth of the pixel's sub-samples (camera z), 0 where it sees none of
            the mesh; ``None`` once :meth:`sampled`.
        valid: ``(H, W) bool`` the pixel may teach / be scored (visibility test passed); ``None`` once
            :meth:`sampled`.
        rejected: pixels that hit the mesh but failed the test, by reason (for the report).
        depth_factor: what :func:`depth_factor` found of the photo's depth map (``None``: it has none), for
            the photo prepared again at another pose (not judged, nor warned about, twice).
    """

    index: int
    camera: Camera
    pixels: np.ndarray | None
    face_id: np.ndarray | None
    depth: np.ndarray | None
    valid: np.ndarray | None
    rejected: dict
    depth_factor: float | None = None

    @property
    def image(self) -> np.ndarray | None:
        """``(H, W, 3) float32`` in [0, 1], ``None`` once :meth:`sampled`: made from :attr:`pixels` at each
        call (about 1 ms for 640x480), so hold it in a variable while it is used."""
        if self.pixels is None or self.pixels.dtype != np.uint8:
            return self.pixels
        return self.pixels.astype(np.float32) / np.float32(255.0)

    def sampled(self) -> PhotoView:
        """The view without its maps, once the texture has been sampled: what the report still asks (index,
        camera, rejections; a room's four hundred views of 640x480 held 1.5 GB of maps through the bake)."""
        return dataclasses.replace(self, pixels=None, face_id=None, depth=None, valid=None)


def working_camera(camera: Camera, max_side: int) -> Camera:
    """``camera`` for its photo box-filtered down so its longer side is at most ``max_side``."""
    factor = min(1.0, max_side / max(camera.width, camera.height))
    w, h = max(1, round(camera.width * factor)), max(1, round(camera.height * factor))
    return camera if (w, h) == (camera.width, camera.height) else resized_camera(camera, w, h)


def resize_depth(depth: np.ndarray, width: int, height: int) -> np.ndarray:
    """A depth map at ``width x height`` by nearest sampling at the same relative positions (a depth
    map must not be averaged across an object's edge); NaN stays NaN."""
    h, w = depth.shape
    ys = np.clip(((np.arange(height) + 0.5) * h / height).astype(int), 0, h - 1)
    xs = np.clip(((np.arange(width) + 0.5) * w / width).astype(int), 0, w - 1)
    return depth[ys[:, None], xs[None, :]]


def depth_factor(measured: np.ndarray, mesh_depth: np.ndarray, hit: np.ndarray, tolerance: float,
                 source=None) -> float:
    """The factor that brings ``measured`` (a photo's depth map at the working size, metres) to the mesh's
    scale, or 0: the map is not of this photo's view.

    Where at least half of the pixels both see agree within ``tolerance``, the map is right as it is (1; its
    disagreeing pixels are then rejected: an object moved after the scan). When most disagree and one factor
    brings at least 80 % of them within it, the map's unit is off (millimetres read as another unit, a
    tenth-millimetre sensor): that factor, with a warning. When no factor does, the map is not of this
    photo's view (a depth camera not registered to the colour camera, another frame's map): 0, with a
    warning, so that the photo is used without it rather than losing most of its pixels. ``hit``: the pixels
    that see the mesh cleanly."""
    both = hit & np.isfinite(measured) & (measured > 0)
    if both.sum() < 100:
        return 1.0
    m, d = measured[both], mesh_depth[both]
    if (np.abs(m - d) <= tolerance * d).mean() >= 0.5:
        return 1.0
    factor = float(np.median(d / m))
    if (np.abs(m * factor - d) <= tolerance * d).mean() < 0.8:
        log.warning("%s: the depth map disagrees with the mesh on %.0f %% of the pixels both see, in any unit: "
                    "not this photo's view (a depth camera not registered to the colour camera?); the photo is "
                    "used without it", source or "depth map", 100 * (np.abs(m - d) > tolerance * d).mean())
        return 0.0
    log.warning("%s: the depth map is %.4g times the mesh's depth where both see the surface; read in the mesh's "
                "scale", source or "depth map", 1 / factor)
    return factor


def prepare_photo(scan: Scan, photos: PhotoSet, i: int, caster: RayCaster, max_side: int,
                  settings: VisibilitySettings = VisibilitySettings()) -> PhotoView:
    """Photo ``i`` at the working resolution, ray cast and tested for visibility."""
    from scipy import ndimage

    from scantex.io.images import box_downscaled

    cam = working_camera(photos.cameras[i], max_side)
    W, H = cam.width, cam.height
    photo = photos.load_image(i)
    if (W, H) != photo.shape[1::-1]:
        photo = box_downscaled(photo, W, H)

    s = max(1, settings.supersample)
    centre, _, n_hit, all_hit, mean_depth, spread = _footprints(caster, cam, s)
    any_hit = n_hit > 0
    clean = all_hit & (spread < 0.02 * mean_depth)

    contours = contour_map(any_hit, np.where(any_hit, mean_depth, np.inf))
    if settings.edge_margin_px > 0:
        near_edge = ndimage.binary_dilation(contours | (any_hit & ~clean), iterations=settings.edge_margin_px)
    else:
        near_edge = contours
    near_edge &= any_hit

    n = np.take(scan.face_normals, np.where(centre >= 0, centre, 0).reshape(-1), axis=0)  # take: faster than [rows]
    cos = cam.ray_cosines(n)
    grazing = any_hit & (cos < np.cos(np.radians(settings.max_angle_deg)))

    hidden = photos.hidden[i]
    if hidden is not None:
        # another part of the scene in front (a tile's neighbours), with the edge margin a contour gets
        hidden = resize_depth(np.asarray(hidden, bool), W, H)
        hidden = any_hit & (ndimage.binary_dilation(hidden, iterations=settings.edge_margin_px)
                            if settings.edge_margin_px > 0 else hidden)
    else:
        hidden = np.zeros_like(any_hit)

    measured, factor = photos.load_depth(i), None
    if measured is not None:
        measured = resize_depth(measured, W, H)
        factor = photos.depth_factors[i]  # judged on a whole scan when this one is a part of it, or at another pose
        if factor is None:
            factor = depth_factor(measured, mean_depth, clean, settings.depth_tolerance, photos.depths[i])
        measured = None if factor == 0 else measured if factor == 1 else measured * np.float32(factor)
    if measured is not None:
        known = np.isfinite(measured)
        disagree = any_hit & known & (np.abs(measured - mean_depth) > settings.depth_tolerance * mean_depth)
        if settings.depth_gap_px > 1 and any_hit.any() and known[any_hit].mean() >= DENSE_DEPTH:
            disagree |= any_hit & depth_gaps(known, settings.depth_gap_px)
    else:
        disagree = np.zeros_like(any_hit)

    valid = clean & ~near_edge & ~grazing & ~disagree & ~hidden & (centre >= 0)
    rejected = {"edge": int((any_hit & near_edge).sum()), "grazing": int((grazing & ~near_edge).sum()),
                "depth_map": int((disagree & ~near_edge & ~grazing).sum()),
                "hidden": int((hidden & ~disagree & ~near_edge & ~grazing).sum())}
    if hidden.any():
        # no depth where another surface is in front: nothing of this scan is seen there, not even through it
        mean_depth = np.where(hidden, np.float32(0), mean_depth)
    return PhotoView(i, cam, np.ascontiguousarray(photo[..., :3], np.uint8), centre.astype(np.int32), mean_depth,
                     valid, rejected, factor)


def depth_gaps(known: np.ndarray, width: int) -> np.ndarray:
    """``(H, W) bool``: the pixels of a depth map's lines of missing depth narrower than ``width`` (what closing
    ``known`` with a ``width`` square fills; the image border counts as missing, so a band along it is no line),
    grown by :data:`GAP_MARGIN_PX`. The closing as a maximum then a minimum filter, separable: the same pixels as
    ``binary_closing`` with that square, in a fifth of its time (3 ms at 640x480)."""
    from scipy import ndimage

    grown = ndimage.maximum_filter(known.view(np.uint8), size=width, mode="constant", cval=0)
    gaps = ~known & ndimage.minimum_filter(grown, size=width, mode="constant", cval=0).view(bool)
    return ndimage.binary_dilation(gaps, iterations=GAP_MARGIN_PX) if GAP_MARGIN_PX > 0 and gaps.any() else gaps


def _footprints(caster: RayCaster, cam: Camera, s: int):
    """What an ``s x s`` supersampled ray cast of ``cam`` says of each pixel: ``(face_id (H, W) int32, bary
    (H, W, 2) float32)`` of its centre sub-sample (index ``s // 2`` on both axes), and :func:`pixel_footprints`'
    ``(hits, all_hit, mean_depth, spread)``.

    Only the centre sub-samples are cast everywhere; the others only where the centre samples of the 3x3
    pixels around change between hit and miss or in depth by over 1 %: elsewhere all ``s * s`` sub-samples
    lie on one smooth surface (they fall among those 9 centre samples), so they hit, spread less than 1 %
    in depth (the visibility test's limit is 2 %), and the mean depth is taken as the centre sample's (off
    by under 1 %). Walls and floors need a few per cent of the rays a full supersampled cast takes.
    """
    H, W = cam.height, cam.width
    fine, c = cam.scaled(s), s // 2
    ys, xs = np.divmod(np.arange(H * W), W)
    hits = caster.intersect(fine.center, fine.rays_through(xs * s + c, ys * s + c))
    face_id = hits.face_id.reshape(H, W)
    bary = hits.bary.reshape(H, W, 2)
    hit = face_id >= 0
    n_hit = np.where(hit, np.int32(s * s), np.int32(0))
    all_hit = hit.copy()
    mean_depth = np.where(hit, hits.t.reshape(H, W), np.float32(0))
    spread = np.where(hit, np.float32(0), np.float32(-np.inf))
    if s == 1:
        return face_id, bary, n_hit, all_hit, mean_depth, spread
    ask = np.flatnonzero(_changing(hit, mean_depth))
    if ask.size:
        # every sub-sample of those pixels, row by row: an (n * s, s) supersampled image of n pixels
        row, column = np.divmod(np.arange(s * s), s)
        Y = (ask // W * s)[:, None] + row
        X = (ask % W * s)[:, None] + column
        more = caster.intersect(fine.center, fine.rays_through(X.reshape(-1), Y.reshape(-1)))
        k = pixel_footprints(more.face_id.reshape(-1, s), more.t.reshape(-1, s), s)
        for out, value in zip((n_hit, all_hit, mean_depth, spread), k):
            out.reshape(-1)[ask] = value.reshape(-1)
    return face_id, bary, n_hit, all_hit, mean_depth, spread


def _changing(hit: np.ndarray, depth: np.ndarray) -> np.ndarray:
    """``(H, W) bool``: the pixels among whose 3x3 neighbours (the image's edge repeated) some hit ``hit (H, W)``
    and some miss, or which hit where their hitting neighbours' ``depth (H, W)`` spans over 1 % of their own;
    compiled (:mod:`scantex.jit`: one pass, where scipy's four 3x3 filters took 20 ms a VGA photo), or in numpy
    (:func:`_changing_numpy`, its twin) where numba is missing."""
    from scantex import jit

    kernel = jit.compiled(_changing_kernel)
    if kernel is None:
        return _changing_numpy(hit, depth)
    out = np.empty(hit.shape, bool)
    kernel(np.ascontiguousarray(hit), np.ascontiguousarray(depth, np.float32), out)
    return out


def _changing_numpy(hit: np.ndarray, depth: np.ndarray) -> np.ndarray:
    from scipy import ndimage

    near = ndimage.maximum_filter(np.where(hit, depth, -np.inf), 3)
    far = ndimage.minimum_filter(np.where(hit, depth, np.inf), 3)
    mixed = ndimage.maximum_filter(hit, 3) != ndimage.minimum_filter(hit, 3)
    with np.errstate(invalid="ignore"):
        return mixed | (hit & (near - far > 0.01 * depth))


def _changing_kernel(hit, depth, out):
    """:func:`_changing`'s kernel, pixel by pixel: ``out`` filled in."""
    H, W = hit.shape
    for y in range(H):
        for x in range(W):
            hits = misses = 0
            near, far = -np.inf, np.inf
            for v in range(max(y - 1, 0), min(y + 2, H)):
                for u in range(max(x - 1, 0), min(x + 2, W)):
                    if hit[v, u]:
                        hits += 1
                        near = max(near, depth[v, u])
                        far = min(far, depth[v, u])
                    else:
                        misses += 1
            out[y, x] = (hits > 0 and misses > 0) or (hit[y, x] and near - far > np.float32(0.01) * depth[y, x])


def halved(view: PhotoView) -> PhotoView:
    """``view`` at half its working resolution (for fits that need many pixels, not fine ones): the image
    box-filtered, a pixel usable where all four of its pixels are, face and depth those of its top-left pixel
    (half a working pixel off: below the poses' own error)."""
    H, W = view.face_id.shape
    h, w = H // 2, W // 2
    if h < 1 or w < 1:
        return view
    corners = [(slice(a, 2 * h, 2), slice(b, 2 * w, 2)) for a in (0, 1) for b in (0, 1)]
    full = view.image
    image = sum(full[c] for c in corners) * np.float32(0.25)  # elementwise: reductions over strided
    valid = np.logical_and.reduce([view.valid[c] for c in corners])  # axes are several times slower
    camera = resized_camera(crop_camera(view.camera, 2 * w, 2 * h), w, h)  # an odd last row or column dropped
    return PhotoView(view.index, camera, image, view.face_id[:2 * h:2, :2 * w:2], view.depth[:2 * h:2, :2 * w:2],
                     valid, view.rejected, view.depth_factor)


def crop_camera(camera: Camera, width: int, height: int) -> Camera:
    """``camera`` with its image cut to the top-left ``width x height`` pixels."""
    return Camera(camera.K, camera.world_to_camera, width, height)


def texture_seen(scan: Scan, view: PhotoView, caster: RayCaster) -> np.ndarray:
    """``(H, W, 3) float32``: ``scan``'s texture at the surface points ``view``'s pixels see (black where
    none): the scan rendered through the view's camera. Cast again rather than kept from the view's own ray
    cast: a view's barycentrics held 8 bytes a pixel, a room's 219 views 0.5 GB, for this one use."""
    from scantex.views.render import render

    return render(scan, view.camera, caster)[0]


def prepare_photos(scan: Scan, photos: PhotoSet, indices: Sequence[int], caster: RayCaster, max_side: int,
                   settings: VisibilitySettings = VisibilitySettings(),
                   update: Callable[[int, int], None] | None = None) -> list[PhotoView]:
    """:func:`prepare_photo` of each of ``indices``, in order, two photos at a time (Embree and numpy
    release the interpreter lock for most of the work; each photo holds its ray cast, about 50 bytes a
    working pixel, while it is prepared)."""
    indices = [int(i) for i in indices]
    views = []
    with ThreadPoolExecutor(PAIR_THREADS) as pool:
        for k, view in enumerate(pool.map(lambda i: prepare_photo(scan, photos, i, caster, max_side, settings),
                                          indices)):
            views.append(view)
            if update:
                update(k + 1, len(indices))
    return views


def split_photos(n: int, holdout: float, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """``(train, held_out)`` photo indices: ``ceil(holdout * n)`` photos spread evenly over the
    capture (neighbouring photos nearly repeat each other, so an even spread is the fair test), never
    all of them. ``holdout`` >= 1 is a count."""
    if n < 2 or holdout <= 0:
        return np.arange(n), np.arange(0)
    k = int(holdout) if holdout >= 1 else int(np.ceil(holdout * n))
    if k > n - 1:
        log.warning("holding out %d of the %d photos for the score, not %d: one at least makes the texture",
                    n - 1, n, k)
    k = min(max(k, 1), n - 1)
    offset = np.random.default_rng(seed).uniform(0, n / k)
    held = np.unique(np.floor(offset + np.arange(k) * n / k).astype(int) % n)
    train = np.setdiff1d(np.arange(n), held)
    return train, held


def photo_rays(views: Sequence[PhotoView], groups: Sequence[int]):
    """Training rays of photo views, each ray's appearance group its photo's ``groups[k]``."""
    from scantex.field.rays import RayDataset

    parts = []
    for view, group in zip(views, groups):
        _, directions = view.camera.pixel_rays()
        valid = view.valid.reshape(-1)
        m = int(valid.sum())
        parts.append(RayDataset(
            origins=np.broadcast_to(view.camera.center.astype(np.float32), (m, 3)).copy(),
            directions=directions[valid],
            depth=view.depth.reshape(-1)[valid],
            rgb=view.image.reshape(-1, 3)[valid],
            chart=np.full(m, group, np.int64),
        ))
    return RayDataset.concatenate(parts)


def taught_by_photos(views: Sequence[PhotoView], n_faces: int, min_rays: int = 4) -> np.ndarray:
    """``(F,) bool`` faces that at least ``min_rays`` valid photo pixels see."""
    counts = np.zeros(n_faces + 1, np.int64)
    for v in views:  # each photo's counts (the last bin its unusable pixels'): no copy of every photo's hits
        counts += np.bincount(np.where(v.valid, v.face_id, n_faces).reshape(-1), minlength=n_faces + 1)
    return counts[:n_faces] >= min_rays


def colour_match(render: np.ndarray, photo: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """``render`` with the per-channel gain and offset that best map it onto ``photo`` over ``mask``
    (least squares; a flat render gets the photo's mean)."""
    out = render.copy()
    for c in range(3):
        x, y = render[..., c][mask], photo[..., c][mask]
        if x.size < 2 or np.var(x) < 1e-10:
            out[..., c] = y.mean() if y.size else out[..., c]
            continue
        gain = np.cov(x, y, bias=True)[0, 1] / np.var(x)
        out[..., c] = gain * render[..., c] + (y.mean() - gain * x.mean())
    return np.clip(out, 0, 1)


#: the Gaussian (working pixels) under the Laplacian that measures a held-out render's fine detail
#: (:func:`score_photos`)
DETAIL_SIGMA = 1.0


def score_photos(scans: dict[str, Scan], views: Sequence[PhotoView], caster: RayCaster,
                 supersample: int = 2, images: dict | None = None, align: bool = False) -> dict:
    """PSNR / SSIM of each scan rendered through held-out photos' cameras, raw and colour-matched,
    over the pixels that pass the visibility test (averaged over photos); with ``detail``, the render's fine
    detail (mean |Laplacian of a Gaussian| of its grey there, :data:`DETAIL_SIGMA`) and ``photo_detail``, the
    photos' own.

    Args:
        images: if given, receives for each scored photo (by its index in the set) one
            ``(H, W * (1 + len(scans)), 3) float32`` image: the photo, then each scan's render through its
            camera, side by side (for people to look at); with ``align``, a second row below it: the photo
            again, then each scan's render through the camera aligned to it (``(2 H, ...)``).
        align: also score each scan after aligning the held-out photo's pose to *its* texture
            (:func:`scantex.photos.poses.align_camera`, a small rotation, translation and focal change, from the
            recorded pose and from each other scan's aligned pose, the one that agrees better with the photo kept):
            ``psnr_aligned`` / ``ssim_aligned``, colour-matched, and ``aligned_by_deg``, the turn from the recorded
            pose. A recorded pose that is a few pixels off penalises a sharp texture more than a blurred one;
            aligning each scan's view on its own (as pose-refining NeRFs are evaluated) scores the texture rather
            than the held-out pose.
    """
    from scipy import ndimage

    from scantex.metrics.image import psnr, ssim, ssim_maps
    from scantex.photos.poses import PoseSettings, align_camera, reprojection_error, rotation_between
    from scantex.views.render import render, render_scans, shade_hits

    def score(view: PhotoView) -> tuple[dict[str, dict[str, float]], np.ndarray | None] | None:
        """Each scan's scores through ``view``, and the side-by-side image when ``images`` asks for it
        (``None``: too few pixels)."""
        mask = view.valid
        if mask.sum() < 64:
            return None
        photo = view.image  # made from the view's 8-bit pixels at each read: once here
        row = [photo]
        renders = render_scans(scans, view.camera, caster, supersample=supersample)  # one ray cast for all
        matched = {name: colour_match(img, photo, mask) for name, (img, _) in renders.items()}
        # every render's SSIM against the photo, the photo's own filtering done once
        maps = iter(ssim_maps([image for name in scans for image in (renders[name][0], matched[name])], photo))
        inner = ndimage.binary_erosion(mask, iterations=4)  # the filter's reach off the mask's border

        def detail(image: np.ndarray) -> float:
            """Fine detail: mean |Laplacian of a Gaussian of 1 px| of the grey, over the pixels scored (the plain
            Laplacian counts a noisy photo's sensor noise as detail: the bolster's photos score 0.16 by it, 0.04 by
            this, its texture's renders 0.10 and 0.03)."""
            grey = image.mean(axis=2)
            return float(np.abs(ndimage.gaussian_laplace(grey, DETAIL_SIGMA))[inner].mean()) if inner.any() else 0.0

        photo_detail = detail(photo)
        out = {}
        aligned_row = [photo]
        settings = PoseSettings(max_side=max(view.camera.width, view.camera.height))

        def fit(scan: Scan, start: Camera) -> Camera:
            return align_camera(scan, start, photo, lambda f, b: shade_hits(scan, f, b), caster, settings,
                                index=view.index).camera

        fits = {name: fit(scan, view.camera) for name, scan in scans.items()} if align else {}
        for name, scan in scans.items():
            img, _ = renders[name]
            row.append(img)
            s = out[name] = {"psnr": psnr(img, photo, mask), "ssim": float(next(maps)[mask].mean()),
                             "psnr_matched": psnr(matched[name], photo, mask),
                             "ssim_matched": float(next(maps)[mask].mean()),
                             "detail": detail(img), "photo_detail": photo_detail}
            if align:
                # a sharp texture's photometric basin is narrow: aligned from the recorded pose, it can stop where
                # another texture's alignment went on (the real bolster's held-out photo 11, the result: 0.14 degrees
                # and 20.67 dB; from the input's aligned pose, 23.57). Each texture is also aligned from the other
                # textures' aligned poses, where they differ, and scored at the one that agrees best with the photo
                starts = [fits[name]] + [fit(scan, fits[other]) for other in scans if other != name
                                         and reprojection_error(scan, fits[other], fits[name], caster) > 0.5]
                best = None
                for camera in starts:
                    moved, alpha = render(scan, camera, caster, supersample=supersample)
                    covered = mask & (alpha > 0.999)
                    matched_moved = colour_match(moved, photo, covered)
                    score_here = psnr(matched_moved, photo, covered)
                    if best is None or score_here > best[0]:
                        best = (score_here, camera, moved, matched_moved, covered)
                score_here, camera, moved, matched_moved, covered = best
                aligned_row.append(moved)
                s.update(psnr_aligned=score_here, ssim_aligned=ssim(matched_moved, photo, covered),
                         aligned_by_deg=rotation_between(camera, view.camera))
        if images is None:
            return out, None
        rows = [row, aligned_row] if align else [row]
        return out, np.concatenate([np.concatenate(r, axis=1) for r in rows], axis=0)

    # the photos side by side: Embree, numpy and scipy's filtering release the interpreter lock
    with ThreadPoolExecutor(PAIR_THREADS) as pool:
        scored = list(pool.map(score, views))
    scores = {name: {"psnr": [], "ssim": [], "psnr_matched": [], "ssim_matched": []} for name in scans}
    for view, result in zip(views, scored):
        if result is None:
            continue
        values, row = result
        for name, s in values.items():
            for k, v in s.items():
                scores[name].setdefault(k, []).append(v)
        if images is not None:
            images[view.index] = row
    return {name: {k: float(np.mean(v)) for k, v in s.items() if v} | {"photos": len(s["psnr"])}
            for name, s in scores.items()}
