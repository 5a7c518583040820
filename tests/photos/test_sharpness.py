"""Each photo's fine detail against the photos that see the same surface: a shaken frame named, a far one not."""

from __future__ import annotations

import dataclasses

import numpy as np
from PIL import Image
from scipy import ndimage

from scantex.photos.sharpness import BLURRED, blurred_photos, pair_rows, relative_detail
from scantex.photos.texturing import photo_overlaps
from scantex.photos.training import prepare_photos
from scantex.views.camera import Camera
from scantex.views.raycast import RayCaster
from tests.conftest import grid_wall
from tests.photos.test_alignment import photograph


def speckled_wall():
    """A 2 m wall printed with random blocks of 3 cm, in colour: detail at every photo's scale."""
    rng = np.random.default_rng(4)
    image = np.kron(rng.uniform(0.1, 0.9, (64, 64, 3)), np.ones((8, 8, 1)))
    wall = grid_wall()
    return dataclasses.replace(wall, materials=(dataclasses.replace(wall.materials[0], image=(
        255 * image).astype(np.uint8)),))


def photos_of(tmp_path, scan, eyes, smeared=(), length=9):
    """Photos of the wall from ``eyes`` (320x240), those of ``smeared`` blurred by a horizontal box of ``length``
    pixels (a shaken frame), and their working views (160 px)."""
    tmp_path.mkdir(exist_ok=True)
    cams = [Camera.look_at(e, (1.0, 0.0, 1.0), fov_deg=60, width=320, height=240) for e in eyes]
    photos = photograph(scan, cams, tmp_path)
    for k in smeared:
        im = np.asarray(Image.open(photos.images[k])).astype(np.float64)
        Image.fromarray(np.round(ndimage.uniform_filter1d(im, length, axis=1)).astype(np.uint8)).save(photos.images[k])
    caster = RayCaster(scan.positions, scan.faces)
    return photos, prepare_photos(scan, photos, range(len(photos)), caster, 160)


EYES = [(0.7, -2.2, 1.0), (1.0, -2.1, 1.1), (1.3, -2.2, 0.9), (0.9, -2.3, 0.8), (1.2, -2.0, 1.2)]


def test_a_shaken_photo_is_named_and_the_others_are_not(tmp_path):
    scan = speckled_wall()
    _, sharp = photos_of(tmp_path / "sharp", scan, EYES)
    assert blurred_photos(sharp) == []
    relative = relative_detail(5, pair_rows(sharp))
    assert relative.shape == (5, 2) and np.abs(relative).max() < 0.3  # the same wall from alike distances, in focus
    _, views = photos_of(tmp_path / "shaken", scan, EYES, smeared=[2])
    found = blurred_photos(views)
    assert [d["photo"] for d in found] == [2]
    assert found[0]["detail"] < 0.37
    relative = relative_detail(5, pair_rows(views))  # against its partners, pair by pair
    # smeared along its rows: its detail along them is the least, and less than across them
    assert relative[2, 0] < -1.2 and relative[2, 1] > relative[2, 0] + 0.5
    assert (np.delete(relative, 2, axis=0) > -0.6).all()


def test_where_a_third_of_the_photos_are_shaken_each_is_judged_against_the_sharp_ones(tmp_path):
    """Three of nine photos smeared, the third less than the others: judged against all its partners, two of them
    shaken, it passes; against the sharp ones, once the other two are named, it is named too."""
    scan = speckled_wall()
    eyes = [*EYES, (0.8, -2.0, 1.05), (1.1, -2.3, 0.95), (1.15, -2.15, 1.15), (0.85, -2.15, 0.9)]
    photos, _ = photos_of(tmp_path, scan, eyes)
    for k, length in ((1, 9), (4, 9), (6, 7)):
        im = np.asarray(Image.open(photos.images[k])).astype(np.float64)
        Image.fromarray(np.round(ndimage.uniform_filter1d(im, length, axis=1)).astype(np.uint8)).save(photos.images[k])
    views = prepare_photos(scan, photos, range(9), RayCaster(scan.positions, scan.faces), 160)
    rows = pair_rows(views)
    first = relative_detail(9, rows).min(axis=1)
    assert first[1] < BLURRED and first[4] < BLURRED and first[6] > BLURRED
    assert [d["photo"] for d in blurred_photos(views)] == [1, 4, 6]
    again = relative_detail(9, rows, blurred={1, 4}).min(axis=1)
    assert again[6] < BLURRED and np.abs(np.delete(again, [1, 4, 6])).max() < 0.3  # the sharp ones alike


def test_a_photo_left_with_two_sharp_partners_is_judged_on_all_its_pairs():
    """A median of two is their mean: photo 0, paired with a named photo (1), a far-off pair (2) and a plain one (3),
    keeps its median over the three; photo 4, with three sharp partners besides the named one, is judged on them."""
    rows = np.array([(0, 1, -0.3, -0.3, 1), (0, 2, 3.0, 3.0, 1), (0, 3, 0.0, 0.0, 1),
                     (4, 1, 0.5, 0.5, 1), (4, 2, 0.1, 0.1, 1), (4, 3, 0.2, 0.2, 1), (4, 5, 0.3, 0.3, 1)], float)
    got = relative_detail(6, rows, blurred={1})
    np.testing.assert_allclose(got[0], [0.0, 0.0])  # not -1.5, the mean of -3 and 0
    np.testing.assert_allclose(got[4], [-0.2, -0.2])  # 0.1, 0.2, 0.3, without the named photo's 0.5
    np.testing.assert_allclose(relative_detail(6, rows)[4], [-0.25, -0.25])


def test_a_photo_from_further_away_is_not_called_blurred(tmp_path):
    """It resolves less of the wall, and read at the closer photos' pixels it would look soft: a pair is measured
    on the coarser photo's pixels."""
    scan = speckled_wall()
    eyes = [*EYES[:4], (1.0, -4.4, 1.0)]  # twice as far
    _, views = photos_of(tmp_path, scan, eyes)
    assert blurred_photos(views) == []
    shared = photo_overlaps(views)
    assert shared[4, :4].min() > 0
    relative = relative_detail(5, pair_rows(views, shared))
    assert np.abs(relative).max() < 0.3  # read on the near photos' pixels, it measured -0.56


def test_photos_that_share_no_surface_are_not_measured(tmp_path):
    scan = speckled_wall()
    _, views = photos_of(tmp_path, scan, EYES[:1])
    assert len(pair_rows(views)) == 0 and np.isnan(relative_detail(1, pair_rows(views))).all()
    assert blurred_photos(views) == []
