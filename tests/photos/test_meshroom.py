"""Meshroom's (AliceVision's) ``cameras.sfm`` (:mod:`scantex.photos.meshroom`), against files written by hand as
AliceVision writes them and its camera model."""

from __future__ import annotations

import json
import logging

import numpy as np
import pytest
from PIL import Image
from scipy.spatial.transform import Rotation

from scantex.photos import detect_format, load_photos
from tests.photos.projection import stored_pixel

W, H = 64, 48
FX, FY, OFFSET = 55.0, 53.5, (1.25, -0.75)
POSES = [(Rotation.from_euler("xyz", [100, 10, -20], degrees=True).as_matrix(), np.array([0.5, -3.0, 1.0])),
         (Rotation.from_euler("xyz", [95, -30, 60], degrees=True).as_matrix(), np.array([3.0, 1.0, 1.5]))]
DISTORTIONS = {"radial3": [-0.1, 0.02, 0.001], "brown": [-0.08, 0.01, 0.0, 0.002, -0.0015],
               "fisheye4": [0.03, -0.01, 0.0, 0.0], "pinhole": []}


def strings(values) -> list[str]:
    return [repr(float(v)) for v in values]


def write_sfm(folder, *, version=(1, 2, 5), model="radial3", photos_at=None, extra_views=()) -> None:
    """A ``cameras.sfm`` as AliceVision writes it (every value a string) for two photos of ``W x H``, in ``images/``
    beside it (or recorded at ``photos_at``: where Meshroom ran)."""
    (folder / "images").mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(0)
    intrinsic = {"intrinsicId": "4021", "width": str(W), "height": str(H), "serialNumber": "x", "type": model,
                 "initializationMode": "estimated", "distortionParams": strings(DISTORTIONS[model]), "locked": "0"}
    if version >= (1, 2, 8):  # the camera's type, its distortion's apart
        intrinsic.update(type="pinhole", undistortionType="none", distortionType={
            "radial3": "radialk3", "brown": "brown", "fisheye4": "fisheye", "pinhole": "none"}[model])
    if version < (1, 2, 0):
        intrinsic.update(pxFocalLength=repr(FX), pxInitialFocalLength="-1")
    elif version < (1, 2, 2):
        intrinsic.update(pxFocalLength=strings([FX, FY]), pxInitialFocalLength="-1")
    else:
        sensor = 6.17
        ratio = FX / FY if version < (1, 2, 5) else FY / FX  # the focal ratio before 1.2.5, the pixel ratio since
        focal = FX if version < (1, 2, 11) else FY  # fx's in millimetres, fy's since 1.2.11
        intrinsic.update(focalLength=repr(focal * sensor / W), initialFocalLength="-1", sensorWidth=repr(sensor),
                         sensorHeight=repr(sensor * H / W), pixelRatio=repr(ratio), pixelRatioLocked="1")
    centre = (W / 2 + OFFSET[0], H / 2 + OFFSET[1])
    intrinsic["principalPoint"] = strings(centre if version < (1, 2, 1) else OFFSET)
    views, poses = [], []
    for i, (R, C) in enumerate(POSES):
        name = f"IMG_{i:04d}.JPG"
        Image.fromarray(rng.integers(0, 255, (H, W, 3), dtype=np.uint8)).save(folder / "images" / name)
        path = f"{photos_at}/{name}" if photos_at else str(folder / "images" / name)
        views.append({"viewId": str(100 + i), "poseId": str(100 + i), "intrinsicId": "4021", "path": path,
                      "width": str(W), "height": str(H), "metadata": {"Make": "x"}})
        poses.append({"poseId": str(100 + i), "pose": {"transform": {"rotation": strings(R.ravel(order="F")),
                                                                     "center": strings(C)},
                                                       "locked": "0", "valid": "1"}})
    doc = {"version": [str(v) for v in version], "featuresFolders": [], "views": views + list(extra_views),
           "intrinsics": [intrinsic], "poses": poses}
    (folder / "cameras.sfm").write_text(json.dumps(doc, indent=4))


def alicevision_pixel(points, i: int, model: str, fy: float = FY) -> np.ndarray:
    """AliceVision's projection (``Pose3``: ``R (X - C)``; ``cam2ima``: the distorted point times the focal lengths
    plus the principal point, ``w / 2 + offset``; the models' ``addDistortion``)."""
    R, C = POSES[i]
    x_cam = R @ (np.asarray(points).T - C[:, None])
    x, y = x_cam[0] / x_cam[2], x_cam[1] / x_cam[2]
    d = DISTORTIONS[model]
    if model == "fisheye4":
        r = np.hypot(x, y)
        t = np.arctan(r)
        scale = (t + d[0] * t**3 + d[1] * t**5 + d[2] * t**7 + d[3] * t**9) / r
        x, y = x * scale, y * scale
    elif model in ("radial3", "brown"):
        r2 = x * x + y * y
        k = 1 + d[0] * r2 + d[1] * r2**2 + d[2] * r2**3
        t1, t2 = (d[3], d[4]) if model == "brown" else (0.0, 0.0)
        x, y = x * k + t2 * (r2 + 2 * x * x) + 2 * t1 * x * y, y * k + t1 * (r2 + 2 * y * y) + 2 * t2 * x * y
    return np.stack([FX * x + W / 2 + OFFSET[0], fy * y + H / 2 + OFFSET[1]], 1)


@pytest.mark.parametrize("version, model", [((1, 2, 5), "radial3"), ((1, 2, 5), "brown"), ((1, 2, 5), "fisheye4"),
                                            ((1, 2, 4), "radial3"), ((1, 2, 1), "pinhole"), ((1, 0, 0), "radial3"),
                                            ((1, 2, 8), "brown"), ((1, 2, 11), "radial3"), ((1, 2, 11), "fisheye4")])
def test_cameras_project_as_alicevision_projects(tmp_path, version, model):
    """World points land where AliceVision puts them, whichever version wrote the file: the focal length in pixels
    (one, then two) or millimetres with the pixel ratio (a focal ratio before 1.2.5; fy's since 1.2.11), the
    principal point from the corner (before 1.2.1) or its offset from the centre, the lens in the camera's type or
    (since 1.2.8) a distortionType of its own, the rotation in Eigen's column-major order. (AliceVision's own
    compatibility scenes, versions 1.2.0 to 1.2.11, read by hand: fx 1000, fy 2000, principal point 2020, 1040.)"""
    write_sfm(tmp_path, version=version, model=model)
    photos = load_photos(tmp_path)
    assert photos.format == "meshroom" and len(photos) == 2
    rng = np.random.default_rng(1)
    points = np.array([0.5, 0.5, 0.5]) + rng.uniform(-0.4, 0.4, (50, 3))
    fy = FX if version < (1, 2, 0) else FY  # a single focal length before 1.2.0
    for i in range(2):
        np.testing.assert_allclose(stored_pixel(photos, i, points), alicevision_pixel(points, i, model, fy),
                                   atol=1e-6)
        w2c = photos.cameras[i].world_to_camera
        np.testing.assert_allclose(-w2c[:3, :3].T @ w2c[:3, 3], POSES[i][1], atol=1e-9)


def test_views_without_a_pose_are_skipped_and_photos_found_by_name(tmp_path, caplog):
    """The photo paths of the machine Meshroom ran on are looked for by name beside the file, in ``images/``; a view
    the reconstruction left out (no pose) is skipped."""
    unposed = {"viewId": "7", "poseId": "7", "intrinsicId": "4021", "path": "C:/scan/IMG_0009.JPG", "width": str(W),
               "height": str(H)}
    write_sfm(tmp_path, photos_at="C:\\Users\\me\\scan", extra_views=[unposed])
    with caplog.at_level(logging.WARNING):
        photos = load_photos(tmp_path / "cameras.sfm")
    assert [p.name for p in photos.images] == ["IMG_0000.JPG", "IMG_0001.JPG"]
    assert "1 of its 3 views have no pose (not reconstructed): skipped" in caplog.text


def test_a_newer_version_is_read_with_a_warning(tmp_path, caplog):
    write_sfm(tmp_path, version=(1, 3, 0))
    with caplog.at_level(logging.WARNING):
        assert len(load_photos(tmp_path)) == 2
    assert "version 1.3.0, newer than scantex knows (1.2.14)" in caplog.text


def test_found_as_a_json_file_and_in_a_folder(tmp_path):
    write_sfm(tmp_path)
    (tmp_path / "cameras.sfm").rename(tmp_path / "sfm.json")
    assert detect_format(tmp_path / "sfm.json") == ("meshroom", tmp_path / "sfm.json")
    (tmp_path / "sfm.json").rename(tmp_path / "cameras.sfm")
    assert detect_format(tmp_path) == ("meshroom", tmp_path / "cameras.sfm")


def edited(tmp_path, edit, **options):
    """A ``cameras.sfm`` (:func:`write_sfm`) whose parsed document ``edit`` changes in place; returns the folder."""
    write_sfm(tmp_path, **options)
    doc = json.loads((tmp_path / "cameras.sfm").read_text())
    edit(doc)
    (tmp_path / "cameras.sfm").write_text(json.dumps(doc))
    return tmp_path


def unsupported_model(tmp_path):
    return (edited(tmp_path, lambda doc: doc["intrinsics"][0].update(type="equidistant_r3")),
            "camera model 'equidistant_r3' is not supported")


def bad_rotation(tmp_path):
    return (edited(tmp_path, lambda doc: doc["poses"][0]["pose"]["transform"]["rotation"].__setitem__(0, "2.0")),
            "view 100 (IMG_0000.JPG): its rotation is no rotation")


def missing_photo(tmp_path):
    write_sfm(tmp_path, photos_at="/elsewhere")
    (tmp_path / "images" / "IMG_0001.JPG").unlink()
    return tmp_path, "view 101 (IMG_0001.JPG): its photo is neither at /elsewhere/IMG_0001.JPG nor in"


def wrong_parameters(tmp_path):
    return (edited(tmp_path, lambda doc: doc["intrinsics"][0].update(distortionParams=["0.1", "0.2"])),
            "a radialk3 distortion has 3 parameters, not 2")


def not_numbers(tmp_path):
    return (edited(tmp_path, lambda doc: doc["intrinsics"][0].update(focalLength="abc")),
            "focalLength is not numbers")


def undistortion_model(tmp_path):
    return (edited(tmp_path, lambda doc: doc["intrinsics"][0].update(undistortionType="3deanamorphic4"),
                   version=(1, 2, 11)),
            "camera model '3deanamorphic4' is not supported")


def no_version(tmp_path):
    return edited(tmp_path, lambda doc: doc.pop("version")), "no 'version': not an AliceVision SfM file"


def fractional_width(tmp_path):
    return (edited(tmp_path, lambda doc: doc["intrinsics"][0].update(width="64.9")),
            "width is not a whole number of pixels")


@pytest.mark.parametrize("make", [unsupported_model, bad_rotation, missing_photo, wrong_parameters, not_numbers,
                                  undistortion_model, no_version, fractional_width])
def test_bad_files_are_one_line_naming_the_file(tmp_path, make, capsys):
    from tests.io.hostile import assert_photos_refused

    path, message = make(tmp_path / "capture")
    assert_photos_refused(capsys, tmp_path, path, "cameras.sfm: ")
    assert_photos_refused(capsys, tmp_path, path, message)


def test_a_fisheye_without_coefficients_is_still_a_fisheye(tmp_path):
    """AliceVision's ``fisheye4`` of four zeros projects through ``theta = atan r``: it was read as a pinhole."""
    write_sfm(tmp_path, model="fisheye4")
    doc = json.loads((tmp_path / "cameras.sfm").read_text())
    doc["intrinsics"][0]["distortionParams"] = ["0", "0", "0", "0"]
    (tmp_path / "cameras.sfm").write_text(json.dumps(doc))
    photos = load_photos(tmp_path)
    assert photos.lenses[0] is not None and photos.distortions[0].projection == "equidistant"


def test_a_relative_photo_path_is_the_file_s_not_the_working_folder(tmp_path, monkeypatch):
    """A view's relative ``path`` is looked for from the file's folder: from the working folder, another capture's
    photo of that name was taken silently."""
    write_sfm(tmp_path / "capture", photos_at="images")
    other = tmp_path / "other"
    (other / "images").mkdir(parents=True)
    Image.fromarray(np.zeros((H, W, 3), np.uint8)).save(other / "images" / "IMG_0000.JPG")
    monkeypatch.chdir(other)
    photos = load_photos(tmp_path / "capture")
    assert photos.images[0].resolve() == (tmp_path / "capture" / "images" / "IMG_0000.JPG").resolve()
