"""Each photo shows what its camera sees: a photo stored upside down, or another frame's, is left out."""

from __future__ import annotations

import dataclasses
import logging

import numpy as np
import pytest
from PIL import Image

from scantex.errors import ScanError
from scantex.photos.matching import (consensus_matches, could_be_turned, leave_out_mismatched, mismatched,
                                     photo_match)
from scantex.scan import Scan
from scantex.views.camera import Camera
from scantex.views.raycast import RayCaster
from tests.conftest import shared_scan
from tests.photos.test_alignment import partial_wall_scan


def wall_and_photos(tmp_path):
    part, photos = partial_wall_scan(tmp_path)
    return part, photos, RayCaster(part.positions, part.faces)


def test_photos_that_show_their_cameras_views_are_kept(tmp_path):
    part, photos, caster = wall_and_photos(tmp_path)
    matches = [photo_match(part, photos, i, caster) for i in range(len(photos))]
    assert all(m.agreement > 0.9 and m.pixels >= 2000 for m in matches), matches
    # agreeing that well, none could be named upside down: none is measured turned
    assert all(m.turned is None for m in matches) and not any(could_be_turned(m.agreement) for m in matches)
    assert mismatched(matches) == {}
    train, held, left_out = leave_out_mismatched(part, photos, np.array([0, 1, 2]), np.array([3]), caster)
    assert train.tolist() == [0, 1, 2] and held.tolist() == [3] and left_out == []


def test_a_photo_upside_down_or_cropped_is_left_out(tmp_path, caplog):
    """Photo 1 stored turned by 180 degrees; photo 3 cropped to its middle 3/4 after capture, its intrinsics as
    recorded (its size read from the file): each passes every check of file and camera."""
    part, photos, caster = wall_and_photos(tmp_path)
    turned, cropped = tmp_path / "turned.png", tmp_path / "cropped.png"
    Image.open(photos.images[1]).rotate(180).save(turned)
    Image.open(photos.images[3]).crop((20, 0, 140, 120)).save(cropped)
    camera = photos.cameras[3]
    bad = dataclasses.replace(photos, images=(photos.images[0], turned, photos.images[2], cropped),
                              cameras=(*photos.cameras[:3], Camera(camera.K, camera.world_to_camera, 120, 120)))
    with caplog.at_level(logging.WARNING):
        train, held, left_out = leave_out_mismatched(part, bad, np.array([0, 1, 2]), np.array([3]), caster)
    assert train.tolist() == [0, 2] and held.tolist() == []
    assert [d["photo"] for d in left_out] == [1, 3]
    assert "upside down" in left_out[0]["why"] and left_out[0]["turned_180"] > 0.9
    assert "cropped or turned after capture, or the mesh wrong" in left_out[1]["why"] and left_out[1]["agreement"] < 0.3
    assert "turned.png: photo 1 does not show what its camera sees" in caplog.text
    assert "cropped.png: photo 3 does not show" in caplog.text


def test_no_verdict_without_the_textures_contrast(tmp_path):
    """A view of a blank wall agrees by its shading alone: kept whatever it shows."""
    part, photos, caster = wall_and_photos(tmp_path)
    material = part.materials[0]
    grey = dataclasses.replace(material, image=np.full_like(material.image, 128))
    blank = dataclasses.replace(part, materials=(grey,))
    assert all(photo_match(blank, photos, i, caster).agreement is None for i in range(len(photos)))


def test_an_untextured_scans_photos_are_checked_against_one_another(tmp_path, caplog):
    """No texture to check against: each photo against the others' consensus where they see its surface too."""
    part, photos, caster = wall_and_photos(tmp_path)
    bare = Scan(positions=part.positions, faces=part.faces)
    assert not bare.is_textured
    matches = consensus_matches(photos, range(4), caster)
    assert all(m.agreement > 0.9 for m in matches) and mismatched(matches) == {}
    train, held, left_out = leave_out_mismatched(bare, photos, np.array([0, 1]), np.array([2, 3]), caster)
    assert train.tolist() == [0, 1] and held.tolist() == [2, 3] and left_out == []
    Image.open(photos.images[2]).rotate(180).save(tmp_path / "turned.png")
    bad = dataclasses.replace(photos, images=(*photos.images[:2], tmp_path / "turned.png", photos.images[3]))
    with caplog.at_level(logging.WARNING):
        train, held, left_out = leave_out_mismatched(bare, bad, np.array([0, 1]), np.array([2, 3]), caster)
    assert train.tolist() == [0, 1] and held.tolist() == [3] and [d["photo"] for d in left_out] == [2]
    assert "turned by 180 degrees it agrees with the other photos' consensus" in caplog.text


def test_no_training_photo_left_is_one_clear_line(tmp_path):
    part, photos, caster = wall_and_photos(tmp_path)
    turned = []
    for i in range(2):
        turned.append(tmp_path / f"turned{i}.png")
        Image.open(photos.images[i]).rotate(180).save(turned[-1])
    bad = dataclasses.replace(photos, images=(*turned, *photos.images[2:]))
    with pytest.raises(ScanError, match="no training photo shows what its camera sees"):
        leave_out_mismatched(part, bad, np.array([0, 1]), np.array([2, 3]), caster)


def test_bolster_photos_match_and_one_turned_is_found(tmp_path):
    """The real Kinect capture and its app-style texture: every photo agrees at its recorded pose (0.90-0.97);
    one stored upside down is found, against the texture and, on the bare mesh, against the other photos."""
    from scantex.io import load_scan
    from scantex.photos import load_photos

    folder = shared_scan("bolster_rgbd_posed")
    scan = load_scan(folder / "app_style_input" / "bolster_app_style.obj")
    photos = load_photos(folder)
    caster = RayCaster(scan.positions, scan.faces)
    matches = [photo_match(scan, photos, i, caster) for i in range(len(photos))]
    assert min(m.agreement for m in matches) > 0.8 and mismatched(matches) == {}
    Image.open(photos.images[5]).rotate(180).save(tmp_path / "turned.jpg")
    bad = dataclasses.replace(photos, images=(*photos.images[:5], tmp_path / "turned.jpg", *photos.images[6:]))
    assert list(mismatched([*matches[:5], photo_match(scan, bad, 5, caster), *matches[6:]])) == [5]
    # the bare Kinect mesh: against one another (0.83-0.95; the one turned -0.13, turned back 0.92)
    bare = load_scan(folder / "bloster.ply")
    caster = RayCaster(bare.positions, bare.faces)
    matches = consensus_matches(photos, range(len(photos)), caster)
    assert min(m.agreement for m in matches) > 0.7 and mismatched(matches) == {}
    assert list(mismatched(consensus_matches(bad, range(len(photos)), caster))) == [5]


def test_a_degraded_capture_keeps_every_photo(tmp_path):
    """Photos with a capture's faults (exposure and white balance per photo, blur, noise, JPEG, poses 1-5 px off)
    of a scan whose atlas an app degraded (seams, holes, blur): every photo agrees where there is a verdict, and
    none is left out (a coarser check left out six good photos of a synthetic room's 110)."""
    from scantex.synth import make_wall
    from scantex.synth.photos import PhotoCapture, capture_photos

    # the demo wall's atlas (1024²), coarser geometry and truth: detail enough for verdicts, made in seconds
    demo = make_wall(grid=(24, 18), gt_texture_size=2048, scan_texture_size=1024, seed=0)
    photos = capture_photos(demo, tmp_path, PhotoCapture(n_photos=12), seed=1)
    caster = RayCaster(demo.scan.positions, demo.scan.faces)
    matches = [photo_match(demo.scan, photos, i, caster) for i in range(len(photos))]
    judged = [m for m in matches if m.agreement is not None]
    assert len(judged) >= 2 and min(m.agreement for m in judged) > 0.3 and mismatched(matches) == {}
    train, held, left_out = leave_out_mismatched(demo.scan, photos, np.arange(10), np.array([10, 11]), caster)
    assert len(train) == 10 and len(held) == 2 and left_out == []
