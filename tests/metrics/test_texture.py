"""Texture metrics: atlas-space scores, texel density, coverage, render scores."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from scantex.metrics.image import psnr
from scantex.metrics.texture import atlas_scores, chart_texel_density, coverage, kept_faces, render_reference, \
    render_scores, texel_density, texture_summary
from scantex.scan import Material
from scantex.views.camera import Camera


def with_image(scan, image):
    return scan.replace(materials=(Material("m", image),))


def test_kept_faces(wall, cube):
    assert kept_faces(wall, with_image(wall, wall.materials[0].image[::2, ::2])).all()
    uvs = wall.uvs.copy()
    uvs[0] += 0.01
    kept = kept_faces(wall, wall.replace(uvs=uvs))
    assert np.array_equal(~kept, (wall.face_uvs == 0).any(axis=1)) and kept.any()
    assert kept_faces(wall, cube) is None


def charted_apart(scan, faces):
    """``scan`` with ``faces`` given UVs of their own in a corner, as a kept layout charts the faces its input
    gave no texture space."""
    uvs = np.concatenate([scan.uvs, [[0.0, 0.0], [0.01, 0.0], [0.0, 0.01]]])
    face_uvs = scan.face_uvs.copy()
    face_uvs[faces] = len(scan.uvs) + np.arange(3)
    return scan.replace(uvs=uvs, face_uvs=face_uvs)


def test_atlas_scores_over_the_faces_a_kept_layout_keeps(wall):
    """A kept layout gives the few faces its input left without texture space charts of their own: the atlas
    score was skipped ("the UV layouts differ") for 10 such faces of the bathroom's 132,317."""
    moved = charted_apart(wall, [0, 5])
    s = atlas_scores(moved, wall)
    assert s["psnr"] == float("inf") and (s["faces"], s["faces_total"]) == (wall.n_faces - 2, wall.n_faces)
    assert 0 < s["texels"] <= 128 * 128
    # a face of no area (its corners on one line) shows none of its texels: not scored
    flat = dataclasses.replace(wall, faces=np.vstack([wall.faces, [[0, 0, 1]]]),
                               face_uvs=np.vstack([wall.face_uvs, [[0, 1, 2]]]),
                               face_materials=np.append(wall.face_materials, 0))
    s = atlas_scores(flat, flat)
    assert (s["faces"], s["faces_total"]) == (wall.n_faces, wall.n_faces + 1)


def test_atlas_scores_identical_and_mismatched(wall, cube):
    s = atlas_scores(wall, wall)
    assert s["psnr"] == float("inf") and s["ssim"] == pytest.approx(1.0) and s["texels"] == 128 * 128
    with pytest.raises(ValueError, match="same UV layout"):
        atlas_scores(wall, cube)


def test_atlas_scores_against_a_direct_computation(wall):
    rng = np.random.default_rng(0)
    truth = wall.materials[0].image
    noisy = np.clip(truth.astype(int) + rng.integers(-20, 21, truth.shape), 0, 255).astype(np.uint8)
    s = atlas_scores(with_image(wall, noisy), wall)
    # the grid wall's single chart covers the whole atlas: every texel counts
    expected = psnr(noisy / 255.0, truth / 255.0)
    assert s["psnr"] == pytest.approx(expected, abs=1e-6)
    assert 0 < s["ssim"] < 1


def test_atlas_scores_read_a_smaller_atlas_bilinearly(wall):
    """An atlas at half the resolution is judged as the renderer would show it, not rejected."""
    truth = wall.materials[0].image
    half = truth.reshape(64, 2, 64, 2, 3).mean(axis=(1, 3)).astype(np.uint8)
    s = atlas_scores(with_image(wall, half), wall)
    assert 10 < s["psnr"] < 40 and s["texels"] == 128 * 128


def test_texel_density_of_a_two_metre_wall(wall):
    # one chart over the whole 128 x 128 atlas, about 200 cm x 200 cm of wall (plus a little relief)
    d = texel_density(wall)
    assert d["charts"] == 1
    assert d["px_per_cm_mean"] == pytest.approx(128 / 200, rel=2e-3)
    density, area = chart_texel_density(wall, unit_m=0.01)  # the same file read as centimetres
    assert density[0] == pytest.approx(128 / 2, rel=2e-3) and area[0] == pytest.approx(4e-4, rel=2e-3)


def test_faces_of_no_area_count_for_neither_density_nor_holes(wall):
    """The bathroom's 3,869 faces of no area, black in its atlas, each a chart of its own, made its texel density
    median 0 px/cm and its hole count 3,918 where 49 holes show."""
    image = wall.materials[0].image.copy()
    image[:40, :40] = 0
    holed = with_image(wall, image)
    n = len(wall.uvs)
    flat = dataclasses.replace(holed, faces=np.vstack([wall.faces, [[0, 0, 1]] * 3]),
                               uvs=np.vstack([wall.uvs, [[0.01, 0.99], [0.02, 0.99], [0.01, 0.98]]]),
                               face_uvs=np.vstack([wall.face_uvs, [[n, n + 1, n + 2]] * 3]),
                               face_materials=np.append(wall.face_materials, [0] * 3))
    d, before = texel_density(flat), texel_density(holed)
    assert d["charts"] == 2 and d["px_per_cm_median"] == d["px_per_cm_min"] == pytest.approx(128 / 200, rel=2e-3)
    assert coverage(flat)["hole_faces"] == coverage(holed)["hole_faces"] > 0 and before["charts"] == 1


def test_coverage_sees_black_holes(wall):
    full = coverage(wall)
    assert full["atlas_used"] == pytest.approx(1.0) and full["textured_area_share"] == 1.0
    image = wall.materials[0].image.copy()
    image[:40, :40] = 0  # the top-left corner of the atlas: the top-left of the wall
    holed = coverage(with_image(wall, image))
    assert 0.8 < holed["textured_area_share"] < 1.0 and holed["hole_faces"] > 0


def test_texture_summary_is_json_ready(cube):
    import json

    s = texture_summary(cube)
    assert s["charts"] == 6 and s["seam_edges"] > 0
    json.dumps(s)


def test_render_scores(wall):
    cam = Camera.look_at((1.0, -2.5, 1.0), (1.0, 0.0, 1.0), width=64, height=48)
    darker = with_image(wall, (wall.materials[0].image * 0.8).astype(np.uint8))
    s = render_scores(render_reference(wall), {"same": wall, "darker": darker}, [cam])
    assert s["same"]["psnr"] == float("inf") and s["same"]["views"] == 1
    assert 10 < s["darker"]["psnr"] < 30 and s["darker"]["ssim"] < 1


def test_render_scores_pool_the_views_errors(wall):
    # b identical to the reference in one view and darker in the other: the views' PSNRs are inf and ~20 dB,
    # whose plain mean said "inf (identical)" for textures that differ
    near = Camera.look_at((1.0, -2.5, 1.0), (1.0, 0.0, 1.0), width=64, height=48)
    far = Camera.look_at((0.5, -3.0, 1.0), (0.5, 0.0, 1.0), width=64, height=48)
    darker = with_image(wall, (wall.materials[0].image * 0.8).astype(np.uint8))
    same, changed = render_reference(wall), render_reference(darker)
    s = render_scores(lambda cam: same(cam) if cam is near else changed(cam), {"b": wall}, [near, far])["b"]
    errors = render_scores(changed, {"b": wall}, [far])["b"]["mse"]
    assert s["psnr"] == pytest.approx(10 * np.log10(2 / errors))
    assert s["psnr_mean_of_views"] == pytest.approx((100 + 10 * np.log10(1 / errors)) / 2)
