"""Photos as training data: the visibility test, the split, colour matching, and photo-mode ``enhance``."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from PIL import Image
from scipy import ndimage

from scantex.photos.training import (VisibilitySettings, _footprints, colour_match, depth_gaps, halved, photo_rays,
                                     prepare_photo, resize_depth, score_photos, split_photos, taught_by_photos,
                                     texture_seen, working_camera)
from scantex.scan import Scan
from scantex.views.camera import Camera
from scantex.views.raycast import RayCaster, cast_gbuffer, pixel_footprints
from scantex.views.render import render
from tests.conftest import grid_wall, textured_cube
from tests.photos.test_alignment import photograph


def cube_set(tmp_path, width=96, height=72, depth_error: float | None = None):
    scan = textured_cube()
    eyes = [(2.6, -1.8, 1.9), (-1.6, -2.2, 1.4), (2.4, 2.0, 2.2), (-1.5, 2.4, 0.9)]
    cams = [Camera.look_at(e, (0.5, 0.5, 0.5), fov_deg=50, width=width, height=height) for e in eyes]
    photos = photograph(scan, cams, tmp_path)
    if depth_error is not None:  # depth maps at half size, in millimetres, off by depth_error (relative)
        caster = RayCaster(scan.positions, scan.faces)
        depths = []
        for i, cam in enumerate(cams):
            small = cam.scaled(0.5)
            g = cast_gbuffer(caster, small, scan.face_normals)
            mm = np.where(g.mask, g.depth * (1 + depth_error) * 1000, 0).astype(np.uint16)
            Image.fromarray(mm).save(tmp_path / f"d{i}.png")
            depths.append(tmp_path / f"d{i}.png")
        photos = dataclasses.replace(photos, depths=tuple(depths))
    return scan, photos


def test_split_spreads_and_never_takes_all(caplog):
    train, held = split_photos(14, 0.1)
    assert len(held) == 2 and len(train) == 12 and not set(train) & set(held)
    assert abs(int(held[1]) - int(held[0])) >= 5  # spread, not neighbours
    assert len(split_photos(14, 3)[1]) == 3  # a count
    assert len(split_photos(2, 0.9)[1]) == 1  # never all
    assert len(split_photos(1, 0.5)[1]) == 0 and len(split_photos(8, 0)[1]) == 0
    assert np.array_equal(split_photos(20, 0.2, seed=4)[1], split_photos(20, 0.2, seed=4)[1])
    with caplog.at_level("WARNING"):
        assert len(split_photos(12, 100)[1]) == 11  # more than there are: said, not only done
    assert "holding out 11 of the 12 photos for the score, not 100" in caplog.text


def test_valid_pixels_see_what_the_photo_shows(tmp_path):
    scan, photos = cube_set(tmp_path)
    caster = RayCaster(scan.positions, scan.faces)
    view = prepare_photo(scan, photos, 0, caster, max_side=96)
    assert view.image.shape == (72, 96, 3) and view.valid.shape == (72, 96)
    assert 0.1 < view.valid.mean() < 0.6
    # a valid pixel's colour is the texture at its face: rendering the scan there gives the photo back
    again, _ = render(scan, view.camera, caster)
    assert np.abs(again[view.valid] - view.image[view.valid]).max() < 2 / 255
    # nothing valid touches the silhouette
    hit = view.face_id >= 0
    from scipy import ndimage

    assert not (view.valid & ~ndimage.binary_erosion(hit, iterations=2)).any()
    assert view.rejected["edge"] > 0


def test_a_view_holds_its_photo_as_read_and_what_the_mesh_says_in_13_bytes_a_pixel(tmp_path):
    scan, photos = cube_set(tmp_path)
    caster = RayCaster(scan.positions, scan.faces)
    view = prepare_photo(scan, photos, 0, caster, max_side=96)
    # the photo's 8-bit pixels (a room's 219 views of 640x480 held 2.0 GB as float colours and barycentrics)
    assert view.pixels.dtype == np.uint8
    assert view.image.dtype == np.float32
    assert np.array_equal(view.image, photos.load_image(0).astype(np.float32) / 255.0)
    held = sum(a.nbytes for a in (view.pixels, view.face_id, view.depth, view.valid))
    assert held <= 13 * view.valid.size
    assert view.sampled().pixels is None and view.sampled().image is None
    # what the mesh's texture shows at the pixels: the render through the view's camera, black where none
    seen = texture_seen(scan, view, caster)
    again, _ = render(scan, view.camera, caster)
    assert np.array_equal(seen, again)
    assert np.abs(seen[view.valid] - view.image[view.valid]).mean() < 0.02  # the photo was taken of that texture


def stepped_scene() -> Scan:
    """A wall with a panel 4 % nearer in front (a step in depth too small for a contour, large enough
    for a pixel that straddles it to be unclean), a cube farther in front (silhouettes, contours), and a
    sliver thinner than a pixel."""
    cube = textured_cube()
    parts = [grid_wall(n=6, size=3.0), grid_wall(n=4, size=1.0)]
    parts[0] = dataclasses.replace(parts[0], positions=parts[0].positions + (-1.5, 2.0, -1.5))
    parts[1] = dataclasses.replace(parts[1], positions=parts[1].positions + (0.2, 1.85, 0.2))
    sliver = Scan(np.array([[-1.2, 1.0, -1.4], [-1.19, 1.0, -1.4], [-1.2, 1.0, 1.4]]), np.array([[0, 2, 1]]))
    positions, faces, offset = [], [], 0
    for part in [*parts, dataclasses.replace(cube, positions=cube.positions * 0.6 - (0.9, 0.6, 0.3)), sliver]:
        positions.append(part.positions)
        faces.append(part.faces + offset)
        offset += len(part.positions)
    return Scan(np.concatenate(positions), np.concatenate(faces))


@pytest.mark.parametrize("s", [2, 3])
def test_sparse_supersampling_matches_the_full_cast(s):
    scan = stepped_scene()
    caster = RayCaster(scan.positions, scan.faces)
    cam = Camera.look_at((0.3, -4.0, 0.6), (0.0, 1.5, 0.0), fov_deg=60, width=160, height=120)
    face_id, bary, n_hit, all_hit, depth, spread = _footprints(caster, cam, s)
    g = cast_gbuffer(caster, cam.scaled(s))
    full = pixel_footprints(g.face_id, g.depth, s)
    # the centre sub-sample is the same ray, cast alike
    assert np.array_equal(face_id, g.face_id.reshape(120, s, 160, s)[:, s // 2, :, s // 2])
    assert np.array_equal(bary, g.bary.reshape(120, s, 160, s, 2)[:, s // 2, :, s // 2])
    # the visibility test's inputs are the full cast's: the steps and silhouettes are found; a sliver
    # thinner than a pixel, off the wall, can slip between the centre samples (a few pixels partly hit)
    assert np.array_equal(all_hit, full[1])
    assert (n_hit != full[0]).sum() <= 8
    clean = all_hit & (spread < 0.02 * depth)
    assert np.array_equal(clean, full[1] & (full[3] < 0.02 * full[2]))
    assert (~clean & (face_id >= 0)).sum() > 100  # they are there to be found
    hit = (full[0] > 0) & (n_hit == full[0])
    assert np.allclose(depth[hit], full[2][hit], rtol=0.01)


def test_halved_view_is_the_same_photo_at_half_size(tmp_path):
    scan, photos = cube_set(tmp_path)
    caster = RayCaster(scan.positions, scan.faces)
    view = prepare_photo(scan, photos, 0, caster, max_side=96)
    half = halved(view)
    assert half.image.shape == (36, 48, 3) and half.valid.shape == half.face_id.shape == half.depth.shape == (36, 48)
    assert (half.camera.width, half.camera.height) == (48, 36)
    assert np.allclose(half.image[5, 7], view.image[10:12, 14:16].mean(axis=(0, 1)))
    # usable only where all four pixels are
    assert np.array_equal(half.valid, view.valid[0::2, 0::2] & view.valid[1::2, 0::2] & view.valid[0::2, 1::2]
                          & view.valid[1::2, 1::2])
    # a surface point lands at half the pixel coordinates (centres kept: x' = (x + 0.5) / 2 - 0.5)
    point = np.array([[0.5, 0.2, 0.6]])
    full, _ = view.camera.project(point)
    small, _ = half.camera.project(point)
    assert np.allclose(small, (full + 0.5) / 2 - 0.5)
    # the texture at the halved view's pixels is the render at half size, near enough for an exposure fit
    seen = texture_seen(scan, half, caster)
    assert np.abs(seen[half.valid] - half.image[half.valid]).mean() < 0.05


def test_photos_are_box_filtered_to_max_side(tmp_path):
    scan, photos = cube_set(tmp_path)
    cam = working_camera(photos.cameras[0], 48)
    assert (cam.width, cam.height) == (48, 36)
    view = prepare_photo(scan, photos, 0, RayCaster(scan.positions, scan.faces), max_side=48)
    full = photos.load_image(0).astype(np.float32) / 255
    assert np.allclose(view.image, full.reshape(36, 2, 48, 2, 3).mean(axis=(1, 3)), atol=1 / 255)


def test_grazing_pixels_are_rejected(tmp_path):
    scan, photos = cube_set(tmp_path)
    caster = RayCaster(scan.positions, scan.faces)
    loose = prepare_photo(scan, photos, 0, caster, 96, VisibilitySettings(max_angle_deg=89.9))
    strict = prepare_photo(scan, photos, 0, caster, 96, VisibilitySettings(max_angle_deg=45))
    assert strict.valid.sum() < loose.valid.sum() and strict.rejected["grazing"] > 0


@pytest.mark.parametrize("error", [0.0, 0.2, -0.9])
def test_depth_maps_in_another_unit_are_rescaled(tmp_path, error, caplog):
    """A depth map that agrees (at half size, in mm) rejects (almost) nothing; one 20 % off everywhere, or
    in tenths of its unit, is off as a whole (its unit, not the mesh): read in the mesh's scale, with a
    warning, it rejects (almost) nothing either."""
    scan, photos = cube_set(tmp_path, depth_error=error)
    caster = RayCaster(scan.positions, scan.faces)
    with caplog.at_level("WARNING"):
        view = prepare_photo(scan, photos, 0, caster, 96)
    plain = prepare_photo(scan, dataclasses.replace(photos, depths=(None,) * 4), 0, caster, 96)
    assert view.valid.sum() >= 0.95 * plain.valid.sum()
    assert ("times the mesh's depth" in caplog.text) == (error != 0)


@pytest.mark.parametrize("error", [0.2, None])
def test_a_photo_prepared_again_keeps_its_depth_maps_judgement(tmp_path, error, caplog):
    """A photo prepared again at another pose (a held-out photo aligned for the texture from every photo, the
    consensus poses' rounds) takes the factor its depth map was found to need, or that it is not of its view
    (0), as it is: the warning was printed twice, and a map set aside on a whole scan was judged again by
    each tile."""
    from scantex.pipeline.enhance import judged

    scan, photos = cube_set(tmp_path, depth_error=error or 0.0)
    if error is None:  # another view's map
        depth = np.asarray(Image.open(photos.depths[0])).astype(np.float64)
        noise = np.random.default_rng(0).uniform(0.3, 3.0, depth.shape) * np.median(depth[depth > 0])
        Image.fromarray(noise.astype(np.uint16)).save(photos.depths[0])
    caster = RayCaster(scan.positions, scan.faces)
    with caplog.at_level("WARNING"):
        first = prepare_photo(scan, photos, 0, caster, 96)
    assert first.depth_factor == (0.0 if error is None else pytest.approx(1 / 1.2, rel=0.02))
    caplog.clear()
    with caplog.at_level("WARNING"):
        again = prepare_photo(scan, judged(photos, [first]), 0, caster, 96)
    assert caplog.text == "" and again.depth_factor == first.depth_factor
    assert np.array_equal(again.valid, first.valid)


def test_depth_maps_that_disagree_in_places_reject_those_pixels(tmp_path):
    """Where the depth map sees something nearer than the mesh (an object moved after the scan), the
    pixels are rejected; the rest of the photo stays usable."""
    scan, photos = cube_set(tmp_path, depth_error=0.0)
    caster = RayCaster(scan.positions, scan.faces)
    plain = prepare_photo(scan, dataclasses.replace(photos, depths=(None,) * 4), 0, caster, 96)
    depth = np.asarray(Image.open(photos.depths[0])).astype(np.uint16)
    h, w = depth.shape
    depth[: h // 2, : w // 2] = (depth[: h // 2, : w // 2] * 0.6).astype(np.uint16)  # a quarter 40 % nearer
    Image.fromarray(depth).save(photos.depths[0])
    view = prepare_photo(scan, photos, 0, caster, 96)
    assert view.rejected["depth_map"] > 0
    assert not view.valid[:36, :48].any() or view.valid[:36, :48].sum() < 0.1 * plain.valid[:36, :48].sum()
    assert view.valid[36:, 48:].sum() >= 0.95 * plain.valid[36:, 48:].sum()


def test_a_thin_line_of_missing_depth_in_a_dense_map_is_left_out(tmp_path):
    """A lamp's pole that the depth sensor lost, and the mesh with it: a line of missing depth across a map measured
    everywhere else. With ``depth_gap_px`` its pixels, and two on either side, teach nothing; without, they do (as
    missing depth always did). A sparse map's holes (a grid: a map reprojected from a coarser depth camera) tell
    nothing, and a band of missing depth along the image's border is no line."""
    scan, photos = cube_set(tmp_path, depth_error=0.0)
    caster = RayCaster(scan.positions, scan.faces)
    gaps = VisibilitySettings(depth_gap_px=7)
    full = np.asarray(Image.open(photos.depths[0])).astype(np.uint16)  # 48 x 36, the working size's half

    def prepared(depth, settings=gaps):
        Image.fromarray(depth).save(photos.depths[0])
        return prepare_photo(scan, photos, 0, caster, 96, settings)

    plain = prepared(full)
    line = full.copy()
    line[:, 24] = 0  # one map pixel wide: working columns 48 and 49
    lost = prepared(line)
    gone = plain.valid & ~lost.valid
    assert gone[:, 48].sum() > 10 and lost.rejected["depth_map"] > plain.rejected["depth_map"]
    assert not lost.valid[:, 46:52].any()  # the line and two pixels on either side
    assert np.array_equal(lost.valid[:, :44], plain.valid[:, :44])
    assert np.array_equal(lost.valid[:, 54:], plain.valid[:, 54:])
    assert np.array_equal(prepared(line, VisibilitySettings()).valid, prepared(full, VisibilitySettings()).valid)
    sparse = full.copy()
    sparse[::2, ::2] = sparse[1::2, 1::2] = 0  # half the map missing, in a grid
    assert np.array_equal(prepared(sparse).valid, plain.valid)
    known = np.ones((40, 60), bool)
    known[:, :3] = False  # a band along the left edge, where the depth camera does not reach: no line
    known[10:30, 30] = False  # a line
    known[5:20, 40:50] = False  # a patch wider than 7: a dark or shiny surface
    found = depth_gaps(known, 7)
    closed = ndimage.binary_closing(known, structure=np.ones((7, 7), bool), border_value=0)  # what it computes
    assert np.array_equal(found, ndimage.binary_dilation(closed & ~known, iterations=2))
    assert found[10:30, 28:33].all() and not found[:, :3].any() and not found[5:20, 40:50].any()
    assert not found[:8, :35].any() and not found[32:].any()


def test_pixels_a_surface_outside_the_scan_hides_are_rejected(tmp_path):
    """A tile of a bigger scan does not have its neighbours' geometry: the pixels where one of them is in front
    (``PhotoSet.hidden``, at any size) are never usable, with the margin a contour gets."""
    scan, photos = cube_set(tmp_path)
    caster = RayCaster(scan.positions, scan.faces)
    plain = prepare_photo(scan, photos, 0, caster, 96)
    mask = np.zeros((144, 192), bool)  # twice the working size: resized, nearest
    mask[:72, :96] = True  # the top-left quarter
    view = prepare_photo(scan, dataclasses.replace(photos, hidden=(mask, None, None, None)), 0, caster, 96)
    assert view.rejected["hidden"] > 0 and plain.rejected["hidden"] == 0
    assert not view.valid[:38, :48].any() and not view.valid[:36, :50].any()  # the quarter, two pixels around
    assert np.array_equal(view.valid[40:, 52:], plain.valid[40:, 52:])
    assert np.array_equal(view.face_id, plain.face_id)
    # no depth there either: a loose fragment's colour is not taken through the surface in front
    gone = (view.depth == 0) & (plain.depth > 0)
    assert gone[:36, :48].sum() == ((plain.depth > 0)[:36, :48]).sum() and not gone[40:, 52:].any()


def test_a_depth_map_of_another_view_is_set_aside_not_used_to_reject_the_photo(tmp_path, caplog):
    """A depth map that disagrees with the mesh almost everywhere, in any unit (another frame's map, a depth
    camera not registered to the colour camera), says nothing about what this photo sees: the photo is used
    without it, with a warning, instead of losing most of its pixels."""
    scan, photos = cube_set(tmp_path, depth_error=0.0)
    caster = RayCaster(scan.positions, scan.faces)
    plain = prepare_photo(scan, dataclasses.replace(photos, depths=(None,) * 4), 0, caster, 96)
    depth = np.asarray(Image.open(photos.depths[0])).astype(np.float64)
    noise = np.random.default_rng(0).uniform(0.3, 3.0, depth.shape) * np.median(depth[depth > 0])
    Image.fromarray(noise.astype(np.uint16)).save(photos.depths[0])  # depths with no relation to the view
    with caplog.at_level("WARNING"):
        view = prepare_photo(scan, photos, 0, caster, 96)
    assert "not this photo's view" in caplog.text
    assert view.rejected["depth_map"] == 0 and np.array_equal(view.valid, plain.valid)


def test_resize_depth_is_nearest_and_keeps_nan():
    d = np.array([[1.0, 2.0], [np.nan, 4.0]], np.float32)
    r = resize_depth(d, 4, 4)
    assert r.shape == (4, 4) and set(np.unique(r[np.isfinite(r)])) == {1.0, 2.0, 4.0}
    assert np.isnan(r[3, 0]) and r[0, 0] == 1.0 and r[3, 3] == 4.0


def test_colour_match_recovers_gain_and_offset():
    rng = np.random.default_rng(0)
    render_ = rng.uniform(0.1, 0.8, (20, 20, 3)).astype(np.float32)
    photo = np.clip(render_ * np.array([1.2, 0.9, 1.05]) + np.array([0.02, -0.03, 0.0]), 0, 1)
    mask = np.ones((20, 20), bool)
    assert np.abs(colour_match(render_, photo, mask) - photo).max() < 1e-5
    flat = np.full_like(render_, 0.5)
    assert np.allclose(colour_match(flat, photo, mask)[mask].mean(axis=0), photo[mask].mean(axis=0), atol=1e-5)


def test_rays_and_taught_faces(tmp_path):
    scan, photos = cube_set(tmp_path)
    caster = RayCaster(scan.positions, scan.faces)
    views = [prepare_photo(scan, photos, i, caster, 96) for i in range(2)]
    rays = photo_rays(views, [5, 9])
    assert len(rays) == sum(int(v.valid.sum()) for v in views)
    assert set(np.unique(rays.chart)) == {5, 9}
    # each ray hits its surface at its depth: origin + depth * direction lies on the hit face's plane
    # (pixels across a crease of the cube average two faces' depths: within 1 % of the depth)
    hit = rays.origins + rays.depth[:, None] * rays.directions
    fid = np.concatenate([v.face_id[v.valid] for v in views])
    n = scan.face_normals[fid]
    p0 = scan.positions[scan.faces[fid, 0]]
    off = np.abs(np.einsum("ij,ij->i", hit - p0, n))
    assert np.quantile(off, 0.95) < 1e-3 and (off < 0.01 * rays.depth).all()
    taught = taught_by_photos(views, scan.n_faces)
    assert taught.any() and not taught.all()


def test_score_photos_prefers_the_true_texture(tmp_path):
    scan, photos = cube_set(tmp_path)
    caster = RayCaster(scan.positions, scan.faces)
    views = [prepare_photo(scan, photos, i, caster, 96) for i in range(2)]
    grey = scan.replace(materials=tuple(dataclasses.replace(m, image=np.full_like(m.image, 128))
                                        for m in scan.materials))
    sheets: dict = {}
    s = score_photos({"true": scan, "grey": grey}, views, caster, images=sheets)
    assert s["true"]["psnr"] > 30 and s["grey"]["psnr"] < 20 and s["true"]["photos"] == 2
    assert sorted(sheets) == [0, 1] and sheets[0].shape == (72, 3 * 96, 3)
    assert np.array_equal(sheets[1][:, :96], views[1].image)
    assert s["grey"]["psnr_matched"] > s["grey"]["psnr"] - 1e-6
    # fine detail: the true texture's renders hold about the photos' own, a flat grey none
    assert s["true"]["detail"] == pytest.approx(s["true"]["photo_detail"], rel=0.2)
    assert s["grey"]["detail"] < 0.1 * s["grey"]["photo_detail"] and s["true"]["photo_detail"] > 0


def test_the_summary_says_when_the_blend_is_much_softer_than_the_photos():
    from scantex.report.html import fine_detail

    def detail_summary(scores, texturing):
        return fine_detail(scores, texturing)[0]

    def scores(result):
        return {"input": {"detail": 0.0224, "photo_detail": 0.0229},
                "enhanced": {"detail": result, "photo_detail": 0.0229}}

    hint = "--detail sharp takes"
    soft = detail_summary(scores(0.0097), {"mode": "projective"})
    assert "photos 0.0229, input 0.0224, result 0.0097" in soft and hint in soft and "; --detail blend)" in soft
    assert hint not in detail_summary(scores(0.0200), {"mode": "projective"})
    # asked for sharp detail already, or the field's colour: no hint
    sharp = detail_summary(scores(0.0097), {"mode": "projective", "detail": {"gain": 1.0}})
    assert hint not in sharp and "; --detail sharp)" in sharp
    assert hint not in detail_summary(scores(0.0097), {"mode": "projective", "detail": {}})  # before gains
    field = detail_summary(scores(0.0097), {"mode": "field"})
    assert hint not in field and "--detail" not in field
    # balanced: the best views' detail at half its contrast; sharp has more of it
    balanced = detail_summary(scores(0.0097), {"mode": "projective", "detail": {"gain": 0.5}})
    assert "; --detail balanced)" in balanced and hint in balanced
    assert detail_summary({"input": {}, "enhanced": {}}, {}) == ""  # scored before detail was measured
    assert fine_detail(scores(0.0097), {"mode": "projective"})[1] and not fine_detail(scores(0.02), {})[1]


@pytest.mark.parametrize("canonical", ["input", "photos"])
def test_photo_mode_rays_groups_and_colour_balance(tmp_path, canonical):
    from scantex.field.rays import RayDataset
    from scantex.pipeline.enhance import PhotoData, photo_mode_rays

    scan, photos = cube_set(tmp_path)
    caster = RayCaster(scan.positions, scan.faces)
    views = [prepare_photo(scan, photos, i, caster, 96) for i in range(3)]
    data = PhotoData(photos, views, [], None)
    n = 50
    synthetic = RayDataset(np.zeros((n, 3), np.float32), np.ones((n, 3), np.float32), np.ones(n, np.float32),
                           np.zeros((n, 3), np.float32), np.arange(n) % 2)
    rays, offset, weights = photo_mode_rays(synthetic, data, 2, 0.1, canonical)
    assert offset == 3 and weights.shape == (5,)
    assert len(rays) == sum(int(v.valid.sum()) for v in views) + n
    assert set(np.unique(rays.chart[-n:])) == {3, 4}  # the charts follow the photos
    assert np.allclose(rays.weight[-n:], 0.1) and np.allclose(rays.weight[:-n], 1.0)
    if canonical == "input":  # only the input texture's charts fix the colour balance
        assert (weights[:3] == 0).all() and (weights[3:] == n // 2).all()
    else:
        assert (weights[3:] == 0).all() and weights[0] == views[0].valid.sum()
    only_photos, _, w = photo_mode_rays(None, data, 2, 0.1, "input")  # untextured: the photos' balance
    assert len(only_photos) == len(rays) - n and (w[:3] > 0).all()
    with pytest.raises(Exception, match="canonical"):
        photo_mode_rays(synthetic, data, 2, 0.1, "median")


def test_the_compiled_changing_pixels_are_the_numpy_ones():
    """Where a photo's G-buffer is cast supersampled: hit and miss meet, or the depth steps by over 1 %; the
    compiled pass against scipy's four 3x3 filters, edges and corners included."""
    from scantex.photos.training import _changing, _changing_numpy

    rng = np.random.default_rng(5)
    for shape in [(48, 64), (7, 5), (1, 9), (6, 1)]:
        hit = rng.random(shape) > 0.15
        depth = np.where(hit, 2 + 0.05 * (rng.random(shape) > 0.9) + 0.001 * rng.random(shape), 0).astype(np.float32)
        got, expected = _changing(hit, depth), _changing_numpy(hit, depth)
        assert np.array_equal(got, expected) and 0 < expected.sum() < expected.size
