"""Seam blending and texture transfer onto a new layout."""

from __future__ import annotations

import numpy as np
import pytest

from scantex.atlas.seams import SeamEdges, seam_edges, seam_visibility, with_seams_of
from scantex.scan import Material, Scan
from scantex.uv import blend_seams, plan_uvs, transfer_texture
from tests.atlas.test_seams_holes_bake import cylinder_with_one_seam
from tests.conftest import grid_wall, textured_cube


def test_blending_closes_the_cylinder_seam_and_leaves_the_rest():
    scan = cylinder_with_one_seam()
    assert seam_visibility(scan) == pytest.approx(150.0, abs=1.0)
    blended = blend_seams(scan, band_texels=3.0)
    assert blended.positions is scan.positions and blended.faces is scan.faces
    assert seam_visibility(blended) < 5.0
    before, after = scan.materials[0].image, blended.materials[0].image
    # the seam runs along u = 0 / u = 1 (columns 0 and 63); columns farther than the band stay
    assert np.array_equal(after[4:-4, 8:56], before[4:-4, 8:56])
    # next to the seam both sides meet at the mean (50 + 200) / 2
    assert abs(int(after[16, 0, 0]) - 125) <= 10 and abs(int(after[16, 63, 0]) - 125) <= 10


def test_blending_needs_a_positive_band():
    with pytest.raises(ValueError, match="band"):
        blend_seams(cylinder_with_one_seam(), band_texels=0)


def test_blending_an_untextured_or_seamless_scan_changes_nothing():
    wall = grid_wall(n=6)
    bare = Scan(wall.positions, wall.faces)
    assert blend_seams(bare) is bare
    assert blend_seams(wall) is wall  # one chart, no seam


def test_blending_across_materials():
    cube = textured_cube(materials=2)
    solid = cube.replace(materials=(Material("a", np.full((64, 64, 3), 40, np.uint8)),
                                    Material("b", np.full((64, 64, 3), 220, np.uint8))))
    before = seam_visibility(solid)
    assert before > 50
    assert seam_visibility(blend_seams(solid, max_crease_deg=180)) < 0.2 * before


def test_blending_leaves_sharp_creases_alone():
    """A cube's faces meet at 90 degrees: the colour may change there for real (a wall meeting the floor),
    so the default blend leaves those seams as they are; a smooth seam is still blended (the cylinder)."""
    cube = textured_cube(materials=2)
    solid = cube.replace(materials=(Material("a", np.full((64, 64, 3), 40, np.uint8)),
                                    Material("b", np.full((64, 64, 3), 220, np.uint8))))
    kept = blend_seams(solid)
    for a, b in zip(kept.materials, solid.materials):
        assert np.array_equal(a.image, b.image)
    assert seam_visibility(blend_seams(cylinder_with_one_seam())) < 5.0


def test_blending_lowers_seam_visibility_on_the_demo_wall():
    from scantex.synth.wall import make_wall

    demo = make_wall(grid=(40, 30), gt_texture_size=256, scan_texture_size=128)
    before = seam_visibility(demo.scan)
    blended = blend_seams(demo.scan)
    after = seam_visibility(blended)
    assert after < 0.6 * before
    # texels deeper inside a chart than the band keep their colour
    from scipy import ndimage

    from scantex.atlas.texelmap import texel_map

    covered = texel_map(demo.scan.triangle_uvs, 128, 128).mask
    inner = ndimage.binary_erosion(covered, iterations=4)
    same = (blended.materials[0].image == demo.scan.materials[0].image).all(axis=2)
    assert inner.sum() > 100 and same[inner].mean() > 0.9


def test_transfer_texture_onto_a_new_layout_keeps_the_colours():
    wall = grid_wall(n=12)
    plan = plan_uvs(wall, "unwrap", texture_size=128)
    moved = transfer_texture(wall, plan.scan, size=128)
    assert moved.materials[0].image.shape == (128, 128, 3)
    # the same surface points show the same colour through either layout
    rng = np.random.default_rng(0)
    faces = rng.integers(0, wall.n_faces, 200)
    bary = rng.dirichlet([2, 2, 2], 200)[:, 1:]
    from scantex.views.render import shade_hits

    a, b = shade_hits(wall, faces, bary), shade_hits(moved, faces, bary)
    assert np.median(np.abs(a - b)) < 0.05


@pytest.mark.parametrize("rows, batch", [(3, 50), (16, 2_000_000)])
def test_blending_in_strips_is_blending_the_whole_atlas(rows, batch, monkeypatch):
    """Strips of a few rows (and candidate batches that split edges) give the whole-atlas result."""
    import scantex.atlas.padding
    import scantex.atlas.texelmap
    import scantex.uv.blend

    from scantex.synth import make_wall

    scans = [cylinder_with_one_seam(), textured_cube(),
             make_wall(grid=(16, 12), gt_texture_size=192, scan_texture_size=96, seed=2).scan]
    # every seam blended, the cube's creases too (the strips are what is tested)
    whole = [blend_seams(s, band_texels=3.0, max_crease_deg=180) for s in scans]  # default strips: one strip each
    monkeypatch.setattr(scantex.atlas.texelmap, "ROWS_PER_STRIP", rows)
    monkeypatch.setattr(scantex.atlas.padding, "ROWS_PER_STRIP", rows)
    monkeypatch.setattr(scantex.uv.blend, "CANDIDATES_PER_BATCH", batch)
    for scan, ref in zip(scans, whole):
        out = blend_seams(scan, band_texels=3.0, max_crease_deg=180)
        for a, b, before in zip(out.materials, ref.materials, scan.materials):
            assert before.image.shape[0] < 512  # so that `whole` was one strip
            diff = np.abs(a.image.astype(int) - b.image.astype(int))
            # float64 sums regrouped across batches may round a texel the other way, never more
            assert diff.max() <= 1 and (diff > 0).mean() < 1e-3
        assert any(not np.array_equal(a.image, s.image) for a, s in zip(out.materials, scan.materials))


@pytest.mark.parametrize("rows", [None, 7])
def test_blending_with_the_bakes_layout_is_blending_without_it(rows, monkeypatch):
    """The bake hands its texel map (its strips of rows: one, or 14 of 7 rows) and gutter padding to the seam
    blending, which then neither rasterises the UVs nor runs the distance transform again: the same images, bit
    for bit, and the bake's face map is the texel map's."""
    import scantex.atlas.texelmap
    from scantex.atlas.bake import bake
    from scantex.atlas.texelmap import texel_map

    if rows:
        monkeypatch.setattr(scantex.atlas.texelmap, "ROWS_PER_STRIP", rows)

    cube = textured_cube(materials=2)

    def stripes(points, normals, face_ids, bary):  # a colour that differs across every seam
        return np.stack([(points[:, 0] * 3) % 1, face_ids % 7 / 7, (points[:, 2] * 5) % 1], axis=1)

    layouts: list = []
    images = bake(cube, stripes, size=96, layouts=layouts)
    assert len(layouts) == len(images) == 2
    for m, layout in enumerate(layouts):
        faces = np.flatnonzero(cube.face_materials == m)
        assert len(layout.strips) == (-(-96 // rows) if rows else 1) and layout.shape == (96, 96)
        assert np.array_equal(np.concatenate(layout.strips), texel_map(cube.triangle_uvs, 96, 96, faces).face_id)
    baked = cube.replace(materials=tuple(mat.with_image(img) for mat, img in zip(cube.materials, images)))
    plain = blend_seams(baked, max_crease_deg=180)
    reused = blend_seams(baked, max_crease_deg=180, layouts=layouts)
    for a, b, before in zip(plain.materials, reused.materials, baked.materials):
        assert np.array_equal(a.image, b.image) and not np.array_equal(a.image, before.image)


def wall_with_a_step() -> tuple[Scan, SeamEdges]:
    """A one-chart wall whose texture steps from dark to bright along the mesh edges at u = 0.5 (an old
    layout's seam, baked into a new chart), and those edges."""
    from scantex.uv.unwrap import interior_edges

    wall = grid_wall(n=9)
    image = np.full((64, 64, 3), 50, np.uint8)
    image[:, 32:] = 200  # texel centres (x + 0.5) / 64: the step at u = 0.5
    wall = wall.replace(materials=(Material("wall", image),))
    pairs, corners = interior_edges(wall.faces)
    u = wall.uvs[:, 0]
    ends = wall.faces[pairs[:, 0, None], corners[:, 0]]  # [E, 2] the edge's two vertices
    on_line = np.isclose(u[ends], 0.5).all(axis=1)
    return wall, SeamEdges(pairs[on_line], corners[on_line])


def test_blending_an_old_seam_inside_a_chart_moves_each_side_towards_the_other():
    """Both sides of an edge inside one chart are in the same chart: each side moves only the texels on its
    own face's side (else the two pulls would cancel on every texel and the step would stay)."""
    wall, edges = wall_with_a_step()
    assert len(edges) == 8 and seam_visibility(wall, edges) > 100
    blended = blend_seams(wall, band_texels=3.0, edges=edges)
    before, after = wall.materials[0].image[..., 0].astype(int), blended.materials[0].image[..., 0].astype(int)
    assert seam_visibility(blended, edges) < 0.2 * seam_visibility(wall, edges)
    assert np.array_equal(after[:, :28], before[:, :28]) and np.array_equal(after[:, 36:], before[:, 36:])
    # towards the mean from either side, never past it: the dark side brightens, the bright side darkens
    assert (after[4:-4, 28:32] >= 50).all() and (after[4:-4, 28:32] <= 126).all()
    assert (after[4:-4, 32:36] <= 200).all() and (after[4:-4, 32:36] >= 124).all()
    assert abs(after[32, 31] - 125) <= 15 and abs(after[32, 32] - 125) <= 15


def test_a_layouts_seams_with_an_old_layouts():
    own = seam_edges(textured_cube(materials=1))
    assert len(with_seams_of(own, own)) == len(own)  # an edge in both, once
    flipped = SeamEdges(own.faces[:5, ::-1], own.corners[:5, ::-1])  # the same edges, sides swapped
    assert len(with_seams_of(own, flipped)) == len(own)
    _, old = wall_with_a_step()
    both = with_seams_of(own, old)
    assert len(both) == len(own) + len(old) and np.array_equal(both.faces[:len(own)], own.faces)
