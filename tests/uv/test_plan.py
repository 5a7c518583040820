"""Shells and seam distances, optimise (split / merge), unwrap, density, and the public ``plan_uvs``."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest
import trimesh

from scantex.atlas.seams import seam_edges, uv_shells
from scantex.scan import Material, Scan
from scantex.uv import plan_uvs, seam_distances, summarise, texel_density
from scantex.uv.param import overlap_share
from scantex.uv.unwrap import (
    UnwrapLog,
    UnwrapOptions,
    _run_xatlas,
    unwrap,
    xatlas_pieces,
)
from tests.atlas.test_seams_holes_bake import cylinder_with_one_seam
from tests.conftest import grid_wall, textured_cube


@pytest.fixture(scope="module")
def demo_wall():
    from scantex.synth.wall import make_wall

    return make_wall(grid=(40, 30), gt_texture_size=256, scan_texture_size=128)


def check_layout(before: Scan, after: Scan, threshold: float) -> None:
    """Geometry untouched, UVs inside the atlas, no chart over the threshold, no overlap anywhere."""
    assert after.positions is before.positions and after.faces is before.faces
    assert after.has_uvs and (after.uvs >= 0).all() and (after.uvs <= 1).all()
    summary = summarise(after)
    assert summary.stretch["max"] <= threshold
    assert overlap_share(after.triangle_uvs) == 0.0


# -- shells and seams -----------------------------------------------------------------------------


def test_cube_seam_distances():
    cube = textured_cube(materials=1)
    d = seam_distances(cube)
    assert d.shape == (12,) and np.isfinite(d).all() and (d > 1.0).all()
    two = seam_distances(textured_cube(materials=2))
    assert np.isinf(two).sum() > 0  # sides in different atlases are infinitely far apart


def test_cylinder_seam_distance_is_the_atlas_width():
    scan = cylinder_with_one_seam()
    (d,) = seam_distances(scan)
    assert d == pytest.approx(64.0)  # u = 0 and u = 1 of a 64-texel-wide atlas


def test_texel_density_of_the_cube():
    cube = textured_cube(materials=1)
    density = texel_density(cube)
    # each side: a 0.29 x 0.46 UV rectangle of a 64² atlas over about 1 m² = 10^4 cm²
    expected = np.sqrt(0.29 * 64 * 0.46 * 64 / 1e4)
    assert density.shape == (6,) and density == pytest.approx(expected, rel=0.01)


def test_summary_counts(cube):
    s = summarise(cube)
    assert s.shells == 6 and s.seam_edges == 12
    assert s.stretch["max"] > 1.0  # 0.29 x 0.46 rectangles on unit squares are anisotropic
    assert summarise(Scan(cube.positions, cube.faces)) is None
    # a face of no area, a chart of its own (the bathroom has 3,869): no density, no zero in the figures
    n = len(cube.uvs)
    flat = dataclasses.replace(cube, faces=np.vstack([cube.faces, [[0, 0, 1]]]),
                               uvs=np.vstack([cube.uvs, [[0.01, 0.01], [0.02, 0.01], [0.01, 0.02]]]),
                               face_uvs=np.vstack([cube.face_uvs, [[n, n + 1, n + 2]]]),
                               face_materials=np.append(cube.face_materials, 0))
    density = summarise(flat).density_px_per_cm
    assert summarise(flat).shells == 7 and density == s.density_px_per_cm and density["min"] > 0


def test_summary_leaves_faces_collapsed_in_uv_out_of_the_stretch(cube):
    """A face of some surface whose UV corners lie in a row (the bathroom has 10) stretches its texels without
    bound: its chart's stretch read 7.7e11, the layout's area-weighted stretch 7.4e10. Such faces are counted
    apart, and the stretch figures are the rest's."""
    s = summarise(cube)
    n = len(cube.uvs)
    face = cube.faces[0]
    line = dataclasses.replace(cube, faces=np.vstack([cube.faces, [face]]),  # a second face on the same corners
                               uvs=np.vstack([cube.uvs, [[0.01, 0.01], [0.02, 0.01], [0.03, 0.01]]]),
                               face_uvs=np.vstack([cube.face_uvs, [[n, n + 1, n + 2]]]),
                               face_materials=np.append(cube.face_materials, 0))
    t = summarise(line)
    assert s.collapsed_faces == 0 and t.collapsed_faces == 1 and t.shells == 7
    assert t.stretch == s.stretch and t.stretch_area_weighted == pytest.approx(s.stretch_area_weighted)


# -- optimize -------------------------------------------------------------------------------------


def test_optimize_merges_cube_sides_within_the_threshold():
    cube = textured_cube(materials=2)
    plan = plan_uvs(cube, "optimize", threshold=1.1, texture_size=64)
    after = plan.report["after"]
    assert after["shells"] < 6 and after["seam_edges"] < 12
    check_layout(cube, plan.scan, 1.1)
    assert len(plan.scan.materials) == 1 and plan.scan.materials[0].image.shape == (64, 64, 3)


def test_optimize_flattens_a_stretched_shell_again_without_cutting_it():
    wall = grid_wall(n=10)
    u, v = wall.uvs[:, 0], wall.uvs[:, 1]
    warped = wall.replace(uvs=np.stack([u ** 3, v], axis=1))  # strongly non-uniform along u
    assert summarise(warped).stretch["max"] > 1.5
    plan = plan_uvs(warped, "optimize", threshold=1.1, texture_size=128)
    done = plan.report["optimize"]
    assert done["shells_reflattened"] == 1 and done["shells_split"] == 0
    assert plan.report["after"]["shells"] == 1 and plan.report["after"]["seam_edges"] == 0
    assert summarise(plan.scan).stretch["max"] < 1.01  # a flat wall flattens without stretch
    check_layout(warped, plan.scan, 1.1)


def dome(subdivisions: int = 3) -> Scan:
    """An icosphere but for a cap below, as one UV shell projected from above: stretched and folded at its
    rim, and curved beyond what a conformal map flattens within 1.1."""
    sphere = trimesh.creation.icosphere(subdivisions)
    upper = sphere.triangles_center[:, 2] > -0.5
    mesh = trimesh.Trimesh(sphere.vertices, sphere.faces[upper], process=False)
    mesh.remove_unreferenced_vertices()
    p = np.asarray(mesh.vertices)
    uvs = (p[:, :2] + 1.0) / 2.0 * 0.9 + 0.05
    faces = np.asarray(mesh.faces)
    return Scan(p, faces, uvs, faces.copy(), None, (Material("dome", np.zeros((64, 64, 3), np.uint8)),))


def test_optimize_splits_a_shell_no_conformal_map_flattens():
    scan = dome()
    plan = plan_uvs(scan, "optimize", threshold=1.1, texture_size=256)
    done = plan.report["optimize"]
    assert done["shells_reflattened"] == 0 and done["shells_split"] == 1 and done["charts_from_splits"] > 1
    assert 1 < plan.report["after"]["shells"] < done["charts_from_splits"]  # split, then merged back in part
    check_layout(scan, plan.scan, 1.1)


def test_merging_without_retry_never_tries_a_union_holding_one_that_failed():
    from scantex.uv.merge import MergeLog, Merger, Piece
    from scantex.uv.unwrap import UnwrapOptions, interior_edges, planar_charts

    scan = dome(4)
    positions, faces = scan.welded_geometry()
    pairs, corners = interior_edges(faces)
    pieces = [Piece(*p) for p in planar_charts(positions, faces, scan.face_normals, scan.face_areas, pairs,
                                               UnwrapOptions(threshold=1.1))]
    tried = {}
    for retry in (True, False):
        merger = Merger(positions, faces, pieces, pairs, corners, 1.1, retry=retry)
        attempts, original = [], merger.try_merge

        def logged(a, b, record, merger=merger, attempts=attempts, original=original):
            sides = (set(merger.pieces[a].faces.tolist()), set(merger.pieces[b].faces.tolist()))
            ok = original(a, b, record)
            attempts.append((*sides, ok))
            return ok

        merger.try_merge = logged
        log = MergeLog()
        merged = merger.run(float("inf"), log)
        assert sum(len(p.faces) for p in merged) == len(faces) and not log.out_of_time
        tried[retry] = attempts
    failed_before = []
    for a, b, ok in tried[False]:
        assert not any((fa <= a and fb <= b) or (fa <= b and fb <= a) for fa, fb in failed_before)
        if not ok:
            failed_before.append((a, b))
    assert failed_before  # the dome's charts do fail to merge, and retrying tries such unions again
    assert len(tried[True]) > len(tried[False])


def test_optimize_reduces_shells_and_seams_on_the_demo_wall(demo_wall):
    scan = demo_wall.scan
    plan = plan_uvs(scan, "optimize", threshold=1.1, texture_size=128)
    before, after = plan.report["before"], plan.report["after"]
    assert before["shells"] == len(np.unique(uv_shells(scan))) and before["shells"] > 10
    assert after["shells"] < before["shells"] / 4 and after["seam_edges"] < before["seam_edges"] / 4
    check_layout(scan, plan.scan, 1.1)
    density = after["density_px_per_cm"]
    assert density["max"] / density["min"] < 1.01  # uniform texel density
    json.dumps(plan.report)


def test_optimize_keeps_relative_density_when_asked(demo_wall):
    scan = demo_wall.scan
    plan = plan_uvs(scan, "optimize", texture_size=128, equalise_density=False)
    assert plan.report["equalise_density"] is False and plan.scan.has_uvs


# -- unwrap ---------------------------------------------------------------------------------------


def test_unwrap_a_mesh_without_uvs():
    sphere = trimesh.creation.icosphere(2)
    scan = Scan(sphere.vertices, sphere.faces)
    plan = plan_uvs(scan, "unwrap", texture_size=256)
    check_layout(scan, plan.scan, 1.1)
    assert plan.report["before"] is None and plan.report["after"]["shells"] >= 2
    kept = plan_uvs(scan, "keep", texture_size=256)
    assert kept.scan.has_uvs and any("no UVs" in f for f in kept.report["fallbacks"])


def test_unwrap_a_flat_wall_is_one_chart():
    wall = grid_wall(n=20)
    plan = plan_uvs(Scan(wall.positions, wall.faces), "unwrap", texture_size=128)
    assert plan.report["after"]["shells"] == 1 and plan.report["after"]["seam_edges"] == 0


def test_unwrap_and_optimise_see_faces_meet_where_positions_repeat():
    # an STL, or a glTF whose normals are split, repeats a position for every face using it
    wall = grid_wall(n=20)
    split = Scan(wall.positions[wall.faces.reshape(-1)], np.arange(3 * wall.n_faces).reshape(-1, 3))
    plan = plan_uvs(split, "unwrap", texture_size=128)
    assert plan.report["after"]["shells"] == 1 and plan.report["after"]["seam_edges"] == 0
    assert np.array_equal(plan.scan.positions, split.positions) and np.array_equal(plan.scan.faces, split.faces)
    # the unwrapped wall stored with a UV index and a vertex of its own for every face corner: one shell, kept
    F = plan.scan.n_faces
    corners = Scan(split.positions, split.faces, plan.scan.uvs[plan.scan.face_uvs.reshape(-1)],
                   np.arange(3 * F).reshape(F, 3))
    optimised = plan_uvs(corners, "optimize", texture_size=128)
    assert optimised.report["before"]["shells"] == 1 and optimised.report["after"]["shells"] == 1


def test_merging_keeps_a_large_charts_layout_and_places_small_ones_around_it():
    """Unwrapping's merges of slivers into a large chart (``absorb_faces``): the large chart's UVs stay as
    they are, each small chart (laid out anywhere, turned) joins it where they share a seam, and the union is
    still an isometric chart without overlaps: the flat grid is one chart again."""
    from scantex.uv.charts import compact
    from scantex.uv.merge import Merger, MergeLog, Piece
    from scantex.uv.unwrap import interior_edges

    wall = grid_wall(n=24)
    positions, faces = wall.positions, wall.faces
    centre = positions[faces].mean(axis=1)
    rng = np.random.default_rng(1)
    seeds = rng.choice(len(faces), 6, replace=False)
    small = np.full(len(faces), -1)
    for k, seed in enumerate(seeds):  # a few faces around each seed make a small chart
        near = np.argsort(np.linalg.norm(centre - centre[seed], axis=1))[:int(rng.integers(2, 8))]
        small[near[small[near] < 0]] = k
    flat = positions[:, [0, 2]]  # the wall's own plane
    pieces = []
    for k in range(-1, len(seeds)):
        sel = np.flatnonzero(small == k)
        if sel.size == 0:
            continue
        corner_node, vertex = compact(faces[sel])
        turn = rng.uniform(0, 2 * np.pi) if k >= 0 else 0.0
        rotation = np.array([[np.cos(turn), -np.sin(turn)], [np.sin(turn), np.cos(turn)]])
        pieces.append(Piece(sel, corner_node, flat[vertex] @ rotation.T + (rng.normal(0, 9, 2) if k >= 0 else 0)))
    large = pieces[0]
    pairs, corners = interior_edges(faces)
    record = MergeLog()
    merger = Merger(positions, faces, pieces, pairs, corners, 1.1, small_faces=12, absorb_faces=256)
    merged = merger.run(float("inf"), record)
    assert len(merged) == 1 and record.absorbed == len(pieces) - 1 and record.planar == record.lscm == 0
    chart = merged[0]
    assert np.array_equal(np.sort(chart.faces), np.arange(len(faces)))
    rows = np.flatnonzero(np.isin(chart.faces, large.faces))
    assert np.array_equal(chart.faces[rows], large.faces)
    assert np.array_equal(chart.node_uv[chart.corner_node[rows]], large.node_uv[large.corner_node])
    tri_uv = chart.node_uv[chart.corner_node]
    assert np.allclose(tri_uv, flat[faces[chart.faces]], atol=1e-9)  # the small charts' faces where they belong
    assert overlap_share(tri_uv) == 0.0


def test_a_sliver_that_would_close_a_large_charts_cut_is_merged_by_flattening_the_union():
    """A large chart cut along a slit keeps two nodes at each vertex of the slit; a sliver below the slit's
    end touches both sides of it, so welding it joins two of the large chart's own nodes: its layout cannot be
    kept, and the union is flattened afresh (here: its plane) instead of being absorbed."""
    from scantex.uv.charts import compact
    from scantex.uv.merge import Merger, MergeLog, Piece
    from scantex.uv.unwrap import interior_edges

    n, k, r0 = 20, 10, 12  # the slit: grid column k, from vertex row r0 up to the top
    wall = grid_wall(n=n)
    positions, faces = wall.positions, wall.faces
    cells = n - 1
    row, column = np.divmod(np.arange(len(faces)) % (cells * cells), cells)  # each face's cell
    sliver = (row == r0 - 1) & ((column == k - 1) | (column == k))
    large = np.flatnonzero(~sliver)
    corners = faces[large].copy()
    right = (row[large] >= r0) & (column[large] == k)  # faces right of the slit take copies of its vertices
    slit = np.arange(r0, n) * n + k
    copy = np.where(right[:, None] & np.isin(corners, slit), corners + n * n, corners)
    corner_node, key = compact(copy)
    flat = positions[:, [0, 2]]
    pieces = [Piece(large, corner_node, flat[key % (n * n)])]
    small_node, small_key = compact(faces[np.flatnonzero(sliver)])
    pieces.append(Piece(np.flatnonzero(sliver), small_node, flat[small_key] + 7.0))
    pairs, edge_corners = interior_edges(faces)
    record = MergeLog()
    merged = Merger(positions, faces, pieces, pairs, edge_corners, 1.1, small_faces=12, absorb_faces=256).run(
        float("inf"), record)
    assert len(merged) == 1 and record.absorbed == 0 and record.planar == 1
    assert overlap_share(merged[0].node_uv[merged[0].corner_node]) == 0.0


def test_xatlas_runs_in_a_subprocess_and_times_out_cleanly():
    sphere = trimesh.creation.icosphere(2)
    result = _run_xatlas(sphere.vertices, sphere.faces, timeout=120)
    assert result is not None
    region = np.arange(len(sphere.faces))
    pieces = xatlas_pieces(sphere.vertices, sphere.faces, region, result)
    assert sum(len(p[0]) for p in pieces) == len(sphere.faces) and len(pieces) > 1
    assert _run_xatlas(sphere.vertices, sphere.faces, timeout=0.01) is None


def test_unwrap_hands_small_charts_to_xatlas():
    sphere = trimesh.creation.icosphere(2)
    record = UnwrapLog()
    # every chart counts as small: what merging leaves goes to xatlas
    charts = unwrap(sphere.vertices, sphere.faces, UnwrapOptions(min_chart_faces=10**6), record=record)
    assert record.xatlas_regions == 1 and record.xatlas_charts == charts.n_charts
    for d in charts.distortions(sphere.vertices[sphere.faces]):
        assert d.flipped_share == 0


def test_regions_xatlas_misses_are_reported_in_one_line():
    """A fused room leaves thousands of small regions to xatlas; those it misses (here: every one, the time
    budget spent) are one line of the report, not one each, and keep their planar charts."""
    balls = [trimesh.creation.icosphere(1) for _ in range(5)]
    positions = np.concatenate([b.vertices + [3.0 * k, 0, 0] for k, b in enumerate(balls)])
    faces = np.concatenate([b.faces + len(balls[0].vertices) * k for k, b in enumerate(balls)])
    record = UnwrapLog()
    charts = unwrap(positions, faces, UnwrapOptions(min_chart_faces=10**6), time_budget_s=0.0, record=record)
    missed = [f for f in record.fallbacks if f.startswith("xatlas on")]
    assert missed == ["xatlas on 5 regions of 80-80 faces (400 in all) failed or ran out of time: kept their "
                      "small planar charts"]
    assert record.xatlas_regions == 0 and charts.n_charts >= 5


# -- the public entry point ------------------------------------------------------------------------


def test_plan_rejects_bad_arguments(cube):
    with pytest.raises(ValueError, match="mode"):
        plan_uvs(cube, "shuffle")
    with pytest.raises(ValueError, match="threshold"):
        plan_uvs(cube, "optimize", threshold=0.5)


def test_keep_returns_the_scan_itself(cube):
    plan = plan_uvs(cube, "keep")
    assert plan.scan is cube and plan.report["before"] == plan.report["after"]
    assert plan.report["before"]["shells"] == 6 and len(seam_edges(cube)) == 12


def test_plan_reports_its_progress_in_percent_forwards_to_the_end(demo_wall, cube):
    """The UV stage's bar: whole percentages of 100, never backwards (a merge lengthens the merge queue), each
    said once, ending at 100, in every mode. The same layout as without a progress callback."""
    sphere = trimesh.creation.icosphere(2)
    for scan, mode in ((demo_wall.scan, "optimize"), (Scan(sphere.vertices, sphere.faces), "unwrap"), (cube, "keep")):
        said = []
        plan = plan_uvs(scan, mode, texture_size=128, progress=lambda done, total: said.append((done, total)))
        assert {t for _, t in said} == {100} and said[-1] == (100, 100)
        done = [d for d, _ in said]
        assert all(0 <= a < b for a, b in zip(done, done[1:]))
        if mode != "keep":
            assert len(done) > 3  # steps between the start and the end
            assert np.array_equal(plan.scan.uvs, plan_uvs(scan, mode, texture_size=128).scan.uvs)
