"""UV shells and seams, hole detection, harmonic fill, gutter padding and baking."""

from __future__ import annotations

import dataclasses
import importlib.util

import numpy as np
import pytest
import trimesh

from scantex.atlas.bake import bake, bake_reference
from scantex.atlas.holes import untextured_faces
from scantex.atlas.inpaint import grow_faces, harmonic_vertex_colours
from scantex.atlas.padding import pad_gutters
from scantex.atlas.seams import seam_edges, seam_visibility, uv_shells
from scantex.atlas.texelmap import covered_texels, texel_map, texel_map_reference
from scantex.scan import Material, Scan
from scantex.views.render import sample_texture, shade_hits
from tests.conftest import checker, grid_wall


def test_cube_has_six_shells_and_twelve_seam_edges(cube):
    shells = uv_shells(cube)
    assert len(np.unique(shells)) == 6
    assert (shells[0::2] == shells[1::2]).all()  # the two triangles of a side share a shell
    edges = seam_edges(cube)
    assert len(edges) == 12  # every cube edge joins two sides
    assert (shells[edges.faces[:, 0]] != shells[edges.faces[:, 1]]).all()


def test_a_layouts_charts_and_seams_are_found_once_and_kept_by_copies_on_that_layout(cube):
    """A texture baked onto the scan's own layout (``Scan.replace(materials=...)``) shares its charts and seam
    edges; new texture coordinates find their own. The shared arrays are read-only."""
    shells, edges = uv_shells(cube), seam_edges(cube)
    assert uv_shells(cube) is shells and seam_edges(cube) is edges
    with pytest.raises(ValueError):
        shells[0] = 99
    with pytest.raises(ValueError):
        edges.faces[0, 0] = 0
    bounds = cube.bounds
    black = tuple(dataclasses.replace(m, image=np.zeros_like(m.image)) for m in cube.materials)  # all holes
    repainted = cube.replace(materials=black)
    assert uv_shells(repainted) is shells and seam_edges(repainted) is edges
    assert repainted.welded is cube.welded and repainted.bounds is bounds
    # the faces left black depend on the images: each copy finds its own
    assert not untextured_faces(cube).any() and untextured_faces(repainted).all()
    moved = cube.replace(uvs=cube.uvs * 0.5)
    assert uv_shells(moved) is not shells
    np.testing.assert_array_equal(uv_shells(moved), shells)


def cylinder_with_one_seam(sections: int = 12) -> Scan:
    """An open cylinder unrolled into one chart: a single seam where u = 0 meets u = 1."""
    ring = np.linspace(0, 2 * np.pi, sections, endpoint=False)
    positions = np.concatenate([np.stack([np.cos(ring), np.sin(ring), np.full(sections, z)], 1) for z in (0, 1)])
    u = np.arange(sections + 1) / sections
    uvs = np.concatenate([np.stack([u, np.full(sections + 1, v)], 1) for v in (0.1, 0.9)])
    faces, face_uvs = [], []
    for k in range(sections):
        a, b, c, d = k, (k + 1) % sections, sections + (k + 1) % sections, sections + k
        ua, ub, uc, ud = k, k + 1, sections + 1 + k + 1, sections + 1 + k
        faces += [[a, b, c], [a, c, d]]
        face_uvs += [[ua, ub, uc], [ua, uc, ud]]
    img = np.zeros((32, 64, 3), np.uint8)
    img[:, :32] = 50
    img[:, 32:] = 200  # u < 0.5 dark, u > 0.5 bright: the seam joins the two halves
    return Scan(positions, np.array(faces), uvs, np.array(face_uvs), None, (Material("c", img),))


def test_cylinder_has_one_shell_and_one_seam():
    scan = cylinder_with_one_seam()
    assert len(np.unique(uv_shells(scan))) == 1
    edges = seam_edges(scan)
    assert len(edges) == 1
    assert abs(seam_visibility(scan, edges) - 150.0) < 1.0  # dark one side, bright the other


def test_seam_visibility_is_zero_for_a_continuous_texture():
    scan = cylinder_with_one_seam()
    flat = scan.replace(materials=(Material("c", np.full((32, 64, 3), 120, np.uint8)),))
    assert seam_visibility(flat) < 1e-3


def test_black_faces_are_holes():
    wall = grid_wall(n=6)
    img = wall.materials[0].image.copy()
    img[: img.shape[0] // 2] = 0  # the top half of the atlas (v > 0.5) is untextured
    scan = wall.replace(materials=(Material("w", img),))
    holes = untextured_faces(scan)
    v_centre = scan.triangle_uvs[:, :, 1].mean(axis=1)
    assert holes[v_centre > 0.6].all() and not holes[v_centre < 0.4].any()
    assert not untextured_faces(wall).any()


def test_harmonic_fill_is_linear_on_a_strip():
    wall = grid_wall(n=9)
    x = wall.positions[:, 0]
    z = wall.positions[:, 2]
    known = (x < 0.3) | (x > 1.7) | (z < 0.01) | (z > 1.99)  # a closed boundary
    colours = np.stack([x, x, x], axis=1) / 2.0
    filled = harmonic_vertex_colours(wall, known, np.where(known[:, None], colours, 0))
    assert np.allclose(filled[known], colours[known])
    inside = ~known
    # linear data on a closed boundary: the graph-harmonic interior of a regular grid is that linear function
    assert np.abs(filled[inside] - colours[inside]).max() < 0.01


def test_harmonic_fill_crosses_uv_seams_where_positions_repeat():
    # a capture app's OBJ or GLB repeats a position at every UV seam: here every face has corners of its own,
    # so no two faces share a vertex index, as in a GLB whose every face is a chart
    wall = grid_wall(n=9)
    split = dataclasses.replace(wall, positions=wall.positions[wall.faces.reshape(-1)],
                                faces=np.arange(3 * wall.n_faces).reshape(-1, 3))
    x, z = split.positions[:, 0], split.positions[:, 2]
    known = (x < 0.3) | (x > 1.7) | (z < 0.01) | (z > 1.99)
    _, weld = np.unique(split.positions, axis=0, return_inverse=True)
    weld = weld.reshape(-1)
    # the copies of one position disagree at a seam (charts of different exposure), by up to 0.1, about
    # their mean x / 2
    step = np.where(np.arange(len(x)) % 2 == 0, 0.05, -0.05)
    step -= (np.bincount(weld[known], step[known], weld.max() + 1)
             / np.maximum(np.bincount(weld[known], minlength=weld.max() + 1), 1))[weld]
    colours = np.stack([x, x, x], axis=1) / 2.0 + step[:, None]
    assert np.abs(step[known]).max() > 0.04
    filled = harmonic_vertex_colours(split, known, np.where(known[:, None], colours, 0))
    assert np.array_equal(filled[known], colours[known])  # known corners keep their own colour
    inside = ~known
    # the hole is filled from the colours around it, as on the welded strip, not with the mean colour
    assert np.abs(filled[inside] - x[inside, None] / 2.0).max() < 0.01
    # and the copies of one position get one colour
    for v in np.unique(weld[inside]):
        assert np.ptp(filled[(weld == v) & inside], axis=0).max() == 0


def test_grow_faces_adds_a_ring():
    wall = grid_wall(n=8)
    seed = np.zeros(wall.n_faces, bool)
    seed[40] = True
    grown = grow_faces(wall, seed)
    assert grown.sum() > 1 and grown[40]
    shared = np.isin(wall.faces, wall.faces[40]).any(axis=1)
    assert np.array_equal(grown, shared)


def test_pad_gutters_fills_from_nearest():
    img = np.zeros((4, 4, 3), np.float32)
    img[1, 1] = 1.0
    covered = np.zeros((4, 4), bool)
    covered[1, 1] = True
    assert (pad_gutters(img, covered) == 1.0).all()


def test_bake_of_the_texture_lookup_reproduces_the_texture(wall):
    """Baking "the scan's own colour at each point" must give back (nearly) the same atlas."""
    image = wall.materials[0].image

    def colour(points, normals, faces, bary):
        uv_tri = wall.triangle_uvs[faces]
        w = np.stack([1 - bary[:, 0] - bary[:, 1], bary[:, 0], bary[:, 1]], 1)
        return sample_texture(image, np.einsum("nk,nkc->nc", w, uv_tri))

    (baked,) = bake(wall, colour, size=image.shape[0])
    inner = (slice(2, -2), slice(2, -2))
    assert np.abs(baked[inner].astype(int) - image[inner].astype(int)).max() <= 1


def test_bake_at_the_input_size_keeps_every_covered_texel_exactly(wall):
    """scale 1 on the input's own UVs: texel centres coincide, so the lookup bakes the very texels
    (scale 2, the field bake's default, resamples them)."""
    image = wall.materials[0].image

    def colour(points, normals, faces, bary):
        return shade_hits(wall, faces, bary)

    (same,) = bake(wall, colour, scale=1)
    (double,) = bake(wall, colour)
    covered = covered_texels(wall.triangle_uvs, *image.shape[1::-1])
    assert same.shape == image.shape and double.shape == (2 * image.shape[0], 2 * image.shape[1], 3)
    assert covered.mean() > 0.5 and np.array_equal(same[covered], image[covered])


def test_a_bake_of_some_faces_colours_their_texels_as_a_full_bake_does(wall):
    """``only``: the texels of those faces are the full bake's, away from the faces left out (a texel beside
    an edge is rasterised from the faces about it), to one 8-bit level (a strip's texel map starts at another
    row: the barycentrics agree to 1e-7); the rest of the atlas is gutter, filled from them (the held-out
    photos' texture of ``photos.final`` all is baked so, its faces grown by 2 rings)."""
    from scipy import ndimage

    def colour(points, normals, faces, bary):
        return shade_hits(wall, faces, bary)

    only = np.zeros(wall.n_faces, bool)
    only[: wall.n_faces // 3] = True
    (full,) = bake(wall, colour)
    (part,) = bake(wall, colour, only=only)
    H, W = full.shape[:2]
    whole = texel_map(wall.triangle_uvs, W, H, np.arange(wall.n_faces)).face_id
    theirs = (whole >= 0) & only[np.maximum(whole, 0)]  # texels a face of ``only`` colours in the full bake
    inside = ndimage.binary_erosion(theirs | (whole < 0), iterations=2) & theirs
    assert inside.mean() > 0.05 and np.abs(part[inside].astype(int) - full[inside].astype(int)).max() <= 1
    assert (part[inside] == full[inside]).all(axis=1).mean() > 0.9
    others = (whole >= 0) & ~only[np.maximum(whole, 0)]
    assert not np.array_equal(part[others], full[others])  # not coloured: padding


def test_a_bake_on_threads_pads_as_one_on_a_single_core(cube, wall):
    """``workers`` 2 finds the gutters' nearest texels on a thread of its own while colouring (the texel map drawn
    a second time for its mask): the same images and layouts as one core's bake, for a few faces as for all."""
    from scantex.atlas.bake import AtlasLayout
    from scantex.atlas.texelmap import rasterised_cheaply

    assert rasterised_cheaply() == (importlib.util.find_spec("numba") is not None)

    def colour(points, normals, faces, bary):
        return np.clip(np.abs(np.sin(5 * points + normals)), 0, 1)

    for scan, only in ((cube, None), (wall, None), (wall, np.arange(wall.n_faces) % 3 == 0)):
        one: list[AtlasLayout | None] = []
        two: list[AtlasLayout | None] = []
        alone = bake(scan, colour, size=64, chunk=500, layouts=one, only=only)
        threaded = bake(scan, colour, size=64, chunk=500, layouts=two, only=only, workers=2)
        assert all(np.array_equal(a, b) for a, b in zip(alone, threaded, strict=True))
        for a, b, image in zip(one, two, alone, strict=True):
            assert a.shape == b.shape == image.shape[:2]
            assert np.array_equal(np.concatenate(a.strips), np.concatenate(b.strips))
            assert np.array_equal(a.sources, b.sources)


def test_bake_keeps_layout_per_material(cube):
    def colour(points, normals, faces, bary):
        return np.tile(np.array([[0.0, 1.0, 0.0]], np.float32), (len(points), 1))

    images = bake(cube, colour, size=32)
    assert len(images) == 2 and all(im.shape == (32, 32, 3) for im in images)
    assert (images[0][..., 1] == 255).all()  # gutters padded too


def test_untextured_scan_has_no_holes():
    mesh = trimesh.creation.icosphere(2)
    assert not untextured_faces(Scan(mesh.vertices, mesh.faces)).any()


def test_checker_helper_is_two_colour():
    assert len(np.unique(checker(16, 4).reshape(-1, 3), axis=0)) == 2


def test_seams_found_when_positions_are_repeated_along_them(cube):
    """glTF stores one vertex per (position, UV): the seam's two faces share no vertex index."""
    pairs = np.unique(np.stack([cube.faces.ravel(), cube.face_uvs.ravel()], 1), axis=0, return_inverse=True)[1]
    corner_pos = cube.faces.ravel()
    positions = np.zeros((pairs.max() + 1, 3))
    positions[pairs] = cube.positions[corner_pos]
    uvs = np.zeros((pairs.max() + 1, 2))
    uvs[pairs] = cube.uvs[cube.face_uvs.ravel()]
    faces = pairs.reshape(-1, 3)
    split = Scan(positions, faces, uvs, faces.copy(), cube.face_materials, cube.materials)
    assert len(seam_edges(split)) == len(seam_edges(cube)) == 12
    assert abs(seam_visibility(split) - seam_visibility(cube)) < 1e-6


def test_chart_gains_recover_an_exposure_step():
    """Two charts of one flat colour, one stored 20 % brighter: the seam says so."""
    from scantex.atlas.levelling import chart_gains

    scan = cylinder_with_one_seam()
    img = np.full((32, 64, 3), 100, np.uint8)
    img[:, 32:] = 120
    # two charts: faces whose UVs lie left / right of u = 0.5; the seam at u = 0 / 1 joins them
    charts = (scan.triangle_uvs[:, :, 0].mean(axis=1) > 0.5).astype(int)
    gains = chart_gains(scan.replace(materials=(Material("c", img),)), charts)
    assert np.allclose(gains[1] / gains[0], 1.2, atol=0.03)
    assert np.allclose(np.log(gains).mean(axis=0), 0, atol=1e-6)


@pytest.mark.parametrize("rows, chunk", [(3, 37), (7, 5000), (512, 16384)])
def test_streamed_bake_is_the_untiled_bake(rows, chunk, cube, wall, monkeypatch):
    """Strips of a few rows and chunks that straddle them: the same images byte for byte, and the colour
    function called with the same chunks as the whole-atlas twin."""
    import scantex.atlas.padding
    import scantex.atlas.texelmap

    monkeypatch.setattr(scantex.atlas.texelmap, "ROWS_PER_STRIP", rows)
    monkeypatch.setattr(scantex.atlas.padding, "ROWS_PER_STRIP", rows)
    for scan, size in ((cube, 48), (wall, 64), (cylinder_with_one_seam(), 40)):
        calls = {"tiled": [], "untiled": []}

        def recorder(name):
            def colour(points, normals, faces, bary):
                calls[name].append((len(points), int(faces[0])))
                return np.clip(np.abs(np.sin(3 * points + normals)) * (0.5 + 0.5 * bary[:, :1]), 0, 1)
            return colour

        progress = []
        tiled = bake(scan, recorder("tiled"), size=size, chunk=chunk, progress=lambda d, t: progress.append((d, t)))
        untiled = bake_reference(scan, recorder("untiled"), size=size, chunk=chunk)
        assert len(tiled) == len(untiled)
        for a, b in zip(tiled, untiled):
            assert a.dtype == np.uint8 and np.array_equal(a, b)
        assert calls["tiled"] == calls["untiled"]
        assert progress[-1][0] == progress[-1][1] == sum(n for n, _ in calls["tiled"])
        assert all(d2 >= d1 for (d1, _), (d2, _) in zip(progress, progress[1:]))


@pytest.mark.parametrize("path", ["compiled", "embree"])
def test_streamed_texel_map_and_mask_match_the_reference(wall, monkeypatch, path):
    import scantex.atlas.texelmap
    from scantex import jit

    if path == "embree":  # where numba is missing
        monkeypatch.setattr(jit, "compiled", lambda function: None)
    monkeypatch.setattr(scantex.atlas.texelmap, "ROWS_PER_STRIP", 5)
    ref = texel_map_reference(wall.triangle_uvs, 50, 37)
    tmap = texel_map(wall.triangle_uvs, 50, 37)
    assert (tmap.face_id == ref.face_id).mean() > 0.999  # ties on shared edges may go either way
    assert np.array_equal(covered_texels(wall.triangle_uvs, 50, 37), tmap.mask)


def test_a_mostly_empty_atlas_casts_only_where_triangles_reach(monkeypatch):
    """Strips that triangles' boxes reach sparsely cast rays only there: the same map as a ray at every texel,
    and the reference rasteriser's (Embree's path, where numba is missing), and the compiled path's."""
    import scantex.atlas.texelmap
    from scantex import jit

    rng = np.random.default_rng(3)
    corner = rng.random((40, 1, 2)) * 0.9
    triangle_uvs = corner + rng.random((40, 3, 2)) * 0.06  # small charts scattered over the square
    monkeypatch.setattr(scantex.atlas.texelmap, "ROWS_PER_STRIP", 16)
    compiled = texel_map(triangle_uvs, 160, 120)
    maps = {}
    with monkeypatch.context() as m:
        m.setattr(jit, "compiled", lambda function: None)
        for name, share in (("every texel", 0.0), ("where boxes reach", 1.0)):
            m.setattr(scantex.atlas.texelmap, "SPARSE_STRIP", share)
            maps[name] = texel_map(triangle_uvs, 160, 120)
    dense, sparse = maps["every texel"], maps["where boxes reach"]
    assert np.array_equal(dense.face_id, sparse.face_id) and np.array_equal(dense.bary, sparse.bary)
    assert 0.01 < sparse.mask.mean() < 0.5
    ref = texel_map_reference(triangle_uvs, 160, 120)
    assert (ref.face_id == sparse.face_id).mean() > 0.999
    assert (ref.face_id == compiled.face_id).mean() > 0.999
    both = (ref.face_id == compiled.face_id) & ref.mask
    np.testing.assert_allclose(compiled.bary[both], ref.bary[both], atol=1e-6)


@pytest.mark.parametrize("numba", [True, False])
def test_gutter_padding_in_place_is_nearest_texel(numba, monkeypatch):
    """Compiled (rows on threads: 151 rows make two parts) and in numpy (strips of rows) alike."""
    import scantex.atlas.padding
    from scantex import jit

    monkeypatch.setattr(scantex.atlas.padding, "ROWS_PER_STRIP", 4)
    if not numba:
        monkeypatch.setattr(jit, "compiled", lambda function: None)
    rng = np.random.default_rng(0)
    image = rng.integers(0, 255, (151, 17, 3)).astype(np.uint8)
    covered = rng.random((151, 17)) < 0.2
    padded = pad_gutters(image, covered)
    from scipy.ndimage import distance_transform_edt

    _, (iy, ix) = distance_transform_edt(~covered, return_indices=True)
    assert np.array_equal(padded, image[iy, ix]) and padded is not image
    # float texels, the colour channels of an RGBA atlas (a view) and a column-major image, in place, alike
    from scantex.atlas.padding import fill_gutters

    floats = image.astype(np.float32) / 255
    fill_gutters(floats, covered)
    assert np.array_equal(floats, image[iy, ix].astype(np.float32) / 255)
    rgba = np.concatenate([image, np.full((151, 17, 1), 7, np.uint8)], axis=2)
    fill_gutters(rgba[..., :3], covered)
    assert np.array_equal(rgba[..., :3], image[iy, ix]) and (rgba[..., 3] == 7).all()
    columns = np.asfortranarray(image)
    fill_gutters(columns, covered)
    assert np.array_equal(columns, image[iy, ix])


@pytest.mark.parametrize("numba", [True, False])
def test_gutter_sources_are_the_nearest_covered_texels(numba, monkeypatch):
    """The compiled passes (rows and columns shared among threads) against their twin, scipy's distance transform,
    on masks full of ties (covered texels on lattices, single texels, one row or column): every texel named is
    covered and as near as scipy's; covered texels name themselves. Without numba the twin runs."""
    from scantex import jit
    from scantex.atlas.padding import gutter_sources, gutter_sources_scipy

    if not numba:
        monkeypatch.setattr(jit, "compiled", lambda function: None)
    rng = np.random.default_rng(3)
    masks = [np.eye(1, 9, 4, dtype=bool), np.eye(9, 1, 4, dtype=bool), rng.random((300, 200)) < 0.001]
    for _ in range(40):
        H, W = rng.integers(1, 90, 2)
        mask = np.zeros((H, W), bool)
        mask[::rng.integers(2, 7), ::rng.integers(2, 7)] = rng.random() < 0.5
        masks.append(mask | (rng.random((H, W)) < rng.choice([0.002, 0.02, 0.3])))
    for covered in masks:
        if covered.all() or not covered.any():
            assert gutter_sources(covered) is None
            continue
        H, W = covered.shape
        ours, theirs = gutter_sources(covered), gutter_sources_scipy(covered)
        assert ours.shape == (H, W) and ours.dtype == np.int32
        y, x = np.indices((H, W))

        def distance(sources):
            return (sources // W - y) ** 2 + (sources % W - x) ** 2

        assert covered.reshape(-1)[ours.reshape(-1)].all()
        assert np.array_equal(distance(ours), distance(theirs))
        assert np.array_equal(ours[covered], (y * W + x)[covered])


def test_vertex_colours_baked_into_a_texture_render_as_the_vertex_colours():
    from scantex.atlas.bake import texture_from_vertex_colours

    wall = grid_wall(n=12)
    x, z = wall.positions[:, 0], wall.positions[:, 2]
    rgb = np.stack([0.2 + 0.3 * x, 0.5 + 0.2 * z, 0.8 - 0.1 * x * z], axis=1)
    coloured = Scan(wall.positions, wall.faces, vertex_colors=np.column_stack(
        [np.round(rgb * 255), np.full(len(x), 255)]).astype(np.uint8))
    textured = texture_from_vertex_colours(coloured, size=256)
    assert textured.is_textured and textured.positions is coloured.positions and textured.faces is coloured.faces
    rng = np.random.default_rng(0)
    face = rng.integers(0, wall.n_faces, 2000)
    bary = rng.dirichlet(np.ones(3), 2000)[:, 1:]
    assert np.abs(shade_hits(textured, face, bary) - shade_hits(coloured, face, bary)).max() < 3 / 255

    # an atlas too coarse for the vertices is doubled (the charts' UV area times its texels below the target)
    (image,) = [m.image for m in texture_from_vertex_colours(coloured, size=64, texels_per_vertex=64).materials]
    assert image.shape[:2] in ((128, 128), (256, 256)) and image.shape[0] ** 2 > 64 * coloured.n_vertices
    assert texture_from_vertex_colours(coloured, size=64).materials[0].image.shape[:2] == (64, 64)


def test_black_texel_lookup_of_an_8_bit_atlas_is_the_ramps_arithmetic():
    """The 8-bit table takes the texels at black level and above the ramp as they are (weights exactly 1 and
    0) and computes only the ramp: the same lookups as the arithmetic on every texel (a float atlas)."""
    from scantex.atlas.colour import _dark_texels

    wall = grid_wall(n=8)
    rng = np.random.default_rng(0)
    atlas = rng.integers(0, 45, (64, 64, 3)).astype(np.uint8)  # black, the ramp and above it
    atlas[::7] = rng.integers(0, 256, (len(atlas[::7]), 64, 3))
    as_bytes = wall.replace(materials=(Material("m", atlas),))
    as_floats = wall.replace(materials=(Material("m", atlas.astype(np.float32) / 255),))
    face = rng.integers(0, wall.n_faces, 5000)
    bary = rng.dirichlet(np.ones(3), 5000)[:, 1:].astype(np.float32)
    share, dark = _dark_texels(as_bytes)(face, bary)
    share_f, dark_f = _dark_texels(as_floats)(face, bary)
    assert 0 < (share > 0).mean() < 1  # both kinds of texel are looked up
    assert np.array_equal(share, share_f) and np.array_equal(dark, dark_f)
