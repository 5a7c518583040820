"""Cross-view correspondences and back-projection on a textured cube."""

from __future__ import annotations

import numpy as np
import pytest

from scantex.atlas.bake import bake
from scantex.refine.correspond import correspond, partners
from scantex.refine.fusion import ViewResiduals, edge_confidence, fuse_views, occlusion_edges
from scantex.views.camera import Camera
from scantex.views.planning import plan_views
from scantex.views.raycast import RayCaster, cast_gbuffer
from scantex.views.render import render_gbuffer, shade_hits
from tests.conftest import textured_cube


@pytest.fixture(scope="module")
def cube():
    return textured_cube(materials=1)


def test_a_point_seen_in_two_views_maps_to_its_pixel_and_occluded_points_are_excluded(cube):
    caster = RayCaster(cube.positions, cube.faces)
    a = Camera.look_at((-1.5, -1.2, 1.6), (0.5, 0.5, 0.5), width=96, height=80)
    b = Camera.look_at((0.5, -2.0, 1.8), (0.5, 0.5, 0.5), width=96, height=80)
    ga, gb = cast_gbuffer(caster, a, cube.face_normals), cast_gbuffer(caster, b, cube.face_normals)
    pixels, mask = correspond(a, ga.depth, ga.mask, b, gb.depth, gb.mask)

    # reference, independent of the depth-buffer test: a ray from B's centre reaches the point first
    points = ga.points(cube.positions, cube.faces)[ga.mask]
    hits = caster.intersect(np.broadcast_to(b.center, points.shape), points - b.center)
    pix_ref, _ = b.project(points)
    inside = (pix_ref[:, 0] > -0.5) & (pix_ref[:, 0] < 95.5) & (pix_ref[:, 1] > -0.5) & (pix_ref[:, 1] < 79.5)
    seen_ref = inside & (np.abs(hits.t - 1) < 1e-4)
    assert (~seen_ref).sum() > 100 and seen_ref.sum() > 500  # both cases occur: B sees some, not all
    agree = mask[ga.mask] == seen_ref
    assert agree.mean() > 0.95  # only pixels at silhouettes and cube edges may differ
    # the B pixel of a corresponding point is that point's projection, and B's G-buffer sees it there
    both = mask[ga.mask] & seen_ref
    assert np.abs(pixels[ga.mask][both] - pix_ref[both]).max() < 1e-3
    px = np.rint(pixels[ga.mask][both]).astype(int)
    seen_points = gb.points(cube.positions, cube.faces)[px[:, 1], px[:, 0]]
    footprint = 2 * np.tan(np.radians(30)) * 3.0 / 96
    assert np.median(np.linalg.norm(seen_points - points[both], axis=1)) < footprint


def test_partners_pick_the_most_overlapping_view():
    face_id = np.array([[[0, 1, 2]], [[0, 1, 5]], [[7, 8, 9]]])
    assert partners(face_id, face_id >= 0, 10).tolist() == [1, 0, 0]


def rendered_views(scan, n=8, size=128):
    caster = RayCaster(scan.positions, scan.faces)
    cameras = plan_views(scan, n, mode="orbit", width=size, height=size, seed=0, caster=caster)
    images, depths, conf = [], [], []
    for cam in cameras:
        g = cast_gbuffer(caster, cam, scan.face_normals)
        images.append(render_gbuffer(scan, g))
        depths.append(np.where(g.mask, g.depth, np.inf).astype(np.float32))
        conf.append(edge_confidence(occlusion_edges(g.depth, g.mask), ramp=2))
    return tuple(cameras), np.stack(images), np.stack(depths), np.stack(conf)


def test_views_of_the_scan_fused_back_reproduce_its_texture(cube):
    cameras, images, depths, conf = rendered_views(cube)
    truth = bake(cube, lambda p, n, f, b: shade_hits(cube, f, b), size=64)[0].astype(np.float32) / 255

    def zero(p, n, f, b):
        return np.zeros((len(p), 3), np.float32)

    # base 0 and the renders as residuals: the fusion must give back the texture the views show
    fused = bake(cube, fuse_views(ViewResiduals(cameras, images, depths, conf), zero), size=64)[0]
    error = np.abs(fused.astype(np.float32) / 255 - truth).mean(axis=-1)
    assert np.median(error) < 0.02 and error.mean() < 0.06


def test_unchanged_views_give_back_the_base_exactly_and_unseen_texels_keep_it(cube):
    cameras, images, depths, conf = rendered_views(cube, n=2)

    def base(p, n, f, b):
        return shade_hits(cube, f, b)

    colour = fuse_views(ViewResiduals(cameras, np.zeros_like(images), depths, conf), base)
    assert np.array_equal(bake(cube, colour, size=64)[0], bake(cube, base, size=64)[0])
    # a constant residual of -0.1 shows only where some view sees the surface
    plus = fuse_views(ViewResiduals(cameras, np.full_like(images, -0.1), depths, conf), base)
    pts = cube.triangles.mean(axis=1)
    faces = np.arange(cube.n_faces)
    bary = np.full((cube.n_faces, 2), 1 / 3, np.float32)
    diff = plus(pts, cube.face_normals, faces, bary) - base(pts, cube.face_normals, faces, bary)
    seen = np.abs(diff + 0.1).max(axis=1) < 1e-5
    unseen = np.abs(diff).max(axis=1) < 1e-6
    assert seen.any() and unseen.any() and (seen | unseen).all()
