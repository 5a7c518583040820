"""Bundler's ``bundle.out`` (:mod:`scantex.photos.bundler`) and VisualSfM's ``.nvm`` (:mod:`scantex.photos.nvm`),
against files written by hand as those tools write them and their documented projections."""

from __future__ import annotations

import logging

import numpy as np
import pytest
from PIL import Image
from scipy.spatial.transform import Rotation

from scantex.photos import detect_format, load_photos
from scantex.views.camera import Camera
from tests.photos.projection import stored_pixel

W, H = 64, 48
F = 55.0


def looking_at_the_points(eye, roll_deg: float) -> tuple[np.ndarray, np.ndarray]:
    """``(R, C)``: a camera at ``eye`` looking at the test points, turned about its axis by ``roll_deg``."""
    cam = Camera.look_at(eye, (0.5, 0.5, 0.5), up=(0, 0, 1), width=W, height=H)
    return Rotation.from_euler("z", roll_deg, degrees=True).as_matrix() @ cam.R, np.asarray(eye, np.float64)


POSES = [looking_at_the_points((0.5, -2.5, 1.0), 10.0), looking_at_the_points((2.8, 1.0, 1.5), -25.0)]
FLIP = np.diag([1.0, -1.0, -1.0])  # OpenCV's camera axes to Bundler's (x right, y up, looking down -z)


def photos_in(folder, n: int, names=None) -> list[str]:
    folder.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(0)
    names = names or [f"IMG_{i:04d}.JPG" for i in range(n)]
    for name in names:
        (folder / name).parent.mkdir(parents=True, exist_ok=True)
        Image.fromarray(rng.integers(0, 255, (H, W, 3), dtype=np.uint8)).save(folder / name)
    return names


def write_bundle(folder, *, k=(0.0, 0.0), unregistered=0, list_name="list.txt", subfolder="") -> None:
    """A ``bundle.out`` as Bundler writes it: per camera ``f k1 k2``, Bundler's ``R`` (OpenCV's with its second and
    third rows negated) and ``t``; one point; the image list (``path 0 focal``, as Bundler's ``list.txt``)."""
    n = len(POSES) + unregistered
    names = photos_in(folder, n, [f"{subfolder}IMG_{i:04d}.JPG" for i in range(n)])
    lines = ["# Bundle file v0.3", f"{n} 1"]
    for i in range(n):
        if i >= len(POSES):
            lines += ["0 0 0"] + ["0 0 0"] * 4
            continue
        R, C = POSES[i]
        Rb, tb = FLIP @ R, FLIP @ (-R @ C)
        lines += [f"{F!r} {k[0]!r} {k[1]!r}", *(" ".join(repr(float(v)) for v in row) for row in Rb),
                  " ".join(repr(float(v)) for v in tb)]
    lines += ["0.1 0.2 0.3", "255 0 0", "1 0 5 1.5 -2.5"]
    (folder / "bundle.out").write_text("\n".join(lines) + "\n")
    (folder / list_name).write_text("".join(f"{name} 0 {F}\n" for name in names))


def bundler_pixel(points, i: int, k=(0.0, 0.0)) -> np.ndarray:
    """Bundler's projection: ``P = R X + t``, ``p = -P / P.z``, ``p' = f r(p) p``, from the image's centre, y up."""
    R, C = POSES[i]
    Rb, tb = FLIP @ R, FLIP @ (-R @ C)
    P = Rb @ np.asarray(points).T + tb[:, None]
    p = -P[:2] / P[2]
    r2 = (p ** 2).sum(axis=0)
    q = F * (1 + k[0] * r2 + k[1] * r2 ** 2) * p
    return np.stack([(W - 1) / 2 + q[0], (H - 1) / 2 - q[1]], 1)


def write_nvm(folder, *, r=0.0, r9t=False, fixed=None, models=1) -> None:
    """An ``.nvm`` as VisualSfM writes it: ``name f qw qx qy qz cx cy cz r 0`` (``NVM_V3_R9T``: the rotation's rows and
    ``t``), the points after, and ``models`` models; ``fixed``: a ``FixedK fx cx fy cy r`` header."""
    names = photos_in(folder, len(POSES))
    header = "NVM_V3_R9T" if r9t else "NVM_V3"
    if fixed is not None:
        header += " FixedK " + " ".join(repr(float(v)) for v in fixed)
    lines = [header, "", str(len(POSES))]
    for name, (R, C) in zip(names, POSES):
        if r9t:
            pose = [*R.ravel(), *(-R @ C)]
        else:
            x, y, z, w = Rotation.from_matrix(R).as_quat()
            pose = [w, x, y, z, *C]
        lines.append(" ".join([name, repr(F)] + [repr(float(v)) for v in pose] + [repr(r), "0"]))
    points = ["1", "0.1 0.2 0.3 255 0 0 2 0 5 1.5 -2.5 1 7 3.0 4.0"]
    lines += [""] + points
    for _ in range(models - 1):
        lines += ["", "2", lines[3], lines[4], ""] + points
    lines += ["", "0", ""]
    (folder / "scene.nvm").write_text("\n".join(lines))


def vsfm_pixel(points, i: int, r: float, K=None) -> np.ndarray:
    """VisualSfM's projection: ``x_u = R (X - C)`` normalised, the distorted point ``x_d`` with ``x_u = x_d (1 + r
    |x_d|^2)`` (solved here by fixed-point iteration), times the focal length plus the image's centre."""
    R, C = POSES[i]
    x_cam = R @ (np.asarray(points).T - C[:, None])
    xu = x_cam[:2] / x_cam[2]
    xd = xu.copy()
    for _ in range(200):
        xd = xu / (1 + r * (xd ** 2).sum(axis=0))
    fx, cx, fy, cy = K if K is not None else (F, (W - 1) / 2, F, (H - 1) / 2)
    return np.stack([fx * xd[0] + cx, fy * xd[1] + cy], 1)


def inside(pixels: np.ndarray) -> np.ndarray:
    """The pixels inside the image: beyond it, an undistortion with a negative term has no unique inverse."""
    return (pixels[:, 0] > -0.5) & (pixels[:, 0] < W - 0.5) & (pixels[:, 1] > -0.5) & (pixels[:, 1] < H - 0.5)


POINTS = np.array([0.5, 0.5, 0.5]) + np.random.default_rng(1).uniform(-0.4, 0.4, (50, 3))


@pytest.mark.parametrize("k", [(0.0, 0.0), (-0.12, 0.03)])
def test_bundler_cameras_project_as_bundler_projects(tmp_path, k):
    """World points land where Bundler's manual puts them: its camera looking down -z with y up, the principal point
    at the image's centre, its two radial terms (undone when the photos are read)."""
    write_bundle(tmp_path, k=k)
    photos = load_photos(tmp_path)
    assert photos.format == "bundler" and len(photos) == 2
    assert (photos.lenses[0] is None) == (k == (0.0, 0.0))
    for i in range(2):
        np.testing.assert_allclose(stored_pixel(photos, i, POINTS), bundler_pixel(POINTS, i, k), atol=1e-6)
        w2c = photos.cameras[i].world_to_camera
        np.testing.assert_allclose(-w2c[:3, :3].T @ w2c[:3, 3], POSES[i][1], atol=1e-9)


def test_bundler_unregistered_cameras_are_skipped_and_lists_found(tmp_path, caplog):
    """A camera of focal length 0 was not registered; the image list is found under the names the exporters give it,
    its paths relative to its folder."""
    write_bundle(tmp_path / "a", unregistered=1, list_name="image_list.txt", subfolder="images/")
    with caplog.at_level(logging.WARNING):
        photos = load_photos(tmp_path / "a" / "bundle.out")
    assert [p.name for p in photos.images] == ["IMG_0000.JPG", "IMG_0001.JPG"]
    assert "1 of its 3 cameras were not registered (focal length 0): skipped" in caplog.text
    write_bundle(tmp_path / "b", list_name="bundle-list.txt")
    assert len(load_photos(tmp_path / "b")) == 2
    assert detect_format(tmp_path / "b") == ("bundler", tmp_path / "b" / "bundle.out")
    write_bundle(tmp_path / "d", subfolder="my photos/")  # a path with a space, before Bundler's "0 focal"
    assert [p.parent.name for p in load_photos(tmp_path / "d").images] == ["my photos"] * 2
    write_bundle(tmp_path / "c", list_name="model.list.txt")  # COLMAP's model_converter --output_type Bundler
    (tmp_path / "c" / "bundle.out").rename(tmp_path / "c" / "model.bundle.out")
    assert len(load_photos(tmp_path / "c")) == 2


@pytest.mark.parametrize("r9t, r", [(False, 0.0), (False, -0.15), (True, 0.1)])
def test_nvm_cameras_project_as_visualsfm_projects(tmp_path, r9t, r):
    """World points land where VisualSfM puts them: the quaternion (w first) and the centre, or R9T's rotation rows
    and translation; the focal length in pixels at the image's centre; its radial *undistortion* of the normalised
    point, solved exactly when the photos are read."""
    write_nvm(tmp_path, r=r, r9t=r9t)
    photos = load_photos(tmp_path)
    assert photos.format == "nvm" and len(photos) == 2
    for i in range(2):
        expected = vsfm_pixel(POINTS, i, r)
        seen = inside(expected)
        assert seen.sum() >= 10
        np.testing.assert_allclose(stored_pixel(photos, i, POINTS)[seen], expected[seen], atol=1e-6)


def test_nvm_fixed_calibration_and_several_models(tmp_path, caplog):
    K = (57.0, 31.0, 56.0, 24.25)
    write_nvm(tmp_path, fixed=(*K, -0.05), models=2)
    with caplog.at_level(logging.WARNING):
        photos = load_photos(tmp_path / "scene.nvm")
    assert len(photos) == 2 and "holds more than one model: reading the first (2 cameras)" in caplog.text
    assert "its focal length 55 is not FixedK's fx 57: FixedK's calibration is used" in caplog.text
    for i in range(2):
        expected = vsfm_pixel(POINTS, i, -0.05, K)
        seen = inside(expected)
        assert seen.sum() >= 10
        np.testing.assert_allclose(stored_pixel(photos, i, POINTS)[seen], expected[seen], atol=1e-6)


@pytest.mark.parametrize("fmt", ["bundler", "nvm"])
def test_written_and_read_back(tmp_path, fmt):
    """:func:`write_bundler` and :func:`write_nvm` round trips: the cameras, the lens each holds, the photos' bytes;
    a camera neither can hold (the principal point off the centre) is refused."""
    import dataclasses

    from scantex.photos import write_bundler, write_nvm as writer_nvm

    if fmt == "bundler":
        write_bundle(tmp_path / "in", k=(-0.1, 0.02))
        writer = write_bundler
    else:
        write_nvm(tmp_path / "in", r=0.08)
        writer = writer_nvm
    photos = load_photos(tmp_path / "in")
    back = load_photos(writer(photos, tmp_path / "out"))
    assert back.format == fmt and len(back) == 2
    for i in range(2):
        np.testing.assert_allclose(back.cameras[i].K, photos.cameras[i].K, atol=1e-12)
        np.testing.assert_allclose(back.cameras[i].world_to_camera, photos.cameras[i].world_to_camera, atol=1e-12)
        assert back.distortions[i] == photos.distortions[i]
        assert back.images[i].read_bytes() == photos.images[i].read_bytes()
    stored = photos.as_stored()
    K = stored.cameras[0].K.copy()
    K[0, 2] += 1.0
    moved = dataclasses.replace(stored, cameras=(dataclasses.replace(stored.cameras[0], K=K),) + stored.cameras[1:])
    with pytest.raises(ValueError, match="principal point at the image's centre"):
        writer(moved, tmp_path / "bad")


def rewritten(path, change):
    """``path`` with its lines changed in place by ``change(lines)``; returns it."""
    lines = path.read_text().splitlines()
    change(lines)
    path.write_text("\n".join(lines) + "\n")
    return path


def not_a_bundle(tmp_path):
    write_bundle(tmp_path)
    (tmp_path / "bundle.out").write_text("hello\n")
    return tmp_path / "bundle.out", "not a Bundler file"


def no_list(tmp_path):
    write_bundle(tmp_path)
    (tmp_path / "list.txt").unlink()
    return tmp_path / "bundle.out", "no image list beside it"


def short_list(tmp_path):
    write_bundle(tmp_path)
    (tmp_path / "list.txt").write_text("IMG_0000.JPG\n")
    return tmp_path / "bundle.out", "list.txt: names 1 photos, bundle.out has 2 cameras"


def truncated_bundle(tmp_path):
    write_bundle(tmp_path)
    return rewritten(tmp_path / "bundle.out", lambda lines: lines.__delitem__(slice(6, None))), (
        "it ends before its 2 cameras do")


def bad_bundle_rotation(tmp_path):
    write_bundle(tmp_path)
    return rewritten(tmp_path / "bundle.out", lambda lines: lines.__setitem__(3, "2 0 0")), (
        "camera 0 (IMG_0000.JPG): its rotation is no rotation")


def missing_photo(tmp_path):
    write_bundle(tmp_path)
    (tmp_path / "IMG_0001.JPG").unlink()
    return tmp_path / "bundle.out", "camera 1 (IMG_0001.JPG): its photo is neither at"


def truncated_nvm(tmp_path):
    write_nvm(tmp_path)
    return rewritten(tmp_path / "scene.nvm", lambda lines: lines.__delitem__(slice(4, None))), (
        "it ends before its 2 cameras do")


def nvm_not_numbers(tmp_path):
    write_nvm(tmp_path)
    text = (tmp_path / "scene.nvm").read_text().replace(f" {F!r} ", " abc ", 1)
    (tmp_path / "scene.nvm").write_text(text)
    return tmp_path / "scene.nvm", "camera 0 (IMG_0000.JPG): not numbers"


def nvm_no_count(tmp_path):
    write_nvm(tmp_path)
    (tmp_path / "scene.nvm").write_text("NVM_V3\n\nIMG_0000.JPG 55 1 0 0 0 0 0 0 0 0\n")
    return tmp_path / "scene.nvm", "no camera count where it should be"


def nvm_bad_fixed(tmp_path):
    write_nvm(tmp_path, fixed=(57.0, 31.0))
    return tmp_path / "scene.nvm", "its FixedK calibration is not 4 or 5 numbers"


@pytest.mark.parametrize("make", [not_a_bundle, no_list, short_list, truncated_bundle, bad_bundle_rotation,
                                  missing_photo, truncated_nvm, nvm_not_numbers, nvm_no_count, nvm_bad_fixed])
def test_bad_files_are_one_line_naming_the_file(tmp_path, make, capsys):
    from tests.io.hostile import assert_photos_refused

    path, message = make(tmp_path / "capture")
    assert_photos_refused(capsys, tmp_path, path, message)


def test_bundler_radial_undistort_output_and_a_list_of_another_count(tmp_path):
    """Bundler's RadialUndistort writes ``bundle.rd.out`` (its registered cameras alone) with ``list.rd.txt``: found;
    the original ``list.txt`` beside it (a line for every photo, registered or not) gave its cameras the wrong photos
    silently: refused."""
    write_bundle(tmp_path, unregistered=1)
    text = (tmp_path / "bundle.out").read_text().splitlines()
    rd = ["# Bundle file v0.3", "2 1"] + text[2:2 + 10] + text[-3:]
    (tmp_path / "bundle.rd.out").write_text("\n".join(rd) + "\n")
    (tmp_path / "bundle.out").unlink()
    with pytest.raises(Exception, match="list.txt: names 3 photos, bundle.rd.out has 2 cameras"):
        load_photos(tmp_path / "bundle.rd.out")
    (tmp_path / "list.rd.txt").write_text("IMG_0000.JPG\nIMG_0001.JPG\n")
    assert [p.name for p in load_photos(tmp_path / "bundle.rd.out").images] == ["IMG_0000.JPG", "IMG_0001.JPG"]


def test_nvm_points_and_trailing_models_are_not_trusted(tmp_path, caplog):
    """Whether more models follow is read from the points, which scantex does not use: a count that is not a count
    crashed it, negative counts looped for ever; VisualSfM's closing model of unregistered images (no points) is no
    second model."""
    write_nvm(tmp_path)
    text = (tmp_path / "scene.nvm").read_text()
    head = text[:text.index("\n1\n")]
    for points in ("1\n0.1 0.2 0.3 255 0 0 abc", "1\n0.1 0.2 0.3 255 0 0 nan", "99999999999\n0 0 0 255 0 0 -1 -2 -2 -2",
                   f"1\n0.1 0.2 0.3 255 0 0 0\n\n1\nIMG_0000.JPG {F} 1 0 0 0 0 0 0 0 0\n0\n\n0\n"):
        (tmp_path / "scene.nvm").write_text(head + "\n" + points + "\n")
        with caplog.at_level(logging.WARNING):
            caplog.clear()
            assert len(load_photos(tmp_path / "scene.nvm")) == 2
        assert "more than one model" not in caplog.text


def test_writers_drop_a_lens_ignored_when_read_that_they_cannot_hold(tmp_path):
    """A lens under a pixel is ignored when read (the photo taken for a pinhole one); a writer whose format cannot
    hold it refused the whole set (VisualSfM's r = 0.0005 in Bundler's and OpenMVG's, Bundler's k1 in VisualSfM's),
    where the same lens, strong, is written undistorted. Now it is dropped, as the run drops it."""
    from scantex.photos import write_bundler, write_nvm as writer_nvm, write_openmvg

    write_nvm(tmp_path / "nvm", r=0.0005)
    photos = load_photos(tmp_path / "nvm")
    assert photos.lenses[0] is None and photos.distortions[0] is not None
    for writer in (write_bundler, write_openmvg):
        back = load_photos(writer(photos, tmp_path / writer.__name__))
        assert back.distortions[0] is None and np.allclose(back.cameras[0].K, photos.cameras[0].K)
    write_bundle(tmp_path / "bundle", k=(0.0005, 0.0))
    photos = load_photos(tmp_path / "bundle")
    assert photos.lenses[0] is None
    back = load_photos(writer_nvm(photos, tmp_path / "again"))
    assert back.distortions[0] is None


def nvm_zero_quaternion(tmp_path):
    write_nvm(tmp_path)

    def change(lines):
        words = lines[3].split()
        lines[3] = " ".join(words[:2] + ["0"] * 4 + words[6:])
    return rewritten(tmp_path / "scene.nvm", change), "camera 0 (IMG_0000.JPG): its quaternion is zero"


def test_a_zero_quaternion_is_one_line(tmp_path, capsys):
    from tests.io.hostile import assert_photos_refused

    path, message = nvm_zero_quaternion(tmp_path / "capture")
    assert_photos_refused(capsys, tmp_path, path, message)
