"""Does each photo show what its camera sees? Checked against the scan's own texture, or the other photos.

A photo stored upside down, cropped after capture, or another frame's image under this frame's camera passes
every check of its file and its camera (the size agrees, the intrinsics are plausible), and the texture then
blends it in as a ghost of the scene turned or shifted: on the bolster, one photo of 12 turned by 180 degrees
changed 92,000 of its atlas's texels by more than 20 levels, and the held-out score did not show it. A textured
scan was most likely made from these very photos, so its texture seen through each camera is what the photo
shows, up to exposure (fitted away: a correlation) and a pose a few pixels off (both images blurred by more).

Each photo's agreement is the correlation of a band of the photo's grey detail (:data:`MATCH_BLUR` to
:data:`MATCH_BAND`: not the finest, which a pose a few pixels off moves, nor the coarsest, which exposure and
lighting decide) with the same band of the texture rendered through its camera, at a small working size, over the
pixels where the mesh covers the view (not its contours, not the texture's black holes). A photo is left out,
with a warning, when it agrees hardly at all (under :data:`MISMATCH`) where the others agree (their median at
least :data:`OTHERS_AGREE`), or when turned by 180 degrees it agrees far better than as stored. A view with too
little detail in it (a blank wall, a photo blurred by motion) gets no verdict. Where the texture is not the
photos' (a texture painted by hand, a capture's photos of a scene since changed) no photo agrees and none is
left out. An untextured scan has no texture: each photo is compared with the other photos instead, their band
(each brought to zero mean and unit spread: exposure) at the surface points the photo sees and they see too,
averaged over up to :data:`CONSENSUS_PHOTOS` of those that share the most of its surface.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from scantex.errors import ScanError
from scantex.photos.photoset import PhotoSet
from scantex.scan import Scan
from scantex.views.camera import Camera
from scantex.views.raycast import RayCaster

log = logging.getLogger(__name__)

#: the check's working size (the longer side, pixels): it compares the scene's layout, not its detail
MATCH_SIDE = 320
#: the band of detail compared (sigmas of two Gaussian blurs, working pixels): finer than the first, and a pose a
#: few full-resolution pixels off no longer agrees; coarser than the second, and a capture app's atlas of patches
#: at different exposures, a photo's vignetting and the lighting's gradients decide the correlation, not the
#: scene (a synthetic room's app-style atlas: its photos agreed 0.28-0.52 wherever they saw bare walls, -0.22 one)
MATCH_BLUR, MATCH_BAND = 2.0, 8.0
#: fewest pixels the mesh covers in a view, and the least detail (standard deviation of the band, in [0, 1] grey)
#: of the texture there and of the photo, for a verdict on it: where the texture holds little detail (a blank wall,
#: an app's atlas smoothed where it saw the surface obliquely), a photo agrees by noise alone (the texture's band,
#: measured: the bolster's views 0.07-0.08, the façade's 0.06-0.08, a synthetic room's 0.011-0.067, median 0.031,
#: where a photo of a smoothed ceiling agreed 0.03). The photo's own bar is lower: a real room's washed-out Kinect
#: photos (the G2LTex apartment's) hold 0.02-0.04 and agree 0.37 or more, and at 0.04 another photo's image given
#: for a frame went unjudged; under 0.02 a photo is blank or blurred through
MIN_PIXELS, MIN_CONTRAST, MIN_PHOTO_CONTRAST = 2000, 0.04, 0.02
#: a photo agreeing less than MISMATCH, where the other photos' median agrees at least OTHERS_AGREE, does not show
#: what its camera sees (measured at the recorded poses: the bolster's 14 photos agree 0.90-0.97, the façade's 10
#: 0.77-0.86, a synthetic wall's 24 (noise, blur, exposure, 1-5 px pose errors) 0.35-0.98; a photo cropped to 3/4
#: of its width 0.03, one turned by 180 degrees -0.15)
MISMATCH, OTHERS_AGREE = 0.15, 0.4
#: a photo that, turned by 180 degrees, agrees at least FLIPPED_AGREES and FLIPPED_MARGIN more than as stored is
#: upside down (turned, the photos above agree less than as stored, a room's at most as well; the one upside down
#: 1.11 more)
FLIPPED_AGREES, FLIPPED_MARGIN = 0.3, 0.3


#: an untextured scan's photo is compared with the mean of at most this many other photos (those sharing most of
#: its surface): enough that one photo's fault does not decide another's verdict, and a room's hundred photos
#: cost a few pairs each
CONSENSUS_PHOTOS = 8
#: a point another photo sees: its depth there within this share of the point's depth
DEPTH_AGREES = 0.02


@dataclass(frozen=True)
class PhotoMatch:
    """How well photo ``photo`` agrees with the scan's texture seen through its camera (or, for an untextured
    scan, with the other photos' consensus)."""

    photo: int
    pixels: int
    """pixels of the working-size view the comparison used"""
    agreement: float | None
    """correlation of the photo's band of detail with the texture's (the consensus'), in [-1, 1]; ``None``: no
    verdict (under :data:`MIN_PIXELS`, :data:`MIN_CONTRAST` or :data:`MIN_PHOTO_CONTRAST`)"""
    turned: float | None
    """the same with the photo turned by 180 degrees; ``None`` without a verdict, and where the photo agrees too
    well as stored to be named upside down (:func:`could_be_turned`)"""

    def to_dict(self) -> dict:
        return {"photo": self.photo, "pixels": self.pixels,
                "agreement": None if self.agreement is None else round(self.agreement, 3),
                "turned_180": None if self.turned is None else round(self.turned, 3)}


def photo_match(scan: Scan, photos: PhotoSet, i: int, caster: RayCaster) -> PhotoMatch:
    """Photo ``i``'s agreement with ``scan``'s texture seen through its camera (see the module docstring)."""
    from scipy import ndimage

    from scantex.photos.training import working_camera
    from scantex.views.render import render

    camera = working_camera(photos.cameras[i], MATCH_SIDE)
    texture, alpha = render(scan, camera, caster)
    covered = (alpha >= 0.999) & (texture.max(axis=-1) > 0.02)  # the surface, not the texture's black holes
    # away from its contours too (where a pose a little off sees the background)
    usable = ndimage.binary_erosion(covered, iterations=2)
    pixels = int(usable.sum())
    norms = _band_norms(covered)
    reference = _band(_luma(texture), covered, norms)[usable]
    if pixels < MIN_PIXELS or reference.std() < MIN_CONTRAST:
        return PhotoMatch(i, pixels, None, None)
    luma = _photo_luma(photos, i, camera)
    band = _band(luma, covered, norms)[usable]
    if band.std() < MIN_PHOTO_CONTRAST:
        return PhotoMatch(i, pixels, None, None)
    agreement = _correlation(band, reference)
    if not could_be_turned(agreement):
        return PhotoMatch(i, pixels, agreement, None)
    turned = _band(luma[::-1, ::-1], covered, norms)[usable]
    return PhotoMatch(i, pixels, agreement, _correlation(turned, reference))


def could_be_turned(agreement: float) -> bool:
    """Whether a photo agreeing ``agreement`` as stored could be named upside down: turned, a correlation is at
    most 1, so one that agrees over ``1 - FLIPPED_MARGIN`` as stored is not measured turned (a room's hundreds of
    photos, most of them agreeing well, then blur a third fewer images)."""
    return agreement + FLIPPED_MARGIN <= 1.0


@dataclass(frozen=True)
class _SmallView:
    """A photo at the check's working size, for the consensus of an untextured scan's photos (what the others look
    up in it, and what it is judged by: about 1 MB a photo, a room's hundreds held at once)."""

    camera: Camera
    band: np.ndarray
    """``(H, W) float32`` the band of the photo's luma the check compares (:func:`_band`, over the surface)"""
    centre: float
    spread: float
    """the band's mean and standard deviation over the usable pixels (the photo's exposure, taken out)"""
    turned: np.ndarray
    """``(n,) float32`` the band of the photo turned by 180 degrees, at the usable pixels"""
    depth: np.ndarray
    """``(H, W) float32`` the mesh's depth at each pixel, infinite where it sees none"""
    usable: np.ndarray
    """``(H, W) bool`` whole pixels of the surface, away from its contours"""
    faces: np.ndarray
    """the faces the usable pixels see, sorted"""

    def points(self) -> np.ndarray:
        """``(n, 3) float32`` the surface points of the usable pixels, row-major."""
        origin, directions = self.camera.pixel_rays()
        rows = self.usable.reshape(-1)
        return origin.astype(np.float32) + directions[rows] * self.depth.reshape(-1)[rows, None]


def _small_view(photos: PhotoSet, i: int, caster: RayCaster) -> _SmallView:
    from scipy import ndimage

    from scantex.photos.training import working_camera
    from scantex.views.raycast import cast_gbuffer

    camera = working_camera(photos.cameras[i], MATCH_SIDE)
    g = cast_gbuffer(caster, camera)
    hit = g.face_id >= 0
    usable = ndimage.binary_erosion(hit, iterations=2)
    luma = _photo_luma(photos, i, camera)
    norms = _band_norms(hit)
    band = _band(luma, hit, norms)
    values = band[usable]
    centre, spread = (float(values.mean()), float(values.std())) if values.size else (0.0, 0.0)
    return _SmallView(camera, band, centre, spread, _band(luma[::-1, ::-1], hit, norms)[usable],
                      np.where(hit, g.depth, np.inf).astype(np.float32), usable, np.unique(g.face_id[usable]))


def consensus_matches(photos: PhotoSet, indices: Sequence[int], caster: RayCaster) -> list[PhotoMatch]:
    """Each photo of ``indices`` compared with the other photos' consensus (an untextured scan; see the module
    docstring): a :class:`PhotoMatch` each, its agreement ``None`` where under :data:`MIN_PIXELS` pixels have a
    consensus, the others' mean band there varies under :data:`MIN_CONTRAST` (as a texture's must for a verdict)
    or the photo's own under :data:`MIN_PHOTO_CONTRAST`."""
    from scantex.threads import side_by_side

    views = list(side_by_side(lambda i: _small_view(photos, i, caster), indices))
    matches = []
    for k, (i, v) in enumerate(zip(indices, views)):
        shared = sorted(((len(np.intersect1d(v.faces, o.faces, assume_unique=True)), m)
                         for m, o in enumerate(views) if m != k), reverse=True)
        points = v.points()
        total, count = np.zeros(len(points), np.float32), np.zeros(len(points), np.int32)
        detail = np.zeros(len(points), np.float32)  # the others' bands as they are: how much detail they see
        for n, m in shared[:CONSENSUS_PHOTOS]:
            if n == 0:
                break
            o = views[m]
            pix, z = o.camera.project(points)
            x, y = np.rint(pix[:, 0]), np.rint(pix[:, 1])
            inside = np.flatnonzero((x >= 0) & (x < o.camera.width) & (y >= 0) & (y < o.camera.height) & (z > 0))
            x, y = x[inside].astype(np.intp), y[inside].astype(np.intp)
            seen = np.abs(o.depth[y, x] - z[inside]) <= DEPTH_AGREES * z[inside]  # not hidden from the other photo
            values = o.band[y[seen], x[seen]]
            # each other photo's band brought to zero mean and unit spread: its exposure out of the mean
            total[inside[seen]] += (values - o.centre) / max(o.spread, 1e-6)
            detail[inside[seen]] += values
            count[inside[seen]] += 1
        agreed = count > 0
        own = v.band[v.usable]
        if (agreed.sum() < MIN_PIXELS or own.std() < MIN_PHOTO_CONTRAST
                or (detail[agreed] / count[agreed]).std() < MIN_CONTRAST):
            matches.append(PhotoMatch(int(i), int(agreed.sum()), None, None))
            continue
        consensus = total[agreed] / count[agreed]
        matches.append(PhotoMatch(int(i), int(agreed.sum()), _correlation(own[agreed], consensus),
                                  _correlation(v.turned[agreed], consensus)))
    return matches


def mismatched(matches: Sequence[PhotoMatch], against: str = "the scan's texture") -> dict[int, str]:
    """``{photo: why}`` for the photos of ``matches`` that do not show what their cameras see; ``against``: what
    they were compared with, for the reasons."""
    found = {}
    judged = [m for m in matches if m.agreement is not None]
    for m in judged:
        others = np.median([o.agreement for o in judged if o.photo != m.photo]) if len(judged) >= 3 else -1.0
        if m.turned is not None and m.turned >= FLIPPED_AGREES and m.turned >= m.agreement + FLIPPED_MARGIN:
            found[m.photo] = (f"turned by 180 degrees it agrees with {against} {m.turned:.2f}, as stored "
                              f"{m.agreement:.2f}: stored upside down?")
        elif others >= OTHERS_AGREE and m.agreement < MISMATCH:
            found[m.photo] = (f"it agrees with {against} {m.agreement:.2f}, the other photos {others:.2f} "
                              "(median): another frame's photo, cropped or turned after capture, or the mesh "
                              "wrong just before its camera?")
    return found


def leave_out_mismatched(scan: Scan, photos: PhotoSet, train: np.ndarray, held: np.ndarray,
                         caster: RayCaster) -> tuple[np.ndarray, np.ndarray, list[dict]]:
    """``(train, held, left_out)``: the training and held-out photo indices without the photos that do not show
    what their cameras see (each named in a warning), and those, as ``PhotoMatch.to_dict`` with ``why``, for
    metrics.json. A textured scan's photos are checked against its texture, an untextured scan's against one
    another.

    Raises:
        ScanError: no training photo is left.
    """
    from scantex.threads import side_by_side

    indices = [int(i) for i in (*train, *held)]
    if scan.is_textured:
        matches = list(side_by_side(lambda i: photo_match(scan, photos, i, caster), indices))
        found = mismatched(matches)
    else:
        matches = consensus_matches(photos, indices, caster)
        found = mismatched(matches, "the other photos' consensus")
    for i, why in found.items():
        log.warning("%s: photo %d does not show what its camera sees (%s): left out", photos.images[i], i, why)
    if not found:
        return train, held, []
    kept_train = np.array([i for i in train if int(i) not in found], dtype=np.asarray(train).dtype)
    if not len(kept_train):
        raise ScanError(photos.source, "no training photo shows what its camera sees (each disagrees with the "
                                       "scan's texture or the other photos): are these the capture's photos and "
                                       "poses?")
    kept_held = np.array([i for i in held if int(i) not in found], dtype=np.asarray(held).dtype)
    left_out = [{**m.to_dict(), "image": str(photos.images[m.photo]), "why": found[m.photo]}
                for m in matches if m.photo in found]
    return kept_train, kept_held, left_out


def _photo_luma(photos: PhotoSet, i: int, camera: Camera) -> np.ndarray:
    """``(H, W) float32`` luma of photo ``i`` box-filtered down to ``camera``'s size (its working camera)."""
    from scantex.io.images import box_downscaled

    image = photos.load_image(i)
    if image.shape[1::-1] != (camera.width, camera.height):
        image = box_downscaled(image, camera.width, camera.height)
    return _luma(image.astype(np.float32) / 255.0)


def _luma(image: np.ndarray) -> np.ndarray:
    """``(H, W) float32`` luma of an ``(H, W, 3)`` image in [0, 1]."""
    return image @ np.array([0.299, 0.587, 0.114], np.float32)


def _band_norms(covered: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The normalised convolution's denominators of :func:`_band` for ``covered``: the blurs :data:`MATCH_BLUR` and
    :data:`MATCH_BAND` of its weight (made once for the several images banded over one view)."""
    from scipy import ndimage

    weight = covered.astype(np.float32)
    return tuple(np.maximum(ndimage.gaussian_filter(weight, sigma), 1e-6) for sigma in (MATCH_BLUR, MATCH_BAND))


def _band(luma: np.ndarray, covered: np.ndarray, norms: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray:
    """``(H, W) float32``: the band of ``luma``'s detail the check compares, between the blurs :data:`MATCH_BLUR`
    and :data:`MATCH_BAND`, each a blur of the ``covered`` pixels alone (normalised convolution): the mesh's
    border against the background, and what a photo shows beyond it, are no detail of the surface. ``norms``:
    :func:`_band_norms` of ``covered``, when already made."""
    from scipy import ndimage

    fine, coarse = _band_norms(covered) if norms is None else norms
    weighted = luma * covered.astype(np.float32)
    return ndimage.gaussian_filter(weighted, MATCH_BLUR) / fine - ndimage.gaussian_filter(weighted, MATCH_BAND) / coarse


def _correlation(a: np.ndarray, b: np.ndarray) -> float:
    a, b = a - a.mean(), b - b.mean()
    norm = float(np.sqrt((a * a).sum() * (b * b).sum()))
    return float((a * b).sum() / norm) if norm > 0 else 0.0
