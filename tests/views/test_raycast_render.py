"""Cameras, Embree G-buffers and rendering, against slow references."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from scantex.views.camera import Camera
from scantex.views.raycast import RayCaster, cast_gbuffer, interpolate
from scantex.views.render import render, render_gbuffer, sample_texture, sample_texture_reference, shade_lit
from tests.conftest import grid_wall


def test_look_at_points_the_camera_at_the_target():
    cam = Camera.look_at([1.0, -4.0, 2.0], [0.5, 0.0, 1.0], width=64, height=48, fov_deg=50)
    assert np.allclose(cam.center, [1.0, -4.0, 2.0])
    pix, z = cam.project(np.array([[0.5, 0.0, 1.0]]))
    assert np.allclose(pix, [[31.5, 23.5]]) and z[0] > 0
    R = cam.R
    assert np.allclose(R @ R.T, np.eye(3)) and np.isclose(np.linalg.det(R), 1.0)


def test_pixel_rays_reproject_to_their_pixels():
    cam = Camera.look_at([0, -3, 0.5], [0, 0, 0], width=20, height=10)
    o, d = cam.pixel_rays()
    pix, z = cam.project(o + 2.5 * d)
    ys, xs = np.mgrid[0:10, 0:20]
    assert np.allclose(pix, np.stack([xs.ravel(), ys.ravel()], 1), atol=1e-3)
    assert np.allclose(z, 2.5, atol=1e-5)  # directions have unit camera-z: t is depth


def test_rays_through_pixels_and_their_cosines_are_the_pixel_rays():
    cam = Camera.look_at([0, -3, 0.5], [0, 0, 0], width=20, height=10)
    _, d = cam.pixel_rays()
    ys, xs = np.divmod(np.arange(200), 20)
    assert np.array_equal(cam.rays_through(xs, ys), d)  # bit for bit
    normals = np.random.default_rng(0).normal(size=(200, 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    normals[:5] = 0
    unit = d / np.linalg.norm(d, axis=1, keepdims=True)
    expected = np.abs(np.einsum("ij,ij->i", unit, normals)).reshape(10, 20)
    np.testing.assert_allclose(cam.ray_cosines(normals), expected, atol=1e-6)
    assert not cam.ray_cosines(normals)[0, :5].any()


def test_scaled_camera_keeps_pixel_centres_consistent():
    cam = Camera.look_at([0, -3, 0], [0, 0, 0], width=16, height=12)
    big = cam.scaled(2)
    X = np.array([[0.3, 0.0, -0.2]])
    p1, _ = cam.project(X)
    p2, _ = big.project(X)
    assert np.allclose((p2 + 0.5) / 2 - 0.5, p1)


def test_camera_dict_roundtrip():
    cam = Camera.look_at([1, 2, 3], [0, 0, 0], width=7, height=5)
    back = Camera.from_dict(cam.to_dict())
    assert np.array_equal(back.K, cam.K) and np.array_equal(back.world_to_camera, cam.world_to_camera)


def first_hits_brute_force(tri, origins, directions):
    """Möller–Trumbore against every triangle: the obviously correct (slow) twin of Embree."""
    out = np.full(len(origins), -1)
    e1, e2 = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    for i, (o, d) in enumerate(zip(origins, directions)):
        p = np.cross(d, e2)
        det = np.einsum("fk,fk->f", e1, p)
        with np.errstate(divide="ignore", invalid="ignore"):
            s = o - tri[:, 0]
            u = np.einsum("fk,fk->f", s, p) / det
            q = np.cross(s, e1)
            v = (q @ d) / det
            t = np.einsum("fk,fk->f", e2, q) / det
        ok = (np.abs(det) > 1e-12) & (u >= 0) & (v >= 0) & (u + v <= 1) & (t > 0)
        if ok.any():
            out[i] = np.flatnonzero(ok)[np.argmin(t[ok])]
    return out


def test_embree_hits_match_reference_intersector():
    mesh = trimesh.creation.icosphere(subdivisions=3)
    rng = np.random.default_rng(0)
    origins = rng.normal(size=(500, 3)) * 3
    directions = -origins + rng.normal(scale=0.5, size=(500, 3))
    hits = RayCaster(mesh.vertices, mesh.faces).intersect(origins, directions)
    ref = first_hits_brute_force(mesh.vertices[mesh.faces], origins, directions)
    agree = hits.face_id == ref
    assert agree.mean() > 0.99  # ties on shared edges may pick either face
    hit = hits.face_id >= 0
    # the barycentric point and the ray point coincide
    p_bary = interpolate(hits.face_id[hit], hits.bary[hit], mesh.vertices[mesh.faces])
    p_ray = origins[hit] + hits.t[hit, None] * directions[hit]
    assert np.abs(p_bary - p_ray).max() < 1e-4
    assert np.isinf(hits.t[~hit]).all()


def test_raycaster_keeps_precision_far_from_origin():
    mesh = trimesh.creation.box()
    far = np.array([500_000.0, 4_000_000.0, 100.0])  # geo-referenced coordinates
    caster = RayCaster(mesh.vertices + far, mesh.faces)
    hits = caster.intersect(np.array([far + [0, 0, 5.0]]), np.array([[0, 0, -1.0]]))
    assert hits.face_id[0] >= 0 and abs(hits.t[0] - 4.5) < 1e-4


def test_gbuffer_of_a_frontal_wall():
    wall = grid_wall(n=8, size=2.0)
    cam = Camera.look_at([1.0, -3.0, 1.0], [1.0, 0.0, 1.0], width=40, height=40, fov_deg=30)
    g = cast_gbuffer(RayCaster(wall.positions, wall.faces), cam, wall.face_normals)
    assert g.mask.all()  # the wall fills a 30° view from 3 m
    assert np.allclose(g.depth, 3.0, atol=0.02)
    assert (g.normal[..., 1] < -0.99).all()  # normals face the camera (-y)
    pts = g.points(wall.positions, wall.faces)
    pix, z = cam.project(pts.reshape(-1, 3))
    ys, xs = np.mgrid[0:40, 0:40]
    assert np.allclose(pix, np.stack([xs.ravel(), ys.ravel()], 1), atol=1e-3)


def test_sample_texture_bilinear_and_wrap():
    img = np.array([[[0], [100]], [[200], [255]]], dtype=np.uint8)  # 2x2, row 0 = top (v = 1)
    # texel centres: (u, v) = (0.25, 0.75) is the top-left texel
    got = sample_texture(img, np.array([[0.25, 0.75], [0.75, 0.25], [0.5, 0.75], [1.25, 0.75]]))[:, 0] * 255
    assert np.allclose(got, [0, 255, 50, 0], atol=1e-3)


@pytest.mark.parametrize("path", ["compiled", "numpy"])
def test_sample_texture_equals_its_reference(path, monkeypatch):
    from scantex import jit

    if path == "numpy":  # where numba is missing
        monkeypatch.setattr(jit, "compiled", lambda function: None)
    rng = np.random.default_rng(3)
    uv = np.concatenate([rng.uniform(-1.5, 2.5, (5000, 2)),  # repeats outside [0, 1]
                         (rng.integers(0, 7, (500, 2)) + 0.5) / 7,  # texel centres
                         [[0.0, 0.0], [1.0, 1.0], [0.0, 1.0], [1.0, 0.0]]])  # the atlas's corners
    for image in (rng.integers(0, 256, (7, 5, 3), dtype=np.uint8), rng.integers(0, 256, (4, 9, 4), dtype=np.uint8),
                  rng.random((6, 6, 3), dtype=np.float32), rng.integers(0, 256, (1, 1, 3), dtype=np.uint8),
                  rng.random((5, 3, 2)), rng.integers(0, 256, (4, 6), dtype=np.uint8)):
        for coordinates in (uv, uv.astype(np.float32)):
            assert np.array_equal(sample_texture(image, coordinates), sample_texture_reference(image, coordinates))


def test_unlit_render_shows_the_texture():
    wall = grid_wall(n=6, size=2.0)
    cam = Camera.look_at([1.0, -3.0, 1.0], [1.0, 0.0, 1.0], width=32, height=32, fov_deg=30)
    caster = RayCaster(wall.positions, wall.faces)
    g = cast_gbuffer(caster, cam, wall.face_normals)
    rgb = render_gbuffer(wall, g)
    # reference: UV of each pixel's point by plain interpolation, then the texture lookup
    uv = interpolate(g.face_id, g.bary, wall.triangle_uvs)
    ref = sample_texture(wall.materials[0].image, uv.reshape(-1, 2)).reshape(32, 32, 3)
    assert np.abs(rgb - ref).max() < 1e-6
    lit = shade_lit(rgb, g, cam)
    assert (lit <= rgb + 1e-6).all() and (lit >= 0.35 * rgb - 1e-6).all()
    img, alpha = render(wall, cam, caster, supersample=2)
    assert img.shape == (32, 32, 3) and np.allclose(alpha, 1.0)


def test_vertex_colour_render():
    mesh = trimesh.creation.icosphere(subdivisions=2)
    from scantex.scan import Scan

    colors = np.tile(np.array([[255, 0, 0, 255]], np.uint8), (len(mesh.vertices), 1))
    scan = Scan(mesh.vertices, mesh.faces, vertex_colors=colors)
    img, alpha = render(scan, Camera.look_at([0, -4, 0], [0, 0, 0], width=16, height=16))
    seen = alpha > 0
    assert seen.any() and np.allclose(img[seen], [1, 0, 0], atol=1e-5)


@pytest.mark.parametrize("path", ["compiled", "embree"])
@pytest.mark.parametrize("size", [(64, 48), (33, 17)])
def test_texel_map_matches_reference(size, path, monkeypatch):
    """The compiled scan-conversion, and Embree where numba is missing, against the reference rasteriser."""
    from scantex import jit
    from scantex.atlas.texelmap import texel_map, texel_map_reference

    if path == "embree":
        monkeypatch.setattr(jit, "compiled", lambda function: None)
    wall = grid_wall(n=9)
    tri = wall.triangle_uvs * 0.9 + 0.05
    fast = texel_map(tri, *size)
    slow = texel_map_reference(tri, *size)
    both = fast.mask & slow.mask
    assert (fast.mask != slow.mask).sum() <= 0.01 * fast.mask.sum()  # edge texels may differ
    corners = np.concatenate([wall.triangles, np.ones((wall.n_faces, 3, 1))], axis=-1)
    p_fast = np.zeros(size[::-1] + (4,))
    p_fast[fast.mask] = fast.points(corners)
    p_slow = np.zeros(size[::-1] + (4,))
    p_slow[slow.mask] = slow.points(corners)
    assert np.abs(p_fast[both] - p_slow[both]).max() < 1e-5  # the same surface point


def test_the_compiled_interpolation_is_numpys_bit_for_bit():
    """Corner values interpolated at hits, compiled, against the numpy twin: misses read 0, shapes kept, float and
    integer corner values; a face out of range is an error, not a read outside the array."""
    from scantex.views.raycast import interpolate_numpy

    rng = np.random.default_rng(6)
    face_id = rng.integers(-1, 50, (7, 9)).astype(np.int32)
    bary = (rng.random((7, 9, 2)) * 0.5).astype(np.float32)
    for corners in (rng.random((50, 3, 3)), rng.random((50, 3, 2)).astype(np.float32),
                    rng.integers(0, 256, (50, 3, 4), dtype=np.uint8)):
        got = interpolate(face_id, bary, corners)
        assert got.shape == (7, 9, corners.shape[2]) and got.dtype == np.float64
        assert np.array_equal(got, interpolate_numpy(face_id, bary, corners))
        assert not got[face_id < 0].any()
    with pytest.raises(IndexError):
        interpolate(np.array([50], np.int32), np.zeros((1, 2), np.float32), rng.random((50, 3, 3)))


@pytest.mark.parametrize("numba", [True, False])
def test_interpolation_through_corner_indices_is_interpolation_of_the_gathered_corners(numba, monkeypatch):
    """``interpolate_indexed`` (how :func:`hit_uvs` reads a scan's UVs through its ``face_uvs``): bit for bit the
    interpolation of ``values[corners]``, misses 0, shapes kept, compiled and in numpy alike."""
    from scantex import jit
    from scantex.views.raycast import interpolate_indexed

    if not numba:
        monkeypatch.setattr(jit, "compiled", lambda function: None)
    rng = np.random.default_rng(7)
    face_id = rng.integers(-1, 40, (6, 11)).astype(np.int32)
    bary = (rng.random((6, 11, 2)) * 0.5).astype(np.float32)
    corners = rng.integers(0, 70, (40, 3))
    for values in (rng.random((70, 2)), rng.random((70, 2)).astype(np.float32), rng.integers(0, 9, (70, 3))):
        got = interpolate_indexed(face_id, bary, corners, values)
        assert got.shape == (6, 11, values.shape[1]) and got.dtype == np.float64
        assert np.array_equal(got, interpolate(face_id, bary, values[corners]))
        assert not got[face_id < 0].any()
    if numba:
        with pytest.raises(IndexError):
            interpolate_indexed(np.array([40], np.int32), np.zeros((1, 2), np.float32), corners, rng.random((70, 2)))
