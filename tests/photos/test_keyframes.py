"""Keyframes (scantex/photos/keyframes.py): a capture's repeated views thinned to the sharpest of each."""

from __future__ import annotations

import dataclasses

import numpy as np
from PIL import Image
from scipy import ndimage

from scantex.photos import PhotoSet
from scantex.photos.keyframes import (
    REPEAT_ANGLE_DEG, REPEAT_DISTANCE, held_apart, keyframes, repeats, viewing_distances)
from scantex.views.camera import Camera
from scantex.views.raycast import RayCaster
from scantex.views.render import render, to_uint8
from tests.conftest import textured_cube


def moved(cam: Camera, shift: np.ndarray, degrees: float = 0.0) -> Camera:
    """``cam`` with its centre moved by ``shift`` and turned by ``degrees`` about its own y axis."""
    a = np.radians(degrees)
    turn = np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]])
    w2c = np.eye(4)
    w2c[:3, :3] = turn @ cam.R
    w2c[:3, 3] = -w2c[:3, :3] @ (cam.center + shift)
    return dataclasses.replace(cam, world_to_camera=w2c)


def capture(tmp_path, cameras, blur=()):
    """Renders of the textured cube through ``cameras`` as PNG photos, those at ``blur`` smeared sideways."""
    scan = textured_cube()
    caster = RayCaster(scan.positions, scan.faces)
    images = []
    for i, cam in enumerate(cameras):
        rgb = to_uint8(render(scan, cam, caster)[0]).astype(np.float64)
        if i in blur:
            rgb = ndimage.uniform_filter1d(rgb, 9, axis=1)
        Image.fromarray(np.round(rgb).astype(np.uint8)).save(tmp_path / f"p{i}.png")
        images.append(tmp_path / f"p{i}.png")
    return scan, caster, PhotoSet(cameras=tuple(cameras), images=tuple(images), source=tmp_path, format="test")


def test_the_sharpest_of_each_repeated_view_is_kept(tmp_path):
    """Two views, each photographed three times from within the limits (one of the copies of the first shaken);
    a view 4 degrees off, one moved 5 % of its distance, and one that sees no mesh repeat nothing."""
    a = Camera.look_at((2.6, -1.8, 1.9), (0.5, 0.5, 0.5), fov_deg=50, width=128, height=96)
    b = Camera.look_at((-1.6, -2.2, 1.4), (0.5, 0.5, 0.5), fov_deg=50, width=128, height=96)
    dist = float(np.linalg.norm(a.center - 0.5))  # about the depth it sees
    side = a.R[0]  # the camera's right, in the world
    cams = [a, moved(a, 0.3 * REPEAT_DISTANCE * dist * side), moved(a, np.zeros(3), 0.5 * REPEAT_ANGLE_DEG),
            b, moved(b, 0.4 * REPEAT_DISTANCE * dist * side, 1.0), moved(b, -0.2 * REPEAT_DISTANCE * dist * side),
            moved(a, np.zeros(3), -4.0), moved(b, 0.05 * dist * side),
            Camera.look_at((9.0, 9.0, 9.0), (20.0, 20.0, 20.0), width=128, height=96)]
    scan, caster, photos = capture(tmp_path, cams, blur={0})
    distances = viewing_distances(photos, range(len(photos)), caster)
    assert np.isnan(distances[8]) and np.all(np.abs(distances[:8] - dist) < 0.6 * dist)
    near = repeats(photos, range(len(photos)), distances)
    assert near[0] == {1, 2} and near[3] == {4, 5} and near[6] == near[7] == near[8] == set()
    calls = []
    kept, repeated = keyframes(photos, range(len(photos)), caster, lambda done, total: calls.append((done, total)))
    # progress: the 9 photos cast, then the 6 that repeat another decoded for their sharpness
    assert calls[:9] == [(k, 18) for k in range(9)] and calls[9:] == [(9 + k, 15) for k in range(7)]
    assert 0 not in kept and len(set(kept) & {1, 2}) == 1 and len(set(kept) & {3, 4, 5}) == 1
    assert {6, 7, 8} <= set(kept) and len(kept) == 5 and kept == sorted(kept)
    assert {d["photo"] for d in repeated} == set(range(9)) - set(kept)
    assert all(d["repeats"] in kept for d in repeated)
    # the same photos listed twice over: each copy repeats its first, but the photo that sees no mesh
    twice = PhotoSet(cameras=photos.cameras * 2, images=photos.images * 2, source=tmp_path, format="test")
    kept2, _ = keyframes(twice, range(len(twice)), caster)
    assert len(kept2) == 6 and {8, 17} <= set(kept2)


def test_a_held_out_photo_is_moved_off_a_repeated_view(tmp_path):
    """A held-out photo whose view a training photo repeats scores what the texture was made from: it is swapped
    for the nearest photo in the capture that nothing repeats; one alone stays; none alone: left as it is."""
    eyes = [(2.6, -1.8, 1.9), (-1.6, -2.2, 1.4), (2.4, 2.0, 2.2), (-1.5, 2.4, 0.9)]
    views = [Camera.look_at(e, (0.5, 0.5, 0.5), fov_deg=50, width=96, height=72) for e in eyes]
    cams = [views[0], moved(views[0], 0.02 * views[0].R[0]), views[1], views[2], views[3]]
    _, caster, photos = capture(tmp_path, cams)
    train, held = held_apart(photos, np.array([0, 2, 3, 4]), np.array([1]), caster)
    assert held.tolist() == [2] and train.tolist() == [0, 1, 3, 4]
    train, held = held_apart(photos, np.array([0, 1, 2, 4]), np.array([3]), caster)
    assert held.tolist() == [3] and train.tolist() == [0, 1, 2, 4]
    pair = PhotoSet(cameras=tuple(cams[:2]), images=photos.images[:2], source=tmp_path, format="test")
    assert [a.tolist() for a in held_apart(pair, np.array([0]), np.array([1]), caster)] == [[0], [1]]
