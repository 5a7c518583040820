"""The benchmark's classical baselines (bench/baselines.py) and one quick scene of the suite."""

from __future__ import annotations

import numpy as np
import pytest

from bench.baselines import backproject, bicubic, blend_seams, inpaint_holes
from scantex.atlas.seams import seam_visibility
from scantex.atlas.texelmap import texel_map
from scantex.synth import make_wall
from scantex.synth.degrade import Degradation
from scantex.views.camera import Camera


@pytest.fixture(scope="module")
def demo():
    return make_wall(grid=(24, 18), gt_texture_size=256, scan_texture_size=64, seed=2,
                     degradation=Degradation(hole_share=0.1, hole_clusters=2))


def same_geometry(a, b) -> bool:
    return a.positions is b.positions and a.faces is b.faces and np.array_equal(a.uvs, b.uvs)


def test_bicubic_doubles_the_atlas(demo):
    out = bicubic(demo.scan)
    assert same_geometry(out, demo.scan)
    assert out.materials[0].image.shape == (128, 128, 3)


def test_inpainting_fills_the_black_texels(demo):
    scan = demo.scan
    covered = texel_map(scan.triangle_uvs, 64, 64).mask
    black = scan.materials[0].image.max(axis=2) == 0
    assert (covered & black).sum() > 20
    out = inpaint_holes(scan)
    assert same_geometry(out, scan)
    assert not (covered & (out.materials[0].image.max(axis=2) <= 6)).any()
    # texels far from any hole are left alone
    from scipy.ndimage import binary_dilation

    far = covered & ~binary_dilation(black, iterations=3)
    assert np.array_equal(out.materials[0].image[far], scan.materials[0].image[far])


def test_seam_blending_levels_seams(demo):
    filled = inpaint_holes(demo.scan)  # black holes at a seam are the inpainting's job
    out = blend_seams(filled)
    assert same_geometry(out, demo.scan)
    assert seam_visibility(out) < 0.5 * seam_visibility(filled)


def test_backprojection_reproduces_a_consistent_texture(wall):
    """On a seamless single-chart wall, averaging its own renders back gives its texture again."""
    cams = [Camera.look_at((x, -2.2, 1.0), (1.0, 0.0, 1.0), width=160, height=120) for x in (0.6, 1.0, 1.4)]
    out = backproject(wall, cams, factor=1)
    assert same_geometry(out, wall)
    a = out.materials[0].image.astype(float)
    b = wall.materials[0].image.astype(float)
    inner = (slice(16, -16), slice(16, -16))  # away from the wall's silhouette
    assert np.abs(a[inner] - b[inner]).mean() < 12  # a resampled checker: edges blur, cells keep their colour
    assert np.median(np.abs(a[inner] - b[inner])) < 2


def test_one_quick_scene_of_the_suite():
    from bench.bench_suite import quick_settings, run_scene, table

    settings = quick_settings()
    rows = run_scene(settings.scenes[0], settings, log=lambda *_: None)
    assert [r["method"] for r in rows] == ["input", "bicubic ×2", "inpaint + seam blend",
                                           "multi-view back-projection", "scantex quick"]
    by = {r["method"]: r for r in rows}
    assert by["inpaint + seam blend"]["hole_psnr"] > by["input"]["hole_psnr"] + 5
    assert "| wall | scantex quick | 64×64 |" in table(rows)  # the input's texels at its size
