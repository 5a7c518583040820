"""View planning: where to put the synthetic cameras, and how well they cover the surface.

Two layouts, as scans come in two shapes:

- **orbit** (a closed object: a statue, a shoe): directions on a Fibonacci sphere (or its upper half
  for an object standing on the ground), all looking at the bounding-sphere centre from a distance at
  which the whole bounding sphere fits the field of view.
- **surface** (an open surface: a wall, a floor, a room seen from inside): cameras in front of spread-out
  points of the surface, on the side its normals face, close enough for a useful footprint and never
  behind another wall.

:func:`face_coverage` counts, per face, the views that see it at a usable angle and resolution, and
:func:`add_views_for_coverage` adds cameras aimed at the faces seen too rarely (the paper's future
work: adaptive view sampling).
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import numpy as np

from scantex.errors import ScanError
from scantex.scan import Scan
from scantex.views.camera import Camera
from scantex.threads import side_by_side
from scantex.views.raycast import PAIR_THREADS, RayCaster, cast_gbuffer

log = logging.getLogger(__name__)

MODES = ("auto", "orbit", "hemisphere", "surface")

#: weight of the unit normal against position (in bounding diagonals) when spreading surface targets:
#: two sides of a thin wall, or two walls meeting in a corner, count as far apart
NORMAL_WEIGHT = 0.25
#: each face should fall in about this many surface-camera footprints (sets the default distance)
FOOTPRINT_OVERLAP = 4.0
#: a camera pushed closer than this share of its planned distance by an obstacle is dropped
MIN_DISTANCE_SHARE = 0.2


# -- layouts ------------------------------------------------------------------------------------------


def orbit_cameras(scan: Scan, n: int, *, width: int = 512, height: int = 512, fov_deg: float = 50.0,
                  hemisphere: bool = False, up=(0.0, 0.0, 1.0), margin: float = 1.1) -> list[Camera]:
    """``n`` cameras around the scan, each seeing its whole bounding sphere.

    Args:
        scan: the scan.
        n: number of cameras.
        width, height: image size in pixels.
        fov_deg: horizontal field of view.
        hemisphere: only directions above the horizon (``up`` side), for objects standing on the ground.
        up: world up direction; the pole of the (hemi)sphere and the cameras' up.
        margin: the bounding sphere's radius is enlarged by this factor before fitting it in view.
    """
    _check_count(n)
    _check_image(width, height, fov_deg)
    center, radius = _bounding_sphere(scan)
    half_fov = _half_fov(fov_deg, width, height)
    distance = margin * radius / math.sin(half_fov)
    up = _unit(np.asarray(up, dtype=np.float64))
    eyes = center + distance * _fibonacci_directions(n, hemisphere, up)  # [n, 3]
    log.debug("orbit: %d cameras at %.4g from the centre (bounding radius %.4g)", n, distance, radius)
    return [Camera.look_at(eye, center, up, fov_deg, width, height) for eye in eyes]


def surface_cameras(scan: Scan, n: int, *, width: int = 512, height: int = 512, fov_deg: float = 50.0,
                    distance: float | None = None, tilt_deg: float = 20.0, up=(0.0, 0.0, 1.0),
                    seed: int = 0, caster: RayCaster | None = None) -> list[Camera]:
    """Up to ``n`` cameras in front of spread-out points of an open surface.

    Targets are area-weighted samples of the surface, thinned by farthest-point selection on position
    and normal. Each camera stands on the side the target's normal faces, along the normal tilted by up
    to ``tilt_deg`` (so views differ in angle), and looks at the target. An obstacle along that line
    (the opposite wall of a room) pulls the camera closer; a camera pulled in too far, or one whose eye
    does not see its target, is dropped and the next spread-out target is tried.

    Args:
        scan: the scan.
        n: number of cameras wanted; fewer are returned (with a warning) when too few places work.
        width, height: image size in pixels.
        fov_deg: horizontal field of view.
        distance: planned camera-to-target distance; ``None``: so that each face falls in about
            ``FOOTPRINT_OVERLAP`` footprints, clamped to [0.05, 0.5] bounding diagonals.
        tilt_deg: largest angle between the viewing line and the target's normal.
        up: world up direction for the cameras' roll.
        seed: seeds the target sampling and the tilts.
        caster: a prebuilt :class:`RayCaster` of the scan (built here when ``None``).
    """
    _check_count(n)
    _check_image(width, height, fov_deg)
    if distance is not None and not distance > 0:
        raise ValueError(f"distance must be positive, got {distance}")
    caster = caster or RayCaster(scan.positions, scan.faces)
    rng = np.random.default_rng(seed)
    faces = np.flatnonzero(scan.face_areas > 0)
    if faces.size == 0:
        raise ScanError(scan.source, "every face has zero area; there is no surface to look at")
    cameras = _cameras_at_targets(scan, caster, faces, n, rng, width=width, height=height,
                                  fov_deg=fov_deg, distance=distance, tilt_deg=tilt_deg, up=up)
    if len(cameras) < n:
        log.warning("surface views: only %d of %d cameras found a clear place", len(cameras), n)
    return cameras


def plan_views(scan: Scan, n: int, *, mode: str = "auto", width: int = 512, height: int = 512,
               fov_deg: float = 50.0, up=(0.0, 0.0, 1.0), seed: int = 0,
               caster: RayCaster | None = None) -> list[Camera]:
    """Cameras for ``n`` synthetic views of the scan.

    Args:
        mode: ``"orbit"``, ``"hemisphere"`` (orbit above the horizon), ``"surface"``, or ``"auto"``:
            orbit for a closed mesh whose normals point outwards (an object), surface otherwise (open
            scans, and closed meshes seen from inside such as a scanned room).
        up: world up direction (glTF scans are y-up: pass ``(0, 1, 0)``).
        seed: seeds the surface layout (the orbit layouts are deterministic).
    """
    if mode not in MODES:
        raise ValueError(f"view mode must be one of {', '.join(MODES)}, got {mode!r}")
    if mode == "auto":
        mode = "orbit" if is_closed_object(scan) else "surface"
        log.info("view planning: %s layout (%s)", mode,
                 "closed, outward-facing mesh" if mode == "orbit" else "open or inward-facing mesh")
    if mode == "surface":
        return surface_cameras(scan, n, width=width, height=height, fov_deg=fov_deg, up=up, seed=seed,
                               caster=caster)
    return orbit_cameras(scan, n, width=width, height=height, fov_deg=fov_deg,
                         hemisphere=mode == "hemisphere", up=up)


def is_closed_object(scan: Scan) -> bool:
    """True when the mesh is watertight (every edge shared by exactly two faces, after welding equal positions)
    and encloses positive volume.

    The weld is the scan's own (:attr:`Scan.welded`): formats like glTF split vertices at UV seams, which would
    otherwise make every textured mesh look open. A watertight mesh with negative volume has inward normals:
    the inside of a room, which must be seen from inside.
    """
    faces = scan.welded[scan.faces]
    if not len(faces):
        return False
    edges = np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), axis=1)
    _, counts = np.unique(edges[:, 0] * (int(faces.max()) + 1) + edges[:, 1], return_counts=True)
    if not (counts == 2).all():
        return False
    t = scan.triangles - scan.triangles.reshape(-1, 3).mean(axis=0)  # centred: less cancellation
    signed_volume = np.einsum("ij,ij->", t[:, 0], np.cross(t[:, 1], t[:, 2])) / 6.0
    return bool(signed_volume > 0)


# -- coverage -----------------------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class Coverage:
    """How many views see each face usably.

    Attributes:
        views_per_face: ``(F,) int32`` number of views that see the face from its front side, at an
            angle to the normal below the limit and a pixel footprint below the limit.
        face_areas: ``(F,) float64`` face areas, the weights of :meth:`fraction_covered`.
        n_views: number of views counted.
    """

    views_per_face: np.ndarray
    face_areas: np.ndarray
    n_views: int

    def fraction_covered(self, k: int = 1) -> float:
        """Share of the surface area seen usably by at least ``k`` views."""
        total = self.face_areas.sum()
        return float(self.face_areas[self.views_per_face >= k].sum() / total) if total > 0 else 0.0

    def under_covered(self, k: int) -> np.ndarray:
        """``(M,) int64`` faces with positive area seen usably by fewer than ``k`` views."""
        return np.flatnonzero((self.views_per_face < k) & (self.face_areas > 0))

    def summary(self) -> str:
        unseen = 1.0 - self.fraction_covered(1)
        median = float(np.median(self.views_per_face)) if self.views_per_face.size else 0.0
        return (f"{self.n_views} views: {100 * self.fraction_covered(1):.1f}% of the surface seen by >= 1, "
                f"{100 * self.fraction_covered(2):.1f}% by >= 2, {100 * unseen:.1f}% unseen; "
                f"median {median:g} views per face")


def face_coverage(scan: Scan, cameras: list[Camera], *, max_angle_deg: float = 70.0,
                  max_pixel_size: float | None = None, caster: RayCaster | None = None) -> Coverage:
    """Count the views that see each face usably, by ray casting their G-buffers.

    A view sees a face when at least one of its pixels hits it (so occlusion is exact at pixel
    resolution, and faces smaller than a pixel may go unseen: such a view holds no sample of them). The
    sighting is usable when the face is seen from its front side at less than ``max_angle_deg`` between
    its normal and the direction to the camera, and one pixel covers at most ``max_pixel_size`` of
    surface there (depth / focal length, stretched by 1 / cos of that angle).

    Args:
        scan: the scan.
        cameras: the views.
        max_angle_deg: steepest usable viewing angle, from the face normal.
        max_pixel_size: coarsest usable pixel footprint on the surface, in scan units (metres for most
            scans: 0.005 is 5 mm); ``None``: a hundredth of the bounding diagonal.
        caster: a prebuilt :class:`RayCaster` of the scan (built here when ``None``).
    """
    if not 0 < max_angle_deg <= 90:
        raise ValueError(f"max_angle_deg must be in (0, 90], got {max_angle_deg}")
    caster = caster or RayCaster(scan.positions, scan.faces)
    sightings = _Sightings(scan, caster, max_angle_deg, max_pixel_size)
    views_per_face = np.zeros(scan.n_faces, dtype=np.int32)
    # the views two at a time (Embree and numpy release the interpreter lock)
    for faces in side_by_side(sightings.usable_faces, cameras, PAIR_THREADS):
        views_per_face[faces] += 1
    return Coverage(views_per_face, scan.face_areas, len(cameras))


def add_views_for_coverage(scan: Scan, cameras: list[Camera], *, min_views: int = 2,
                           max_new: int | None = None, max_angle_deg: float = 70.0,
                           max_pixel_size: float | None = None, tilt_deg: float = 20.0,
                           up=(0.0, 0.0, 1.0), seed: int = 0,
                           caster: RayCaster | None = None) -> list[Camera]:
    """Add cameras aimed at faces seen usably by fewer than ``min_views`` views (adaptive view sampling).

    Rounds of new surface-style cameras (same image size and field of view as ``cameras[0]``) go to
    spread-out points of the under-covered faces, sampled by area times missing views, until every face
    has ``min_views`` views, ``max_new`` cameras have been added, or a round no longer reduces the
    missing views (that round is dropped). Progress counts views up to ``min_views`` per face, so a
    round that takes unseen faces to one view counts even when none reaches ``min_views`` yet.
    Usability is judged as in :func:`face_coverage`.

    Args:
        cameras: the current views, kept first and unchanged in the result.
        min_views: views each face should have.
        max_new: most cameras to add; ``None``: as many as there are already (at least 8).

    Returns:
        ``cameras`` followed by the added cameras.
    """
    if not cameras:
        raise ValueError("add_views_for_coverage needs at least one camera to copy the image size from")
    if min_views < 1:
        raise ValueError(f"min_views must be at least 1, got {min_views}")
    max_new = max(8, len(cameras)) if max_new is None else max_new
    if max_new < 0:
        raise ValueError(f"max_new must be >= 0, got {max_new}")
    caster = caster or RayCaster(scan.positions, scan.faces)
    rng = np.random.default_rng(seed)
    ref = cameras[0]
    fov_deg = math.degrees(2 * math.atan(0.5 * ref.width / ref.K[0, 0]))
    sightings = _Sightings(scan, caster, max_angle_deg, max_pixel_size)
    areas = scan.face_areas
    views_per_face = np.zeros(scan.n_faces, dtype=np.int32)
    for camera in cameras:
        views_per_face[sightings.usable_faces(camera)] += 1

    def progress(counts: np.ndarray) -> float:
        return float(areas @ np.minimum(counts, min_views))

    result = list(cameras)
    per_round = max(1, math.ceil(max_new / 4))
    while len(result) - len(cameras) < max_new:
        under = np.flatnonzero((views_per_face < min_views) & (areas > 0))
        if under.size == 0:
            break
        want = min(per_round, max_new - (len(result) - len(cameras)))
        new = _cameras_at_targets(scan, caster, under, want, rng, width=ref.width, height=ref.height,
                                  fov_deg=fov_deg, distance=None, tilt_deg=tilt_deg, up=up,
                                  weights=areas[under] * (min_views - views_per_face[under]))
        counts = views_per_face.copy()
        for camera in new:
            counts[sightings.usable_faces(camera)] += 1
        if not new or progress(counts) <= progress(views_per_face):
            break
        result += new
        views_per_face = counts
    log.info("adaptive views: added %d cameras; %.1f%% of the surface now has >= %d views",
             len(result) - len(cameras),
             100 * areas[views_per_face >= min_views].sum() / max(areas.sum(), 1e-300), min_views)
    return result


class _Sightings:
    """Per-view usable faces, with the per-face quantities computed once for all views."""

    def __init__(self, scan: Scan, caster: RayCaster, max_angle_deg: float, max_pixel_size: float | None):
        self.caster = caster
        self.normals = scan.face_normals
        self.centroids = scan.triangles.mean(axis=1)  # [F, 3]
        self.cos_max = math.cos(math.radians(max_angle_deg))
        diagonal = float(np.linalg.norm(np.ptp(scan.bounds, axis=0)))
        self.max_pixel_size = diagonal / 100 if max_pixel_size is None else float(max_pixel_size)

    def usable_faces(self, camera: Camera) -> np.ndarray:
        """``(M,) int64`` faces that ``camera`` sees usably."""
        g = cast_gbuffer(self.caster, camera)
        seen = np.zeros(len(self.normals), dtype=bool)
        seen[g.face_id[g.face_id >= 0]] = True
        fid = np.flatnonzero(seen)
        to_camera = camera.center - self.centroids[fid]  # [M, 3]
        dist = np.linalg.norm(to_camera, axis=1)
        cos = np.einsum("ij,ij->i", self.normals[fid], to_camera) / np.maximum(dist, 1e-300)
        depth = -(to_camera @ camera.forward)
        focal = 0.5 * (camera.K[0, 0] + camera.K[1, 1])
        pixel_size = depth / focal / np.maximum(cos, 1e-6)
        return fid[(cos >= self.cos_max) & (pixel_size <= self.max_pixel_size)]


# -- building blocks ----------------------------------------------------------------------------------


def _cameras_at_targets(scan: Scan, caster: RayCaster, faces: np.ndarray, n: int,
                        rng: np.random.Generator, *, width: int, height: int, fov_deg: float,
                        distance: float | None, tilt_deg: float, up,
                        weights: np.ndarray | None = None) -> list[Camera]:
    """Up to ``n`` cameras aimed at spread-out points of ``faces`` (positive-area face indices).

    Targets are sampled in proportion to ``weights (len(faces),)``, the face areas when ``None``.
    """
    diagonal = float(np.linalg.norm(np.ptp(scan.bounds, axis=0)))
    areas = scan.face_areas[faces]
    if distance is None:
        half_fov = _half_fov(fov_deg, width, height)
        footprint = math.sqrt(FOOTPRINT_OVERLAP * areas.sum() / n)  # side of the wanted square
        distance = float(np.clip(footprint / (2 * math.tan(half_fov)), 0.05 * diagonal, 0.5 * diagonal))

    # candidates: area-weighted samples, ordered by farthest-point selection
    n_samples = min(max(2000, 64 * n), 50_000)
    face_of, points = _sample_surface(scan, faces, areas if weights is None else weights, n_samples, rng)
    normals = scan.face_normals[face_of]
    features = np.concatenate([points / diagonal, NORMAL_WEIGHT * normals], axis=1)  # [S, 6]
    order = _farthest_point_order(features, min(n_samples, 4 * n), rng)
    targets, normals = points[order], normals[order]  # [K, 3] each

    directions = _tilted(normals, math.radians(tilt_deg), rng)  # [K, 3], dot with normal > 0
    # free space along the viewing line: start a hair off the surface so the target's face is not hit
    eps = 1e-5 * diagonal
    free = caster.intersect(targets + eps * normals, directions).t.astype(np.float64)  # inf: open
    eye_distance = np.minimum(distance, 0.8 * free)
    eyes = targets + eye_distance[:, None] * directions
    # the eye must see its target: the first hit looking back is the target itself
    back = caster.intersect(eyes, -directions).t.astype(np.float64)
    clear = back >= eye_distance - 1e-3 * diagonal - eps
    ok = np.flatnonzero((eye_distance >= MIN_DISTANCE_SHARE * distance) & clear)[:n]
    log.debug("surface views: %d of %d candidates usable, planned distance %.4g", ok.size, len(order),
              distance)
    return [Camera.look_at(eyes[i], targets[i], up, fov_deg, width, height) for i in ok]


def _sample_surface(scan: Scan, faces: np.ndarray, weights: np.ndarray, count: int,
                    rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Random points on ``faces``, each face drawn in proportion to ``weights``, uniform within it.

    Returns ``(count,) int64`` face ids and ``(count, 3) float64`` points.
    """
    face_of = faces[rng.choice(len(faces), size=count, p=weights / weights.sum())]
    r1, r2 = rng.random((2, count))
    s = np.sqrt(r1)  # uniform over the triangle, not clustered at a corner
    w = np.stack([1 - s, s * (1 - r2), s * r2], axis=1)  # [count, 3]
    points = np.einsum("nk,nkc->nc", w, scan.positions[scan.faces[face_of]])
    return face_of, points


def _farthest_point_order(features: np.ndarray, k: int, rng: np.random.Generator) -> np.ndarray:
    """``(k,) int64`` indices into ``features (S, D)``: a random start, then each farthest from all before."""
    order = np.empty(k, dtype=np.int64)
    order[0] = rng.integers(len(features))
    nearest = np.linalg.norm(features - features[order[0]], axis=1)
    for i in range(1, k):
        order[i] = int(np.argmax(nearest))
        nearest = np.minimum(nearest, np.linalg.norm(features - features[order[i]], axis=1))
    return order


def _tilted(normals: np.ndarray, max_tilt: float, rng: np.random.Generator) -> np.ndarray:
    """``(K, 3)`` unit directions within ``max_tilt`` radians of ``normals (K, 3)``, random azimuth."""
    K = len(normals)
    helper = np.where((np.abs(normals[:, 0]) < 0.9)[:, None], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0])
    t1 = np.cross(normals, helper)
    t1 /= np.linalg.norm(t1, axis=1, keepdims=True)
    t2 = np.cross(normals, t1)
    theta = max_tilt * rng.random(K)[:, None]
    phi = 2 * np.pi * rng.random(K)[:, None]
    return np.cos(theta) * normals + np.sin(theta) * (np.cos(phi) * t1 + np.sin(phi) * t2)


def _fibonacci_directions(n: int, hemisphere: bool, up: np.ndarray) -> np.ndarray:
    """``(n, 3)`` near-uniform unit directions on the sphere (or the half around ``up``)."""
    i = np.arange(n) + 0.5
    z = 1 - i / n if hemisphere else 1 - 2 * i / n  # equal-area bands
    azimuth = i * np.pi * (3 - math.sqrt(5))  # golden angle
    r = np.sqrt(np.clip(1 - z * z, 0, None))
    local = np.stack([r * np.cos(azimuth), r * np.sin(azimuth), z], axis=1)
    helper = np.array([1.0, 0.0, 0.0]) if abs(up[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    x = _unit(np.cross(helper, up))
    y = np.cross(up, x)
    return local @ np.stack([x, y, up])


def _bounding_sphere(scan: Scan) -> tuple[np.ndarray, float]:
    """Centre of the bounding box, and the distance from it to the farthest used vertex."""
    used = scan.positions[np.unique(scan.faces)]
    center = 0.5 * (used.min(axis=0) + used.max(axis=0))
    radius = float(np.linalg.norm(used - center, axis=1).max())
    if radius == 0:
        raise ScanError(scan.source, "all vertices coincide; there is nothing to look at")
    return center, radius


def _half_fov(fov_deg: float, width: int, height: int) -> float:
    """Half the narrower field of view (horizontal ``fov_deg`` or the vertical one), in radians."""
    half_x = math.radians(fov_deg) / 2
    return min(half_x, math.atan(math.tan(half_x) * height / width))


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v)


def _check_count(n: int) -> None:
    if int(n) != n or n < 1:
        raise ValueError(f"the number of views must be a positive integer, got {n}")


def _check_image(width: int, height: int, fov_deg: float) -> None:
    if width < 1 or height < 1:
        raise ValueError(f"image size must be positive, got {width}x{height}")
    if not 0 < fov_deg < 180:
        raise ValueError(f"fov_deg must be in (0, 180), got {fov_deg}")
