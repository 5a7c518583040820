"""Faces an input layout leaves no texture space: charted into free atlas space, the rest kept."""

from __future__ import annotations

import numpy as np

from scantex.atlas.holes import untextured_faces, unmapped_faces
from scantex.atlas.texelmap import covered_texels
from scantex.pipeline.config import preset
from scantex.pipeline.enhance import enhance
from scantex.scan import Material
from scantex.uv import plan_uvs
from scantex.views.render import shade_hits, to_uint8
from tests.conftest import grid_wall


def collapsed_wall():
    """A 2 m wall on the left half of a 256² atlas, a smooth green-to-blue texture; the faces of a 3 x 3 block of
    cells in its middle have every UV corner on one point (as OpenMVS leaves the faces no view saw), and that
    point's texel is black."""
    wall = grid_wall(n=21, size=2.0)
    u, v = np.meshgrid(np.linspace(0, 1, 256), np.linspace(0, 1, 256))
    image = to_uint8(np.stack([0.2 + 0.1 * u, 0.5 + 0.3 * v, 0.6 - 0.2 * v], axis=2))
    image[-2:, :2] = 0  # the collapsed faces' texel, at the atlas's corner (0, 0)
    uvs = wall.uvs * [0.5, 1.0]  # the right half of the atlas is free
    centres = wall.triangles.mean(axis=1) / 2.0 * 20  # in cells: x along u, z along v
    block = (np.floor(centres[:, 0]) >= 9) & (np.floor(centres[:, 0]) < 12) \
        & (np.floor(centres[:, 2]) >= 9) & (np.floor(centres[:, 2]) < 12)
    uvs = np.concatenate([uvs, [[0.002, 0.002]]])
    face_uvs = wall.face_uvs.copy()
    face_uvs[block] = len(uvs) - 1
    return wall.replace(uvs=uvs, face_uvs=face_uvs, materials=(Material("wall", image),)), block


def test_unmapped_faces_get_charts_of_their_own_in_free_space_and_every_other_uv_is_kept():
    scan, block = collapsed_wall()
    assert np.array_equal(unmapped_faces(scan), block) and block.sum() == 18
    plan = plan_uvs(scan, "keep")
    out = plan.scan
    assert plan.report["unmapped"] == {"faces": 18, "charted": 18, "left": 0, "wrapped": 0}
    assert out.positions is scan.positions and out.faces is scan.faces
    np.testing.assert_array_equal(out.triangle_uvs[~block], scan.triangle_uvs[~block])  # the rest kept
    assert not unmapped_faces(out).any()
    new = out.triangle_uvs[block]
    assert ((new >= 0) & (new <= 1)).all()
    # each new chart has the shape of its face (at one scale for all) and no texel any other chart has
    edges_3d = np.linalg.norm(scan.triangles[block][:, [1, 2, 0]] - scan.triangles[block], axis=2)
    edges_uv = np.linalg.norm((new[:, [1, 2, 0]] - new) * 256, axis=2)
    ratio = edges_uv / edges_3d
    np.testing.assert_allclose(ratio, ratio.mean(), rtol=1e-6)
    kept = covered_texels(out.triangle_uvs, 256, 256, np.flatnonzero(~block))
    for f in np.flatnonzero(block):
        own = covered_texels(out.triangle_uvs, 256, 256, np.array([f]))
        assert own.any() and not (own & kept).any()
        kept |= own
    # switched off, or in another mode, the layout is the planner's as before
    assert plan_uvs(scan, "keep", chart_unmapped=False).scan is scan


def test_an_enhanced_scans_unmapped_faces_take_the_colour_around_them():
    """Before, they showed the one texel their UVs pointed at (black in the input; the output's padding there):
    flat triangles of one colour. Now the hole fill colours their charts from around them."""
    scan, block = collapsed_wall()
    assert untextured_faces(scan)[block].all()
    result = enhance(scan, preset("fast"))
    out = result.scan
    assert out.positions is scan.positions or np.array_equal(out.positions, scan.positions)
    np.testing.assert_array_equal(out.faces, scan.faces)
    assert result.metrics["uv"]["unmapped"]["charted"] == 18
    from scantex.cli import enhance_summary

    assert "UV layout: 18 faces it gave no texture space" in enhance_summary(result.metrics)
    f = np.repeat(np.flatnonzero(block), 20)
    bary = np.random.default_rng(0).dirichlet([2, 2, 2], len(f))[:, 1:].astype(np.float32)
    got = shade_hits(out, f, bary)
    # the wall around the block, read through the input at the same points' neighbours: green-blue, not black
    around = shade_hits(scan, np.flatnonzero(~block)[:200], np.full((200, 2), 1 / 3, np.float32))
    assert got.min() > 0.1 and np.abs(got.mean(axis=0) - around.mean(axis=0)).max() < 0.15


def test_tiles_chart_the_unmapped_faces_once_for_the_whole_scan():
    """The tiles share one layout: the faces it gives no texture space are charted before the scan is cut, and
    the fused result colours them as an untiled run does."""
    from scantex.scale.executors import LocalPool
    from scantex.pipeline.config import TilingConfig
    from scantex.scale.tiles import enhance_tiled

    scan, block = collapsed_wall()
    result = enhance_tiled(scan, preset("fast"), TilingConfig(tiles=2), runner=LocalPool(workers=1))
    out = result.scan
    np.testing.assert_array_equal(out.faces, scan.faces)
    assert result.metrics["uv"]["unmapped"]["charted"] == 18 and not unmapped_faces(out).any()
    f = np.repeat(np.flatnonzero(block), 20)
    bary = np.random.default_rng(0).dirichlet([2, 2, 2], len(f))[:, 1:].astype(np.float32)
    assert shade_hits(out, f, bary).min() > 0.1


def test_faces_in_a_whole_tile_outside_the_atlas_show_the_texels_the_texture_repeats_there():
    """UVs moved by whole tiles ([1, 2], [-1, 0]: the texture repeats there, in glTF and every OBJ viewer) are the
    same texels. Read as outside the atlas, the faces had been taken for holes: a layout moved whole by one
    tile was refused ("no view sees any of the surface"), and one moved in part was filled flat there."""
    wall = grid_wall(n=13, size=1.0)
    image = to_uint8(np.random.default_rng(0).uniform(0.1, 0.9, (64, 64, 3)))
    scan = wall.replace(materials=(Material("wall", image),))
    left = wall.triangles.mean(axis=1)[:, 0] < 0.5
    face_uvs = scan.face_uvs.copy()
    face_uvs[left] += len(scan.uvs)  # the left half's faces on UVs of their own, moved by (+1, -1)
    moved = scan.replace(uvs=np.concatenate([scan.uvs, scan.uvs + [1.0, -1.0]]), face_uvs=face_uvs)
    f = np.repeat(np.arange(scan.n_faces), 4)
    bary = np.random.default_rng(1).dirichlet([2, 2, 2], len(f))[:, 1:].astype(np.float32)
    np.testing.assert_allclose(shade_hits(moved, f, bary), shade_hits(scan, f, bary), atol=1e-6)  # as viewers show it
    assert not unmapped_faces(moved).any() and not untextured_faces(moved).any()
    plan = plan_uvs(moved, "keep")
    assert plan.report["unmapped"]["wrapped"] == left.sum() and plan.report["unmapped"]["charted"] == 0
    np.testing.assert_allclose(plan.scan.triangle_uvs, scan.triangle_uvs, atol=1e-12)
    result = enhance(moved, preset("fast"))
    np.testing.assert_array_equal(result.scan.faces, scan.faces)
    # the written texture shows each face what the input showed it (its texels kept: no hole, no fill)
    np.testing.assert_allclose(shade_hits(result.scan, f, bary), shade_hits(moved, f, bary), atol=0.02)
