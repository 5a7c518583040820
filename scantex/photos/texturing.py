"""Projective texturing: every texel sampled directly from the photos that see it best.

A field fitted to the photos is limited by its capacity and by the working resolution it was trained
at; the photos themselves hold the detail. This colour source gives each surface point a smooth,
weighted blend of the training photos' pixels at the photos' **full resolution**:

- **visibility**: a photo may give a point its colour only where the point projects into its image,
  the photo's G-buffer at the working resolution (:class:`~scantex.photos.training.PhotoView`) says the
  pixel is usable (clean, not grazing, away from occluding contours, depth map agreeing) and sees the
  point itself (depth test against the G-buffer's depth: nothing nearer hides it);
- **quality** of a photo for a point: ``log cos(angle) + log(pixels per metre on the surface) +
  log(relative sharpness of the photo)``; the weights are a softmax of the quality over the photos
  with ``temperature`` (the best view dominates, but the weights are continuous: no per-face switch,
  no hard seam where the best view changes);
- **photo-consistency**: a sample far from what the other photos say of the same point (an occluder the
  mesh does not hold, a passer-by, a specular highlight, a misregistered edge) loses its weight: the blend
  is an iteratively reweighted mean with a Cauchy weight ``1 / (1 + (r / consistency)^2)`` on each
  sample's colour distance ``r`` from the current blend (the robust estimate of the colour, as classical
  texture mappers' photo-consistency checks reject outlier views; it needs three photos to outvote one);
- **feathering**: each photo's weight fades to zero over ``feather_px`` working pixels towards the
  edge of its usable region (image border, contours, rejected pixels), so a photo's coverage ends
  without a step;
- **appearance**: each photo's sample is brought to the canonical appearance by the inverse of the
  per-photo affine colour transform the field learned (``canonicalise``);
- **saturation**: a sample with a channel at the photo's white point (an over-exposed photo's clipped
  highlights) says only "at least this bright": brought to the canonical appearance, a clipped red under a
  photo's high gain turns a yellow wall blue. What the other photos' unclipped samples say of the point,
  taken back through this photo's transform (``recorded``), tells how far the photo would have gone past its
  white point; the clipped sample's weight falls from 1 at no overshoot to 1/1000 at ``overshoot``. The
  decision follows the consensus, not the sample's own value: a surface near white in every photo, clipped
  in some samples by noise, keeps its blend (where no photo sees a point unclipped, they blend as before);
- **culling**: given the mesh's faces, a photo is asked only about points on the faces its G-buffer sees
  (and their one-ring neighbours, for faces smaller than a working pixel), so a texel costs the photos that
  see it, not every photo of the capture (a room's hundred photos see a few per cent of it each);
- **detail** (``detail_temperature``, off by default): two bands. A blend of many photos whose registration
  differs by a few pixels (a room's video frames) is a blur; the photos' coarse band (a Gaussian blur) is blended
  at ``temperature`` and the fine band (photo less blur) at a low temperature, nearly the best view's: detail of
  one photo, colour of all (a two-band blend, as panorama stitchers blend). By linearity, three blends of a
  point's samples: the coarse band's at ``temperature``, then the photos' and their coarse band's at the detail
  temperature, whose difference is the blended fine band (the compiled blend samples both bands of a photo in one
  pass; the numpy path runs the three blends one after another), added at ``detail_gain`` of its contrast. In the
  fine band a photo whose coarse band disagrees with what most photos' coarse bands say (an occluder, a highlight)
  gives way (``detail_consistency``);
- **fill**: where no photo sees a point (the largest feather weight is below 1), the result fades
  smoothly into ``fallback`` (the field's canonical colour, harmonic fill in holes).

The photos' samples and their blend run compiled, point by point (:mod:`scantex.photos.compiled`, numba),
where numba is installed and the colour transforms are affine; the numpy path below, photo by photo, is its
twin (the same colours) and runs elsewhere.
"""

from __future__ import annotations

import contextlib
import dataclasses
import logging
import os
import threading
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from functools import partial
from typing import NamedTuple

import numpy as np

from scantex.photos.photoset import PhotoSet
from scantex.photos.training import PhotoView
from scantex.scan import Scan
from scantex.threads import side_by_side
from scantex.views.camera import Camera

log = logging.getLogger(__name__)

#: threads sampling the photos of one chunk of points
_WORKERS = min(8, os.cpu_count() or 1)

#: ``colour(points (n, 3), normals (n, 3), face_ids (n,), bary (n, 2)) -> (n, 3) float`` in [0, 1]
SurfaceColour = Callable[[np.ndarray, np.ndarray, np.ndarray, np.ndarray], np.ndarray]


@dataclass(frozen=True)
class ProjectiveSettings:
    """How texels are sampled from the photos."""

    temperature: float = 5.0
    """softmax temperature on the view quality (log units): lower picks the best view more sharply"""
    feather_px: float = 6.0
    """a photo's weight fades in over this many working pixels from the edge of its usable region"""
    clip_level: float = 0.99
    """a sample with a channel at or above this (as the photo recorded it, in [0, 1]) counts as clipped"""
    overshoot: float = 0.1
    """a clipped sample's weight is 1/1000 where the other photos say its photo would have recorded this
    much above its white point (in [0, 1] units; 0: clipped samples blend as any other)"""
    depth_tolerance: float = 0.02
    """relative depth difference beyond which a point counts as hidden in a photo"""
    max_side: int = 0
    """longest side the photos are sampled at (0: full resolution)"""
    texel_px_per_cm: float = 0.0
    """the output atlas's texel density on the surface: a photo that resolves the surface more than
    ``oversample`` times finer (its median over its usable pixels) is sampled box-filtered down to that, since
    finer pixels would only be averaged inside a texel, and a hundred 12-megapixel photos would not fit in
    memory at full size (0: every photo at full resolution)"""
    oversample: float = 2.0
    """photo pixels per texel kept at most, per axis (see ``texel_px_per_cm``)"""
    memory_mb: float = 0.0
    """the most the photos' samples may hold (packed pixels, and their coarse band with two bands), in MiB: when
    the sizes above would need more, every photo is sampled smaller by one factor, with a warning (0: no bound)"""
    consistency: float = 0.0
    """photo-consistency scale (RGB distance in [0, 1] units): a sample this far from the blend of the
    others keeps half its weight, one twice as far a fifth (0: a plain weighted mean)"""
    consistency_rounds: int = 3
    """reweighting rounds of the robust blend"""
    detail_temperature: float = 0.0
    """two bands (0: one): the photos' coarse band (each photo blurred by a Gaussian of ``detail_sigma`` working
    pixels) blended at ``temperature``, their fine band (the photo less its blur) at this lower temperature, so
    the detail comes from the best views while colour and exposure still average over every photo"""
    detail_gain: float = 1.0
    """two bands: the fine band's share of its contrast kept (1: the best views' detail as it is; 0.5: at half its
    contrast, a single clean copy of each edge where a blend of photos a few pixels apart leaves several faint ones)"""
    detail_sigma: float = 4.0
    """the Gaussian (in working pixels, scaled to each photo's sampling resolution) that splits the bands"""
    detail_consistency: float = 0.05
    """two bands: a photo's weight in the fine band's blend is multiplied by ``exp(-(d / detail_consistency)^2)``,
    ``d`` the RGB distance of its coarse band from what most photos' coarse bands say there (0: not), so the detail
    does not come from a photo that saw an occluder or a highlight there"""
    soft_photos: tuple[int, ...] = ()
    """photos (indices into the photo set) whose fine band gives way to the other photos' (shaken or out of focus,
    :mod:`scantex.photos.sharpness`): their weight in the fine band's blend is multiplied by :data:`SOFT_FINE_WEIGHT`,
    so they give a point its colour and coverage with the others and its detail only where no sharp photo sees it.
    With one band (``detail_temperature`` 0) they make two at the blend's own temperature: the same blend but for
    their fine band"""


#: a soft photo's factor on its weight in the fine band's blend (``ProjectiveSettings.soft_photos``): small enough
#: that any sharp photo seeing the point gives its detail, not 0, so that where only soft photos see it their fine
#: band still blends as before (normalised away) and the weights stay continuous at a sharp photo's feathered edge
SOFT_FINE_WEIGHT = 1e-3


#: a connected part of the mesh holding less than this share of its faces is a loose fragment (see
#: :func:`loose_fragments`)
LOOSE_SHARE = 0.01


@dataclass(frozen=True, eq=False)
class _Source:
    camera: Camera  # at the sampling resolution
    pixels: np.ndarray  # (H * W,) uint32: the RGB image at the sampling resolution, a pixel in one word
    to_view: np.ndarray  # (3, 3): a pixel of ``camera`` to the same point's pixel at the working resolution
    # of the working view only what sampling asks (its pixels and faces are not kept)
    centre: np.ndarray  # (3,) the camera's centre
    # (h, w) float32: each pixel's depth at the working resolution, signed: a usable pixel's, negated where the
    # pixel hits the mesh but is not usable, 0 where it sees none of it (one array, not the view's depth and mask)
    depth: np.ndarray
    feather: np.ndarray  # (h, w) float32 in [0, 1] at the working resolution
    log_sharpness: float
    group: int
    faces: np.ndarray | None  # (F,) bool: faces whose points this photo may see (None: not culled)
    # the pose in float32, about the capture's origin (see ``projective_colour``): a camera-frame point is
    # ``(X - origin) @ rotation_t + translation``; its pixel ``(x_cam @ intrinsics_t)`` over its z, and that
    # pixel at the working resolution ``pixel @ to_view_t + to_view[:2, 2]``. The matrices are transposed
    # into contiguous arrays: numpy multiplies by a transposed view several times slower
    rotation_t: np.ndarray
    translation: np.ndarray
    intrinsics_t: np.ndarray
    to_view_t: np.ndarray
    fine_weight: float = 1.0  # the factor on its weight in the fine band's blend (``SOFT_FINE_WEIGHT``: a soft photo)


def photo_sharpness(image: np.ndarray) -> float:
    """Variance of the Laplacian of ``image (H, W, 3) float`` (a standard focus measure)."""
    from scipy import ndimage

    gray = image[..., :3].mean(axis=2)
    return float(ndimage.laplace(gray).var())


def within_memory(cameras: list[Camera], bytes_per_pixel: int, memory_mb: float) -> list[Camera]:
    """``cameras`` (each photo's at the size it would be sampled at), all made smaller by one factor when their
    pixels, at ``bytes_per_pixel``, would hold more than ``memory_mb`` MiB (0: no bound): a capture of many
    large photos (600 phone frames of 1920x1440 on a fine atlas: 6.6 GB) then fits, a little softer, with a
    warning. A side is kept at 64 pixels at least."""
    wanted = sum(cam.width * cam.height for cam in cameras) * bytes_per_pixel
    if memory_mb <= 0 or wanted <= memory_mb * 2**20:
        return cameras
    from scantex.photos.training import working_camera

    factor = float(np.sqrt(memory_mb * 2**20 / wanted))
    smaller = [working_camera(cam, max(64, int(max(cam.width, cam.height) * factor))) for cam in cameras]
    held = sum(c.width * c.height for c in smaller) * bytes_per_pixel

    def mib(n: float) -> str:
        return f"{n / 2**20:.0f}" if n >= 100 * 2**20 else f"{n / 2**20:.3g}"

    log.warning("the %d photos' samples would hold %s MiB at the resolution the atlas wants: sampled at %.0f %% of "
                "it a side, %s MiB (photos.sample_memory_mb %g; raise it where memory allows)", len(cameras),
                mib(wanted), 100 * factor, mib(held), memory_mb)
    return smaller


def projective_colour(photos: PhotoSet, views: Sequence[PhotoView], groups: Sequence[int],
                      canonicalise: Callable[[np.ndarray, np.ndarray], np.ndarray] | None,
                      fallback: SurfaceColour, settings: ProjectiveSettings = ProjectiveSettings(),
                      faces: np.ndarray | None = None,
                      recorded: Callable[[np.ndarray, np.ndarray], np.ndarray] | None = None,
                      threads: int | None = None, through: np.ndarray | None = None,
                      transforms: np.ndarray | None = None, release: bool = False) -> tuple[SurfaceColour, dict]:
    """A colour source for :func:`scantex.atlas.bake.bake` that samples the photos themselves.

    Args:
        photos: the posed photos (full-resolution images and cameras).
        views: the training photos' working-resolution G-buffers (their ``index`` into ``photos``).
        groups: each view's appearance group (for ``canonicalise``).
        canonicalise: ``(rgb (n, 3), group (n,)) -> (n, 3)``: a photo's colours brought to the canonical
            appearance; ``None`` leaves them as they are.
        fallback: the colour where no photo sees a point.
        faces: the mesh's ``(F, 3)`` vertex indices (welded: a position repeated at a UV seam under one
            index): culls each photo to the faces its G-buffer sees and their one-ring. ``None`` asks every
            photo about every point: slower, and the same colours but where a point on a face that a
            photo neither sees nor borders passes its depth test (a sliver behind a seen surface).
        recorded: ``canonicalise``'s inverse (canonical colours as photo ``group`` recorded them): clipped
            samples give way where the other photos say their photo overshot its white point. ``None``:
            the identity when ``canonicalise`` is ``None``, else clipped samples blend as any other.
        threads: threads sampling the photos of one call side by side (``None``: one a core, up to 8).
            ``colour`` may be called from several threads at once: a caller that colours chunks in parallel
            (``bake``'s ``workers``) passes 1 here (both at once oversubscribe the cores).
        through: ``(F,) bool`` faces few photos see cleanly (:func:`loose_fragments`: a fused scan's loose
            fragments, all contour to every photo, or floating where the depth maps see nothing). Where no
            photo's usable pixel gives them a colour, they take the mean of the photos' pixels they project to
            where no surface of the mesh is in front of them: what the photos show there is what lies behind
            a fragment the scene does not have, as a held-out photo will show it. ``None``: the fallback.
        transforms: the ``(G, 4, 3)`` affine transforms (:func:`fit_photo_transforms`'s) that ``canonicalise``
            undoes and ``recorded`` applies, when they are such: the compiled blend
            (:mod:`scantex.photos.compiled`) then applies them itself. It runs where numba is installed and
            ``canonicalise`` is ``None`` or given with its ``transforms``; elsewhere the same blend runs in numpy.
        release: ``views`` (a list) has each view replaced by its :meth:`~scantex.photos.training.PhotoView.sampled`
            copy once its photo is sampled, so that a caller holding the views nowhere else lets their maps go
            while the samples are made (a room's four hundred views of 640x480: 1.5 GB, held beside as much of
            samples, depth and feather maps, were the run's peak).

    Returns:
        ``(colour, report)``: the colour function and a small dict for the metrics. ``colour`` also takes
        ``without=k``: the same blend without view ``k`` (a leave-one-out consensus for pose refinement),
        and ``coverage=True``: it then returns ``(rgb, share)``, ``share (n,)`` the photos' part of each
        point's colour (1: the photos alone, 0: the fallback alone).
    """
    from scipy import ndimage

    from scantex import heap
    from scantex.io.images import box_downscaled

    incidence = _incidence(faces) if faces is not None else None
    # points are projected in float32 (half the memory traffic of float64), about the cameras' mean centre
    # so that a georeferenced scene's large coordinates keep their precision
    origin = (np.mean([photos.cameras[v.index].center for v in views], axis=0) if len(views)
              else np.zeros(3))

    def sampling_camera(view: PhotoView) -> Camera:
        """The photo's camera at the resolution it is sampled at."""
        cam = photos.cameras[view.index]
        side = max(cam.width, cam.height)
        if settings.max_side:
            side = min(side, settings.max_side)
        if settings.texel_px_per_cm > 0 and view.valid.any():
            px_per_cm = float(np.median(cam.K[0, 0] / view.depth[view.valid])) / 100.0
            side = min(side, max(64, round(max(cam.width, cam.height) * settings.oversample
                                           * settings.texel_px_per_cm / px_per_cm)))
        if side < max(cam.width, cam.height):
            from scantex.photos.training import working_camera

            cam = working_camera(cam, side)
        return cam

    soft = set(settings.soft_photos) & {view.index for view in views}
    if soft and settings.detail_temperature <= 0:
        # one band with soft photos: two at the blend's own temperature (the blend's colours but for their detail)
        settings = dataclasses.replace(settings, detail_temperature=settings.temperature, detail_gain=1.0,
                                       detail_consistency=0.0)
    # every photo's packed image and feather weights end to end, each photo's a view of its part (the compiled
    # blend reads them so, the numpy path photo by photo)
    bands = settings.detail_temperature > 0
    cameras = within_memory([sampling_camera(view) for view in views], 8 if bands else 4, settings.memory_mb)
    pixel_sizes, view_sizes = [cam.width * cam.height for cam in cameras], [view.valid.size for view in views]
    pixel_start, view_start = _starts(pixel_sizes), _starts(view_sizes)
    pixels, feathers = np.empty(sum(pixel_sizes), np.uint32), np.empty(sum(view_sizes), np.float32)
    depths = np.empty(sum(view_sizes), np.float32)  # the views' signed depth (see ``_Source.depth``), end to end
    coarse = np.empty_like(pixels) if bands else pixels  # the photos' coarse band, packed as they are

    def source(k: int) -> _Source:
        """Training photo ``k``, ready to sample: its image at the sampling resolution, packed, its feather
        weights, sharpness and pose, and the faces it may see."""
        view, cam = views[k], cameras[k]
        image = photos.load_image(view.index)
        if image.shape[:2] != (cam.height, cam.width):
            image = box_downscaled(image, cam.width, cam.height)
        packed = _packed(image, pixels[pixel_start[k]:pixel_start[k] + pixel_sizes[k]])
        if bands:
            _packed(_blurred(image, settings.detail_sigma * cam.K[0, 0] / view.camera.K[0, 0]),
                    coarse[pixel_start[k]:pixel_start[k] + pixel_sizes[k]])
        inside = np.pad(view.valid, 1)  # the image border ends the usable region too
        distance = ndimage.distance_transform_edt(inside)[1:-1, 1:-1]
        feather = feathers[view_start[k]:view_start[k] + view_sizes[k]].reshape(view.valid.shape)
        np.clip(distance / max(settings.feather_px, 1e-6), 0, 1, out=feather, casting="same_kind")
        depth = depths[view_start[k]:view_start[k] + view_sizes[k]].reshape(view.valid.shape)
        np.copyto(depth, view.depth)
        np.negative(depth, out=depth, where=~view.valid)
        sharpness = float(np.log(photo_sharpness(view.image) + 1e-8))
        fine_weight = SOFT_FINE_WEIGHT if view.index in soft else 1.0
        if not np.allclose(cam.world_to_camera, view.camera.world_to_camera):
            raise ValueError(f"photo {view.index}: its working view was made at another pose")
        to_view = view.camera.K @ np.linalg.inv(cam.K)
        seen = None
        if incidence is not None:
            seen = np.zeros(len(faces), np.float32)
            seen[view.face_id[view.valid & (view.face_id >= 0) & (view.face_id < len(faces))]] = 1
            seen = (incidence @ (incidence.T @ seen)) > 0  # the faces seen, and those sharing a vertex with one
        to_view, centre = to_view.astype(np.float32), view.camera.center
        if release:  # the view's maps go (and the memory they held, back to the system)
            views[k] = view.sampled()
            del view
            heap.trim()
        return _Source(cam, packed, to_view, centre, depth, feather, sharpness, int(groups[k]), seen,
                       np.ascontiguousarray(cam.R.T, np.float32), (cam.R @ origin + cam.t).astype(np.float32),
                       np.ascontiguousarray(cam.K.T, np.float32), np.ascontiguousarray(to_view[:2, :2].T),
                       fine_weight)

    # the photos read and prepared side by side (decoding and numpy release the interpreter lock)
    with ThreadPoolExecutor(max(1, min(_WORKERS, len(views)))) as pool:
        sources = list(pool.map(source, range(len(views))))
    if sources:
        mean_sharp = float(np.median([s.log_sharpness for s in sources]))
        sources = [_replace_sharpness(s, s.log_sharpness - mean_sharp) for s in sources]
    report = {"photos": len(sources), "sampled_at": [[s.camera.width, s.camera.height] for s in sources],
              "temperature": settings.temperature,
              **detail_report(settings),
              **({"soft_photos": sorted(soft)} if soft else {}),
              "photo_memory_mb": round((pixels.nbytes + (coarse.nbytes if bands else 0)) / 2**20, 1),
              # filled in as the bake samples (the dict is shared by the report's copies)
              "clipped": {"samples": 0, "clipped": 0, "gave_way": 0}}

    to_recorded = recorded if recorded is not None or canonicalise is not None else (lambda rgb, group: rgb)
    from scantex.photos import compiled

    tables = None
    if sources and (canonicalise is None or transforms is not None):
        if compiled.available():
            tables = _tables(sources, origin, transforms, len(faces) if faces is not None else None,
                             pixels, pixel_start, feathers, depths, view_start, coarse if bands else None)
    report["compiled"] = tables is not None
    # the same photos with their coarse band in place of the image (the sources' other arrays shared)
    coarse_sources = ([dataclasses.replace(s, pixels=coarse[start:start + s.pixels.size])
                       for s, start in zip(sources, pixel_start)] if bands else sources)

    tallying = threading.Lock()  # the report's counts, from calls in several threads
    threads = _WORKERS if threads is None else threads

    def compiled_blend(local: np.ndarray, unit: np.ndarray, face_ids: np.ndarray, without: int | None
                       ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The blend, compiled (both bands in one pass): ``(colour (n, 3), total weight (n,), largest feather
        (n,))``; the points in ``threads`` parts side by side (the kernel releases the interpreter lock)."""
        def part(span: slice):
            return compiled.blend(tables, local[span], unit[span], face_ids[span],
                                  depth_tolerance=settings.depth_tolerance, temperature=settings.temperature,
                                  detail_temperature=settings.detail_temperature, detail_gain=settings.detail_gain,
                                  detail_consistency=settings.detail_consistency,
                                  clip_level=settings.clip_level, overshoot=settings.overshoot,
                                  consistency=settings.consistency, rounds=settings.consistency_rounds,
                                  without=without, censors=settings.overshoot > 0 and to_recorded is not None)

        n = len(local)
        parts = max(1, min(threads, n // 4096))
        bounds = np.linspace(0, n, parts + 1).astype(int)
        spans = [slice(a, b) for a, b in zip(bounds[:-1], bounds[1:])]
        if parts > 1:  # a plain pool, not side_by_side: this runs per chunk on the bake's threads, where
            # limiting BLAS (process-wide) from two threads at once could leave it limited
            with ThreadPoolExecutor(parts) as pool:
                results = list(pool.map(part, spans))
        else:
            results = [part(spans[0])]
        out, total, alpha = (np.concatenate([r[k] for r in results]) for k in range(3))
        tally = sum(r[3] for r in results)
        with tallying:
            counts = report["clipped"]
            counts["samples"] += int(tally[0])
            counts["clipped"] += int(tally[1])
            counts["gave_way"] += int(tally[2])
        return out, total, alpha

    def colour(points, normals, face_ids, bary, without: int | None = None, coverage: bool = False):
        n = len(points)
        if not sources or n == 0:
            rgb = np.asarray(fallback(points, normals, face_ids, bary), np.float32)
            return (rgb, np.zeros(n, np.float32)) if coverage else rgb
        local = (points - origin).astype(np.float32)

        def project(s: _Source, at: np.ndarray):
            """Points ``at`` (about the origin) in the photo's camera frame, at its sampling resolution's pixels
            and at its working resolution's."""
            cam = at @ s.rotation_t + s.translation
            with np.errstate(divide="ignore", invalid="ignore"):
                full = cam @ s.intrinsics_t
                full = full[:, :2] / full[:, 2:]  # a point in the camera's plane (z = 0) is not finite
                pix = full @ s.to_view_t + s.to_view[:2, 2]  # the same projection at the working size
            return cam, full, pix

        def each_photo(job, among=sources):
            asked = [s for k, s in enumerate(among) if k != without]
            if len(asked) > 1 and threads > 1:
                with ThreadPoolExecutor(min(threads, len(asked))) as pool:
                    return [x for x in pool.map(job, asked) if x is not None]
            return [x for x in map(job, asked) if x is not None]

        def numpy_blend(among: list[_Source], temperature: float, tally_it: bool,
                        gates: list[np.ndarray] | None = None, fine_band: bool = False
                        ) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[_Samples]]:
            """The blend of the photos ``among`` at ``temperature`` in numpy, photo by photo: ``(colour (n, 3),
            total weight (n,), largest feather (n,), the samples)``; ``tally_it``: count its samples in the report;
            ``gates``: a factor on each photo's weights (for the photos that see some point, in order);
            ``fine_band``: the fine band's blend (each photo's weights times its ``fine_weight``)."""
            # first pass: each photo's samples of the points it sees, their quality and feather weight, the
            # photos side by side on the cores (numpy releases the interpreter lock in the array work)
            unit = normals.astype(np.float32)
            facing = np.einsum("ij,ij->i", unit, local)  # n . (X - origin): the view angle needs n . (X - C)

            def sample(s: _Source):
                sub = np.flatnonzero(s.faces[face_ids]) if s.faces is not None else None  # the faces it sees
                if sub is not None and sub.size == 0:
                    return None
                # np.take: numpy's fancy indexing of rows is several times slower
                cam, full, pix = project(s, local if sub is None else np.take(local, sub, axis=0))
                z = cam[:, 2]
                idx, xi, yi = _seen_in(None, s.depth, pix, z, settings.depth_tolerance)
                if idx.size == 0:
                    return None
                seen = np.take(cam, idx, axis=0)
                distance = np.sqrt(np.einsum("ij,ij->i", seen, seen))  # |X - C|
                z, full = z[idx], np.take(full, idx, axis=0)
                if sub is not None:
                    idx = sub[idx]
                centre = (s.centre - origin).astype(np.float32)
                cos = np.abs(facing[idx] - np.take(unit, idx, axis=0) @ centre) / distance
                quality = np.log(np.maximum(cos, np.float32(1e-3))) + np.log(np.float32(s.camera.K[0, 0]) / z) \
                    + np.float32(s.log_sharpness)
                rgb = _bilinear(s.pixels, s.camera.width, s.camera.height, full)
                # the channels' maximum column by column: numpy's max over a row of three is 20x slower
                clipped = np.maximum(np.maximum(rgb[:, 0], rgb[:, 1]), rgb[:, 2]) >= np.float32(settings.clip_level)
                if canonicalise is not None:
                    recorded_rgb = rgb
                    rgb = canonicalise(rgb, np.full(len(idx), s.group))
                    if clipped.any():
                        _level_clipped_channels(rgb, recorded_rgb, clipped, settings.clip_level)
                return _Samples(idx, quality, s.feather[yi, xi], rgb, clipped, s.group, s.fine_weight)

            seen_by: list[_Samples] = each_photo(sample, among)
            best = np.full(n, -np.inf, np.float32)
            for x in seen_by:
                best[x.idx] = np.maximum(best[x.idx], x.quality)  # a photo sees a point once: idx has no repeats
            # second pass: the softmax of the quality (relative to each point's best view), feathered
            alpha = np.zeros(n, np.float32)
            weights = []
            for k, x in enumerate(seen_by):
                weights.append(np.exp((x.quality - best[x.idx]) / temperature) * x.feather
                               * (gates[k] if gates is not None else np.float32(1))
                               * np.float32(x.fine if fine_band else 1))
                alpha[x.idx] = np.maximum(alpha[x.idx], x.feather)
            gave_way = 0
            if settings.overshoot > 0 and to_recorded is not None and any(x.clipped.any() for x in seen_by):
                out, total, weights, gave_way = _censored_mean(n, seen_by, weights, to_recorded, settings.overshoot)
            else:
                out, total = _weighted_mean(n, seen_by, weights)
            with tallying if tally_it else contextlib.nullcontext():
                tally = report["clipped"] if tally_it else {"samples": 0, "clipped": 0, "gave_way": 0}
                tally["samples"] += sum(len(x.idx) for x in seen_by)
                tally["clipped"] += sum(int(x.clipped.sum()) for x in seen_by)
                tally["gave_way"] += gave_way
            if settings.consistency > 0:
                # photo-consistency: each round reweights every sample by its distance from the last blend
                scale = np.float32(1.0 / settings.consistency ** 2)
                for _ in range(settings.consistency_rounds):
                    robust = [w / (1 + scale * np.square(x.rgb - out[x.idx]).sum(axis=1))
                              for x, w in zip(seen_by, weights)]
                    out, _ = _weighted_mean(n, seen_by, robust)
            return out, total, alpha, seen_by

        if tables is not None:
            out, total, alpha = compiled_blend(points - origin, normals, face_ids, without)
        else:
            out, total, alpha, coarse_seen = numpy_blend(coarse_sources, settings.temperature, tally_it=True)
            if bands:  # the fine band at the detail temperature: the photos' blend less their coarse band's
                td, gates = settings.detail_temperature, None
                if settings.detail_consistency > 0:  # from photos whose coarse band agrees with most photos'
                    gates = _detail_gates(n, coarse_seen, out, settings.temperature, settings.detail_consistency)
                fine = (numpy_blend(sources, td, False, gates, fine_band=True)[0]
                        - numpy_blend(coarse_sources, td, False, gates, fine_band=True)[0])
                out = out + np.float32(settings.detail_gain) * fine
        # the loose fragments' points no usable pixel coloured: the photos seen through them
        loose = np.flatnonzero(through[face_ids] & (total <= 0)) if through is not None else np.zeros(0, np.intp)
        if loose.size:
            def sample_through(s: _Source):
                """The photo's pixels at the loose points no usable pixel coloured that it has in view, no
                surface of the mesh in front of them."""
                cam, full, pix = project(s, local[loose])
                idx = _seen_through(s.depth, pix, cam[:, 2], settings.depth_tolerance)
                if idx.size == 0:
                    return None
                rgb = _bilinear(s.pixels, s.camera.width, s.camera.height, full[idx])
                if canonicalise is not None:
                    rgb = canonicalise(rgb, np.full(idx.size, s.group))
                ones = np.ones(idx.size, np.float32)
                return _Samples(loose[idx], ones, ones, rgb, np.zeros(idx.size, bool), s.group)

            seen_through = each_photo(sample_through)
            alike = [np.ones(len(x.idx), np.float32) for x in seen_through]
            behind, support = _weighted_mean(n, seen_through, alike)
            take = np.flatnonzero(support > 0)
            out[take], total[take], alpha[take] = behind[take], support[take], 1
        # the fallback only where the photos do not fully cover a point
        part = np.flatnonzero((total <= 0) | (alpha < 1))
        share = np.ones(n, np.float32)  # the photos' share of each point's colour
        if part.size:
            base = np.asarray(fallback(points[part], normals[part], face_ids[part], bary[part]), np.float32)
            a = np.where(total[part] > 0, np.clip(alpha[part], 0, 1), 0)[:, None]
            out[part] = a * out[part] + (1 - a) * base
            share[part] = a[:, 0]
        return (np.clip(out, 0, 1), share) if coverage else np.clip(out, 0, 1)

    return colour, report


#: a face whose photos and fallback differ on average by more than this (any channel, 0-1) differs in content
#: (a misregistered edge, a highlight, an object the other does not have), not in exposure: it sets no offset
MAX_FALLBACK_STEP = 0.15


def fallback_offsets(scan: Scan, colour, fallback, *, chunk: int = 65536,
                     max_step: float | None = MAX_FALLBACK_STEP) -> tuple[np.ndarray, dict]:
    """Offsets ``(V, 3)`` per vertex that bring ``fallback`` to the colours of the photos where they meet.

    Where no photo sees the surface, photo mode shows its fallback (the input's texels, holes filled): a
    texture of another exposure than the photos' blend next to it, brought to it only on average (the colour
    transforms are global), so a step in tone where the photos end (a real apartment's unseen upper walls were
    greyer than the photographed walls below them). As seam levelling does between charts, the step is removed
    by a smooth additive field: at each vertex of a face the photos cover entirely (``colour``'s ``coverage``
    share 1 at its sample points), the mean of ``photos - fallback`` over such faces; elsewhere the harmonic
    interpolation of those over the mesh (a part with no covered face: 0). Faces whose difference exceeds
    ``max_step`` set nothing (``None``: every covered face counts, and a part of the mesh with no covered face
    takes the offset of the nearest covered point in space; a flat fallback then becomes the photos' colours
    carried over what they do not see).

    ``colour``: :func:`projective_colour`'s function (its fallback ``fallback``, unlevelled). Returns the offsets
    and a small report."""
    from scantex.atlas.colour import FACE_SAMPLES
    from scantex.atlas.inpaint import harmonic_vertex_colours
    from scantex.views.raycast import interpolate

    F, V, S = scan.n_faces, scan.n_vertices, len(FACE_SAMPLES)
    normals, triangles = scan.face_normals, scan.triangles
    difference = np.zeros((F, 3), np.float32)
    covered = np.zeros(F, bool)
    per = max(1, chunk // S)
    for start in range(0, F, per):
        faces = np.arange(start, min(F, start + per))
        f = np.repeat(faces, S)
        bary = np.tile(FACE_SAMPLES, (len(faces), 1))
        points = interpolate(f, bary, triangles)
        rgb, share = colour(points, normals[f], f, bary, coverage=True)
        base = np.asarray(fallback(points, normals[f], f, bary), np.float32)
        difference[faces] = (rgb - base).reshape(-1, S, 3).mean(axis=1)
        covered[faces] = (share.reshape(-1, S) >= 1).all(axis=1)
    usable = covered if max_step is None else covered & (np.abs(difference) <= max_step).all(axis=1)
    sums, counts = np.zeros((V, 3)), np.zeros(V)
    for k in range(3):
        np.add.at(sums, scan.faces[usable, k], difference[usable])
        np.add.at(counts, scan.faces[usable, k], 1.0)
    known = counts > 0
    offsets = np.zeros((V, 3))
    offsets[known] = sums[known] / counts[known, None]
    if known.any() and not known.all():
        offsets = harmonic_vertex_colours(scan, known, offsets, unanchored=np.zeros(3), nearest=max_step is None)
    reach = ~covered
    size = np.abs(offsets[np.unique(scan.faces[reach])]) if reach.any() else np.zeros((0, 3))
    return offsets.astype(np.float32), {
        "faces_covered": int(covered.sum()), "faces_measured": int(usable.sum()),
        "offset_mean": round(float(size.mean()) if size.size else 0.0, 4),
        "offset_max": round(float(size.max()) if size.size else 0.0, 4)}


def _incidence(faces: np.ndarray):
    """``(F, V)`` sparse face-vertex incidence of ``faces (F, 3)``."""
    from scipy import sparse

    F = len(faces)
    return sparse.csr_matrix((np.ones(3 * F, np.float32), (np.repeat(np.arange(F), 3), faces.reshape(-1))),
                             shape=(F, int(faces.max()) + 1 if F else 0))


def loose_fragments(faces: np.ndarray, max_share: float = LOOSE_SHARE) -> np.ndarray | None:
    """``(F,) bool`` the faces of the mesh's connected parts (``faces``: welded vertex indices) that hold less
    than ``max_share`` of its faces; ``None`` when there are none. A fused scan's loose fragments (a TSDF's
    floaters, a centimetre off a cabinet or in mid-air) are all contour to every photo, and the depth maps
    see nothing where they float: few of their points pass any photo's usability test."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    if not faces.size:
        return None
    n_vertices = int(faces.max()) + 1
    i = np.concatenate([faces[:, 0], faces[:, 1]])
    j = np.concatenate([faces[:, 1], faces[:, 2]])
    graph = coo_matrix((np.ones(i.size, np.int8), (i, j)), shape=(n_vertices, n_vertices))
    _, label = connected_components(graph, directed=False)
    part = label[faces[:, 0]]
    loose = np.bincount(part)[part] < max_share * len(faces)
    return loose if loose.any() else None


def _seen_in(valid: np.ndarray | None, depth: np.ndarray, pix: np.ndarray, z: np.ndarray, depth_tolerance: float
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(idx, x, y)``: the points (of working-resolution pixels ``pix (n, 2)`` and camera depths ``z (n,)``)
    that a view sees (``valid`` and ``depth``: its usable pixels and their depth), a usable pixel whose depth
    agrees within ``depth_tolerance`` (relative), and their nearest pixel. ``valid`` ``None``: ``depth`` is a
    source's signed depth (:attr:`_Source.depth`), whose unusable pixels' depth is not positive."""
    idx, xi, yi, there = _nearest_depth(depth, pix, z)
    z = z[idx]
    seen = np.abs(there - z) < depth_tolerance * z
    if valid is not None:
        seen &= np.take(valid.reshape(-1), yi * depth.shape[1] + xi)
    return idx[seen], xi[seen], yi[seen]


def _seen_through(depth: np.ndarray, pix: np.ndarray, z: np.ndarray, depth_tolerance: float) -> np.ndarray:
    """The points (as :func:`_seen_in`'s) with no surface in front of them closer than ``depth_tolerance``
    (relative) in a source's signed depth ``depth`` (any pixel that hits the mesh, usable or not)."""
    idx, _, _, there = _nearest_depth(depth, pix, z)
    return idx[np.abs(there) > (1 - depth_tolerance) * z[idx]]


def _nearest_depth(depth: np.ndarray, pix: np.ndarray, z: np.ndarray
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``(idx, x, y, depth)``: the points of ``pix (n, 2)`` in front of the camera (``z (n,)``) and inside the
    ``(h, w)`` map ``depth``, their nearest pixel and its depth."""
    h, w = depth.shape
    rounded = np.round(pix)
    x, y = rounded[:, 0], rounded[:, 1]
    # a NaN or infinite pixel fails these comparisons: it is not seen
    idx = np.flatnonzero((z > 0) & (x >= 0) & (x < w) & (y >= 0) & (y < h))
    xi, yi = x[idx].astype(np.intp), y[idx].astype(np.intp)
    return idx, xi, yi, np.take(depth.reshape(-1), yi * w + xi)


def _level_clipped_channels(rgb: np.ndarray, recorded: np.ndarray, clipped: np.ndarray, clip_level: float) -> None:
    """Gives the channels a sample recorded at its photo's white point the brightest of their canonical values,
    in place. ``rgb (m, 3)`` canonical, ``recorded (m, 3)`` as the photo recorded them, ``clipped (m,)`` the
    samples with a channel at the white point.

    Each such channel says only "at least this bright", and the photo's per-channel gains turn the same white
    point into different canonical levels: a white highlight that every photo clipped came out tinted (lilac
    under a photo whose blue gain was the lowest). Raising the clipped channels to the highest of their lower
    bounds keeps every bound and invents no hue: three clipped channels give a neutral white."""
    at = np.flatnonzero(clipped)
    hit = recorded[at] >= np.float32(clip_level)  # [m', 3] which channels are at the white point
    canonical = rgb[at]
    top = np.where(hit, canonical, -np.inf).max(axis=1, keepdims=True)
    rgb[at] = np.where(hit, np.maximum(canonical, top), canonical)


class _Samples(NamedTuple):
    """One photo's samples of the points it sees."""

    idx: np.ndarray
    """``(m,)`` the points"""
    quality: np.ndarray
    """``(m,)`` the photo's view quality for each"""
    feather: np.ndarray
    """``(m,)`` its feather weight there"""
    rgb: np.ndarray
    """``(m, 3)`` its colours, canonical"""
    clipped: np.ndarray
    """``(m,)`` bool: a channel at the photo's white point"""
    group: int
    """the photo's appearance group"""
    fine: float = 1.0
    """the factor on its weights in the fine band's blend (:attr:`_Source.fine_weight`)"""


def _censored_mean(n: int, seen_by: list[_Samples], weights: list[np.ndarray],
                   recorded: Callable[[np.ndarray, np.ndarray], np.ndarray], overshoot: float
                   ) -> tuple[np.ndarray, np.ndarray, list[np.ndarray], int]:
    """:func:`_weighted_mean` with each clipped sample's weight scaled by how far its photo overshot its white
    point there, as the blend of the other photos' unclipped samples says (taken back through ``recorded``):
    1 at no overshoot, 1/1000 at ``overshoot`` and beyond; 1 where no photo sees the point unclipped.

    Returns:
        ``(blend (n, 3), total weight (n,), the scaled weights (one array per photo), gave_way)``: how many
        samples kept less than half their weight. The unclipped samples' sums are made once and serve both
        the consensus and the blend; the clipped samples (few) are added to them with their scaled weights.
    """
    idx = np.concatenate([x.idx for x in seen_by])
    rgb = np.concatenate([x.rgb for x in seen_by])
    weight = np.concatenate(weights)
    clipped = np.flatnonzero(np.concatenate([x.clipped for x in seen_by]))
    kept = weight.copy()
    kept[clipped] = 0
    support, sums = _sums(n, idx, rgb, kept)
    unclipped = sums / np.maximum(support, 1e-12)[:, None]
    before = weight[clipped]
    start = np.cumsum([0] + [len(x.idx) for x in seen_by])
    for x, s0 in zip(seen_by, start):
        at = np.flatnonzero(x.clipped)
        if at.size:
            point = x.idx[at]
            predicted = recorded(unclipped[point].astype(np.float32), np.full(at.size, x.group)).max(axis=1)
            scale = np.clip(1 - (predicted - 1) / np.float32(overshoot), 1e-3, 1)
            weight[s0 + at] *= np.where(support[point] > 0, scale, 1).astype(np.float32)
    w = weight[clipped]
    gave_way = int((w < 0.5 * before).sum())
    total, blend = _sums(n, idx[clipped], rgb[clipped], w)
    total, blend = total + support, blend + sums
    return ((blend / np.maximum(total, 1e-12)[:, None]).astype(np.float32), total.astype(np.float32),
            np.split(weight, start[1:-1]), gave_way)


def detail_report(settings: ProjectiveSettings) -> dict:
    """The two bands' settings as the metrics give them (``{}`` with one band)."""
    if settings.detail_temperature <= 0:
        return {}
    return {"detail": {"temperature": settings.detail_temperature, "sigma_px": settings.detail_sigma,
                       "gain": settings.detail_gain}}


def _detail_gates(n: int, coarse: list[_Samples], blend: np.ndarray, temperature: float, scale: float
                  ) -> list[np.ndarray]:
    """Two bands: each photo's factor on its weight in the fine band's blend, ``exp(-(d / scale)^2)``, ``d`` its
    coarse band's RGB distance from what most photos' coarse bands say of the point (robust Cauchy rounds from the
    coarse ``blend``): the detail does not come from a photo that saw an occluder or a highlight there."""
    from scantex.photos.compiled import DETAIL_ROUNDS

    best = np.full(n, -np.inf, np.float32)
    for x in coarse:
        best[x.idx] = np.maximum(best[x.idx], x.quality)
    base = [x.feather * np.exp((x.quality - best[x.idx]) / temperature) for x in coarse]
    inv = np.float32(1.0 / scale ** 2)
    reference = blend
    for _ in range(DETAIL_ROUNDS):
        robust = [w / (1 + inv * np.square(x.rgb - reference[x.idx]).sum(axis=1)) for x, w in zip(coarse, base)]
        moved, support = _weighted_mean(n, coarse, robust)
        reference = np.where((support > 0)[:, None], moved, reference)
    return [np.exp(-inv * np.square(x.rgb - reference[x.idx]).sum(axis=1)) for x in coarse]


def _weighted_mean(n: int, seen_by: list[_Samples], weights: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """``(blend (n, 3), total weight (n,))`` of the photos' samples ``seen_by`` with ``weights`` (one array
    per photo)."""
    if not seen_by:
        return np.zeros((n, 3), np.float32), np.zeros(n, np.float32)
    total, blend = _sums(n, np.concatenate([x.idx for x in seen_by]), np.concatenate([x.rgb for x in seen_by]),
                         np.concatenate(weights))
    return (blend / np.maximum(total, 1e-12)[:, None]).astype(np.float32), total.astype(np.float32)


def _sums(n: int, idx: np.ndarray, rgb: np.ndarray, weight: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(total weight (n,), weighted colour sum (n, 3))``, float64, of samples ``rgb (m, 3)`` of points
    ``idx (m,)``: one bincount pass over the samples (a scatter-add per photo takes twice the time)."""
    weighted = rgb * weight[:, None]
    return (np.bincount(idx, weight, n),
            np.stack([np.bincount(idx, weighted[:, c], n) for c in range(3)], axis=1))


def _replace_sharpness(s: _Source, value: float) -> _Source:
    return dataclasses.replace(s, log_sharpness=value)


def _tables(sources: list[_Source], origin: np.ndarray, transforms: np.ndarray | None, n_faces: int | None,
            pixels: np.ndarray, pixel_start: np.ndarray, feathers: np.ndarray, depths: np.ndarray,
            view_start: np.ndarray, coarse: np.ndarray | None = None):
    """The sources as :mod:`scantex.photos.compiled` reads them (a :class:`~scantex.photos.compiled.PhotoTables`):
    their arrays end to end, their poses stacked in float64 about ``origin``; ``transforms`` ``None``: the
    photos' colours as they are (one identity transform); ``n_faces`` ``None``: no culling. ``pixels``,
    ``feathers`` and ``depths``: the sources' packed images, feather weights and signed depths end to end (each
    source's a view of its part), each photo's part starting at ``pixel_start`` and ``view_start``; ``coarse``:
    the images' coarse bands, packed as ``pixels`` (two bands), or ``None``. The faces each photo may see are
    held once (``sources`` is changed in place: theirs become views)."""
    from scantex.photos.compiled import PhotoTables

    def stacked(values) -> np.ndarray:
        return np.ascontiguousarray(np.stack(values), np.float64)

    canonical = transforms is not None
    if not canonical:
        transforms = np.concatenate([np.eye(3), np.zeros((1, 3))])[None]
        groups = np.zeros(len(sources), np.int64)
    else:
        groups = np.array([s.group for s in sources], np.int64)
    transforms = np.asarray(transforms, np.float64)
    seen_faces = np.zeros((0, len(sources)), bool)
    if n_faces is not None and all(s.faces is not None for s in sources):
        seen_faces = np.ascontiguousarray(np.stack([s.faces for s in sources], axis=1))
        for k in range(len(sources)):  # held once too
            sources[k] = dataclasses.replace(sources[k], faces=seen_faces[:, k])
    return PhotoTables(
        seen_faces=seen_faces,
        rotation_t=stacked([s.rotation_t for s in sources]), translation=stacked([s.translation for s in sources]),
        intrinsics_t=stacked([s.intrinsics_t for s in sources]),
        to_view=stacked([s.to_view[:2] for s in sources]),
        centre=stacked([s.centre - origin for s in sources]),
        focal=np.array([s.camera.K[0, 0] for s in sources], np.float64),
        log_sharpness=np.array([s.log_sharpness for s in sources], np.float64),
        fine_weight=np.array([s.fine_weight for s in sources], np.float64), group=groups,
        pixel_start=pixel_start, widths=np.array([s.camera.width for s in sources], np.int64),
        heights=np.array([s.camera.height for s in sources], np.int64), pixels=pixels,
        coarse=coarse if coarse is not None else np.empty(0, np.uint32),
        view_start=view_start, view_widths=np.array([s.depth.shape[1] for s in sources], np.int64),
        view_heights=np.array([s.depth.shape[0] for s in sources], np.int64), depth=depths,
        feather=feathers, inverse=np.ascontiguousarray(np.linalg.inv(transforms[:, :3])),
        offset=np.ascontiguousarray(transforms[:, 3]), gain=np.ascontiguousarray(transforms[:, :3]),
        canonical=canonical)


def _blurred(image: np.ndarray, sigma: float) -> np.ndarray:
    """``image (H, W, 3) uint8`` blurred by a Gaussian of ``sigma`` pixels, channel by channel, as uint8."""
    from scipy import ndimage

    out = np.empty_like(image)
    channel = np.empty(image.shape[:2], np.float32)
    for c in range(3):
        channel[:] = image[..., c]  # filtered in place, contiguous: 10 % faster than from the strided bytes
        ndimage.gaussian_filter(channel, sigma, output=channel, mode="nearest")
        np.rint(channel, out=channel)
        out[..., c] = channel  # in [0, 255]: a Gaussian does not leave its input's range
    return out


def _packed(image: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
    """``(H * W,) uint32``: an ``(H, W, 3) uint8`` image with each pixel's bytes in one word (a sample
    then gathers one word per corner instead of a row of three bytes: about twice as fast), written into
    ``out`` when given: red in the low byte, the high byte 0 (in memory, on a little-endian machine: R, G, B, 0,
    as :func:`_bilinear` reads them).

    Built as whole-image shifts and ors of each channel: a byte copy into every fourth byte runs numpy's
    strided loop three bytes at a time (19 ms for a 1920x1080 photo, 50 ms with the bake's other thread
    busy; this way 6 ms)."""
    H, W = image.shape[:2]
    words = np.empty(H * W, np.uint32) if out is None else out
    grid = words.reshape(H, W)
    np.left_shift(image[..., 2], 16, out=grid, dtype=np.uint32)
    grid |= np.left_shift(image[..., 1], 8, dtype=np.uint32)
    grid |= image[..., 0]
    return words


def _starts(sizes) -> np.ndarray:
    """``(n,) int64``: where each of parts of ``sizes`` starts when they are laid end to end."""
    return np.concatenate([[0], np.cumsum(sizes, dtype=np.int64)[:-1]]).astype(np.int64)


def _bilinear(pixels: np.ndarray, W: int, H: int, pix: np.ndarray) -> np.ndarray:
    """``(n, 3) float32`` in [0, 1]: bilinear samples, at pixel centres ``pix (n, 2)``, of the ``H x W``
    image ``pixels`` packed by :func:`_packed`."""
    x = np.clip(pix[:, 0], 0, W - 1.001)
    y = np.clip(pix[:, 1], 0, H - 1.001)
    x0, y0 = x.astype(np.intp), y.astype(np.intp)  # floor: both are >= 0
    fx = (x - x0).astype(np.float32)[:, None]
    fy = (y - y0).astype(np.float32)[:, None]
    i = y0 * W + x0

    def corner(k: np.ndarray) -> np.ndarray:
        # all four bytes converted (contiguous), the unused fourth dropped at the end
        return pixels[k].view(np.uint8).reshape(-1, 4).astype(np.float32)

    a, b, c, d = corner(i), corner(i + 1), corner(i + W), corner(i + W + 1)
    # in place, the same sums as top = a + fx (b - a), bottom = c + fx (d - c), top + fy (bottom - top)
    b -= a
    b *= fx
    b += a
    d -= c
    d *= fx
    d += c
    d -= b
    d *= fy
    d += b
    return d[:, :3] * np.float32(1 / 255)


def fit_photo_transforms(reference: Sequence[np.ndarray] | Callable[[int], np.ndarray] | None,
                         views: Sequence[PhotoView],
                         charts: np.ndarray | None = None, chart_area: np.ndarray | None = None,
                         blur_px: float = 1.0, min_pixels: int = 50, pair_weight: float = 0.0) -> np.ndarray:
    """Each photo's colour transform onto the reference texture's appearance, in closed form.

    ``reference[k]`` is the reference colour (the input texture rendered through view ``k``'s camera,
    ``(H, W, 3)`` float), or ``reference(k)`` makes it when it is asked (once a photo: a room's hundreds of
    references are then not all held at once). A capture app's atlas is itself a patchwork of exposures, one
    per chart, so a photo is not fitted to the texture as it is: per channel, the model is ``photo = g_photo x`` and
    ``texture = g_chart x`` for the true colour ``x`` (exposure and white balance are gains), and
    ``log g_photo - log g_chart`` is measured as the median log ratio of every (photo, chart) pair's
    pixels (robust to the poses' few pixels of error), then solved for all gains at once by least
    squares with the charts' area-weighted mean log gain held at 0: the photos are brought to the input
    texture's average appearance, not to whichever chart they happen to see most.

    A capture app's atlas need not be one exposure per chart either (a best-view blend switches photos
    inside a chart), and then the (photo, chart) pairs disagree. Photos that see the same surface say
    directly how their exposures differ: with ``pair_weight`` > 0, every pair of photos adds the median
    log ratio of their colours at the surface points both see (each photo's pixels unprojected with its
    G-buffer depth and looked up in the other, depth-tested), weighted ``pair_weight`` times as much as a
    (photo, chart) pair of the same size. The photos are then brought to one another's exposure and,
    together, to the texture's average.

    Without a reference (``None``: an untextured scan), the photo pairs alone decide, with the photos' mean
    log gain held at 0: every photo is brought to the photos' average appearance.

    Args:
        charts: ``(F,)`` chart of each face (default: one chart).
        chart_area: ``(C,)`` weights of the gauge (default: equal).
        pair_weight: weight of the photo-to-photo ratios (0: the photos are tied to the texture only; taken
            as 1 without a reference).

    Returns:
        ``(P, 4, 3)``: rows 0-2 are ``A`` (diagonal), row 3 is ``b`` (0): ``photo = canonical @ A + b``.
    """
    from scipy import ndimage, sparse
    from scipy.sparse.linalg import lsqr

    P = len(views)
    charts = np.zeros(max((int(v.face_id.max()) + 1 for v in views), default=1), np.int64) if charts is None else charts
    C = int(charts.max()) + 1 if reference is not None else 0
    area = np.ones(C) if chart_area is None else np.asarray(chart_area, np.float64)

    def blur(image: np.ndarray) -> np.ndarray:
        return np.stack([ndimage.gaussian_filter(image[..., c], blur_px) for c in range(3)], -1)

    def chart_rows(k: int) -> list[tuple[int, int, np.ndarray, float]]:
        """Photo ``k``'s (photo, chart, median log ratio (3,), weight) rows."""
        view, ref = views[k], reference(k) if callable(reference) else reference[k]
        mask = view.valid & (view.face_id >= 0)
        if mask.sum() < min_pixels:
            return []
        x = blur(ref)[mask]
        y = blurred[k][mask]
        chart = charts[view.face_id[mask]]
        ok = ((x > 0.03) & (x < 0.97) & (y > 0.03) & (y < 0.97)).all(axis=1)  # neither dark nor clipped
        ratio, chart = np.log(y[ok]) - np.log(x[ok]), chart[ok]
        order = np.argsort(chart, kind="stable")
        ratio, chart = ratio[order], chart[order]
        bounds = np.flatnonzero(np.diff(chart)) + 1
        return [(k, int(c), np.median(part, axis=0), float(np.sqrt(len(part))))
                for part, c in zip(np.split(ratio, bounds), chart[np.r_[0, bounds]] if chart.size else [])
                if len(part) >= min_pixels]

    # the photos side by side (numpy and scipy's filters release the interpreter lock)
    blurred = list(side_by_side(lambda view: blur(view.image), views))
    rows = [row for photo in side_by_side(chart_rows, range(P if reference is not None else 0)) for row in photo]
    out = np.tile(np.vstack([np.eye(3), np.zeros((1, 3))]), (P, 1, 1))
    if reference is None:
        pair_weight = pair_weight or 1.0
    elif not rows:
        return out
    pairs = (_photo_pairs(views, blurred, min_pixels, partial(_median_ratio, min_pixels=min_pixels))
             if pair_weight > 0 else [])
    if not rows and not pairs:
        return out
    n, m = len(rows), len(pairs)
    r = np.arange(n)
    k_idx = np.array([row[0] for row in rows], int)
    c_idx = np.array([row[1] for row in rows], int)
    w = np.array([row[3] for row in rows], float)
    # photo-to-photo rows: log g_l - log g_k = median log(photo_l / photo_k) at the points both see
    pw = pair_weight * np.array([pair[3] for pair in pairs], float)
    pk, pl = np.array([pair[0] for pair in pairs], int), np.array([pair[1] for pair in pairs], int)
    q = n + np.arange(m)
    # unknowns: log g_photo (P), then log g_chart (C); gauge row: the charts' area-weighted mean gain 0 (without
    # a reference, the photos' mean gain); a weak ridge keeps charts (and photos) that nothing ties down at gain 1
    gauge = (area / area.sum(), P + np.arange(C)) if C else (np.full(P, 1.0 / P), np.arange(P))
    A = sparse.vstack([
        sparse.csr_matrix((np.r_[w, -w, pw, -pw], (np.r_[r, r, q, q], np.r_[k_idx, P + c_idx, pl, pk])),
                          shape=(n + m, P + C)),
        sparse.csr_matrix((100.0 * (w.sum() if n else pw.sum()) * gauge[0], (np.zeros(len(gauge[1]), int), gauge[1])),
                          shape=(1, P + C)),
        1e-3 * sparse.identity(P + C, format="csr")]).tocsr()
    # a photo that no row ties down (it sees too little, or only what is dark or clipped) takes the others'
    # median gain, not gain 1: the photos of a capture share most of their exposure, and a gain of 1 among
    # photos 1.46 times brighter than the reference painted a bright band where that photo was the best view
    # (a real apartment cut into tiles, a photo with 900 usable pixels near a lamp in one of them)
    tied = np.zeros(P, bool)
    tied[np.r_[k_idx, pk, pl].astype(int)] = True
    for ch in range(3):
        rhs = np.r_[w * np.array([row[2][ch] for row in rows]).reshape(n),
                    pw * np.array([pair[2][ch] for pair in pairs]).reshape(m), 0.0, np.zeros(P + C)]
        solution = lsqr(A, rhs, atol=1e-10, btol=1e-10)[0][:P]
        solution[~tied] = np.median(solution[tied])
        out[:, ch, ch] = np.exp(np.clip(solution, -2.5, 2.5))
    return out


def _photo_pairs(views: Sequence[PhotoView], blurred: Sequence[np.ndarray], min_pixels: int,
                 reduce: Callable[[np.ndarray, np.ndarray], tuple | None] | None = None,
                 usable: Sequence[np.ndarray] | None = None, neighbours: int = 0, per_photo: int = 4000,
                 depth_tolerance: float = 0.02, seed: int = 0) -> list[tuple]:
    """``(k, l, value, weight)`` for every ordered pair of photos that see at least ``min_pixels`` of the same
    surface points: up to ``per_photo`` of photo ``k``'s usable pixels, unprojected with their G-buffer depth,
    looked up in photo ``l`` where it sees the same point (usable pixel, depth within ``depth_tolerance``);
    ``blurred``: each photo's working image, blurred (robust to the poses' few pixels of error). ``reduce(a, b)``
    makes a pair's ``(value, weight)`` (or ``None``: no row) of the two photos' colours ``(n, 3)`` at those points
    (default: ``median log(photo_l / photo_k) (3,)`` over the points neither dark nor clipped in either, weight
    ``sqrt(points)``); ``usable``: per photo, ``(h, w) bool`` the pixels a pair may use besides the views' own
    (default: all); ``neighbours``: photo ``k`` is paired with the photos that see the most faces it sees, this many
    (0: every photo it shares a face with). Pairs whose faces do not overlap are not projected."""
    reduce = reduce or _median_ratio
    rng = np.random.default_rng(seed)
    P = len(views)
    shared = photo_overlaps(views)
    # each photo's sample of its pixels, drawn in photo order (the same draws however the photos are spread)
    picked = []
    for k, v in enumerate(views):
        ys, xs = np.nonzero(v.valid if usable is None else v.valid & usable[k])
        if len(ys) >= min_pixels:
            pick = rng.choice(len(ys), min(per_photo, len(ys)), replace=False)
            ys, xs = ys[pick], xs[pick]
        picked.append((ys, xs))

    def pairs_of(k: int) -> list[tuple]:
        """The pairs (k, l) of photo ``k``."""
        v, (ys, xs) = views[k], picked[k]
        if len(ys) < min_pixels:
            return []
        points = view_points(v, xs, ys)
        own = blurred[k][ys, xs]
        partners = [l for l in np.argsort(-shared[k], kind="stable") if l != k and shared[k, l] >= 1]
        out = []
        for l in sorted(partners[:neighbours] if neighbours else partners):
            u = views[l]
            ok, x, y = _seen_in(u.valid, u.depth, *u.camera.project(points), depth_tolerance)
            if usable is not None:
                keep = usable[l][y, x]
                ok, x, y = ok[keep], x[keep], y[keep]
            if len(ok) >= min_pixels and (row := reduce(own[ok], blurred[l][y, x])) is not None:
                out.append((k, l, *row))
        return out

    # the photos side by side (numpy releases the interpreter lock)
    return [pair for photo in side_by_side(pairs_of, range(P)) for pair in photo]


def view_points(view: PhotoView, xs: np.ndarray, ys: np.ndarray) -> np.ndarray:
    """``(n, 3)`` world points of the view's pixels ``(xs, ys)``, unprojected at their G-buffer depth."""
    K = view.camera.K
    rays = np.stack([(xs - K[0, 2]) / K[0, 0], (ys - K[1, 2]) / K[1, 1], np.ones(len(xs))], axis=1)
    return (rays * view.depth[ys, xs, None] - view.camera.t) @ view.camera.R  # camera -> world


def photo_overlaps(views: Sequence[PhotoView]) -> np.ndarray:
    """``(P, P)``: how many faces each two views both see with a usable pixel."""
    from scipy import sparse

    P = len(views)
    n_faces = max((int(v.face_id.max()) + 1 for v in views), default=0)

    def faces_seen(v: PhotoView) -> np.ndarray:
        marked = np.zeros(n_faces, bool)  # a mark per face, not a sort of every pixel's (np.unique): 4x faster
        marked[v.face_id[v.valid & (v.face_id >= 0)]] = True
        return np.flatnonzero(marked)

    seen = list(side_by_side(faces_seen, views))
    sees = sparse.csr_matrix((np.ones(sum(f.size for f in seen), np.float32),
                              (np.repeat(np.arange(P), [f.size for f in seen]), np.concatenate(seen or [[]]))),
                             shape=(P, n_faces))
    return (sees @ sees.T).toarray()


def _median_ratio(a: np.ndarray, b: np.ndarray, min_pixels: int = 50) -> tuple[np.ndarray, float] | None:
    """``(median log(b / a) (3,), sqrt(points))`` over the points ``(n, 3)`` neither dark nor clipped in either."""
    good = ((a > 0.03) & (a < 0.97) & (b > 0.03) & (b < 0.97)).all(axis=1)
    if good.sum() < min_pixels:
        return None
    return np.median(np.log(b[good]) - np.log(a[good]), axis=0), float(np.sqrt(good.sum()))


def inverse_transforms(transforms: np.ndarray) -> Callable[[np.ndarray, np.ndarray], np.ndarray]:
    """``canonicalise(rgb (n, 3), group (n,))`` for :func:`projective_colour`: a photo's colours brought
    back to the reference appearance by the inverse of its transform from :func:`fit_photo_transforms`."""
    inverse = np.linalg.inv(transforms[:, :3]).astype(np.float32)  # (P, 3, 3)
    offset = transforms[:, 3].astype(np.float32)

    def canonicalise(rgb: np.ndarray, group: np.ndarray) -> np.ndarray:
        if group.size and (group == group[0]).all():  # one photo's samples (projective_colour's calls)
            return ((rgb - offset[group[0]]) @ inverse[group[0]]).astype(np.float32)
        return np.einsum("ni,nij->nj", rgb - offset[group], inverse[group]).astype(np.float32)

    return canonicalise


def recorded_transforms(transforms: np.ndarray) -> Callable[[np.ndarray, np.ndarray], np.ndarray]:
    """``recorded(rgb (n, 3), group (n,))`` for :func:`projective_colour`: canonical colours as photo ``group``
    recorded them (the transforms of :func:`fit_photo_transforms` themselves; ``inverse_transforms``'s
    inverse)."""
    gain = transforms[:, :3].astype(np.float32)
    offset = transforms[:, 3].astype(np.float32)

    def recorded(rgb: np.ndarray, group: np.ndarray) -> np.ndarray:
        if group.size and (group == group[0]).all():  # one photo's samples (projective_colour's calls)
            return (rgb @ gain[group[0]] + offset[group[0]]).astype(np.float32)
        return (np.einsum("ni,nij->nj", rgb, gain[group]) + offset[group]).astype(np.float32)

    return recorded
