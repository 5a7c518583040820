"""The synthetic demo scans: geometry, charts, ground truth, degradation, determinism, writing."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import ndimage, sparse

from scantex.atlas.texelmap import texel_map, uv_to_pixel
from scantex.synth import (
    Degradation, DemoScan, Finish, ProceduralAlbedo, Unwrap, make_geometry, make_room, make_wall,
    render_ground_truth, room_panels, wall_panels, write_demo,
)
from scantex.synth.charts import pack_charts, split_charts
from scantex.synth.noise import NoiseField
from scantex.synth.procedural import brick_layout
from scantex.views.camera import Camera
from scantex.views.raycast import RayCaster, cast_gbuffer
from scantex.views.render import render

TINY = dict(grid=(24, 18), gt_texture_size=256, scan_texture_size=64)
SMALL = dict(grid=(48, 36), gt_texture_size=512, scan_texture_size=128, n_charts=12)


@pytest.fixture(scope="module")
def tiny_wall() -> DemoScan:
    return make_wall(0, **TINY)


@pytest.fixture(scope="module")
def small_wall() -> DemoScan:
    return make_wall(3, **SMALL)


@pytest.fixture(scope="module")
def room() -> DemoScan:
    return make_room(0, gt_texture_size=256, scan_texture_size=128)


def wall_camera(width: int = 160, height: int = 120) -> Camera:
    return Camera.look_at((0.2, -1.8, 1.5), (0.0, 0.0, 1.5), fov_deg=75, width=width, height=height)


def psnr(a: np.ndarray, b: np.ndarray) -> float:
    return float(-10 * np.log10(np.mean((a.astype(np.float64) - b) ** 2)))


def connected_components(faces: np.ndarray, n_vertices: int) -> int:
    """Components of the vertex graph of ``faces`` that faces reach."""
    edges = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]]])
    graph = sparse.coo_matrix((np.ones(len(edges)), (edges[:, 0], edges[:, 1])), shape=(n_vertices,) * 2)
    _, label = sparse.csgraph.connected_components(graph, directed=False)
    return len(np.unique(label[faces.ravel()]))


# -- smoke and shapes ------------------------------------------------------------------------------------


def test_tiny_wall_shapes(tiny_wall):
    scan, gt = tiny_wall.scan, tiny_wall.ground_truth
    assert scan.positions.shape == (24 * 18, 3)
    assert scan.faces.shape == (2 * 23 * 17, 3)
    assert scan.materials[0].image.shape == (64, 64, 3) and scan.materials[0].image.dtype == np.uint8
    assert gt.materials[0].image.shape == (256, 256, 3) and gt.materials[0].image.dtype == np.uint8
    # same geometry and UVs, only the texture differs
    assert gt.positions is scan.positions and gt.faces is scan.faces
    np.testing.assert_array_equal(gt.face_uvs, scan.face_uvs)
    assert scan.materials[0].image_name != gt.materials[0].image_name
    assert tiny_wall.chart_of_face.shape == (len(scan.faces),)
    assert tiny_wall.name == "wall" and tiny_wall.seed == 0
    assert ((scan.uvs >= 0) & (scan.uvs <= 1)).all()


def test_default_wall_counts_and_size():
    mesh = make_geometry(wall_panels(), seed=0)  # the default wall's geometry, without its 4096² bake
    assert mesh.positions.shape == (40_000, 3)
    assert mesh.faces.shape == (79_202, 3)
    extent = mesh.positions.max(axis=0) - mesh.positions.min(axis=0)
    assert extent[0] == pytest.approx(4.0, abs=0.01) and extent[2] == pytest.approx(3.0, abs=0.01)
    # relief and scanner noise: a few millimetres of depth, no more
    assert 0.003 < extent[1] < 0.03


def test_wall_matches_its_geometry_only_path(tiny_wall):
    mesh = make_geometry(wall_panels(grid=TINY["grid"]), seed=0)
    np.testing.assert_array_equal(mesh.positions, tiny_wall.scan.positions)
    np.testing.assert_array_equal(mesh.faces, tiny_wall.scan.faces)


def test_bad_input_raises():
    with pytest.raises(ValueError, match="whole multiple"):
        make_wall(grid=(8, 8), gt_texture_size=200, scan_texture_size=64)
    with pytest.raises(ValueError, match="at least 2 x 2"):
        make_wall(grid=(1, 8))
    with pytest.raises(ValueError, match="unknown finish"):
        Finish("marble")
    with pytest.raises(ValueError, match=r"\(N, 3\)"):
        ProceduralAlbedo(wall_panels())(np.zeros((4, 2)))


# -- geometry --------------------------------------------------------------------------------------------


def test_wall_faces_look_towards_minus_y():
    mesh = make_geometry(wall_panels(grid=(60, 45)), seed=1)
    t = mesh.positions[mesh.faces]
    n = np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    assert (n[:, 1] < -0.7).all()
    assert n[:, 1].mean() < -0.97


def test_mortar_joints_are_recessed():
    panel = wall_panels(grid=(200, 200))[0]
    mesh = make_geometry((panel,), seed=0)
    uv = panel.plane_coordinates(mesh.positions)
    _, _, joint = brick_layout(uv[:, 0].astype(np.float32), uv[:, 1].astype(np.float32))
    # +y is away from the cameras: joints lie deeper than brick faces
    depth_in_joints = mesh.positions[joint < 0.002, 1].mean()
    depth_on_bricks = mesh.positions[joint > 0.02, 1].mean()
    assert depth_in_joints - depth_on_bricks > 0.002


def test_room_faces_point_into_the_room(room):
    scan = room.scan
    X, Y = 4.0, 3.0
    caster = RayCaster(scan.positions, scan.faces)
    rng = np.random.default_rng(0)
    directions = rng.normal(size=(4000, 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    hits = caster.intersect(np.array([0.5 * X, 0.5 * Y, 1.6]), directions)
    seen = hits.face_id >= 0
    # an open-topped room: rays upwards escape, every other ray hits a face that faces the camera
    assert seen.mean() > 0.5
    facing = np.einsum("ij,ij->i", scan.face_normals[hits.face_id[seen]], directions[seen])
    assert (facing < 0).all()


def test_room_is_one_welded_shell_plus_boxes(room):
    scan = room.scan
    assert 2000 < scan.n_faces < 8000
    # floor and walls share their edges; each of the two boxes is its own piece
    assert connected_components(scan.faces, scan.n_vertices) == 3


# -- charts and UVs --------------------------------------------------------------------------------------


def test_default_wall_charts_are_many_connected_and_packed_apart():
    panels = wall_panels()
    mesh = make_geometry(panels, seed=0)
    rng = np.random.default_rng(5)
    unwrap = Unwrap()
    chart_of_face = split_charts(mesh, panels, unwrap.n_charts, unwrap, rng)
    n = chart_of_face.max() + 1
    assert 60 <= n <= 100
    cells = np.full(panels[0].cells, -1)
    cells[mesh.cell_of_face[:, 0], mesh.cell_of_face[:, 1]] = chart_of_face
    for c in range(n):
        assert ndimage.label(cells == c)[1] == 1, f"chart {c} is in pieces"

    layout = pack_charts(mesh, panels, chart_of_face, 1024, unwrap, rng)
    pix = uv_to_pixel(layout.uvs[layout.face_uvs], 1024, 1024)  # [F, 3, 2]
    lo = np.full((n, 2), np.inf)
    hi = np.full((n, 2), -np.inf)
    np.minimum.at(lo, chart_of_face, pix.min(axis=1))
    np.maximum.at(hi, chart_of_face, pix.max(axis=1))
    gap = 2 * unwrap.gutter_texels - 1e-6
    for a in range(n):
        apart = (lo[a, 0] - hi[:, 0] >= gap) | (lo[:, 0] - hi[a, 0] >= gap) \
            | (lo[a, 1] - hi[:, 1] >= gap) | (lo[:, 1] - hi[a, 1] >= gap)
        apart[a] = True
        assert apart.all(), f"chart {a} is closer than the gutters to another chart"


def test_seams_rotations_and_shuffled_packing(small_wall):
    scan = small_wall.scan
    # one UV per (chart, vertex): a position on a chart border has several UVs
    pairs = np.unique(np.stack([scan.faces.ravel(), scan.face_uvs.ravel()], axis=1), axis=0)
    uvs_per_position = np.bincount(pairs[:, 0], minlength=scan.n_vertices)
    assert (uvs_per_position > 1).sum() > 50
    chart_pairs = np.unique(np.stack([np.repeat(small_wall.chart_of_face, 3), scan.faces.ravel(),
                                      scan.face_uvs.ravel()], axis=1), axis=0)
    assert len(chart_pairs) == len(np.unique(chart_pairs[:, :2], axis=0))

    uv = scan.triangle_uvs
    e1, e2 = uv[:, 1] - uv[:, 0], uv[:, 2] - uv[:, 0]
    assert (e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0] > 0).all(), "a chart is mirrored"
    # a chart turned by 90°: atlas u grows along the wall's z instead of its x
    xz = scan.triangles[:, :, [0, 2]]
    edges_xz = np.stack([xz[:, 1] - xz[:, 0], xz[:, 2] - xz[:, 0]], axis=1)  # [F, 2, 2]
    du = np.stack([e1[:, 0], e2[:, 0]], axis=1)  # [F, 2]
    gradient = np.linalg.solve(edges_xz, du[..., None])[..., 0]  # [F, 2]: du/dx, du/dz
    turned = np.abs(gradient[:, 1]) > np.abs(gradient[:, 0])
    faces_per_chart = np.bincount(small_wall.chart_of_face)
    share = np.mean(np.bincount(small_wall.chart_of_face, weights=turned) / faces_per_chart > 0.5)
    assert 0.05 < share < 0.7

    # atlas order does not follow the wall: reading orders are unrelated
    centre = scan.triangles.mean(axis=1)
    chart = small_wall.chart_of_face
    n = chart.max() + 1
    wall_x = np.bincount(chart, weights=centre[:, 0]) / faces_per_chart
    atlas_u = np.bincount(chart, weights=uv[:, :, 0].mean(axis=1)) / faces_per_chart
    rank = lambda a: np.argsort(np.argsort(a))  # noqa: E731
    assert abs(np.corrcoef(rank(wall_x), rank(atlas_u))[0, 1]) < 0.8
    assert n == small_wall.n_charts >= 8


# -- ground truth ----------------------------------------------------------------------------------------


def test_ground_truth_is_the_albedo_at_texel_centres():
    demo = make_wall(0, **TINY, supersample=1)
    gt = demo.ground_truth
    texels = texel_map(gt.triangle_uvs, 256, 256)
    expected = demo.albedo(texels.points(gt.triangles))
    stored = gt.materials[0].image[texels.mask].astype(np.float64) / 255
    assert np.abs(stored - expected).max() <= 0.5 / 255 + 1e-6


def test_supersampled_bake_matches_a_per_triangle_reference(small_wall):
    """Sub-texel points found by searching the containing UV triangle, against the Jacobian shortcut."""
    gt = small_wall.ground_truth
    size = gt.materials[0].image.shape[0]
    pix = uv_to_pixel(gt.triangle_uvs, size, size)  # [F, 3, 2]
    texels = texel_map(gt.triangle_uvs, size, size)
    rng = np.random.default_rng(0)
    rows, cols = np.nonzero(texels.mask)
    pick = rng.choice(len(rows), 150, replace=False)
    a, b, c = pix[:, 0], pix[:, 1], pix[:, 2]
    det = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0])
    checked = 0
    for r, q in zip(rows[pick], cols[pick]):
        samples = []
        for dy in (-0.25, 0.25):
            for dx in (-0.25, 0.25):
                p = np.array([q + dx, r + dy])
                w1 = ((p[0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (p[1] - a[:, 1]) * (c[:, 0] - a[:, 0])) / det
                w2 = ((b[:, 0] - a[:, 0]) * (p[1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (p[0] - a[:, 0])) / det
                inside = np.flatnonzero((w1 >= 0) & (w2 >= 0) & (w1 + w2 <= 1))
                if inside.size == 0:
                    break
                f = inside[0]
                t = gt.triangles[f]
                samples.append((1 - w1[f] - w2[f]) * t[0] + w1[f] * t[1] + w2[f] * t[2])
        if len(samples) < 4:  # a sub-texel point beyond the chart's edge: no reference there
            continue
        expected = small_wall.albedo(np.array(samples)).mean(axis=0)
        stored = gt.materials[0].image[r, q] / 255
        np.testing.assert_allclose(stored, expected, atol=1.0 / 255)
        checked += 1
    assert checked > 100


def test_ground_truth_atlas_renders_like_the_exact_albedo(small_wall):
    camera = wall_camera()
    exact, alpha = render_ground_truth(small_wall, camera, supersample=2)
    through_atlas, _ = render(small_wall.ground_truth, camera, supersample=2)
    assert alpha.min() == 1.0  # the wall fills the view
    assert psnr(through_atlas, exact) > 26


# -- degradation -----------------------------------------------------------------------------------------


def test_degraded_scan_is_measurably_worse(small_wall):
    camera = wall_camera()
    exact, _ = render_ground_truth(small_wall, camera, supersample=2)
    scan_view, _ = render(small_wall.scan, camera, supersample=2)
    gt_view, _ = render(small_wall.ground_truth, camera, supersample=2)
    scan_psnr = psnr(scan_view, exact)
    assert np.isfinite(scan_psnr)
    assert psnr(gt_view, exact) > scan_psnr + 5


def test_holes_are_black_blobs_in_the_scan_only(small_wall):
    scan = small_wall.scan
    holes = small_wall.hole_faces
    area = scan.face_areas
    assert 0.02 <= area[holes].sum() / area.sum() <= 0.045
    assert connected_components(scan.faces[holes], scan.n_vertices) <= Degradation().hole_clusters

    camera = Camera.look_at((0.0, -4.5, 1.5), (0.0, 0.0, 1.5), fov_deg=60, width=320, height=240)
    g = cast_gbuffer(RayCaster(scan.positions, scan.faces), camera, scan.face_normals)
    is_hole = np.zeros(scan.n_faces, dtype=bool)
    is_hole[holes] = True
    # pixels well inside a hole, whose bilinear lookups touch hole texels only: 5 pixels (8 cm) are
    # two texels of this wall's 128² atlas
    inside = ndimage.binary_erosion(is_hole[g.face_id] & g.mask, iterations=5)
    assert inside.sum() > 50
    scan_view, _ = render(scan, camera)
    gt_view, _ = render(small_wall.ground_truth, camera)
    assert (scan_view[inside] == 0).all()
    assert gt_view[inside].min() > 0.05


def test_charts_get_their_own_exposure(small_wall):
    scan, gt = small_wall.scan, small_wall.ground_truth
    size = scan.materials[0].image.shape[0]
    texels = texel_map(scan.triangle_uvs, size, size)
    truth = gt.materials[0].image.astype(np.float64).reshape(size, 4, size, 4, 3).mean(axis=(1, 3))
    keep = texels.mask & ~np.isin(texels.face_id, small_wall.hole_faces)
    chart = small_wall.chart_of_face[texels.face_id[keep]]
    ratio = scan.materials[0].image[keep].mean(axis=1) / np.maximum(truth[keep].mean(axis=1), 1)
    per_chart = np.bincount(chart, weights=ratio) / np.bincount(chart)
    per_chart = per_chart[np.bincount(chart) > 20]
    assert per_chart.std() > 0.03


# -- determinism -----------------------------------------------------------------------------------------


def test_same_seed_same_demo_other_seed_other_demo(tiny_wall):
    again = make_wall(0, **TINY)
    other = make_wall(1, **TINY)
    for field in ("positions", "faces", "uvs", "face_uvs"):
        np.testing.assert_array_equal(getattr(again.scan, field), getattr(tiny_wall.scan, field))
    for demo in ("scan", "ground_truth"):
        np.testing.assert_array_equal(getattr(again, demo).materials[0].image,
                                      getattr(tiny_wall, demo).materials[0].image)
    np.testing.assert_array_equal(again.hole_faces, tiny_wall.hole_faces)
    np.testing.assert_array_equal(again.chart_of_face, tiny_wall.chart_of_face)
    assert not np.array_equal(other.scan.positions, tiny_wall.scan.positions)
    assert not np.array_equal(other.ground_truth.materials[0].image, tiny_wall.ground_truth.materials[0].image)
    assert not np.array_equal(other.scan.uvs, tiny_wall.scan.uvs)


def test_albedo_is_deterministic_chunked_and_in_range():
    panels = room_panels()
    rng = np.random.default_rng(0)
    points = rng.uniform([0, 0, 0], [4, 3, 2.5], (150_000, 3))  # more than one chunk
    albedo = ProceduralAlbedo(panels, seed=2)
    colours = albedo(points)
    assert colours.dtype == np.float32 and colours.shape == (150_000, 3)
    assert colours.min() >= 0 and colours.max() <= 1
    np.testing.assert_array_equal(colours, ProceduralAlbedo(panels, seed=2)(points))
    # the threaded, chunked path against one plain evaluation
    np.testing.assert_array_equal(colours[:5000], albedo._evaluate(points[:5000]))
    assert np.abs(colours - ProceduralAlbedo(panels, seed=3)(points)).mean() > 0.01


def test_albedo_has_millimetre_detail():
    albedo = ProceduralAlbedo(wall_panels(finish=Finish("plaster", cracks=0.0)))
    x = np.linspace(-1.0, -0.9, 2001)
    line = albedo(np.stack([x, np.zeros_like(x), np.full_like(x, 1.3)], axis=1)).mean(axis=1)
    # detail a 4 mm texel averages away, a 1 mm one keeps
    fine = line - ndimage.uniform_filter1d(line, 80)  # 80 samples = 4 mm
    assert fine.std() > 0.01


def test_noise_field_is_periodic_with_unit_variance():
    field = NoiseField.random(np.random.default_rng(0), spacing=0.01, n=64)
    assert field.lattice.std() == pytest.approx(1.0, rel=1e-4)
    u = np.random.default_rng(1).uniform(0, 1, 1000)
    v = np.random.default_rng(2).uniform(0, 1, 1000)
    np.testing.assert_allclose(field(u, v), field(u + 0.64, v - 1.28), atol=1e-4)
    # at the lattice nodes, the field is the lattice
    nodes = np.arange(64) * 0.01
    np.testing.assert_allclose(field(nodes, np.full(64, 0.03)), field.lattice[3], atol=1e-5)


# -- writing ---------------------------------------------------------------------------------------------


def test_write_demo_round_trips(tiny_wall, tmp_path):
    from scantex.io import load_scan

    paths = write_demo(tiny_wall, tmp_path)
    assert set(paths) == {"scan", "ground_truth"}
    assert (tmp_path / "scan_albedo.png").exists() and (tmp_path / "ground_truth_albedo.png").exists()
    for name, original in (("scan", tiny_wall.scan), ("ground_truth", tiny_wall.ground_truth)):
        loaded = load_scan(paths[name])
        np.testing.assert_array_equal(loaded.faces, original.faces)
        np.testing.assert_allclose(loaded.positions, original.positions, atol=1e-9)
        np.testing.assert_array_equal(loaded.materials[0].image[..., :3], original.materials[0].image)


def test_app_wall_is_a_subtle_sharp_degradation():
    """The app-realistic variant: full-resolution atlas, small holes, subtle exposure, far closer to the
    truth than the demo wall's degradation, yet not the truth."""
    from scantex.synth import make_app_wall
    from scantex.synth.wall import APP_LIKE

    app = make_app_wall(0, grid=(60, 46), size_m=(2.0, 1.5), texture_size=512, n_charts=12, supersample=1)
    poor = make_wall(0, grid=(60, 46), size_m=(2.0, 1.5), gt_texture_size=512, scan_texture_size=512, n_charts=12,
                     supersample=1)
    assert app.scan.materials[0].image.shape == app.ground_truth.materials[0].image.shape == (512, 512, 3)
    area = app.scan.face_areas
    assert 0 < area[app.hole_faces].sum() / area.sum() <= 2 * APP_LIKE.hole_share
    camera = Camera.look_at((0.0, -2.2, 0.75), (0.0, 0.0, 0.75), fov_deg=60, width=160, height=120)
    exact, _ = render_ground_truth(app, camera, supersample=2)
    app_view, _ = render(app.scan, camera, supersample=2)
    poor_view, _ = render(poor.scan, camera, supersample=2)
    assert psnr(app_view, exact) > psnr(poor_view, exact) + 3
    assert psnr(app_view, exact) < 45
