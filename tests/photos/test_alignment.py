"""The alignment check: aligned synthetic photos pass, a moved or turned mesh fails with a clear line."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from PIL import Image

from scantex.errors import ScanError
from scantex.photos import PhotoSet, check_alignment, load_photos, require_alignment
from scantex.photos.alignment import _MeshEdges, contour_map, edge_map, resized_camera
from scantex.views.camera import Camera
from scantex.views.raycast import RayCaster
from scantex.views.render import render, to_uint8
from tests.conftest import grid_wall, shared_scan, textured_cube


def photograph(scan, cams, folder) -> PhotoSet:
    caster = RayCaster(scan.positions, scan.faces)
    images = []
    for i, cam in enumerate(cams):
        Image.fromarray(to_uint8(render(scan, cam, caster)[0])).save(folder / f"p{i}.png")
        images.append(folder / f"p{i}.png")
    return PhotoSet(cameras=tuple(cams), images=tuple(images), source=folder, format="rendered")


def cube_photos(tmp_path):
    scan = textured_cube()
    eyes = [(2.6, -1.8, 1.9), (-1.6, -2.2, 1.4), (2.4, 2.0, 2.2), (-1.5, 2.4, 0.9)]
    cams = [Camera.look_at(e, (0.5, 0.5, 0.5), fov_deg=50, width=96, height=72) for e in eyes]
    return scan, photograph(scan, cams, tmp_path)


def moved(scan, offset=(0.0, 0.0, 0.0), turn_deg=0.0, axis=2, about=(0.0, 0.0, 0.0)):
    a = np.radians(turn_deg)
    c, s = np.cos(a), np.sin(a)
    i, j = [k for k in range(3) if k != axis]
    R = np.eye(3)
    R[i, i], R[i, j], R[j, i], R[j, j] = c, -s, s, c
    positions = (scan.positions - about) @ R.T + np.asarray(about) + offset
    return dataclasses.replace(scan, positions=positions)


def test_aligned_photos_pass(tmp_path):
    scan, photos = cube_photos(tmp_path)
    report = require_alignment(scan, photos)
    assert report.ok and report.problem is None and len(report.photos) == 4
    assert report.edge_distance_px < 1.0 and report.ratio < 0.35
    # the rigid estimate's own wander on four toy photos (a 5 degree turn is refused below)
    assert report.offset_m < 0.02 and report.turn_deg < 1.5 and report.displacement < 0.006
    assert all(0.05 < p.coverage < 0.9 for p in report.photos)
    assert report.summary().startswith("mesh and photos aligned") and "\n" not in report.summary()


def test_photos_are_compared_at_max_side(tmp_path):
    scan, photos = cube_photos(tmp_path)
    report = check_alignment(scan, photos, n_photos=2, max_photos=2, max_side=48)
    assert [p.size for p in report.photos] == [(48, 36), (48, 36)] and report.ok


def test_mesh_far_away_fails(tmp_path):
    scan, photos = cube_photos(tmp_path)
    with pytest.raises(ScanError) as err:
        require_alignment(moved(scan, offset=(30.0, 0.0, 0.0)), photos)
    message = str(err.value)
    assert message.startswith(f"{photos.source}: the mesh is not in the cameras' frame")
    assert "projects outside 4 of the 4 photos" in message and "median edge distance" in message
    # cameras described wrongly misfit the same way: the message names them too
    assert "check the cameras: intrinsics for the photos' own size, poses world-to-camera" in message
    assert "\n" not in message and "same as XMP" not in message
    # RealityCapture's cameras: its mesh export in a frame of its own is the usual cause, said first
    with pytest.raises(ScanError, match="RealityCapture exports a mesh in the XMPs' frame with its coordinate system "
                                        "'same as XMP'; if the mesh is where"):
        require_alignment(moved(scan, offset=(30.0, 0.0, 0.0)), dataclasses.replace(photos, format="realitycapture"))


def test_turned_mesh_fails(tmp_path):
    """A wall turned 90 degrees about a vertical line through its middle: still in view, edges wrong."""
    wall = grid_wall()  # x-z plane, x and z in [0, 2]
    cams = [Camera.look_at((1.0 + dx, -3.0, 1.0 + dz), (1.0, 0.0, 1.0), fov_deg=70, width=96, height=72)
            for dx, dz in ((0.0, 0.0), (1.2, 0.4), (-1.2, -0.3), (0.5, 1.0))]
    photos = photograph(wall, cams, tmp_path)
    assert check_alignment(wall, photos).ok
    turned = moved(wall, turn_deg=90, axis=2, about=(1.0, 0.0, 1.0))  # now in the y-z plane
    report = check_alignment(turned, photos)
    # seen edge-on, the turned wall shows no edges at all: refused either way
    assert not report.ok and ("miss the photos' edges" in report.problem or "no edges" in report.problem)
    with pytest.raises(ScanError, match="the mesh is not in the cameras' frame"):
        require_alignment(turned, photos)


def test_small_shift_of_a_textured_mesh_is_caught(tmp_path):
    scan, photos = cube_photos(tmp_path)
    report = check_alignment(moved(scan, offset=(0.15, -0.1, 0.1)), photos)
    assert not report.ok


def partial_wall_scan(tmp_path, noise: float = 0.0):
    """A 4 m textured wall photographed whole, and a scan of only a ragged patch of it (open border inside
    every photo, where the photographed wall simply goes on). ``noise``: the wall's vertices jittered by
    this much (m, standard deviation) across it, as a fused depth scan's are."""
    from scipy import ndimage

    rng = np.random.default_rng(3)
    texture = ndimage.gaussian_filter(rng.uniform(0, 1, (256, 256, 3)), (4, 4, 0))
    texture = (255 * np.clip((texture - texture.mean()) * 6 + 0.5, 0, 1)).astype(np.uint8)
    wall = grid_wall(n=41, size=4.0)
    if noise:
        positions = wall.positions.copy()
        positions[:, 1] += np.random.default_rng(1).normal(0, noise, len(positions))
        wall = dataclasses.replace(wall, positions=positions)
    whole = dataclasses.replace(wall, materials=(dataclasses.replace(grid_wall().materials[0], image=texture),))
    eyes = [(2.0, -3.0, 2.0), (3.2, -2.8, 2.5), (0.9, -3.1, 1.6), (2.4, -2.9, 3.0)]
    cams = [Camera.look_at(e, (2.0, 0.0, 2.0), fov_deg=60, width=160, height=120) for e in eyes]
    photos = photograph(whole, cams, tmp_path)
    centres = whole.positions[whole.faces].mean(axis=1)
    angle = np.arctan2(centres[:, 2] - 2.0, centres[:, 0] - 2.0)
    radius = np.hypot(centres[:, 0] - 2.0, centres[:, 2] - 2.0)
    keep = radius < 1.3 + 0.15 * np.sin(5 * angle) + 0.05 * np.sin(17 * angle)
    part = dataclasses.replace(whole, faces=whole.faces[keep], face_uvs=whole.face_uvs[keep],
                               face_materials=None if whole.face_materials is None else whole.face_materials[keep])
    return part, photos


def test_open_partial_wall_scan_passes(tmp_path):
    """The border of a partial scan is no edge in the photos: it must not make the check refuse."""
    part, photos = partial_wall_scan(tmp_path)
    report = require_alignment(part, photos)
    assert report.ok and sum(p.n_border for p in report.photos) > 100
    assert report.offset_m < 0.02 and report.turn_deg < 0.5


def test_a_scans_noise_is_no_crease(tmp_path):
    """A fused depth scan's noise bends single faces by more than a crease's angle: as creases they drew
    render edges no photo has (an aligned apartment scan was refused at ratio 0.58). The same partial wall
    with 3 cm of noise on its 10 cm grid passes, and moved 15 cm it is refused saying by how much."""
    part, photos = partial_wall_scan(tmp_path, noise=0.03)
    report = require_alignment(part, photos)
    assert report.ok and report.ratio < 0.2
    bad = check_alignment(moved(part, offset=(0.15, 0.0, 0.0), axis=1, about=(2.0, 0.0, 2.0)), photos)
    assert not bad.ok and "away from where the photos see it" in bad.problem and 0.10 < bad.offset_m < 0.20
    # a real crease stays one: the cube's twelve edges
    assert len(_MeshEdges.of(textured_cube()).creases) == 12


@pytest.mark.parametrize("offset, turn", [((0.15, 0.0, 0.0), 0.0), ((0.0, 0.0, -0.15), 0.0), ((0.0,) * 3, 5.0)])
def test_moved_or_turned_partial_wall_is_refused_saying_by_how_much(tmp_path, offset, turn):
    """Moved by 15 cm (4 % of the patch, as 5 cm is of a 1.2 m object) or turned 5 degrees in its plane."""
    part, photos = partial_wall_scan(tmp_path)
    bad = moved(part, offset=offset, turn_deg=turn, axis=1, about=(2.0, 0.0, 2.0))
    report = check_alignment(bad, photos)
    assert not report.ok and "away from where the photos see it" in report.problem
    if turn:
        assert 3.5 < report.turn_deg < 6.5
    else:
        assert 0.10 < report.offset_m < 0.20
    with pytest.raises(ScanError, match=r"the mesh is not in the cameras' frame: it sits about \d+\.\d cm"):
        require_alignment(bad, photos)


def bare_and_smudged_wall(tmp_path):
    """A 4 m wall: its left third bare (one flat colour), the rest printed with blobs. The scan's atlas has
    the blobs right in the middle third and unrelated ones in the right third (a capture app's smudge).
    Photos 0, 2, 5 and 7 (those checked first) see the bare third; 1 and 3 the middle; 4 and 6 the right."""
    from scipy import ndimage

    def blobs(seed):
        rng = np.random.default_rng(seed)
        t = ndimage.gaussian_filter(rng.uniform(0, 1, (256, 256, 3)), (4, 4, 0))
        return np.clip((t - t.mean()) * 6 + 0.5, 0, 1)

    truth, atlas = blobs(3), blobs(4)
    truth[:, :86] = 0.5
    atlas[:, :171] = truth[:, :171]
    wall = grid_wall(n=41, size=4.0)
    textured = [dataclasses.replace(wall, materials=(dataclasses.replace(wall.materials[0], image=to_uint8(t)),))
                for t in (truth, atlas)]
    at = {"bare": 0.65, "middle": 2.0, "right": 3.35}
    where = ["bare", "middle", "bare", "middle", "right", "bare", "right", "bare"]
    cams = [Camera.look_at((at[w] + 0.1 * (k % 3 - 1), -1.6, 1.7 + 0.25 * (k % 2)), (at[w], 0.0, 2.0),
                           fov_deg=40, width=160, height=120) for k, w in enumerate(where)]
    return textured[1], photograph(textured[0], cams, tmp_path)


def test_photos_of_bare_and_smudged_walls_do_not_refuse_an_aligned_scan(tmp_path):
    """A room's photos of bare walls show no edges to compare, and where its atlas is smudged the render's
    edges match nothing: neither is evidence that the mesh is elsewhere. More photos are checked, and the
    verdict rests on the photos whose edges do match."""
    scan, photos = bare_and_smudged_wall(tmp_path)
    report = require_alignment(scan, photos)
    assert report.ok and len(report.photos) == 8
    by_index = {p.index: p for p in report.photos}
    assert all(not np.isfinite(by_index[i].ratio) for i in (0, 2, 5, 7))  # bare: nothing to compare
    assert all(by_index[i].ratio < 0.3 for i in (1, 3)) and all(by_index[i].ratio > 0.6 for i in (4, 6))
    assert report.offset_m < 0.05 and report.turn_deg < 1.0
    # the same scan 15 cm away, and in another frame altogether, is still refused
    assert not check_alignment(moved(scan, offset=(0.15, 0.0, 0.0)), photos).ok
    far = check_alignment(moved(scan, offset=(1.3, 0.0, 0.0)), photos)
    assert not far.ok


def with_depth_maps(photos: PhotoSet, scan, folder) -> PhotoSet:
    """``photos`` with a depth map each (uint16 PNG, millimetres), read off ``scan`` as an RGB-D camera would."""
    from scantex.views.raycast import cast_gbuffer

    caster = RayCaster(scan.positions, scan.faces)
    paths = []
    for i, cam in enumerate(photos.cameras):
        g = cast_gbuffer(caster, cam)
        mm = np.where(g.mask, np.round(np.nan_to_num(g.depth, posinf=0) * 1000), 0).astype(np.uint16)
        Image.fromarray(mm).save(folder / f"d{i}.png")
        paths.append(folder / f"d{i}.png")
    return dataclasses.replace(photos, depths=tuple(paths))


def test_depth_maps_confirm_a_bare_scan_whose_edges_show_nothing(tmp_path):
    """A bare (untextured) scan of a flat printed wall: its render has no edges at all (its border is the
    scan's end), so the photos cannot confirm it by edges and it was refused. The capture's depth maps agree
    with it on every pixel: it passes, saying so. The same scan 10 cm nearer the cameras, or turned 5 degrees,
    gets no confirmation from them and is refused."""
    printed = grid_wall(n=21, size=2.0)
    bare = dataclasses.replace(printed, uvs=None, face_uvs=None, materials=(dataclasses.replace(
        printed.materials[0], image=None),))
    eyes = [(0.6, -1.8, 1.0), (1.4, -1.7, 0.8), (1.0, -2.0, 1.3), (0.8, -1.6, 0.7)]
    cams = [Camera.look_at(e, (1.0, 0.0, 1.0), fov_deg=45, width=120, height=90) for e in eyes]
    photos = photograph(printed, cams, tmp_path)
    assert not check_alignment(bare, photos).ok  # nothing but its border to compare
    rgbd = with_depth_maps(photos, printed, tmp_path)
    report = require_alignment(bare, rgbd)
    assert report.ok and report.depth_agreement > 0.99
    assert "the depth maps agree with it on 100 % of its pixels" in report.summary()
    assert not check_alignment(moved(bare, offset=(0.0, -0.1, 0.0)), rgbd).ok
    turned = check_alignment(moved(bare, turn_deg=5, axis=0, about=(1.0, 0.0, 1.0)), rgbd)
    assert not turned.ok and turned.depth_agreement < 0.8


def test_contour_map_marks_the_nearer_side():
    mask = np.zeros((6, 8), bool)
    mask[1:5, 2:6] = True
    depth = np.where(mask, 2.0, np.inf).astype(np.float32)
    depth[1:5, 4:6] = 3.0  # a step back on the right half
    edges = contour_map(mask, depth)
    ring = mask & ~np.pad(mask[1:-1, 1:-1] & mask[:-2, 1:-1] & mask[2:, 1:-1] & mask[1:-1, :-2]
                          & mask[1:-1, 2:], 1)
    expected = ring.copy()
    expected[1:5, 3] = True  # the near side of the depth step
    assert np.array_equal(edges, expected)


def test_edge_map_finds_a_step_once():
    img = np.zeros((20, 20), np.float32)
    img[:, 10:] = 1.0
    edges = edge_map(img)
    cols = np.nonzero(edges.any(axis=0))[0]
    assert set(cols) <= {9, 10} and edges[:, 9:11].any(axis=1).all()
    assert not edge_map(np.full((20, 20), 0.5, np.float32)).any()


def test_resized_camera_keeps_image_corners():
    cam = Camera.look_at((0, -3, 0), (0, 0, 0), width=64, height=48)
    small = resized_camera(cam, 16, 12)
    X = np.array([[0.3, 0.0, -0.2]])
    (p,), _ = cam.project(X)
    (q,), _ = small.project(X)
    np.testing.assert_allclose((p + 0.5) / 4, q + 0.5)


def test_bolster_alignment():
    """The real Kinect capture: untextured mesh, contours only. Aligned, and a mesh moved by 20 cm or
    turned by 90 degrees is caught."""
    from scantex.io import load_scan

    folder = shared_scan("bolster_rgbd_posed")
    photos = load_photos(folder)
    scan = load_scan(folder / "bloster.ply")
    report = require_alignment(scan, photos)
    assert report.ratio < 0.35 and report.coverage > 0.05
    centre = scan.positions.mean(axis=0)
    assert not check_alignment(moved(scan, offset=(0.2, 0.0, 0.0)), photos).ok
    assert not check_alignment(moved(scan, turn_deg=90, axis=2, about=centre), photos).ok


@pytest.mark.parametrize("mesh", ["app_style_input/bolster_app_style.obj", "bloster.ply"])
def test_bolster_moved_5cm_or_turned_5deg_is_refused(mesh):
    from scantex.io import load_scan

    folder = shared_scan("bolster_rgbd_posed")
    photos = load_photos(folder)
    scan = load_scan(folder / mesh)
    assert check_alignment(scan, photos).ok
    centre = scan.positions.mean(axis=0)
    shifted = check_alignment(moved(scan, offset=(0.05, 0.0, 0.0)), photos)
    assert not shifted.ok and 0.035 < shifted.offset_m < 0.065
    turned = check_alignment(moved(scan, turn_deg=5, axis=2, about=centre), photos)
    assert not turned.ok and 3.5 < turned.turn_deg < 6.5


def test_facade_partial_scan_passes_and_a_moved_one_is_refused():
    """The façade's mesh ends in the sky and the lawn: its border is no edge in the photos."""
    from scantex.io import load_scan

    folder = shared_scan("facade_openmvs")
    photos = load_photos(folder / "cameras.json")
    scan = load_scan(folder / "app_style_input" / "scene_mesh_baked.obj")
    assert require_alignment(scan, photos).ok
    # 5 cm on a 1.2 m object is 43 cm on this 10 m façade
    assert not check_alignment(moved(scan, offset=(0.43, 0.0, 0.0)), photos).ok


def test_facade_in_centimetres_is_refused_though_its_check_passes():
    """The façade exported in centimetres passes the check by a large correction (its image moving 19 % of the photo
    side, its shift under 2 % of its 1 km size); in metres it lines up as it is, far closer to the photos' edges:
    refused, saying so."""
    from scantex.io import load_scan

    folder = shared_scan("facade_openmvs")
    photos = load_photos(folder / "cameras.json")
    scan = load_scan(folder / "app_style_input" / "scene_mesh_baked.obj")
    in_cm = dataclasses.replace(scan, positions=scan.positions * 100.0)
    assert check_alignment(in_cm, photos).ok
    with pytest.raises(ScanError, match="it fits the photos only after its image moves 1[5-9] % of the photo side, but "
                                        "it lines up with the photos at 1/100 of its size: is the mesh in centimetres"):
        require_alignment(in_cm, photos)


def test_edges_out_of_view_are_skipped_without_changing_a_pixel():
    """Mesh edges wholly behind the camera or beyond one side of the image are not sampled (a room's border
    mostly is): the pixels drawn are exactly those of sampling every edge the same way."""
    from scantex.photos.alignment import _edge_pixels

    def every_edge_sampled(segments, camera, depth):
        H, W = camera.height, camera.width
        out = np.zeros((H, W), bool)
        ends = camera.project(segments.reshape(-1, 3))[0].reshape(-1, 2, 2)
        length = np.nan_to_num(np.linalg.norm(ends[:, 1] - ends[:, 0], axis=1), nan=0.0)
        for (a, b), n in zip(segments, np.clip(np.ceil(2 * length), 1, 2 * max(H, W)).astype(int)):
            pix, z = camera.project(a + np.linspace(0, 1, n + 1)[:, None] * (b - a))
            ok = np.isfinite(pix).all(axis=1) & (z > 0)
            x, y, z = np.round(pix[ok, 0]).astype(int), np.round(pix[ok, 1]).astype(int), z[ok]
            inside = (x >= 0) & (x < W) & (y >= 0) & (y < H)
            x, y, z = x[inside], y[inside], z[inside]
            if depth is not None:
                seen = z <= depth[y, x] * 1.01 + 1e-6
                x, y = x[seen], y[seen]
            out[y, x] = True
        return out

    cam = Camera.look_at((0.0, -3.0, 0.0), (0.0, 0.0, 0.0), fov_deg=60, width=80, height=60)
    segments = np.random.default_rng(5).uniform(-8, 8, (3000, 2, 3))  # in front, behind, beside, across
    for depth in (None, np.full((60, 80), 3.2)):
        drawn = _edge_pixels(segments, cam, depth)
        assert drawn.any() and np.array_equal(drawn, every_edge_sampled(segments, cam, depth))


def test_every_shift_at_once_is_the_shift_search_one_by_one():
    """The best image shift from one correlation is the one a search over every shift finds (points
    away from the border, where the two read the image the same way)."""
    from scipy import ndimage

    from scantex.photos.alignment import _best_shift, _lookup

    rng = np.random.default_rng(5)
    for _ in range(20):
        H, W = rng.integers(60, 160, 2)
        field = ndimage.gaussian_filter(rng.random((H, W)) * 10, 3)
        r = max(2, round(0.06 * max(H, W)))
        step = max(1, r // 12)
        n = int(rng.integers(1, 400))
        pix = np.stack([rng.uniform(r + 2, W - r - 3, n), rng.uniform(r + 2, H - r - 3, n)], axis=1)
        shifts = [(dx, dy) for dy in range(-r, r + 1, step) for dx in range(-r, r + 1, step)]
        costs = [float(_lookup(field, pix + s).mean()) for s in shifts]
        assert _best_shift(field, pix, r, step) == shifts[int(np.argmin(costs))]


def test_the_rigid_fit_jacobian_is_the_residuals_derivative():
    from scipy import ndimage

    from scantex.photos.alignment import _edge_jacobian, _edge_residuals, _EdgeSample

    rng = np.random.default_rng(2)
    cams = [Camera.look_at(e, (0.0, 0.0, 0.0), fov_deg=50, width=160, height=120)
            for e in [(0.3, -2.0, 0.5), (-1.5, -1.2, 0.8)]]
    samples = [_EdgeSample(cam, rng.uniform(-0.4, 0.4, (300, 3)),
                           ndimage.gaussian_filter(rng.random((120, 160)) * 30, 4)) for cam in cams]
    centre, spread = np.array([0.05, 0.0, -0.02]), 0.3
    x = np.array([0.02, -0.03, 0.01, 0.05, -0.02, 0.03])
    numeric = np.stack([(_edge_residuals(samples, centre, spread, x + 1e-6 * e)
                         - _edge_residuals(samples, centre, spread, x - 1e-6 * e)) / 2e-6 for e in np.eye(6)], axis=1)
    np.testing.assert_allclose(_edge_jacobian(samples, centre, spread, x), numeric, atol=1e-5 * np.abs(numeric).max())


def test_the_compiled_rigid_fit_terms_are_the_numpy_ones():
    """The rigid fit's residuals and Jacobian, compiled, against their numpy twins: points on the image, off its
    sides and behind a camera."""
    from scipy import ndimage

    from scantex.photos.alignment import (_edge_jacobian, _edge_jacobian_numpy, _edge_residuals,
                                          _edge_residuals_numpy, _EdgeSample)

    rng = np.random.default_rng(4)
    cams = [Camera.look_at(e, (0.0, 0.0, 0.0), fov_deg=50, width=160, height=120)
            for e in [(0.3, -2.0, 0.5), (-1.5, -1.2, 0.8)]]
    points = np.concatenate([rng.uniform(-1.6, 1.6, (400, 3)), [[0.3, -2.5, 0.5]]])  # some off, one behind
    samples = [_EdgeSample(cam, points, ndimage.gaussian_filter(rng.random((120, 160)) * 30, 4).astype(dtype))
               for cam, dtype in zip(cams, (np.float32, np.float64))]
    centre, spread = np.array([0.05, 0.0, -0.02]), 0.3
    x = np.array([0.02, -0.03, 0.01, 0.05, -0.02, 0.03])
    slow = _edge_residuals_numpy(samples, centre, spread, x)
    assert 20 < (slow == slow.max()).sum() < 400  # both kinds of points are there
    np.testing.assert_allclose(_edge_residuals(samples, centre, spread, x), slow, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(_edge_jacobian(samples, centre, spread, x),
                               _edge_jacobian_numpy(samples, centre, spread, x), rtol=1e-8, atol=1e-9)


@pytest.mark.parametrize("factor, said", [(1000.0, "at 1/1000 of its size: is the mesh in millimetres and the cameras "
                                                   "in metres? Export the mesh in metres"),
                                          (100.0, "at 1/100 of its size: is the mesh in centimetres"),
                                          (0.001, "at 1000 times its size: is the mesh in metres and the cameras in "
                                                  "millimetres? Export the mesh in millimetres")])
def test_a_mesh_in_other_units_is_refused_saying_which(tmp_path, factor, said):
    """A mesh exported in millimetres against cameras in metres (or the other way round) showed no edges in the
    photos, and the message sent the user to the cameras; now it says which units line it up."""
    scan, photos = cube_photos(tmp_path)
    with pytest.raises(ScanError) as err:
        require_alignment(dataclasses.replace(scan, positions=scan.positions * factor), photos)
    message = str(err.value)
    assert message.startswith(f"{photos.source}: the mesh is not in the cameras' frame") and said in message
    assert "\n" not in message
    with pytest.raises(ScanError) as err:  # a mesh moved, not in other units: the message it had
        require_alignment(moved(scan, offset=(30.0, 0.0, 0.0)), photos)
    assert "lines up" not in str(err.value)


@pytest.mark.parametrize("written, said", [
    (lambda w2c: np.linalg.inv(w2c), "with each camera's pose inverted: are the poses camera-to-world?"),
    (lambda w2c: np.diag([1.0, -1.0, -1.0, 1.0]) @ w2c, "are the poses in OpenGL's convention (y up, looking down"),
    (lambda w2c: np.linalg.inv(np.diag([1.0, -1.0, -1.0, 1.0]) @ w2c), "are the poses OpenGL camera-to-world")])
def test_poses_written_in_another_convention_are_refused_saying_which(tmp_path, written, said):
    """A camera file written by hand with camera-to-world poses, OpenGL's camera axes, or both (nerfstudio's
    transform_matrix copied into a cameras.json) was refused sending the user to check the cameras; now the message
    says which convention lines the mesh up."""
    scan, photos = cube_photos(tmp_path)
    cameras = tuple(dataclasses.replace(c, world_to_camera=written(c.world_to_camera)) for c in photos.cameras)
    with pytest.raises(ScanError) as err:
        require_alignment(scan, dataclasses.replace(photos, cameras=cameras, format="cameras.json"))
    message = str(err.value)
    assert "the mesh is not in the cameras' frame" in message and said in message and "\n" not in message
    # another format has a convention of its own, which its importer follows: no such hint
    with pytest.raises(ScanError) as err:
        require_alignment(scan, dataclasses.replace(photos, cameras=cameras, format="nerfstudio"))
    assert "lines up" not in str(err.value)


def test_a_close_up_capture_is_not_refused_for_its_estimate_s_wander(tmp_path):
    """Photos of a room's walls from 0.3 m, poses exact: the rigid estimate wanders (2 cm, its image motion 18 % of
    the side); a rule refusing a large image motion whatever the shift (tried for a mesh in other units) refused
    it, and a wrong unit hint followed."""
    from scantex.synth import make_room
    from scantex.synth.photos import PhotoCapture, capture_photos

    demo = make_room(seed=3, gt_texture_size=256, scan_texture_size=128)
    capture_photos(demo, tmp_path, PhotoCapture(n_photos=12, width=160, height=120, distance=0.3, jitter_deg=0.0,
                                                jitter_m=0.0), seed=3)
    report = require_alignment(demo.scan, load_photos(tmp_path))
    assert report.ok
