"""Photos' tone curves levelled against one another: a gamma per photo, measured at the flat surface they share."""

from __future__ import annotations

import dataclasses

import numpy as np
from PIL import Image

from scantex.photos.texturing import fit_photo_transforms, inverse_transforms, projective_colour
from scantex.photos.tones import fit_photo_tones, tone_table, toned, toned_view
from scantex.photos.training import VisibilitySettings, prepare_photos
from scantex.views.camera import Camera
from scantex.views.raycast import RayCaster
from scantex.views.render import shade_hits
from tests.conftest import grid_wall
from tests.photos.test_alignment import photograph
from tests.photos.test_texturing import grey, surface_points


def blocky_wall():
    """A 2 m wall of flat blocks, from dark grey to near white (flat: a pair's points away from edges say
    how the photos' tones differ), its top third near-white."""
    rng = np.random.default_rng(1)
    blocks = rng.uniform(0.15, 0.75, (6, 6, 3))
    blocks[:2] = 0.93  # the top rows of the texture (v near 0): a near-white wall
    image = np.kron(blocks, np.ones((64, 64, 1)))
    wall = grid_wall()
    return dataclasses.replace(wall, materials=(dataclasses.replace(wall.materials[0], image=(
        255 * image).astype(np.uint8)),))


def toned_photos(tmp_path, scan, gammas):
    """Photos of ``scan`` from beside one another, photo ``k`` recorded on a curve ``y = x ** gammas[k]`` (white
    stays white) and their working views."""
    eyes = [(0.8, -2.2, 1.0), (1.2, -2.1, 1.05), (1.0, -2.3, 0.9)][:len(gammas)]
    cams = [Camera.look_at(e, (1.0, 0.0, 1.0), fov_deg=60, width=320, height=240) for e in eyes]
    photos = photograph(scan, cams, tmp_path)
    for path, gamma in zip(photos.images, gammas):
        im = np.asarray(Image.open(path)).astype(np.float64) / 255
        Image.fromarray(np.round(255 * im ** gamma).astype(np.uint8)).save(path)
    caster = RayCaster(scan.positions, scan.faces)
    return photos, prepare_photos(scan, photos, range(len(photos)), caster, 160, VisibilitySettings(supersample=2))


def test_tone_table_keeps_black_and_white():
    table = tone_table(np.array([0.7, 1.0, 1.4]))  # one a channel (a photo's is one for all three)
    assert table.shape == (256, 3) and table.dtype == np.uint8
    np.testing.assert_array_equal(table[[0, 255]], [[0, 0, 0], [255, 255, 255]])
    np.testing.assert_array_equal(table[:, 1], np.arange(256))  # gamma 1: as recorded
    assert (np.diff(table.astype(int), axis=0) >= 0).all()
    assert table[64, 0] < 64 < table[64, 2]  # gamma 0.7 brightened the photo's mid-tones: brought back down
    image = np.array([[[64, 64, 64]]], np.uint8)
    np.testing.assert_array_equal(toned(image, np.array([0.7, 1.0, 1.4])), table[[64], [0, 1, 2]][None, None])
    np.testing.assert_allclose(toned(image / np.float32(255), np.array([0.7, 1.0, 1.4]))[0, 0],
                               (64 / 255) ** (1 / np.array([0.7, 1.0, 1.4])), rtol=1e-5)
    np.testing.assert_array_equal(tone_table(0.7), np.repeat(table[:, :1], 3, axis=1))


def test_toned_photos_are_the_same_compiled_and_in_numpy(monkeypatch):
    """The tone table looked up by the compiled loop and by its numpy twin (numba missing): the same bytes, for a
    photo as decoded (writable), as the cache keeps it (read-only), not contiguous, and with a fourth channel."""
    from scantex import jit

    rng = np.random.default_rng(0)
    gamma = np.array([0.7, 1.0, 1.4])
    photo = rng.integers(0, 256, (37, 53, 4), dtype=np.uint8)
    kept = photo[..., :3].copy()
    kept.flags.writeable = False
    images = [photo[..., :3].copy(), kept, photo[:, ::2, :3], photo]
    compiled = [toned(image, gamma) for image in images]
    monkeypatch.setattr(jit, "compiled", lambda function: None)
    for image, fast in zip(images, compiled):
        twin = toned(image, gamma)
        assert fast.shape == twin.shape == (*image.shape[:2], 3) and fast.dtype == np.uint8
        np.testing.assert_array_equal(fast, twin)
        np.testing.assert_array_equal(twin[..., 2], tone_table(gamma)[image[..., 2], 2])


def test_a_photo_set_reads_its_photos_on_the_common_curve(tmp_path):
    scan = blocky_wall()
    photos, _ = toned_photos(tmp_path, scan, [1.0, 0.8])
    gamma = 0.8
    levelled = dataclasses.replace(photos, tones=(None, gamma))
    np.testing.assert_array_equal(levelled.load_image(0), photos.load_image(0))
    np.testing.assert_array_equal(levelled.load_image(1), toned(photos.load_image(1), gamma))
    assert levelled.subset([1]).tones[0] is gamma


def test_fitted_tones_recover_the_photos_gammas(tmp_path, monkeypatch):
    """Three photos on curves of gamma 1, 1.35 and 0.8: without the pull towards 1, the fitted gammas' ratios to
    the first's are those, and their mean log is 0; with it (the default), each is drawn part of the way to 1."""
    import scantex.photos.tones as tones

    scan = blocky_wall()
    truth = np.array([1.0, 1.35, 0.8])
    _, views = toned_photos(tmp_path, scan, truth)
    pulled = fit_photo_tones(views)
    monkeypatch.setattr(tones, "PRIOR", 0.0)
    gammas = fit_photo_tones(views)
    np.testing.assert_allclose(gammas / gammas[0], truth, rtol=0.05)
    np.testing.assert_allclose(np.log(gammas).mean(), 0.0, atol=1e-3)
    share = np.log(pulled / pulled[0])[1:] / np.log(gammas / gammas[0])[1:]
    assert ((share > 0.6) & (share < 0.95)).all()
    # one photo alone: nothing to measure against
    np.testing.assert_array_equal(fit_photo_tones(views[:1]), np.ones(1))


def test_levelled_tones_leave_no_exposure_step_on_a_white_wall(tmp_path):
    """The second photo's auto-exposure lifted its mid-tones (gamma 0.7) but not the near-white wall. One gain a
    photo, fitted where the photos overlap, splits the difference and the two photos' colours of the white wall
    disagree (where one photo's frame ends, a step); brought to one curve first, they agree there and elsewhere."""
    scan = blocky_wall()
    photos, views = toned_photos(tmp_path, scan, [1.0, 0.7])
    points, normals, f, b = surface_points(scan, 20000)
    white = shade_hits(scan, f, b).min(axis=1) > 0.9

    def disagreement(photo_set, tones):
        transforms = fit_photo_transforms(None, [toned_view(v, g) for v, g in zip(views, tones)]
                                          if tones is not None else views)
        canonicalise = inverse_transforms(transforms)
        one = [projective_colour(photo_set, [views[k]], [k], canonicalise, grey)[0] for k in range(2)]
        a, c = (colour(points, normals, f, b) for colour in one)
        both = (np.abs(a - 0.5).max(axis=1) > 1e-6) & (np.abs(c - 0.5).max(axis=1) > 1e-6)
        return np.abs(a - c)[both & white].mean(), np.abs(a - c)[both & ~white].mean()

    gain_white, gain_rest = disagreement(photos, None)
    tones = fit_photo_tones(views)
    tone_white, tone_rest = disagreement(dataclasses.replace(photos, tones=tuple(tones)), tones)
    assert gain_white > 0.03  # a visible step
    assert tone_white < 0.3 * gain_white and tone_rest < 0.5 * gain_rest
