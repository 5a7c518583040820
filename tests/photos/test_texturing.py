"""Projective texturing: texels sampled from the photos at full resolution, smooth weights, field fill."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from PIL import Image

from scantex.photos.texturing import (
    ProjectiveSettings,
    fit_photo_transforms,
    inverse_transforms,
    loose_fragments,
    photo_sharpness,
    projective_colour,
    recorded_transforms,
)
from scantex.photos.training import VisibilitySettings, prepare_photos
from scantex.views.camera import Camera
from scantex.views.raycast import RayCaster
from scantex.views.render import render, shade_hits
from tests.conftest import grid_wall
from tests.photos.test_alignment import photograph


def smooth_wall():
    """A 2 m wall whose texture is a smooth colour ramp plus a fine stripe (detail a 96 px view misses)."""
    u, v = np.meshgrid(np.linspace(0, 1, 512), np.linspace(0, 1, 512))
    stripes = 0.15 * np.sin(2 * np.pi * u * 40)
    rgb = np.stack([0.3 + 0.4 * u + stripes, 0.3 + 0.4 * v, 0.5 + stripes], axis=-1)
    wall = grid_wall()
    return dataclasses.replace(wall, materials=(dataclasses.replace(wall.materials[0], image=(
        255 * np.clip(rgb, 0, 1)).astype(np.uint8)),))


def wall_photos(tmp_path, scan, gains=(1.0, 1.0)):
    eyes = [(0.7, -2.2, 1.0), (1.3, -2.0, 1.1)]
    cams = [Camera.look_at(e, (1.0, 0.0, 1.0), fov_deg=55, width=640, height=480) for e in eyes]
    photos = photograph(scan, cams, tmp_path)
    for path, gain in zip(photos.images, gains):  # a photo's own exposure
        im = np.asarray(Image.open(path)).astype(np.float32) * gain
        Image.fromarray(np.clip(im, 0, 255).astype(np.uint8)).save(path)
    caster = RayCaster(scan.positions, scan.faces)
    views = prepare_photos(scan, photos, range(len(photos)), caster, 160, VisibilitySettings(supersample=2))
    return photos, views


def surface_points(scan, n=4000, seed=0):
    rng = np.random.default_rng(seed)
    f = rng.integers(0, scan.n_faces, n)
    b = rng.uniform(0, 1, (n, 2))
    b = np.where(b.sum(1, keepdims=True) > 1, 1 - b, b)
    tri = scan.triangles[f]
    points = tri[:, 0] + b[:, :1] * (tri[:, 1] - tri[:, 0]) + b[:, 1:] * (tri[:, 2] - tri[:, 0])
    return points, scan.face_normals[f], f, b.astype(np.float32)


def grey(points, normals, face_ids, bary):
    return np.full((len(points), 3), 0.5, np.float32)


def test_texels_come_from_the_full_resolution_photos(tmp_path):
    """Working views are 160 px, the photos 640 px: the fine stripes survive only if sampled at 640."""
    scan = smooth_wall()
    photos, views = wall_photos(tmp_path, scan)
    colour, report = projective_colour(photos, views, [0, 1], None, grey)
    assert report["sampled_at"] == [[640, 480], [640, 480]]
    points, normals, f, b = surface_points(scan)
    truth = shade_hits(scan, f, b)
    got = colour(points, normals, f, b)
    seen = np.abs(got - 0.5).max(axis=1) > 1e-6
    assert seen.mean() > 0.5
    err = np.abs(got[seen] - truth[seen]).mean()
    low, _ = projective_colour(photos, views, [0, 1], None, grey, ProjectiveSettings(max_side=160))
    err_low = np.abs(low(points, normals, f, b)[seen] - truth[seen]).mean()
    assert err < 0.03 and err < 0.6 * err_low



def test_photos_much_finer_than_the_atlas_are_sampled_at_the_atlas_density(tmp_path):
    """The 640 px photos resolve this 2 m wall at about 3 px/cm. An atlas of 2.5 texels/cm wants all of
    them; one of 0.5 texels/cm only about a third (2 photo pixels per texel): they are held at that size."""
    scan = smooth_wall()
    photos, views = wall_photos(tmp_path, scan)
    _, fine = projective_colour(photos, views, [0, 1], None, grey, ProjectiveSettings(texel_px_per_cm=2.5))
    assert fine["sampled_at"] == [[640, 480], [640, 480]]
    colour, coarse = projective_colour(photos, views, [0, 1], None, grey, ProjectiveSettings(texel_px_per_cm=0.5))
    assert all(150 < w < 300 and h == round(w * 480 / 640) for w, h in coarse["sampled_at"])
    assert coarse["photo_memory_mb"] < 0.25 * fine["photo_memory_mb"]
    points, normals, f, b = surface_points(scan)
    truth = shade_hits(scan, f, b)
    blurred = np.clip(np.mean(truth, axis=0), 0, 1)  # still the photos' colours, only less fine
    got = colour(points, normals, f, b)
    seen = np.abs(got - 0.5).max(axis=1) > 1e-6
    assert seen.mean() > 0.5 and np.abs(got[seen].mean(axis=0) - blurred).max() < 0.05


def test_photos_are_sampled_smaller_where_their_samples_would_pass_the_memory_bound(tmp_path, caplog):
    """Two 640x480 photos hold 2.3 MiB packed: bounded to 0.6, both are sampled at half their size (one factor
    for all), said in a warning, and still give the wall its colours."""
    scan = smooth_wall()
    photos, views = wall_photos(tmp_path, scan)
    _, whole = projective_colour(photos, views, [0, 1], None, grey, ProjectiveSettings(memory_mb=4.0))
    assert whole["sampled_at"] == [[640, 480], [640, 480]]
    with caplog.at_level("WARNING"):
        colour, bound = projective_colour(photos, views, [0, 1], None, grey, ProjectiveSettings(memory_mb=0.6))
    assert bound["sampled_at"] == [[323, 242], [323, 242]]
    assert 0.5 < bound["photo_memory_mb"] <= 0.6
    assert ("would hold 2.34 MiB" in caplog.text and "sampled at 51 % of it a side, 0.596 MiB (photos.sample_memory_mb "
            "0.6;" in caplog.text)
    # two bands hold 8 bytes a pixel: the same bound, a smaller factor
    _, bands = projective_colour(photos, views, [0, 1], None, grey,
                                 ProjectiveSettings(memory_mb=0.6, detail_temperature=0.1))
    assert bands["sampled_at"] == [[228, 171], [228, 171]]
    points, normals, f, b = surface_points(scan)
    truth = shade_hits(scan, f, b)
    got = colour(points, normals, f, b)
    seen = np.abs(got - 0.5).max(axis=1) > 1e-6
    assert seen.mean() > 0.5 and np.abs(got[seen] - truth[seen]).mean() < 0.05


def test_unseen_points_get_the_fallback_and_appearance_is_corrected(tmp_path):
    scan = smooth_wall()
    photos, views = wall_photos(tmp_path, scan, gains=(0.6, 0.6))
    behind = np.array([[1.0, 0.5, 1.0]])  # off the wall, seen by no photo
    colour, _ = projective_colour(photos, views, [0, 1], None, grey)
    np.testing.assert_allclose(colour(behind, np.array([[0.0, -1.0, 0.0]]), np.array([0]),
                                      np.zeros((1, 2), np.float32)), 0.5)
    points, normals, f, b = surface_points(scan)
    truth = shade_hits(scan, f, b)
    dark = colour(points, normals, f, b)
    fixed, _ = projective_colour(photos, views, [0, 1], lambda rgb, g: rgb / 0.6, grey)
    bright = fixed(points, normals, f, b)
    seen = np.abs(dark - 0.5).max(axis=1) > 1e-6
    inner = seen & (truth.max(axis=1) < 0.9)  # not clipped in the photos
    assert np.abs(bright[inner] - truth[inner]).mean() < 0.5 * np.abs(dark[inner] - truth[inner]).mean()


def test_weights_are_smooth_between_photos(tmp_path):
    """Two photos of different exposure: along a line across the wall, no step where the best view changes."""
    scan = smooth_wall()
    photos, views = wall_photos(tmp_path, scan, gains=(1.0, 0.7))
    colour, _ = projective_colour(photos, views, [0, 1], None, grey)
    x = np.linspace(0.6, 1.4, 801)
    points = np.stack([x, np.zeros_like(x), np.full_like(x, 1.0)], axis=1)
    caster = RayCaster(scan.positions, scan.faces)
    hits = caster.intersect(points + [0, -1, 0], np.tile([[0.0, 1.0, 0.0]], (len(x), 1)).astype(np.float32))
    rgb = colour(points, scan.face_normals[hits.face_id], hits.face_id, hits.bary)
    green = rgb[:, 1]  # the green ramp runs along z only: a step in it is an exposure switch
    assert np.abs(np.diff(green)).max() < 0.01
    assert (green > 0.7 * 0.5 - 0.02).all() and (green < 0.5 + 0.02).all()  # between the two exposures


def close_and_far(tmp_path):
    """The striped wall photographed from close and from farther away: ``(scan, photos, caster, views, (points,
    normals, faces, bary) on its surface, their true colours, the points in the wall's middle both photos see)``."""
    scan = smooth_wall()
    cams = [Camera.look_at(e, (1.0, 0.0, 1.0), fov_deg=55, width=640, height=480)
            for e in [(0.9, -2.0, 1.0), (1.2, -3.6, 1.1)]]
    photos = photograph(scan, cams, tmp_path)
    caster = RayCaster(scan.positions, scan.faces)
    views = prepare_photos(scan, photos, range(2), caster, 160, VisibilitySettings(supersample=2))
    points, normals, f, b = surface_points(scan)
    truth = shade_hits(scan, f, b)
    # the wall's middle, well inside both photos (the far one alone sees more, where it gives the detail too)
    seen = (np.abs(points[:, 0] - 1.0) < 0.6) & (np.abs(points[:, 2] - 1.0) < 0.45) & (truth.max(axis=1) < 0.95)
    return scan, photos, caster, views, (points, normals, f, b), truth, seen


def test_sharp_detail_comes_from_the_best_view_and_colour_from_every_photo(tmp_path):
    """A close photo and a far one whose registration is off by half the stripes' period there (4 px): blended at the
    default temperature, the stripes cancel; with two bands, the fine band at the detail temperature, they come
    from the close photo alone, while the coarse colour is still both photos' (the far one's exposure shows in
    it). Where the photos agree, the two bands give the one band's colours."""
    scan, photos, caster, views, (points, normals, f, b), truth, seen = close_and_far(tmp_path)
    sharp_settings = ProjectiveSettings(detail_temperature=0.1)

    def colours(settings, photos=photos, views=views):
        colour, report = projective_colour(photos, views, [0, 1], None, grey, settings)
        return colour(points, normals, f, b), report

    agreeing, _ = colours(ProjectiveSettings())
    agreeing_sharp, report = colours(sharp_settings)
    assert report["detail"] == {"temperature": 0.1, "sigma_px": 4.0, "gain": 1.0}
    assert seen.mean() > 0.1 and (np.abs(agreeing[seen] - 0.5).max(axis=1) > 1e-6).all()
    assert np.abs(agreeing_sharp[seen] - agreeing[seen]).mean() < 0.01
    shifted = np.roll(np.asarray(Image.open(photos.images[1])).astype(np.float32), 4, axis=1) * 0.8
    Image.fromarray(shifted.astype(np.uint8)).save(tmp_path / "shifted.png")  # misregistered, darker
    photos = dataclasses.replace(photos, images=(photos.images[0], tmp_path / "shifted.png"))
    views = prepare_photos(scan, photos, range(2), caster, 160, VisibilitySettings(supersample=2))
    blend, _ = colours(ProjectiveSettings(), photos, views)
    sharp, _ = colours(sharp_settings, photos, views)

    def matched_error(got):  # after a gain and offset per channel: the stripes' error, not the exposure's
        fit = [np.polyval(np.polyfit(truth[seen, c], got[seen, c], 1), truth[seen, c]) for c in range(3)]
        return np.abs(np.stack(fit, axis=1) - got[seen]).mean()

    error_blend, error_sharp = matched_error(blend), matched_error(sharp)
    assert error_sharp < 0.5 * error_blend, (error_sharp, error_blend)
    # the coarse colour, averaged over many stripes: both photos' exposure, the same in either mode
    assert np.abs(sharp[seen].mean(axis=0) - blend[seen].mean(axis=0)).max() < 0.01
    assert (blend[seen].mean(axis=0) < truth[seen].mean(axis=0) - 0.02).all()


def test_a_shaken_photos_detail_gives_way_to_a_sharp_photos_and_its_colour_stays(tmp_path):
    """The close photo, the best view, shaken across the stripes (smeared sideways by 15 px) and darker: blended in
    whole it washes the stripes out; as a soft photo (``soft_photos``) its fine band gives way to the far photo's,
    which draws them, while its colour still counts (the blend's mean as before, darker than the truth). Where the
    soft photo alone sees the wall, its colours are the blend's: its fine band weighs nothing against no other."""
    scan, photos, caster, views, (points, normals, f, b), truth, seen = close_and_far(tmp_path)
    image = np.asarray(Image.open(photos.images[0])).astype(np.float32)
    smeared = sum(np.roll(image, shift, axis=1) for shift in range(-7, 8)) / 15 * 0.8
    Image.fromarray(smeared.astype(np.uint8)).save(tmp_path / "shaken.png")
    photos = dataclasses.replace(photos, images=(tmp_path / "shaken.png", photos.images[1]))
    views = prepare_photos(scan, photos, range(2), caster, 160, VisibilitySettings(supersample=2))

    def colours(soft, coverage=False):
        colour, report = projective_colour(photos, views, [0, 1], None, grey, ProjectiveSettings(soft_photos=soft))
        assert report.get("soft_photos", []) == list(soft)
        return colour(points, normals, f, b, coverage=coverage)

    def matched_error(got):  # after a gain and offset per channel: the stripes' error, not the exposure's
        fit = [np.polyval(np.polyfit(truth[seen, c], got[seen, c], 1), truth[seen, c]) for c in range(3)]
        return np.abs(np.stack(fit, axis=1) - got[seen]).mean()

    blend, soft = colours(()), colours((0,))
    assert matched_error(soft) < 0.5 * matched_error(blend), (matched_error(soft), matched_error(blend))
    assert np.abs(soft[seen].mean(axis=0) - blend[seen].mean(axis=0)).max() < 0.01
    assert (soft[seen].mean(axis=0) < truth[seen].mean(axis=0) - 0.02).all()
    pix, _ = photos.cameras[0].project(points)
    alone = ((pix[:, 0] < -10) | (pix[:, 0] > 650) | (pix[:, 1] < -10) | (pix[:, 1] > 490)) & (colours((), True)[1] > 0)
    assert alone.sum() > 100
    np.testing.assert_allclose(colours((1,))[alone], blend[alone], atol=1e-4)


def test_the_detail_gain_scales_the_best_views_fine_band_alone(tmp_path):
    """Balanced detail (``detail_gain`` 0.5) is the coarse blend plus half the best views' fine band: halfway between
    the coarse band alone (gain 0) and sharp detail (gain 1) at every point, its stripes at half their contrast."""
    _, photos, _, views, (points, normals, f, b), _, seen = close_and_far(tmp_path)

    def colours(gain):
        colour, report = projective_colour(photos, views, [0, 1], None, grey,
                                           ProjectiveSettings(detail_temperature=0.1, detail_gain=gain))
        assert report["detail"]["gain"] == gain
        return colour(points, normals, f, b)[seen]

    coarse, balanced, sharp = colours(0.0), colours(0.5), colours(1.0)
    np.testing.assert_allclose(balanced, 0.5 * (coarse + sharp), atol=1e-5)
    stripes = np.abs(sharp - coarse).mean()
    assert stripes > 0.02  # the fine band holds the stripes
    assert np.abs(balanced - coarse).mean() == pytest.approx(0.5 * stripes, rel=1e-3)


def test_sharp_detail_does_not_come_from_a_photo_that_saw_an_occluder(tmp_path):
    """The best view has a patterned occluder in front of part of the wall (a tree): the two other photos see the
    wall there. Without the gate the fine band there is the occluder's pattern; with it, the other photos'."""
    scan = smooth_wall()
    eyes = [(1.0, -2.0, 1.0), (0.6, -3.4, 1.0), (1.4, -3.4, 1.0)]  # the first the closest, the best view
    cams = [Camera.look_at(e, (1.0, 0.0, 1.0), fov_deg=55, width=640, height=480) for e in eyes]
    photos = photograph(scan, cams, tmp_path)
    image = np.asarray(Image.open(photos.images[0])).copy()
    yy, xx = np.mgrid[160:320, 240:400]
    image[160:320, 240:400] = np.where(((xx // 6 + yy // 6) % 2 == 0)[..., None], (40, 120, 40), (200, 230, 90))
    Image.fromarray(image).save(photos.images[0])
    caster = RayCaster(scan.positions, scan.faces)
    views = prepare_photos(scan, photos, range(3), caster, 160, VisibilitySettings(supersample=2))
    points, normals, f, b = surface_points(scan, 20000)
    truth = shade_hits(scan, f, b)
    # the wall behind the occluder: where the first photo sees it, well inside the patch
    pix, _ = cams[0].project(points)
    behind = (pix[:, 0] > 260) & (pix[:, 0] < 380) & (pix[:, 1] > 180) & (pix[:, 1] < 300)
    assert behind.sum() > 200

    def error(consistency):
        colour, _ = projective_colour(photos, views, [0, 1, 2], None, grey,
                                      ProjectiveSettings(detail_temperature=0.1, detail_consistency=consistency))
        return np.abs(colour(points, normals, f, b)[behind] - truth[behind]).mean()

    assert error(0.05) < 0.6 * error(0.0), (error(0.05), error(0.0))


def test_a_photo_nothing_ties_down_takes_the_others_median_gain(tmp_path):
    """A photo with too few usable pixels to fit (a sliver of a tile) is not left at gain 1 among photos whose
    gains are far from it: it takes the fitted photos' median."""
    import dataclasses

    scan = smooth_wall()
    _, views = wall_photos(tmp_path, scan, gains=(1.4, 1.5))
    caster = RayCaster(scan.positions, scan.faces)
    references = [render(scan, v.camera, caster)[0] for v in views]
    blind = dataclasses.replace(views[1], valid=np.zeros_like(views[1].valid))
    fitted = fit_photo_transforms(references, views)
    alone = fit_photo_transforms(references, [views[0], blind])
    assert abs(fitted[0, 1, 1] - 1.4) < 0.1 and abs(fitted[1, 1, 1] - 1.5) < 0.1
    np.testing.assert_allclose(np.diagonal(alone[1, :3]), np.diagonal(alone[0, :3]))  # not 1


def test_sharpness_measure_prefers_sharp_images():
    rng = np.random.default_rng(0)
    sharp = rng.uniform(0, 1, (64, 64, 3)).astype(np.float32)
    from scipy import ndimage

    blurred = ndimage.gaussian_filter(sharp, (2, 2, 0))
    assert photo_sharpness(sharp) > 10 * photo_sharpness(blurred)


def test_colour_transforms_in_closed_form_undo_each_photos_exposure(tmp_path):
    """Photos taken at gains 0.6 and 1.2: the transforms fitted against the scan's own texture recover the
    gains, and their inverse brings the photos' samples back to the texture's colours."""
    scan = smooth_wall()
    photos, views = wall_photos(tmp_path, scan, gains=(0.6, 1.2))
    caster = RayCaster(scan.positions, scan.faces)
    references = [render(scan, v.camera, caster)[0] for v in views]
    transforms = fit_photo_transforms(references, views)
    assert transforms.shape == (2, 4, 3)
    points, normals, f, b = surface_points(scan)
    truth = shade_hits(scan, f, b)
    dim = truth.max(axis=1) < 0.8
    for t, gain in zip(transforms, (0.6, 1.2)):  # the texture's colours as each photo records them
        np.testing.assert_allclose(truth[dim] @ t[:3] + t[3], gain * truth[dim], atol=0.03)
    canonical = inverse_transforms(transforms)
    raw, _ = projective_colour(photos, views, [0, 1], None, grey)
    fixed, _ = projective_colour(photos, views, [0, 1], canonical, grey)
    got, before = fixed(points, normals, f, b), raw(points, normals, f, b)
    seen = (np.abs(before - 0.5).max(axis=1) > 1e-6) & dim  # seen, not clipped
    assert np.abs(got[seen] - truth[seen]).mean() < 0.4 * np.abs(before[seen] - truth[seen]).mean()


def test_references_made_when_asked_fit_the_same_transforms(tmp_path):
    """A reference given as a function of the photo (rendered when the fit asks, not all held at once) fits the
    transforms of the same references given as a list."""
    scan = smooth_wall()
    photos, views = wall_photos(tmp_path, scan, gains=(0.6, 1.2))
    caster = RayCaster(scan.positions, scan.faces)
    references = [render(scan, v.camera, caster)[0] for v in views]
    asked = []

    def reference(k):
        asked.append(k)
        return render(scan, views[k].camera, caster)[0]

    np.testing.assert_array_equal(fit_photo_transforms(reference, views, pair_weight=4.0),
                                  fit_photo_transforms(references, views, pair_weight=4.0))
    assert sorted(asked) == [0, 1]  # once a photo


def test_views_released_as_their_photos_are_sampled_give_the_same_colours(tmp_path):
    """``release``: each view in the list is replaced by its sampled copy (no maps) as its photo is sampled,
    and the colours are those of the views kept."""
    scan = smooth_wall()
    photos, views = wall_photos(tmp_path, scan, gains=(1.0, 0.7))
    points, normals, f, b = surface_points(scan, 20000)
    kept, _ = projective_colour(photos, views, [0, 1], None, grey, faces=scan.faces)
    given = list(views)
    released, _ = projective_colour(photos, given, [0, 1], None, grey, faces=scan.faces, release=True)
    assert all(v.face_id is None and v.depth is None and v.valid is None and v.pixels is None for v in given)
    assert [v.index for v in given] == [v.index for v in views] and all(v.face_id is not None for v in views)
    np.testing.assert_array_equal(released(points, normals, f, b), kept(points, normals, f, b))


def test_photo_consistency_rejects_an_occluder_one_photo_saw(tmp_path):
    """Four photos of the wall; in one, something the mesh does not hold (a red board) hides part of it. The
    plain blend carries a quarter of the red; the photo-consistent blend outvotes it and keeps the wall's
    colour, and it leaves points every photo agrees on as they were."""
    scan = smooth_wall()
    eyes = [(0.7, -2.2, 1.0), (1.3, -2.0, 1.1), (0.9, -2.4, 0.8), (1.1, -2.1, 1.2)]
    cams = [Camera.look_at(e, (1.0, 0.0, 1.0), fov_deg=55, width=640, height=480) for e in eyes]
    photos = photograph(scan, cams, tmp_path)
    im = np.asarray(Image.open(photos.images[0])).copy()
    im[180:300, 260:380] = (230, 20, 20)
    Image.fromarray(im).save(photos.images[0])
    caster = RayCaster(scan.positions, scan.faces)
    views = prepare_photos(scan, photos, range(4), caster, 160, VisibilitySettings(supersample=2))
    points, normals, f, b = surface_points(scan, 20000)
    pix, _ = photos.cameras[0].project(points)
    board = (pix[:, 0] > 275) & (pix[:, 0] < 365) & (pix[:, 1] > 195) & (pix[:, 1] < 285)
    truth = shade_hits(scan, f, b)
    plain, _ = projective_colour(photos, views, range(4), None, grey)
    robust, _ = projective_colour(photos, views, range(4), None, grey, ProjectiveSettings(consistency=0.1))
    got_plain, got_robust = plain(points, normals, f, b), robust(points, normals, f, b)
    seen = np.abs(got_plain - 0.5).max(axis=1) > 1e-6
    near = (pix[:, 0] > 240) & (pix[:, 0] < 400) & (pix[:, 1] > 160) & (pix[:, 1] < 320)
    inside, outside = board & seen, ~near & seen
    assert inside.sum() > 200 and outside.sum() > 2000
    err_plain = np.abs(got_plain[inside] - truth[inside]).mean()
    err_robust = np.abs(got_robust[inside] - truth[inside]).mean()
    assert err_plain > 0.08 and err_robust < 0.25 * err_plain
    np.testing.assert_allclose(got_robust[outside], got_plain[outside], atol=0.02)


def test_culling_to_the_faces_each_photo_sees_keeps_the_colours(tmp_path):
    """Asking each photo only about the faces its G-buffer sees (and their one-ring) gives the colours of
    asking every photo about every point: the slow, plainly correct twin."""
    scan = smooth_wall()
    photos, views = wall_photos(tmp_path, scan, gains=(1.0, 0.7))
    points, normals, f, b = surface_points(scan, 20000)
    every, _ = projective_colour(photos, views, [0, 1], None, grey)
    culled, _ = projective_colour(photos, views, [0, 1], None, grey, faces=scan.faces)
    np.testing.assert_array_equal(culled(points, normals, f, b), every(points, normals, f, b))


def test_photo_pairs_level_photos_whose_texture_is_a_patchwork(tmp_path):
    """The input atlas is one chart but two exposures (its left half 30 % darker, as a best-view blend
    switching photos inside a chart leaves it); two photos at gains 1.0 and 0.8 see mostly one half each.
    Tied to the texture alone, their fitted gains take in the halves' difference; with the photos' ratio
    to one another, the ratio of their gains is about the true 0.8."""
    scan = smooth_wall()
    photos, views = wall_photos(tmp_path, scan, gains=(1.0, 0.8))
    image = scan.materials[0].image.astype(np.float32)
    image[:, : image.shape[1] // 2] *= 0.7
    patchwork = dataclasses.replace(scan, materials=(dataclasses.replace(scan.materials[0],
                                                                          image=image.astype(np.uint8)),))
    caster = RayCaster(scan.positions, scan.faces)
    references = [render(patchwork, v.camera, caster)[0] for v in views]
    alone = fit_photo_transforms(references, views)
    paired = fit_photo_transforms(references, views, pair_weight=4.0)
    ratio = lambda t: np.diagonal(t[1, :3]) / np.diagonal(t[0, :3])  # noqa: E731
    assert np.abs(ratio(alone) - 0.8).min() > 0.15  # the patchwork misleads the texture-only fit (0.57)
    np.testing.assert_allclose(ratio(paired), 0.8, atol=0.03)  # 0.78: the texture still pulls a little


def test_photo_pairs_alone_level_the_photos_of_an_untextured_scan(tmp_path):
    """No texture to fit to (an untextured scan): the photos' overlaps alone give their exposures relative to
    one another, and the photos' mean log gain is the gauge, so gains 0.6 and 1.2 come out as their ratio
    about their geometric mean (sqrt(0.72)); a photo seeing nothing the others see keeps gain 1."""
    scan = smooth_wall()
    photos, views = wall_photos(tmp_path, scan, gains=(0.6, 1.2))
    transforms = fit_photo_transforms(None, views)
    gains = np.array([np.diagonal(t[:3]) for t in transforms])  # [2, 3]
    np.testing.assert_allclose(gains[1] / gains[0], 2.0, rtol=0.03)
    np.testing.assert_allclose(np.log(gains).mean(axis=0), 0.0, atol=1e-3)
    np.testing.assert_allclose(gains[0], 0.6 / np.sqrt(0.72), rtol=0.03)
    alone = fit_photo_transforms(None, views[:1])
    np.testing.assert_allclose(alone[0, :3], np.eye(3))


def test_packed_photo_samples_are_bilinear():
    """Samples of a photo packed four bytes a pixel are plain bilinear interpolation of its pixels."""
    from scipy import ndimage

    from scantex.photos.texturing import _bilinear, _packed

    rng = np.random.default_rng(3)
    image = rng.integers(0, 256, (37, 53, 3), dtype=np.uint8)
    pix = np.stack([rng.uniform(0, 51.9, 500), rng.uniform(0, 35.9, 500)], axis=1)
    got = _bilinear(_packed(image), 53, 37, pix.astype(np.float32))
    want = np.stack([ndimage.map_coordinates(image[..., c].astype(np.float64), [pix[:, 1], pix[:, 0]], order=1)
                     for c in range(3)], axis=1) / 255
    np.testing.assert_allclose(got, want, atol=1e-4)


def test_a_scene_far_from_the_origin_gets_the_same_colours(tmp_path):
    """Georeferenced coordinates (hundreds of kilometres): the photos are sampled in float32 about the
    cameras' centre, so the colours are those of the same scene at the origin."""
    offset = np.array([512_000.0, 4_300_000.0, 120.0])
    scan = smooth_wall()
    far = dataclasses.replace(scan, positions=scan.positions + offset)
    (tmp_path / "near").mkdir()
    (tmp_path / "far").mkdir()
    photos, views = wall_photos(tmp_path / "near", scan)
    eyes = [(0.7, -2.2, 1.0), (1.3, -2.0, 1.1)]
    cams = [Camera.look_at(np.add(e, offset), np.add((1.0, 0.0, 1.0), offset), fov_deg=55, width=640, height=480)
            for e in eyes]
    far_photos = photograph(far, cams, tmp_path / "far")
    far_views = prepare_photos(far, far_photos, range(2), RayCaster(far.positions, far.faces), 160,
                               VisibilitySettings(supersample=2))
    points, normals, f, b = surface_points(scan, 20000)
    near_colour, _ = projective_colour(photos, views, [0, 1], None, grey, faces=scan.faces)
    far_colour, _ = projective_colour(far_photos, far_views, [0, 1], None, grey, faces=far.faces)
    want = near_colour(points, normals, f, b)
    got = far_colour(points + offset, normals, f, b)
    assert (np.abs(want - 0.5).max(axis=1) > 1e-6).mean() > 0.5  # most points are seen
    assert np.abs(got - want).max(axis=1).mean() < 2 / 255


def test_clipped_samples_give_way_to_a_photo_that_sees_the_point_unclipped(tmp_path):
    """One photo over-exposed 1.8x (its bright half clipped): brought back by its true gain, a clipped sample is
    too dark in the clipped channels, and blending it in tints the surface. Where the other photo sees the point
    unclipped and says this one overshot, the clipped sample gives way; where both photos record the same
    exposure (a surface near white in both, clipped by either), nothing changes."""
    scan = smooth_wall()
    transforms = np.stack([np.vstack([np.eye(3) * g, np.zeros((1, 3))]) for g in (1.0, 1.8)])
    photos, views = wall_photos(tmp_path, scan, gains=(1.0, 1.8))
    points, normals, f, b = surface_points(scan, 20000)
    truth = shade_hits(scan, f, b)

    def blends(photos, views, transforms):
        canonical, recorded = inverse_transforms(transforms), recorded_transforms(transforms)
        censored, _ = projective_colour(photos, views, [0, 1], canonical, grey, recorded=recorded)
        plain, _ = projective_colour(photos, views, [0, 1], canonical, grey, ProjectiveSettings(overshoot=0),
                                     recorded=recorded)
        return censored(points, normals, f, b), plain(points, normals, f, b)

    got, was = blends(photos, views, transforms)
    seen = np.abs(was - 0.5).max(axis=1) > 1e-6
    clipped = (truth.max(axis=1) * 1.8 > 1.1) & seen  # clipped by more than the overshoot in one photo
    assert clipped.mean() > 0.2
    err, err_plain = (np.abs(got - truth).max(axis=1)[clipped].mean(),
                      np.abs(was - truth).max(axis=1)[clipped].mean())
    assert err_plain > 0.05 and err < 0.5 * err_plain
    assert np.abs(got - was).max(axis=1)[seen & (truth.max(axis=1) * 1.8 < 0.99)].max() < 1e-5  # unclipped: as was

    (tmp_path / "same").mkdir()
    photos, views = wall_photos(tmp_path / "same", scan, gains=(1.8, 1.8))  # both clipped alike: no one to defer to
    same = np.stack([transforms[1]] * 2)
    got, was = blends(photos, views, same)
    assert np.abs(got - was).max() < 1e-5


def test_a_highlight_every_photo_clipped_comes_out_neutral(tmp_path):
    """Two photos over-exposed with opposite white balances: where both clipped all three channels, each
    channel says only "at least this bright", and their gains turn the one white point into a blue and a red
    lower bound. The result must not carry either tint (the synthetic room showed a lilac patch there)."""
    scan = smooth_wall()
    gains = (np.array([2.4, 2.7, 3.0]), np.array([3.0, 2.7, 2.4]))
    transforms = np.stack([np.vstack([np.diag(g), np.zeros((1, 3))]) for g in gains])
    photos, views = wall_photos(tmp_path, scan, gains=gains)
    points, normals, f, b = surface_points(scan, 20000)
    truth = shade_hits(scan, f, b)
    colour, _ = projective_colour(photos, views, [0, 1], inverse_transforms(transforms), grey,
                                  recorded=recorded_transforms(transforms))
    got = colour(points, normals, f, b)
    seen = np.abs(got - 0.5).max(axis=1) > 1e-6
    white = seen & ((truth * 2.4).min(axis=1) > 1.2)  # every channel clipped in both photos, neighbours too
    assert white.sum() > 2000
    assert np.ptp(got[white], axis=1).max() < 0.01  # no hue
    # the highest bound the photos give (1 / 2.4), kept everywhere; the grey fallback (0.5) fades in only
    # towards the edges of the photos' coverage
    assert got[white].min() > 1 / 2.4 - 0.01 and np.median(np.abs(got[white] - 1 / 2.4)) < 0.005


def test_recorded_transforms_undo_the_canonical_ones():
    rng = np.random.default_rng(3)
    transforms = np.concatenate([np.eye(3)[None] + 0.1 * rng.normal(size=(4, 3, 3)),
                                 0.05 * rng.normal(size=(4, 1, 3))], axis=1)
    canonical, recorded = inverse_transforms(transforms), recorded_transforms(transforms)
    rgb = rng.uniform(0, 1, (500, 3)).astype(np.float32)
    for group in (rng.integers(0, 4, 500), np.full(500, 2)):  # mixed photos, and one photo's samples
        assert np.abs(recorded(canonical(rgb, group), group) - rgb).max() < 1e-5
        want = np.einsum("ni,nij->nj", rgb, transforms[group, :3]) + transforms[group, 3]
        assert np.abs(recorded(rgb, group) - want).max() < 1e-5


def test_the_report_counts_the_clipped_samples_and_those_that_gave_way(tmp_path):
    scan = smooth_wall()
    transforms = np.stack([np.vstack([np.eye(3) * g, np.zeros((1, 3))]) for g in (1.0, 1.8)])
    photos, views = wall_photos(tmp_path, scan, gains=(1.0, 1.8))
    points, normals, f, b = surface_points(scan, 20000)
    colour, report = projective_colour(photos, views, [0, 1], inverse_transforms(transforms), grey,
                                       recorded=recorded_transforms(transforms))
    colour(points, normals, f, b)
    tally = report["clipped"]
    assert tally["samples"] > 20000  # most points seen by both photos
    assert 0 < tally["gave_way"] <= tally["clipped"] < tally["samples"]


def test_fallback_offsets_carry_the_photos_tone_across_what_they_do_not_see():
    """Photo mode's fallback where no photo sees the surface, levelled to the photos where they meet
    (``photos.level_fallback``): on a wall whose left half the photos cover, 0.1 brighter than the fallback,
    the offset is 0.1 at the covered vertices and carries on smoothly over the uncovered half (no step in tone
    where the photos end); a face whose difference is content (beyond ``MAX_FALLBACK_STEP``) sets nothing; a
    part of the mesh no photo reaches keeps the fallback as it is."""
    from scantex.photos.texturing import MAX_FALLBACK_STEP, fallback_offsets
    from scantex.scan import Scan

    wall = grid_wall(n=11, size=2.0)
    island = wall.positions + np.array([0.0, 0.0, 5.0])  # a second wall, apart from the first
    scan = Scan(np.concatenate([wall.positions, island]), np.concatenate([wall.faces, wall.faces + len(island)]))
    covered_x = 1.0  # the photos see x < 1 of the first wall
    odd = 12  # one covered face whose photos say something else entirely (an object the fallback lacks)
    left_faces = np.flatnonzero((scan.triangles[:, :, 0].max(axis=1) <= covered_x)
                                & (scan.triangles[:, :, 2].max(axis=1) < 3))
    assert odd in left_faces

    def fallback(points, normals, face_ids, bary):
        return np.stack([0.3 + 0.1 * points[:, 0], np.full(len(points), 0.4), 0.5 - 0.1 * points[:, 2] / 6], 1)

    def colour(points, normals, face_ids, bary, coverage=False):
        share = np.isin(face_ids, left_faces).astype(np.float32)
        rgb = fallback(points, normals, face_ids, bary) + 0.1 * share[:, None]
        rgb[face_ids == odd] += 0.3
        return rgb, share

    offsets, report = fallback_offsets(scan, colour, fallback)
    assert report["faces_covered"] == len(left_faces) and report["faces_measured"] == len(left_faces) - 1
    first = np.arange(len(wall.positions))
    np.testing.assert_allclose(offsets[first], 0.1, atol=1e-6)  # the covered half's tone, carried across
    np.testing.assert_allclose(offsets[len(wall.positions):], 0.0)  # the wall no photo reaches is left alone
    assert 0.3 > MAX_FALLBACK_STEP
    # ungated (an untextured scan's flat fallback, whose every difference is content): every covered face counts,
    # and the wall no photo reaches takes the offset of the nearest covered point (the first wall's top: 0.1)
    carried, ungated = fallback_offsets(scan, colour, fallback, max_step=None)
    assert ungated["faces_measured"] == len(left_faces)
    np.testing.assert_allclose(carried[len(wall.positions):], 0.1, atol=1e-6)


def test_a_loose_fragment_takes_what_the_photos_show_behind_it(tmp_path):
    """A fused scan's floater (a fragment of the mesh 15 cm off a wall, in front of its dark half, that the
    scene does not have) is all contour to the photos: no usable pixel colours it, and it took the fallback.
    Now it takes the photos' pixels it projects to, where no surface is in front of it: the dark wall behind
    it, as a held-out photo shows it. The wall's own colours do not change."""
    wall = grid_wall(n=21, size=2.0)  # x-z plane, normals towards -y
    image = np.zeros((160, 160, 3), np.uint8)
    image[:, :80] = (90, 64, 51)      # dark wood on the left half (x < 1)
    image[:, 80:] = (230, 230, 217)   # a white wall on the right
    wall = dataclasses.replace(wall, materials=(dataclasses.replace(wall.materials[0], image=image),))
    eyes = [(0.5, -2.2, 1.0), (0.8, -2.0, 1.1), (0.6, -2.4, 0.8)]
    cams = [Camera.look_at(e, (0.6, 0.0, 1.0), fov_deg=55, width=640, height=480) for e in eyes]
    photos = photograph(wall, cams, tmp_path)  # the scene: the wall alone
    s = 0.008  # the floater: a 1.6 cm square 15 cm in front of the dark half
    square = np.array([[0.6 - s, -0.15, 1.0 - s], [0.6 + s, -0.15, 1.0 - s], [0.6 + s, -0.15, 1.0 + s],
                       [0.6 - s, -0.15, 1.0 + s]])
    n, t = len(wall.positions), len(wall.uvs)
    scan = dataclasses.replace(
        wall, positions=np.concatenate([wall.positions, square]),
        faces=np.concatenate([wall.faces, [[n, n + 1, n + 2], [n, n + 2, n + 3]]]),
        uvs=np.concatenate([wall.uvs, np.full((1, 2), 0.25)]),
        face_uvs=np.concatenate([wall.face_uvs, np.full((2, 3), t)]), face_materials=None)
    caster = RayCaster(scan.positions, scan.faces)
    views = prepare_photos(scan, photos, range(3), caster, 160, VisibilitySettings(supersample=2))
    loose = loose_fragments(scan.faces)
    floater = np.flatnonzero(loose)
    assert floater.tolist() == [scan.n_faces - 2, scan.n_faces - 1]
    assert not any(np.isin(v.face_id[v.valid], floater).any() for v in views)  # no usable pixel on it
    points, normals, f, b = surface_points(scan, 20000)
    centre = np.full((2, 2), 1 / 3, np.float32)
    fp = scan.triangles[floater].mean(axis=1)
    before, _ = projective_colour(photos, views, range(3), None, grey, faces=scan.faces)
    after, _ = projective_colour(photos, views, range(3), None, grey, faces=scan.faces, through=loose)
    np.testing.assert_allclose(before(fp, scan.face_normals[floater], floater, centre), 0.5)
    np.testing.assert_allclose(after(fp, scan.face_normals[floater], floater, centre),
                               np.broadcast_to(np.array([90, 64, 51]) / 255, (2, 3)), atol=0.02)
    on_wall = ~np.isin(f, floater)
    np.testing.assert_array_equal(after(points, normals, f, b)[on_wall], before(points, normals, f, b)[on_wall])
