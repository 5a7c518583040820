"""View planning: orbit and surface layouts, coverage counting, adaptive extra views."""

from __future__ import annotations

import math
import time

import numpy as np
import pytest
import trimesh

from scantex.scan import Scan
from scantex.views.camera import Camera
from scantex.views.planning import (
    Coverage,
    add_views_for_coverage,
    face_coverage,
    is_closed_object,
    orbit_cameras,
    plan_views,
    surface_cameras,
)
from scantex.views.raycast import RayCaster
from tests.conftest import grid_wall


def icosphere(subdivisions: int = 3) -> Scan:
    m = trimesh.creation.icosphere(subdivisions=subdivisions)
    return Scan(m.vertices, m.faces)


def room(extents=(4.0, 3.0, 2.5), subdivisions: int = 3) -> Scan:
    """A closed box with inward normals: a room scanned from inside, corner at the origin."""
    m = trimesh.creation.box(extents=extents)
    for _ in range(subdivisions):
        m = m.subdivide()
    return Scan(m.vertices + np.asarray(extents) / 2, m.faces[:, ::-1])


def facing(scan: Scan, direction) -> Scan:
    """``scan`` with its winding flipped, if need be, so that its normals point along ``direction``."""
    if (scan.face_normals @ np.asarray(direction, dtype=np.float64)).mean() > 0:
        return scan
    return Scan(scan.positions, scan.faces[:, ::-1])


def forward_hits(scan: Scan, cameras: list[Camera]):
    """Where each camera's optical axis first meets the surface: ``(face_id (N,), distance (N,))``."""
    caster = RayCaster(scan.positions, scan.faces)
    hits = caster.intersect(np.array([c.center for c in cameras]), np.array([c.forward for c in cameras]))
    return hits.face_id, hits.t


def coverage_reference(scan: Scan, cameras: list[Camera], max_angle_deg: float,
                       max_pixel_size: float) -> np.ndarray:
    """Views per face of a convex mesh seen whole by every camera, one face and camera at a time.

    On a convex mesh a face is unoccluded exactly when it faces the camera, so no ray casting is needed.
    """
    counts = np.zeros(scan.n_faces, dtype=np.int32)
    for f in range(scan.n_faces):
        centroid = scan.triangles[f].mean(axis=0)
        normal = scan.face_normals[f]
        for cam in cameras:
            to_cam = cam.center - centroid
            cos = float(normal @ to_cam) / float(np.linalg.norm(to_cam))
            depth = float((centroid - cam.center) @ cam.forward)
            pixel = depth / (0.5 * (cam.K[0, 0] + cam.K[1, 1])) / max(cos, 1e-6)
            if cos >= math.cos(math.radians(max_angle_deg)) and pixel <= max_pixel_size:
                counts[f] += 1
    return counts


# -- smoke and bad input ---------------------------------------------------------------------------


def test_plan_views_is_fast_on_a_tiny_mesh(wall):
    start = time.perf_counter()
    cameras = plan_views(wall, 12, width=128, height=96, fov_deg=60)
    face_coverage(wall, cameras)
    assert time.perf_counter() - start < 1.0
    assert len(cameras) == 12
    assert all(c.width == 128 and c.height == 96 for c in cameras)


@pytest.mark.parametrize("call", [
    lambda s: plan_views(s, 0),
    lambda s: plan_views(s, 4, mode="spiral"),
    lambda s: orbit_cameras(s, 4, fov_deg=180),
    lambda s: surface_cameras(s, 4, distance=-1.0),
    lambda s: face_coverage(s, [], max_angle_deg=120),
    lambda s: add_views_for_coverage(s, []),
])
def test_bad_arguments_raise_value_error(wall, call):
    with pytest.raises(ValueError):
        call(wall)


# -- orbit ----------------------------------------------------------------------------------------


def test_orbit_cameras_frame_the_whole_bounding_sphere():
    scan = icosphere(2)
    cameras = orbit_cameras(scan, 10, width=200, height=120, fov_deg=60)
    distances = [np.linalg.norm(c.center) for c in cameras]
    np.testing.assert_allclose(distances, distances[0])
    for cam in cameras:
        np.testing.assert_allclose(cam.forward, -cam.center / np.linalg.norm(cam.center), atol=1e-12)
        pix, depth = cam.project(scan.positions)
        assert (depth > 0).all()
        assert (pix[:, 0] >= 0).all() and (pix[:, 0] <= cam.width - 1).all()
        assert (pix[:, 1] >= 0).all() and (pix[:, 1] <= cam.height - 1).all()


def test_orbit_directions_spread_over_the_sphere():
    cameras = orbit_cameras(icosphere(1), 200)
    directions = np.array([c.center for c in cameras])
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    # a near-uniform spread: the mean is near zero and every octant holds about an eighth
    assert np.linalg.norm(directions.mean(axis=0)) < 0.02
    octant = (directions > 0) @ np.array([1, 2, 4])
    assert np.bincount(octant, minlength=8).min() >= 200 / 8 - 6


def test_hemisphere_cameras_stay_above_the_horizon():
    up = np.array([0.0, 1.0, 0.0])
    cameras = orbit_cameras(icosphere(1), 16, hemisphere=True, up=up)
    assert all(c.center @ up > 0 for c in cameras)


def test_orbit_cameras_see_every_face_of_an_icosphere():
    scan = icosphere(3)
    coverage = face_coverage(scan, orbit_cameras(scan, 20))
    assert coverage.views_per_face.min() >= 1
    assert coverage.fraction_covered(1) == 1.0


# -- surface --------------------------------------------------------------------------------------


@pytest.mark.parametrize("flip", [False, True])
def test_surface_cameras_stay_on_the_front_of_a_wall(flip):
    wall = grid_wall(n=16)
    if flip:
        wall = Scan(wall.positions, wall.faces[:, ::-1])
    cameras = surface_cameras(wall, 10, seed=3)
    assert len(cameras) == 10
    face_id, distance = forward_hits(wall, cameras)
    assert (face_id >= 0).all()  # each camera looks at the wall
    normals = wall.face_normals[face_id]
    targets = np.array([c.center + t * c.forward for c, t in zip(cameras, distance)])
    offsets = np.array([c.center for c in cameras]) - targets
    assert (np.einsum("ij,ij->i", offsets, normals) > 0).all()
    # and the tilt stays within its 20 degrees of the normal
    cos = np.einsum("ij,ij->i", offsets, normals) / np.linalg.norm(offsets, axis=1)
    assert (cos >= math.cos(math.radians(20)) - 1e-6).all()


def test_surface_targets_spread_over_the_wall():
    wall = grid_wall(n=16)
    cameras = surface_cameras(wall, 4, seed=1)
    face_id, distance = forward_hits(wall, cameras)
    targets = np.array([c.center + t * c.forward for c, t in zip(cameras, distance)])
    gaps = np.linalg.norm(targets[:, None] - targets[None], axis=-1) + np.eye(4) * 1e9
    assert gaps.min() > 0.6  # four points on a 2 m square, farthest-point spread


def test_surface_cameras_stay_inside_a_room():
    scan = room()
    cameras = surface_cameras(scan, 24, seed=0)
    assert len(cameras) == 24
    centers = np.array([c.center for c in cameras])
    assert (centers > 0).all() and (centers < np.array([4.0, 3.0, 2.5])).all()
    face_id, distance = forward_hits(scan, cameras)
    normals = scan.face_normals[face_id]
    targets = centers + distance[:, None] * np.array([c.forward for c in cameras])
    assert (np.einsum("ij,ij->i", centers - targets, normals) > 0).all()


def test_surface_cameras_see_their_target_past_an_obstacle():
    # a wall (normals +y) with a screen 0.3 m in front of its left half, facing the wall: a camera for
    # the wall behind the screen must stand between the two, not behind the screen
    wall = facing(grid_wall(n=16), (0, 1, 0))
    screen = facing(grid_wall(n=6, size=1.0), (0, -1, 0))
    positions = np.concatenate([wall.positions, screen.positions + [0.0, 0.3, 0.5]])
    scan = Scan(positions, np.concatenate([wall.faces, screen.faces + len(wall.positions)]))
    cameras = surface_cameras(scan, 24, seed=2)
    face_id, distance = forward_hits(scan, cameras)
    normals = scan.face_normals[face_id]
    centers = np.array([c.center for c in cameras])
    targets = centers + distance[:, None] * np.array([c.forward for c in cameras])
    # the first surface each camera sees is a front side, so nothing it looks through hides the target
    assert (np.einsum("ij,ij->i", centers - targets, normals) > 0).all()
    # wall points deeper in the screen's shadow than a 20 degree tilt can look past its edge
    inset = 0.3 * math.tan(math.radians(20)) + 0.02
    shadowed = ((face_id < wall.n_faces) & (targets[:, 0] > inset) & (targets[:, 0] < 1.0 - inset)
                & (targets[:, 2] > 0.5 + inset) & (targets[:, 2] < 1.5 - inset))
    assert shadowed.any()
    assert ((centers[shadowed, 1] > 0) & (centers[shadowed, 1] < 0.3)).all()


def test_plan_views_auto_picks_orbit_for_objects_and_surface_otherwise(wall):
    sphere = icosphere(2)
    assert is_closed_object(sphere)
    assert not is_closed_object(room())
    assert not is_closed_object(wall)
    # split at every face corner (as glTF splits at UV seams, or OpenMVS writes): welded, still closed
    assert is_closed_object(Scan(sphere.triangles.reshape(-1, 3), np.arange(3 * sphere.n_faces).reshape(-1, 3)))
    assert not is_closed_object(Scan(sphere.positions, sphere.faces[1:]))  # a face missing: a hole
    # two faces more on one edge (a fin): an edge of four faces is not a closed surface's
    fin = np.vstack([sphere.positions, [[3.0, 0.0, 0.0]]])
    a, b = sphere.faces[0, :2]
    assert not is_closed_object(Scan(fin, np.vstack([sphere.faces, [[a, b, len(fin) - 1], [b, a, len(fin) - 1]]])))
    orbit = plan_views(sphere, 8)
    np.testing.assert_allclose([np.linalg.norm(c.center) for c in orbit],
                               [np.linalg.norm(c.center) for c in plan_views(sphere, 8, mode="orbit")])
    inside = np.array([c.center for c in plan_views(room(), 8)])
    assert (inside > 0).all() and (inside < np.array([4.0, 3.0, 2.5])).all()


# -- coverage -------------------------------------------------------------------------------------


def test_fraction_covered_is_area_weighted():
    coverage = Coverage(np.array([0, 1, 2, 3]), np.array([1.0, 2.0, 3.0, 4.0]), 3)
    assert coverage.fraction_covered(1) == pytest.approx(0.9)
    assert coverage.fraction_covered(2) == pytest.approx(0.7)
    assert coverage.fraction_covered(4) == 0.0
    np.testing.assert_array_equal(coverage.under_covered(2), [0, 1])
    assert "3 views" in coverage.summary()


@pytest.mark.parametrize("max_angle_deg,max_pixel_size", [(70.0, 1.0), (40.0, 1.0), (70.0, 0.012)])
def test_face_coverage_matches_a_per_face_loop(max_angle_deg, max_pixel_size):
    scan = icosphere(2)
    cameras = orbit_cameras(scan, 6, width=256, height=256)
    coverage = face_coverage(scan, cameras, max_angle_deg=max_angle_deg, max_pixel_size=max_pixel_size)
    expected = coverage_reference(scan, cameras, max_angle_deg, max_pixel_size)
    np.testing.assert_array_equal(coverage.views_per_face, expected)
    assert coverage.n_views == 6


def test_face_coverage_counts_front_sides_only(wall):
    cameras = surface_cameras(wall, 6)
    flipped = Scan(wall.positions, wall.faces[:, ::-1])
    assert face_coverage(wall, cameras).fraction_covered(1) > 0.5
    assert face_coverage(flipped, cameras).fraction_covered(1) == 0.0


def test_face_coverage_respects_occlusion():
    # two parallel plates facing -y: the back one is hidden by the front one from straight on
    front = facing(grid_wall(n=8), (0, -1, 0))
    back_positions = front.positions + [0.0, 1.0, 0.0]
    scan = Scan(np.concatenate([front.positions, back_positions]),
                np.concatenate([front.faces, front.faces + len(front.positions)]))
    camera = Camera.look_at((1.0, -2.0, 1.0), (1.0, 0.0, 1.0), fov_deg=90, width=256, height=256)
    coverage = face_coverage(scan, [camera])
    F = front.n_faces
    assert (coverage.views_per_face[:F] == 1).all()
    assert (coverage.views_per_face[F:] == 0).all()


# -- adaptive views -------------------------------------------------------------------------------


def test_added_views_fill_what_a_hemisphere_orbit_leaves_unseen():
    scan = icosphere(3)
    cameras = orbit_cameras(scan, 8, width=128, height=128, hemisphere=True)
    caster = RayCaster(scan.positions, scan.faces)
    before = face_coverage(scan, cameras, caster=caster)
    assert before.fraction_covered(1) < 0.8  # the underside is never seen from above the horizon

    more = add_views_for_coverage(scan, cameras, min_views=2, max_new=12, caster=caster)
    after = face_coverage(scan, more, caster=caster)
    assert more[:8] == cameras
    assert 8 < len(more) <= 20
    assert after.fraction_covered(2) > before.fraction_covered(2) + 0.3
    assert after.fraction_covered(1) > 0.95
    # most new cameras go where the largest gap was: below the horizon
    below = sum(c.center[2] < 0 for c in more[8:])
    assert below > (len(more) - 8) / 2


def test_added_views_raise_coverage_inside_a_room():
    scan = room(subdivisions=4)
    cameras = surface_cameras(scan, 6, width=128, height=128)
    caster = RayCaster(scan.positions, scan.faces)
    before = face_coverage(scan, cameras, caster=caster)
    more = add_views_for_coverage(scan, cameras, min_views=2, max_new=12, caster=caster)
    after = face_coverage(scan, more, caster=caster)
    assert after.fraction_covered(1) > before.fraction_covered(1) + 0.2
    assert after.fraction_covered(2) > before.fraction_covered(2) + 0.1
    centers = np.array([c.center for c in more])
    assert (centers > 0).all() and (centers < np.array([4.0, 3.0, 2.5])).all()


def test_added_views_stop_when_nothing_is_missing():
    scan = icosphere(2)
    cameras = orbit_cameras(scan, 20)
    assert face_coverage(scan, cameras).views_per_face.min() >= 2
    assert add_views_for_coverage(scan, cameras, min_views=2) == cameras
