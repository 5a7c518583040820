"""Does the mesh sit where the photos' cameras see it? A check before training on the photos.

A mesh and its photos come from one capture but often not in one frame: an app that re-centres or
re-orients the mesh on export, a nerfstudio file whose world was rotated to z-up, a COLMAP model in
its own arbitrary frame. Trained through such cameras, a texture would come out as a smear. The check
renders the mesh (by ray casting) from a few photos' cameras at a reduced size and compares *edges*:

- the render's edges: silhouette and depth discontinuities (occluding contours); only where a photo
  shows too few of those (a close-up of a flat wall), the edges of the mesh's texture or colours (the
  same detector as for the photo). Contours come first because a capture's own texture is what scantex
  is asked to fix: exposure jumps at its chart borders and black holes make edges no photo has (the
  degraded demo wall at 128 px scored 0.67 with texture edges, "misaligned", though it was aligned);
- the photo's edges: Sobel gradient after a Gaussian blur, thinned by non-maximum suppression and
  thresholded (a light Canny without hysteresis);
- ``edge_distance_px``: the mean distance (working pixels) from a render edge pixel to the nearest
  photo edge, each distance capped at ``DISTANCE_CAP`` (5 %) of the image side (a distance transform
  of the photo's edge map: a one-sided, truncated chamfer distance);
- ``baseline_px``: the same distance after moving the render's edges by a tenth of the image in 8
  directions: what edges that have nothing to do with the photo score on it. Cluttered photos have
  edges everywhere, so only the ratio ``edge_distance / baseline`` tells aligned from not;
- ``coverage``: the share of the photo's pixels that see the mesh.

The set is judged misaligned when the mesh covers less than 1 % of most checked photos, or when the
median ratio over photos is above ``MAX_EDGE_RATIO`` (0.5). Measured at the defaults (4 photos, 480
px): synthetic renders of the mesh itself give about 0.1 (edge distance 0.2 px); the bolster Kinect
demo (aligned, untextured mesh: contours only) 0.17 (1.1 px; 0.10-0.21 per photo over all 14); the
same mesh moved 5 cm (a 15th of its size) 0.58, 20 cm 1.24, turned 20 degrees 0.66, 90 degrees 0.95.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from scantex.errors import ScanError
from scantex.photos.photoset import PhotoSet
from scantex.scan import Scan
from scantex.views.camera import Camera

log = logging.getLogger(__name__)

#: a photo the mesh covers less of than this does not count as seeing it
MIN_COVERAGE = 0.01
#: edge distance / random-offset distance above which the mesh is judged misaligned
MAX_EDGE_RATIO = 0.5
#: fewest render edge pixels for a photo's edge distance to count
MIN_EDGE_PIXELS = 20
#: edge distances are capped at this share of the longer image side (a truncated chamfer distance:
#: one render edge with no counterpart in the photo, a cable or a shadow, must not dominate)
DISTANCE_CAP = 0.05
#: relative depth jump between neighbouring pixels that makes an occluding contour
DEPTH_JUMP = 0.1


@dataclass(frozen=True)
class PhotoAlignment:
    """How one photo agrees with the mesh rendered through its camera.

    Attributes:
        index: the photo's index in the :class:`PhotoSet`.
        image: its file.
        size: ``(width, height)`` the comparison ran at.
        coverage: share of the photo's pixels that see the mesh.
        edge_distance_px: mean distance (pixels at ``size``, each capped at ``DISTANCE_CAP`` of the
            longer side) from the render's edges to the photo's nearest edge; NaN when the render has fewer
            than ``MIN_EDGE_PIXELS`` edge pixels.
        baseline_px: the same for the render's edges moved by a tenth of the image (8 directions).
        n_edges: number of render edge pixels.
    """

    index: int
    image: Path
    size: tuple[int, int]
    coverage: float
    edge_distance_px: float
    baseline_px: float
    n_edges: int

    @property
    def ratio(self) -> float:
        """``edge_distance_px / baseline_px``: about 0 aligned, about 1 unrelated."""
        if not np.isfinite(self.edge_distance_px) or not self.baseline_px > 0:
            return float("nan")
        return self.edge_distance_px / self.baseline_px


@dataclass(frozen=True)
class AlignmentReport:
    """The verdict of :func:`check_alignment`.

    Attributes:
        photos: per checked photo.
        ok: False when the mesh is clearly not in the cameras' frame.
        problem: what is wrong when not ``ok`` (one clause), else ``None``.
    """

    photos: tuple[PhotoAlignment, ...]
    ok: bool
    problem: str | None

    @property
    def edge_distance_px(self) -> float:
        """Median over photos of their edge distance (NaN when no photo has render edges)."""
        return _nanmedian([p.edge_distance_px for p in self.photos])

    @property
    def baseline_px(self) -> float:
        return _nanmedian([p.baseline_px for p in self.photos])

    @property
    def ratio(self) -> float:
        return _nanmedian([p.ratio for p in self.photos])

    @property
    def coverage(self) -> float:
        return float(np.median([p.coverage for p in self.photos]))

    def summary(self) -> str:
        size = max(self.photos[0].size) if self.photos else 0
        verdict = "aligned" if self.ok else f"NOT aligned: {self.problem}"
        return (f"mesh and photos {verdict}; median edge distance {self.edge_distance_px:.1f} px "
                f"(random offsets: {self.baseline_px:.1f} px, ratio {self.ratio:.2f}), mesh covers "
                f"{100 * self.coverage:.0f} % of the photo; {len(self.photos)} photos at {size} px")


def check_alignment(scan: Scan, photos: PhotoSet, *, n_photos: int = 4, max_side: int = 480,
                    caster=None) -> AlignmentReport:
    """Reproject ``scan`` into ``n_photos`` evenly spread photos and measure how well its edges meet the
    photos' edges (see the module docstring).

    Args:
        scan: the mesh, in the frame it will be textured in.
        photos: the posed photos.
        n_photos: how many photos to check.
        max_side: the longer image side the comparison runs at.
        caster: a prebuilt :class:`~scantex.views.raycast.RayCaster` of ``scan`` (built when ``None``).
    """
    from scantex.views.raycast import RayCaster

    if len(photos) == 0:
        raise ValueError("no photos to check")
    caster = caster or RayCaster(scan.positions, scan.faces)
    picks = np.unique(np.linspace(0, len(photos) - 1, min(n_photos, len(photos))).round().astype(int))
    results = tuple(_check_photo(scan, photos, int(i), max_side, caster) for i in picks)
    covered = [p for p in results if p.coverage >= MIN_COVERAGE]
    problem = None
    if 2 * len(covered) <= len(results):
        problem = (f"it projects outside {len(results) - len(covered)} of the {len(results)} photos "
                   f"checked (covers {100 * float(np.median([p.coverage for p in results])):.1f} % of "
                   "a photo on median)")
    else:
        ratio = _nanmedian([p.ratio for p in covered])
        if not np.isfinite(ratio):
            problem = "the rendered mesh shows no edges to compare with the photos"
        elif ratio > MAX_EDGE_RATIO:
            problem = (f"its edges miss the photos' edges (distance ratio {ratio:.2f} to the same edges "
                       f"moved at random; aligned data gives < {MAX_EDGE_RATIO})")
    report = AlignmentReport(results, problem is None, problem)
    log.info("%s", report.summary())
    return report


def require_alignment(scan: Scan, photos: PhotoSet, **kwargs) -> AlignmentReport:
    """:func:`check_alignment`, raising when the mesh is clearly not in the cameras' frame.

    Raises:
        ScanError: naming ``photos.source``: "the mesh is not in the cameras' frame: ... (median edge
            distance N px)".
    """
    report = check_alignment(scan, photos, **kwargs)
    if not report.ok:
        distance = report.edge_distance_px
        detail = (f"median edge distance {distance:.1f} px at {max(report.photos[0].size)} px"
                  if np.isfinite(distance) else "median edge distance: no mesh edges in the photos")
        raise ScanError(photos.source, f"the mesh is not in the cameras' frame: {report.problem} ({detail})")
    return report


def _check_photo(scan: Scan, photos: PhotoSet, i: int, max_side: int, caster) -> PhotoAlignment:
    from PIL import Image
    from scipy import ndimage

    from scantex.views.raycast import cast_gbuffer
    from scantex.views.render import render_gbuffer

    cam = photos.cameras[i]
    factor = min(1.0, max_side / max(cam.width, cam.height))
    w, h = max(1, round(cam.width * factor)), max(1, round(cam.height * factor))
    small = resized_camera(cam, w, h)
    photo = photos.load_image(i)
    if (w, h) != (cam.width, cam.height):
        photo = np.asarray(Image.fromarray(photo).resize((w, h), Image.Resampling.BOX))
    photo_edges = edge_map(_gray(photo.astype(np.float32) / 255.0))

    g = cast_gbuffer(caster, small, scan.face_normals)
    mask = g.mask
    render_edges = contour_map(mask, g.depth)
    if render_edges.sum() < MIN_EDGE_PIXELS:
        colour = render_gbuffer(scan, g)
        render_edges |= edge_map(_gray(colour)) & ndimage.binary_erosion(mask, iterations=2)

    ys, xs = np.nonzero(render_edges)
    n = len(ys)
    if n < MIN_EDGE_PIXELS or not photo_edges.any():
        distance = baseline = float("nan")
    else:
        dt = ndimage.distance_transform_edt(~photo_edges)
        cap = DISTANCE_CAP * max(w, h)
        distance = _chamfer(dt[ys, xs], cap)
        r = max(2, round(0.1 * max(w, h)))
        shifted = []
        for angle in np.arange(8) * np.pi / 4:
            dy, dx = round(r * np.sin(angle)), round(r * np.cos(angle))
            y, x = ys + dy, xs + dx
            inside = (y >= 0) & (y < h) & (x >= 0) & (x < w)
            if inside.sum() >= MIN_EDGE_PIXELS:
                shifted.append(_chamfer(dt[y[inside], x[inside]], cap))
        baseline = float(np.median(shifted)) if shifted else float("nan")
    return PhotoAlignment(i, photos.images[i], (w, h), float(mask.mean()), distance, baseline, n)


def resized_camera(camera: Camera, width: int, height: int) -> Camera:
    """``camera`` for its image resized to ``width x height`` (corners kept: pixel centres move as in
    :meth:`Camera.scaled`, per axis)."""
    sx, sy = width / camera.width, height / camera.height
    K = camera.K.copy()
    K[0, 0] *= sx
    K[0, 1] *= sx
    K[0, 2] = (K[0, 2] + 0.5) * sx - 0.5
    K[1, 1] *= sy
    K[1, 2] = (K[1, 2] + 0.5) * sy - 0.5
    return Camera(K, camera.world_to_camera, width, height)


def edge_map(gray: np.ndarray, sigma: float = 1.0, min_gradient: float = 0.02) -> np.ndarray:
    """``(H, W) bool`` thin edges of ``gray (H, W)`` in [0, 1]: Gaussian blur, Sobel, non-maximum
    suppression across the edge, and the maxima above ``min_gradient`` (intensity change per pixel)."""
    from scipy import ndimage

    g = ndimage.gaussian_filter(gray.astype(np.float32), sigma)
    gx = ndimage.sobel(g, axis=1) / 8.0
    gy = ndimage.sobel(g, axis=0) / 8.0
    mag = np.hypot(gx, gy)
    # non-maximum suppression along the gradient, quantised to 0, 45, 90, 135 degrees
    angle = (np.round(np.arctan2(gy, gx) / (np.pi / 4)) % 4).astype(np.int8)
    padded = np.pad(mag, 1)
    H, W = mag.shape
    is_max = np.zeros_like(mag, dtype=bool)
    for k, (dy, dx) in enumerate(((0, 1), (1, 1), (1, 0), (1, -1))):
        ahead = padded[1 + dy:1 + dy + H, 1 + dx:1 + dx + W]
        behind = padded[1 - dy:1 - dy + H, 1 - dx:1 - dx + W]
        is_max |= (angle == k) & (mag >= ahead) & (mag >= behind)
    return is_max & (mag > min_gradient)


def contour_map(mask: np.ndarray, depth: np.ndarray) -> np.ndarray:
    """``(H, W) bool`` occluding contours of a render: pixels that see the mesh next to one that does
    not (the silhouette), or next to one more than ``DEPTH_JUMP`` (relative) farther away."""
    edges = np.zeros_like(mask)
    for axis in (0, 1):
        a = [slice(None), slice(None)]
        b = [slice(None), slice(None)]
        a[axis], b[axis] = slice(None, -1), slice(1, None)
        ma, mb = mask[tuple(a)], mask[tuple(b)]
        da, db = depth[tuple(a)], depth[tuple(b)]
        with np.errstate(invalid="ignore"):
            jump = ma & mb & (np.abs(da - db) > DEPTH_JUMP * np.minimum(da, db))
        # mark the nearer side: the contour belongs to the occluding surface
        edges[tuple(a)] |= (ma & ~mb) | (jump & (da < db))
        edges[tuple(b)] |= (mb & ~ma) | (jump & (db < da))
    return edges


def _chamfer(distances: np.ndarray, cap: float) -> float:
    return float(np.minimum(distances, cap).mean())


def _gray(rgb: np.ndarray) -> np.ndarray:
    return rgb[..., :3] @ np.array([0.299, 0.587, 0.114], dtype=np.float32)


def _nanmedian(values) -> float:
    values = np.asarray(values, dtype=np.float64)
    values = values[np.isfinite(values)]
    return float(np.median(values)) if values.size else float("nan")
