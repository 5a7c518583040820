"""Chart flattening, distortion, overlap detection and packing."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from scantex.uv.charts import Charts, compact
from scantex.uv.pack import min_area_rotation, pack
from scantex.uv.param import distortion, distortions, lscm, overlap_share, planar_projection, stretch_of_sums, \
    stretch_sums


def flat_grid(n: int = 6, size: float = 2.0) -> tuple[np.ndarray, np.ndarray]:
    u, v = np.meshgrid(np.linspace(0, size, n), np.linspace(0, size, n))
    points = np.stack([u.ravel(), v.ravel(), np.zeros(n * n)], axis=1)
    idx = np.arange(n * n).reshape(n, n)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, 1:].ravel(), idx[1:, :-1].ravel()
    return points, np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])


def test_distortion_of_an_isometry_and_of_a_stretch():
    points, tris = flat_grid()
    iso = distortion(points[tris], points[tris][..., :2] * 7.0)  # a uniform scale is no distortion
    assert iso.stretch == pytest.approx(1.0, abs=1e-9) and iso.flipped_share == 0
    squash = points[:, :2] * np.array([2.0, 1.0])
    d = distortion(points[tris], squash[tris])
    # singular values (2, 1): Sander's L2 of the inverse, normalised: sqrt((1/4 + 1) / 2 * 2) = sqrt(1.25)
    assert d.stretch == pytest.approx(np.sqrt(1.25), rel=1e-9)
    assert d.max_anisotropy == pytest.approx(2.0)


def test_every_charts_distortion_at_once_is_each_charts_own():
    """Charts of a stretched, a mirrored, a degenerate and no face at all: per chart, the same as one by one."""
    points, tris = flat_grid()
    rng = np.random.default_rng(0)
    tri3 = points[tris]
    tri_uv = points[:, :2][tris] * rng.uniform(0.5, 2.0, (len(tris), 1, 2))
    tri_uv[3] = tri_uv[3][[0, 2, 1]]  # mirrored
    tri3[7] = tri3[7][[0, 0, 0]]  # no surface
    chart = rng.integers(0, 6, len(tris))
    chart[chart == 4] = 5  # chart 4: no faces
    chart[7] = 6  # chart 6: only the degenerate face
    together = distortions(tri3, tri_uv, chart)
    assert len(together) == 7
    for c, d in enumerate(together):
        alone = distortion(tri3[chart == c], tri_uv[chart == c])
        for field in ("stretch", "max_anisotropy", "flipped_share", "surface_area", "uv_area"):
            assert getattr(d, field) == pytest.approx(getattr(alone, field), rel=1e-12), (c, field)


def test_distortion_counts_mirrored_faces():
    points, tris = flat_grid()
    uv = points[:, :2].copy()
    tri_uv = uv[tris]
    tri_uv[0] = tri_uv[0][[0, 2, 1]]  # one face mirrored
    d = distortion(points[tris], tri_uv)
    assert 0 < d.flipped_share < 0.1


def test_planar_projection_keeps_lengths_and_winding():
    points, tris = flat_grid()
    rotation = trimesh.transformations.random_rotation_matrix(np.random.default_rng(1).random(3))[:3, :3]
    moved = points @ rotation.T + 5.0
    uv = planar_projection(moved, tris)
    d = distortion(moved[tris], uv[tris])
    assert d.stretch == pytest.approx(1.0, abs=1e-9) and d.flipped_share == 0
    assert d.uv_area == pytest.approx(4.0)
    e1, e2 = uv[tris[:, 1]] - uv[tris[:, 0]], uv[tris[:, 2]] - uv[tris[:, 0]]
    assert (e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0] > 0).all()  # counter-clockwise seen from the front


def test_lscm_unfolds_a_bent_strip_isometrically():
    points, tris = flat_grid(n=7)
    bent = points.copy()
    fold = bent[:, 0] > 1.0
    bent[fold, 2] = bent[fold, 0] - 1.0  # the right half turned up by 90 degrees
    bent[fold, 0] = 1.0
    # projected onto the mean plane each half is squashed by cos 45°: L2 stretch sqrt((1 + 1/2) / sqrt(2))
    planar = distortion(bent[tris], planar_projection(bent, tris)[tris])
    assert planar.stretch == pytest.approx(np.sqrt(1.5 / np.sqrt(2)))
    assert planar.max_anisotropy == pytest.approx(np.sqrt(2))
    uv = lscm(bent, tris)
    d = distortion(bent[tris], uv[tris])
    assert d.stretch == pytest.approx(1.0, abs=1e-6) and d.flipped_share == 0
    assert d.uv_area == pytest.approx(d.surface_area)


def test_lscm_pinned_keeps_its_pins_and_places_the_rest_in_their_frame():
    """A piece joined to a chart that keeps its layout: its shared vertices stay where the chart has them and
    the others follow in the chart's scale and turn (the grid bent up by 90 degrees on the right, pinned by
    its left column where its own flat layout, turned by 30 degrees and moved, has it: laid flat again the
    same way around the pins)."""
    points, tris = flat_grid()
    bent = points.copy()
    fold = bent[:, 0] > 1.0
    bent[fold, 2] = bent[fold, 0] - 1.0
    bent[fold, 0] = 1.0
    turn = np.deg2rad(30.0)
    rotation = np.array([[np.cos(turn), -np.sin(turn)], [np.sin(turn), np.cos(turn)]])
    truth = lscm(bent, tris) @ rotation.T + [5.0, -2.0]
    pins = np.flatnonzero(points[:, 0] == 0.0)  # the left column
    uv = lscm(bent, tris, pins=(pins, truth[pins]))
    assert np.array_equal(uv[pins], truth[pins])
    assert np.allclose(uv, truth, atol=1e-6)
    d = distortion(bent[tris], uv[tris])
    assert d.stretch == pytest.approx(1.0, abs=1e-6) and d.flipped_share == 0


def test_stretch_sums_add_up_to_the_unions_distortion():
    points, tris = flat_grid(8)
    rng = np.random.default_rng(3)
    uv = points[:, :2] * [1.0, 1.3] + rng.normal(0.0, 0.01, (len(points), 2))
    half = np.arange(len(tris)) < len(tris) // 3
    left, left_signed = stretch_sums(points[tris[half]], uv[tris[half]])
    right, _ = stretch_sums(points[tris[~half]], uv[tris[~half]])
    whole = distortion(points[tris], uv[tris])
    assert stretch_of_sums(left + right) == pytest.approx(whole.stretch, rel=1e-12)
    assert (left + right)[1] == pytest.approx(whole.uv_area, rel=1e-12)
    assert (left_signed > 0).all()
    assert stretch_of_sums(np.zeros(4)) == float("inf")


def test_lscm_of_a_sphere_cap_has_scale_distortion():
    sphere = trimesh.creation.icosphere(3)
    keep = sphere.triangles_center[:, 2] > 0.2
    tris, vertex = compact(sphere.faces[keep])
    uv = lscm(sphere.vertices[vertex], tris)
    d = distortion(sphere.vertices[vertex][tris], uv[tris])
    assert d.flipped_share == 0 and 1.01 < d.stretch < 1.2


def test_overlap_share_sees_a_fold_but_not_shared_edges():
    points, tris = flat_grid()
    assert overlap_share(points[tris][..., :2]) == 0.0
    folded = points[:, :2].copy()
    folded[folded[:, 0] > 1.0, 0] = 2.0 - folded[folded[:, 0] > 1.0, 0]  # right half folded onto the left
    assert overlap_share(folded[tris]) > 0.3


def test_min_area_rotation_straightens_a_turned_rectangle():
    rect = np.array([[0, 0], [3, 0], [3, 1], [0, 1]], float)
    a = 0.4
    turned = rect @ np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]]).T
    R = min_area_rotation(turned)
    q = turned @ R.T
    ext = q.max(axis=0) - q.min(axis=0)
    assert ext == pytest.approx([3.0, 1.0]) and np.linalg.det(R) == pytest.approx(1.0)


def test_pack_places_charts_apart_at_one_density():
    # three square charts of 1, 2 and 0.5 metres
    face_uvs, uvs, chart = [], [], []
    for c, side in enumerate([1.0, 2.0, 0.5]):
        base = len(uvs)
        uvs += [[0, 0], [side, 0], [side, side], [0, side]]
        face_uvs += [[base, base + 1, base + 2], [base, base + 2, base + 3]]
        chart += [c, c]
    charts = Charts(np.array(chart), np.array(face_uvs), np.array(uvs, float))
    atlas = pack(charts, 256, gutter=3)
    assert (atlas.uvs >= 0).all() and (atlas.uvs <= 1).all()
    px = atlas.uvs * 256
    boxes = []
    for c in range(3):
        p = px[np.unique(atlas.face_uvs[np.array(chart) == c])]
        boxes.append((p.min(axis=0), p.max(axis=0)))
        side = [1.0, 2.0, 0.5][c]
        assert (p.max(axis=0) - p.min(axis=0)) == pytest.approx([side * atlas.texels_per_metre] * 2)
    for i in range(3):
        for j in range(i + 1, 3):
            gap = np.maximum(boxes[j][0] - boxes[i][1], boxes[i][0] - boxes[j][1]).max()
            assert gap >= 2 * 3 - 1  # gutters of both charts, less one texel of rounding
    assert atlas.texels_per_metre > 256 / 3.5 * 0.8  # a decent fill: 2 + 1 + 0.5 metres across at most


def test_pack_turns_strips_beside_a_large_chart_that_shelves_leave_empty():
    """A square chart half the atlas wide and long thin strips (a cushion's top and its sides): shelves put
    every strip below the square, leaving the room beside it empty; the skyline turns strips upright into
    it. The charts stay apart, each at the one density, turned without mirroring."""
    from scantex.uv.pack import shelf_pack

    face_uvs, uvs, chart, sides = [], [], [], [(1.0, 1.0)] + [(1.1, 0.15)] * 6
    for c, (w, h) in enumerate(sides):
        base = len(uvs)
        uvs += [[0, 0], [w, 0], [w, h], [0, h]]
        face_uvs += [[base, base + 1, base + 2], [base, base + 2, base + 3]]
        chart += [c, c]
    charts = Charts(np.array(chart), np.array(face_uvs), np.array(uvs, float))
    shelf_scale, _ = shelf_pack(np.array(sides), 512, 2)
    atlas = pack(charts, 512, gutter=2)
    assert atlas.texels_per_metre > 1.2 * shelf_scale and atlas.utilisation > 0.75
    px = atlas.uvs * 512
    boxes = []
    for c, (w, h) in enumerate(sides):
        faces = np.flatnonzero(np.array(chart) == c)
        p = px[np.unique(atlas.face_uvs[faces])]
        extent = np.sort(p.max(axis=0) - p.min(axis=0))
        assert extent == pytest.approx(np.sort([w, h]) * atlas.texels_per_metre)
        tri = px[atlas.face_uvs[faces]]
        e1, e2 = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
        assert (e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0] > 0).all()  # counter-clockwise in UV, as given
        boxes.append((p.min(axis=0), p.max(axis=0)))
    turned = sum(b[1][1] - b[0][1] > b[1][0] - b[0][0] for b in boxes[1:])
    assert turned >= 1
    for i in range(len(boxes)):
        for j in range(i + 1, len(boxes)):
            gap = np.maximum(boxes[j][0] - boxes[i][1], boxes[i][0] - boxes[j][1]).max()
            assert gap >= 2 * 2 - 1


def test_compiled_skyline_places_every_box_as_its_python_twin():
    from scantex.uv.pack import skyline_place, skyline_place_reference

    rng = np.random.default_rng(7)
    fitted = 0
    for trial in range(200):
        n = int(rng.integers(1, 50))
        boxes = rng.integers(1, 40, (n, 2))
        if trial % 4 == 0:
            boxes[:, 1] = boxes[:, 0]  # squares: never turned
        size = int(rng.integers(16, 160))
        for by_area in (True, False):
            got, want = skyline_place(boxes, size, by_area), skyline_place_reference(boxes, size, by_area)
            assert (got is None) == (want is None)
            if want is not None:
                fitted += 1
                assert np.array_equal(got[0], want[0]) and np.array_equal(got[1], want[1])
    assert 50 < fitted < 400  # both outcomes were exercised


@pytest.mark.parametrize("compiled", [True, False])
def test_many_charts_go_on_the_skyline_only_when_it_is_compiled(compiled, monkeypatch):
    """Past ``SKYLINE_MAX_CHARTS`` charts the Python skyline is too slow to run; compiled, it packs any
    number (here a square half the atlas wide beside many small squares: shelves leave the room beside it
    empty)."""
    from scantex import jit
    from scantex.uv import pack as packing

    if not compiled:
        monkeypatch.setattr(jit, "compiled", lambda function: None)
    monkeypatch.setattr(packing, "SKYLINE_MAX_CHARTS", 20)
    sides = [1.0] + [0.12] * 40
    face_uvs, uvs, chart = [], [], []
    for c, w in enumerate(sides):
        base = len(uvs)
        uvs += [[0, 0], [w, 0], [w, w], [0, w]]
        face_uvs += [[base, base + 1, base + 2], [base, base + 2, base + 3]]
        chart += [c, c]
    charts = Charts(np.array(chart), np.array(face_uvs), np.array(uvs, float))
    shelf_scale, _ = packing.shelf_pack(np.array([[w, w] for w in sides]), 256, 2)
    atlas = pack(charts, 256, gutter=2)
    if compiled:
        assert atlas.texels_per_metre > 1.08 * shelf_scale  # 1.105 x: the squares stacked beside the big one
    else:
        assert atlas.texels_per_metre == shelf_scale


def test_pack_fails_loudly_when_nothing_fits():
    charts = Charts(np.zeros(1, np.int64), np.array([[0, 1, 2]]), np.array([[0, 0], [1, 0], [0, 1.0]]))
    with pytest.raises(ValueError, match="do not fit"):
        pack(charts, 8, gutter=4)


def test_charts_flattened_together_as_one_by_one():
    """``flatten_planar_all`` and ``overlap_shares`` give each chart what the one-chart functions give it: planar
    projections, the same acceptance (stretch, mirrored faces, overlap) and overlap shares."""
    from scantex.uv.param import overlap_shares
    from scantex.uv.unwrap import flatten_planar, flatten_planar_all

    sphere = trimesh.creation.icosphere(3)
    rng = np.random.default_rng(1)
    positions = sphere.vertices + rng.normal(0, 0.01, sphere.vertices.shape)  # rough: some charts fail
    order = np.argsort(sphere.triangles_center[:, 0] * 7 + sphere.triangles_center[:, 1])  # bands, some folded
    sizes = [1, 2, 3, 5, 8, 40, 120, 200]
    charts = [np.sort(c) for c in np.split(order, np.cumsum(sizes))]
    together = flatten_planar_all(positions, sphere.faces, charts, 1.1)
    results = [flatten_planar(positions, sphere.faces, c, 1.1) for c in charts]
    assert {r is None for r in results} == {True, False}  # both verdicts occur
    for one, both in zip(results, together):
        assert (one is None) == (both is None)
        if one is not None:
            assert np.array_equal(one[0], both[0]) and np.allclose(one[1], both[1], atol=1e-12)
    points, tris = flat_grid()
    folded = points[:, :2].copy()
    folded[folded[:, 0] > 1.0, 0] = 2.0 - folded[folded[:, 0] > 1.0, 0]
    uv = np.concatenate([points[tris][..., :2], folded[tris], folded[tris][:2], folded[tris][:1]])
    chart = np.repeat([0, 1, 2, 3], [len(tris), len(tris), 2, 1])
    shares = overlap_shares(uv, chart, 5)
    assert shares[0] == 0 and shares[1] == overlap_share(folded[tris]) > 0.3 and not shares[2:].any()


def test_overlapped_faces_are_the_faces_sharing_a_texel(monkeypatch):
    """The atlas's own grid (its texel centres, strictly inside): a fold's faces, not faces that only share an
    edge; the compiled pass and its numpy twin agree."""
    from scantex import jit
    from scantex.uv.param import _owned_texels, overlapped_faces

    points, tris = flat_grid()  # 2 m: 50 texels a side at 25 texels a metre
    flat = points[tris][..., :2] * 25
    folded = points[:, :2].copy()
    folded[folded[:, 0] > 1.2, 0] = 2.4 - folded[folded[:, 0] > 1.2, 0]  # the right 0.8 m folded back
    fold = folded[tris] * 25 + [60, 0]
    both = np.concatenate([flat, fold])
    found = overlapped_faces(both, 128)
    assert not found[:len(tris)].any()  # shared edges are no overlap
    reach = fold[:, :, 0].max(axis=1)
    assert found[len(tris):][fold[:, :, 0].min(axis=1) > 60 + 1.2 * 25].all()  # every folded face
    assert not found[len(tris):][reach < 60 + 0.4 * 25 - 1].any()  # the left part, away from the fold
    assert jit.compiled(_owned_texels) is not None  # numba is installed here: the compiled pass ran
    monkeypatch.setattr(jit, "compiled", lambda function: None)  # the numpy twin, as where numba is missing
    assert np.array_equal(overlapped_faces(both, 128), found)


def test_faces_sharing_texels_are_laid_out_apart(monkeypatch):
    """A chart folded onto itself (a merge's or a flattening's fold its coarser test let through) gave two
    surfaces the same texels, one painted with the other's colours: those faces become charts of their own."""
    from scantex.scan import Scan
    from scantex.uv.param import overlapped_faces
    from scantex.uv.plan import _packed_scan

    points, tris = flat_grid()
    folded = points[:, :2].copy()
    folded[folded[:, 0] > 1.2, 0] = 2.4 - folded[folded[:, 0] > 1.2, 0]
    charts = Charts(np.zeros(len(tris), np.int64), tris.copy(), folded.copy())
    report: dict = {}
    scan = _packed_scan(Scan(points, tris), charts, 256, 2, report)
    assert report["faces_apart"] > 0
    assert not overlapped_faces(scan.uvs[scan.face_uvs] * 256, 256).any()
    # the fold's far layer (its faces mirrored) moves whole, one chart: face by face it made one chart a face
    from scantex.atlas.seams import uv_shells

    assert uv_shells(scan).max() + 1 == 2
    # overlaps without a mirror (two pieces of one chart laid over each other): all but the largest group move,
    # each whole
    shifted = points[:, :2].copy()
    shifted[shifted[:, 0] > 1.2, 0] -= 0.8
    right = (points[tris][:, :, 0] > 1.2 - 1e-9).all(axis=1)
    corner_of = tris.copy()
    corner_of[right] += len(points)  # the right part a piece of its own in the chart, not joined at x = 1.2
    charts = Charts(np.zeros(len(tris), np.int64), corner_of, np.concatenate([points[:, :2], shifted]))
    report = {}
    scan = _packed_scan(Scan(points, tris), charts, 256, 2, report)
    assert report["faces_apart"] > 0 and not overlapped_faces(scan.uvs[scan.face_uvs] * 256, 256).any()
    assert uv_shells(scan).max() + 1 <= 3
    # past MAX_GROUPS conformal maps, groups move face by face (bounded time on a layout folded everywhere)
    import scantex.uv.charts as charts_module

    monkeypatch.setattr(charts_module, "MAX_GROUPS", 0)
    scan = _packed_scan(Scan(points, tris), charts, 256, 2, {})
    assert not overlapped_faces(scan.uvs[scan.face_uvs] * 256, 256).any() and uv_shells(scan).max() + 1 > 3
