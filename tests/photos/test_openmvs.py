"""OpenMVS's ``scene.mvs`` (:mod:`scantex.photos.openmvs`), against streams written byte by byte as OpenMVS's
``Interface.h`` lays them out."""

from __future__ import annotations

import logging
import struct

import numpy as np
import pytest
from PIL import Image
from scipy.spatial.transform import Rotation

from scantex.photos import detect_format, load_photos

W, H = 64, 48
K_PIXELS = np.array([[55.0, 0.0, 31.25], [0.0, 54.0, 24.5], [0.0, 0.0, 1.0]])
#: the platform's poses (world -> platform rotation, position) and a camera mounted off the platform's centre
POSES = [(Rotation.from_euler("xyz", [100, 10, -20], degrees=True).as_matrix(), np.array([0.5, -3.0, 1.0])),
         (Rotation.from_euler("xyz", [95, -30, 60], degrees=True).as_matrix(), np.array([3.0, 1.0, 1.5]))]
MOUNT_R = Rotation.from_euler("y", 4, degrees=True).as_matrix()
MOUNT_C = np.array([0.02, -0.01, 0.05])


def s(text: str) -> bytes:
    raw = text.encode()
    return struct.pack("<Q", len(raw)) + raw


def d(values) -> bytes:
    return np.asarray(values, "<f8").tobytes()


def write_scene(folder, *, version=3, normalised=False, unplaced=False, truncate=0) -> None:
    """A scene of one platform (a camera mounted off its centre, ``POSES``) and two photos of ``W x H``."""
    (folder / "images").mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(0)
    out = bytearray(b"MVSI" + struct.pack("<II", version, 0) if version > 0 else b"")
    out += struct.pack("<Q", 1) + s("platform0") + struct.pack("<Q", 1) + s("KODAK")
    if version > 3:
        out += s("RGB")
    K = K_PIXELS / max(W, H) if normalised else K_PIXELS
    if normalised:
        K[2, 2] = 1.0
    if version > 0:
        out += struct.pack("<II", *((0, 0) if normalised else (W, H)))
    out += d(K) + d(MOUNT_R) + d(MOUNT_C)
    out += struct.pack("<Q", len(POSES)) + b"".join(d(R) + d(C) for R, C in POSES)
    out += struct.pack("<Q", 3)
    for i in range(3):
        name = f"images/{i:05d}.jpg"
        Image.fromarray(rng.integers(0, 255, (H, W, 3), dtype=np.uint8)).save(folder / name)
        out += s(name)
        if version > 4:
            out += s("")
        pose = 0xFFFFFFFF if i == 2 and unplaced else min(i, 1)
        out += struct.pack("<III", 0, 0, pose)
        if version > 2:
            out += struct.pack("<I", i)
        if version > 6:
            out += struct.pack("<fff", 1.0, 2.0, 3.0) + struct.pack("<Q", 1) + struct.pack("<IIffff", 1, 9, 1, 0, 1, 1)
    out += struct.pack("<Q", 0) * 3
    if version > 0:
        out += struct.pack("<Q", 0) * 3
    if version > 1:
        out += d(np.eye(4))
    if version > 5:
        out += d(np.eye(3)) + d(np.zeros(3)) + d(np.zeros(3))
    (folder / "scene.mvs").write_bytes(bytes(out[:len(out) - truncate]))


@pytest.mark.parametrize("version, normalised", [(v, n) for v in (0, 1, 3, 5, 7) for n in (False, True)
                                                 if n or v > 0])  # a stream of version 0 keeps no resolution
def test_scene_cameras_are_openmvs_s(tmp_path, version, normalised):
    """World points land where OpenMVS projects them (``Interface::Platform::GetPose``: the camera's mount composed
    with the platform's pose; ``K`` at the image's size, pixel centres at integers, or normalised by its larger
    side), in every stream version."""
    write_scene(tmp_path, version=version, normalised=normalised)
    photos = load_photos(tmp_path)
    assert photos.format == "openmvs" and len(photos) == 3
    rng = np.random.default_rng(1)
    points = rng.uniform(-0.5, 1.5, (40, 3))
    for i in range(3):
        R_pose, C_pose = POSES[min(i, 1)]
        local = MOUNT_R @ (R_pose @ (points.T - C_pose[:, None]) - MOUNT_C[:, None])  # platform, then camera
        expect = (K_PIXELS @ local)[:2] / local[2]
        np.testing.assert_allclose(photos.cameras[i].project(points)[0], expect.T, atol=1e-9)


def test_a_camera_of_another_resolution_is_scaled_as_openmvs_scales_it(tmp_path):
    """``ScaleK``: a camera calibrated at twice the photos' size, its principal point scaled about pixel centres."""
    write_scene(tmp_path)
    data = bytearray((tmp_path / "scene.mvs").read_bytes())
    at = data.index(struct.pack("<II", W, H))
    data[at:at + 8] = struct.pack("<II", 2 * W, 2 * H)
    big = K_PIXELS.copy()
    big[:2, :2] *= 2
    big[:2, 2] = (K_PIXELS[:2, 2] + 0.5) * 2 - 0.5
    data[at + 8:at + 8 + 72] = d(big)
    (tmp_path / "scene.mvs").write_bytes(bytes(data))
    np.testing.assert_allclose(load_photos(tmp_path).cameras[0].K, K_PIXELS, atol=1e-12)


def test_an_image_without_a_pose_is_skipped(tmp_path, caplog):
    write_scene(tmp_path, unplaced=True)
    with caplog.at_level(logging.WARNING):
        photos = load_photos(tmp_path / "scene.mvs")
    assert len(photos) == 2 and "1 of its images are not placed (no pose): skipped" in caplog.text
    assert detect_format(tmp_path) == ("openmvs", tmp_path / "scene.mvs")


def truncated(tmp_path):
    write_scene(tmp_path, truncate=(8 + 16 + 4 * 3 + 4) * 2 + 200)
    return tmp_path, "scene.mvs: not an OpenMVS scene scantex can read: it ends at byte"


def future(tmp_path):
    write_scene(tmp_path)
    data = bytearray((tmp_path / "scene.mvs").read_bytes())
    data[4:8] = struct.pack("<I", 9)
    (tmp_path / "scene.mvs").write_bytes(bytes(data))
    return tmp_path, "scene.mvs: an OpenMVS scene of stream version 9, newer than scantex reads (7)"


def missing_photo(tmp_path):
    write_scene(tmp_path)
    (tmp_path / "images" / "00001.jpg").unlink()
    return tmp_path, "scene.mvs: image 1 (images/00001.jpg): "


def huge_count(tmp_path):
    write_scene(tmp_path)
    data = bytearray((tmp_path / "scene.mvs").read_bytes())
    data[12:20] = struct.pack("<Q", 2**40)
    (tmp_path / "scene.mvs").write_bytes(bytes(data))
    return tmp_path, "a count of 1,099,511,627,776 (a corrupt file)"


@pytest.mark.parametrize("make", [truncated, future, missing_photo, huge_count])
def test_bad_scenes_are_one_line_naming_the_file(tmp_path, make, capsys):
    from tests.io.hostile import assert_photos_refused

    assert_photos_refused(capsys, tmp_path, *make(tmp_path / "capture"))
