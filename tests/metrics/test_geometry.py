"""Geometry metrics: exact zeros for kept geometry, exact distances when a vertex moves, volume."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import trimesh

from scantex.metrics.geometry import ClosestSurface, geometry_identity, geometry_metrics, \
    point_triangle_distance, point_triangle_distance_reference, sample_surface, surface_distances, volume_info
from scantex.scan import Scan
from tests.conftest import grid_wall, textured_cube


def flat_wall(n: int = 9, size: float = 2.0) -> Scan:
    """An exactly flat ``n x n`` grid in the plane y = 0."""
    u, v = np.meshgrid(np.linspace(0, size, n), np.linspace(0, size, n))
    positions = np.stack([u.ravel(), np.zeros(n * n), v.ravel()], axis=1)
    idx = np.arange(n * n).reshape(n, n)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, 1:].ravel(), idx[1:, :-1].ravel()
    return Scan(positions, np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)]))


def moved(scan: Scan, vertex: int, offset) -> Scan:
    positions = scan.positions.copy()
    positions[vertex] += offset
    return dataclasses.replace(scan, positions=positions)


def test_identical_geometry_is_exactly_zero(wall):
    """Identical arrays are the same surface: every distance is 0 without sampling (an enhance run's output
    shares its input's arrays; sampling them measured a surface against itself, 8 s on 800,000 faces), and
    sampling gives the same."""
    retextured = wall.replace(materials=wall.materials)  # same arrays, another Scan object
    m = geometry_metrics(wall, retextured, samples=5000)
    sampled = surface_distances(wall, retextured, samples=5000)
    for d in (m["distance"], sampled):
        for key in ("hausdorff", "hausdorff_a_to_b", "hausdorff_b_to_a", "mean", "mean_a_to_b", "mean_b_to_a"):
            assert d[key] == 0.0, key
        assert d.keys() >= sampled.keys() and d["diagonal"] == sampled["diagonal"]
    assert m["distance"]["samples"] == 0 and "not sampled" in m["distance"]["note"]
    assert m["arrays_identical"] and m["triangles_identical"]
    assert m["max_vertex_displacement"] == 0.0


def test_reordered_faces_are_still_zero(wall):
    """Distances compare surfaces, not files: the same triangles in another order and rotation are 0."""
    order = np.random.default_rng(0).permutation(wall.n_faces)
    faces = np.roll(wall.faces[order], 1, axis=1)
    other = Scan(wall.positions, faces)
    d = surface_distances(wall, other, samples=5000)
    assert d["hausdorff"] == 0.0 and d["mean"] == 0.0
    assert not geometry_identity(wall, other)["arrays_identical"]


def test_moving_one_vertex_is_measured_exactly():
    plane = flat_wall()
    centre = 40  # the middle of the 9 x 9 grid
    delta = 0.05
    bumped = moved(plane, centre, (0.0, delta, 0.0))
    d = surface_distances(plane, bumped, samples=20000)
    # the bumped vertex is delta off the plane, and nothing is farther
    assert d["hausdorff_b_to_a"] == pytest.approx(delta, rel=1e-12)
    assert d["hausdorff"] == pytest.approx(delta, rel=1e-12)
    assert 0 < d["hausdorff_a_to_b"] < delta
    assert 0 < d["mean_a_to_b"] < delta and 0 < d["mean_b_to_a"] < delta
    m = geometry_metrics(plane, bumped, samples=1000)
    assert not m["arrays_identical"] and m["max_vertex_displacement"] == pytest.approx(delta)


def test_tiny_move_is_not_rounded_away():
    plane = flat_wall()
    bumped = moved(plane, 40, (0.0, 1e-9, 0.0))
    assert surface_distances(plane, bumped, samples=1000)["hausdorff"] == pytest.approx(1e-9, rel=1e-6)


def test_point_triangle_distance_matches_the_reference():
    rng = np.random.default_rng(1)
    triangles = rng.normal(size=(400, 3, 3))
    points = rng.normal(size=(400, 3)) * 2
    fast = point_triangle_distance(points, triangles)
    slow = [point_triangle_distance_reference(p, t) for p, t in zip(points, triangles)]
    np.testing.assert_allclose(fast, slow, rtol=1e-9, atol=1e-12)


def test_closest_surface_is_exact_against_brute_force():
    """A fine grid plus one huge face (the 'big face' path) and far-away points."""
    wall = grid_wall(n=15)
    big = np.array([[-5.0, 1.0, -5.0], [9.0, 1.5, -5.0], [-5.0, 0.5, 9.0]])
    positions = np.concatenate([wall.positions, big])
    faces = np.concatenate([wall.faces, [[len(wall.positions), len(wall.positions) + 1, len(wall.positions) + 2]]])
    rng = np.random.default_rng(2)
    points = np.concatenate([rng.uniform(-1, 3, size=(150, 3)), rng.normal(0, 20, size=(30, 3))])
    got = ClosestSurface(positions, faces).distance(points)
    triangles = positions[faces]
    expected = [min(point_triangle_distance_reference(p, t) for t in triangles) for p in points]
    np.testing.assert_allclose(got, expected, rtol=1e-9, atol=1e-12)


def test_samples_lie_on_the_surface(cube):
    points, face = sample_surface(cube, 2000, seed=0)
    assert points.shape == (2000, 3) and face.shape == (2000,)
    d = ClosestSurface(cube.positions, cube.faces).distance(points)
    assert d.max() < 1e-12
    # area-weighted: each of the cube's six equal sides gets about a sixth
    shares = np.bincount(face // 2, minlength=6) / 2000
    assert np.all(np.abs(shares - 1 / 6) < 0.04)


def test_volume_of_a_closed_mesh_with_split_vertices():
    box = trimesh.creation.box(extents=(1.0, 2.0, 3.0))
    # every face with its own three corners, as files split vertices at UV seams
    split = Scan(box.vertices[box.faces].reshape(-1, 3), np.arange(3 * len(box.faces)).reshape(-1, 3))
    info = volume_info(split)
    assert info["watertight"] and info["boundary_edges"] == 0
    assert info["volume"] == pytest.approx(6.0)
    assert info["area"] == pytest.approx(22.0)


def test_volume_of_a_closed_mesh_wound_both_ways():
    # a file whose faces are not all wound the same way (one flipped triangle, half a sphere's faces): their
    # signed volumes cancel, and the volume was reported as 0.5 for the unit cube
    box = trimesh.creation.box(extents=(1.0, 1.0, 1.0))
    faces = box.faces.copy()
    faces[0] = faces[0, ::-1]
    assert volume_info(Scan(box.vertices, faces))["volume"] == pytest.approx(1.0)
    sphere = trimesh.creation.icosphere(subdivisions=2)
    faces = sphere.faces.copy()
    faces[::2] = faces[::2, ::-1]
    assert volume_info(Scan(sphere.vertices, faces))["volume"] == pytest.approx(sphere.volume)
    assert np.array_equal(faces[::2], sphere.faces[::2, ::-1])  # the scan's own faces are not touched


def test_open_mesh_has_no_volume_and_says_why():
    info = volume_info(flat_wall(n=5))
    assert info["volume"] is None and not info["watertight"]
    assert info["boundary_edges"] == 16
    assert "open surface" in info["note"]


def test_counts_are_file_records_and_distinct_positions():
    cube = textured_cube()
    doubled = Scan(np.concatenate([cube.positions, cube.positions]), cube.faces)
    g = geometry_identity(cube, doubled)
    assert g["vertices"] == [8, 16] and g["distinct_positions"] == [8, 8] and g["faces"] == [12, 12]
    assert g["triangles_identical"] and not g["arrays_identical"]
    assert surface_distances(cube, doubled, samples=500)["hausdorff"] == 0.0
