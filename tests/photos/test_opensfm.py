"""OpenSfM's ``reconstruction.json`` (:mod:`scantex.photos.opensfm`), against files written by hand as OpenSfM and
OpenDroneMap write them and OpenSfM's documented cameras (axis-angle world-to-camera poses; intrinsics in units of
the longer side; the pixel map ``u = s x + (w - 1) / 2``)."""

from __future__ import annotations

import json
import logging

import numpy as np
import pytest
from PIL import Image
from scipy.spatial.transform import Rotation

from scantex.errors import ScanError
from scantex.photos import detect_format, load_photos, write_opensfm
from scantex.views.camera import Camera
from tests.photos.projection import stored_pixel

POINTS = np.array([0.5, 0.5, 0.5]) + np.random.default_rng(1).uniform(-0.4, 0.4, (50, 3))
SIZES = [(64, 48), (48, 64)]  # a landscape photo and a portrait one: the intrinsics are in units of the longer side
MODELS = {
    "perspective": {"focal": 0.9, "k1": -0.1, "k2": 0.02},
    "simple_radial": {"focal_x": 0.9, "focal_y": 0.88, "c_x": 0.01, "c_y": -0.02, "k1": -0.05},
    "brown": {"focal_x": 0.9, "focal_y": 0.91, "c_x": 0.012, "c_y": -0.008, "k1": -0.1, "k2": 0.02, "k3": 0.004,
              "p1": 0.003, "p2": -0.002},
    "fisheye": {"focal": 0.6, "k1": 0.02, "k2": -0.01},
    "fisheye_opencv": {"focal_x": 0.6, "focal_y": 0.61, "c_x": 0.01, "c_y": 0.005, "k1": 0.02, "k2": -0.01,
                       "k3": 0.002, "k4": -0.001},
}


def pose(eye, roll_deg: float) -> tuple[np.ndarray, np.ndarray]:
    """``(R, t)`` world-to-camera: a camera at ``eye`` looking at the test points, turned about its axis."""
    cam = Camera.look_at(eye, (0.5, 0.5, 0.5), up=(0, 0, 1), width=64, height=48)
    R = Rotation.from_euler("z", roll_deg, degrees=True).as_matrix() @ cam.R
    return R, -R @ np.asarray(eye, np.float64)


POSES = [pose((0.5, -2.5, 1.0), 10.0), pose((2.8, 1.0, 1.5), -25.0)]


def write_reconstruction(folder, kind="brown", *, images="images", scale=1, extra_cameras=None, extra_shots=None,
                         more=0, name="reconstruction.json"):
    """A ``reconstruction.json`` as OpenSfM writes it (a camera per photo size, shots by file name, axis-angle poses)
    with its photos in ``images`` (relative to ``folder``); ``scale``: the photos stored that many times smaller."""
    folder.mkdir(parents=True, exist_ok=True)
    (folder / images).mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(0)
    cameras, shots = {}, {}
    for i, ((R, t), (w, h)) in enumerate(zip(POSES, SIZES)):
        camera_id = f"v2 test {w} {h} {kind}"
        cameras[camera_id] = {"projection_type": kind, "width": w, "height": h, **MODELS[kind]}
        Image.fromarray(rng.integers(0, 255, (h // scale, w // scale, 3), dtype=np.uint8)).save(
            folder / images / f"IMG_{i:04d}.JPG")
        shots[f"IMG_{i:04d}.JPG"] = {"camera": camera_id, "rotation": Rotation.from_matrix(R).as_rotvec().tolist(),
                                     "translation": t.tolist(), "gps_position": [0, 0, 0], "orientation": 1}
    cameras.update(extra_cameras or {})
    shots.update(extra_shots or {})
    doc = [{"cameras": cameras, "shots": shots, "points": {"1": {"coordinates": [0.1, 0.2, 0.3], "color": [1, 2, 3]}},
            "reference_lla": {"latitude": 48.0, "longitude": 2.0, "altitude": 0.0}}]
    doc += [{"cameras": cameras, "shots": {}, "points": {}}] * more
    (folder / name).write_text(json.dumps(doc))
    return folder / name


def opensfm_pixel(points, i: int, kind: str) -> np.ndarray:
    """OpenSfM's projection (``camera_projections_functions.h``, ``camera_distortions_functions.h``): the point in the
    camera, projected (a fisheye by its angle), distorted, scaled, then ``u = s x + (w - 1) / 2``."""
    (R, t), (w, h), m = POSES[i], SIZES[i], MODELS[kind]
    x, y, z = R @ np.asarray(points).T + t[:, None]
    if kind.startswith("fisheye"):
        r = np.hypot(x, y)
        theta = np.arctan2(r, z)
        a, b = theta * x / r, theta * y / r
    else:
        a, b = x / z, y / z
    rho2 = a * a + b * b
    k = [m.get(f"k{n}", 0.0) for n in range(1, 5)]
    d = 1 + k[0] * rho2 + k[1] * rho2 ** 2 + k[2] * rho2 ** 3 + k[3] * rho2 ** 4
    p1, p2 = m.get("p1", 0.0), m.get("p2", 0.0)
    xd = a * d + 2 * p1 * a * b + p2 * (rho2 + 2 * a * a)
    yd = b * d + 2 * p2 * a * b + p1 * (rho2 + 2 * b * b)
    fx, fy = m.get("focal_x", m.get("focal")), m.get("focal_y", m.get("focal"))
    s = max(w, h)
    u = (fx * xd + m.get("c_x", 0.0)) * s + (w - 1) / 2
    return np.stack([u, (fy * yd + m.get("c_y", 0.0)) * s + (h - 1) / 2], 1)


@pytest.mark.parametrize("kind", sorted(MODELS))
def test_cameras_project_as_opensfm_projects(tmp_path, kind):
    """World points land where OpenSfM's camera puts them, on a landscape photo and a portrait one; the lens undone
    when the photos are read."""
    write_reconstruction(tmp_path, kind)
    photos = load_photos(tmp_path)
    assert photos.format == "opensfm" and len(photos) == 2 and photos.lenses[0] is not None
    for i in range(2):
        np.testing.assert_allclose(stored_pixel(photos, i, POINTS), opensfm_pixel(POINTS, i, kind), atol=1e-6)
        w2c = photos.cameras[i].world_to_camera
        np.testing.assert_allclose(w2c[:3, :3], POSES[i][0], atol=1e-12)
        np.testing.assert_allclose(w2c[:3, 3], POSES[i][1], atol=1e-12)


def test_an_opendronemap_project(tmp_path, caplog):
    """ODM's project: ``opensfm/reconstruction.json``, the photos in ``images/``, and ODM's own ``cameras.json`` (its
    camera models alone), which is not taken for scantex's; photos scaled down since read right (the intrinsics are in
    units of their side); 360 shots skipped with a count, a dual camera's with the reason."""
    project = tmp_path / "project"
    write_reconstruction(project / "opensfm", images="../images", scale=2, extra_cameras={
        "pano": {"projection_type": "spherical", "width": 128, "height": 64},
        "wide": {"projection_type": "dual", "width": 64, "height": 48, "focal": 0.5, "k1": 0, "k2": 0,
                 "transition": 0.5}}, extra_shots={"P.JPG": {"camera": "pano", "rotation": [0, 0, 0],
                                                              "translation": [0, 0, 0]},
                                                   "D.JPG": {"camera": "wide", "rotation": [0, 0, 0],
                                                             "translation": [0, 0, 0]}})
    Image.new("RGB", (64, 48)).save(project / "images" / "D.JPG")
    (project / "cameras.json").write_text(json.dumps({"v2 test 64 48 brown": {"projection_type": "brown"}}))
    assert detect_format(project) == ("opensfm", project / "opensfm" / "reconstruction.json")
    with caplog.at_level(logging.WARNING):
        photos = load_photos(project)
    assert [p.name for p in photos.images] == ["IMG_0000.JPG", "IMG_0001.JPG"]
    assert "1 of its shots are spherical (360) photos" in caplog.text
    assert "1 of its shots skipped: a dual camera, which scantex does not read" in caplog.text
    for i in range(2):
        expected = (opensfm_pixel(POINTS, i, "brown") + 0.5) / 2 - 0.5  # the same view at half the size
        np.testing.assert_allclose(stored_pixel(photos, i, POINTS), expected, atol=1e-6)


def test_bad_reconstructions_are_said_in_one_line(tmp_path, caplog):
    write_reconstruction(tmp_path / "a", more=1)
    with caplog.at_level(logging.WARNING):
        assert len(load_photos(tmp_path / "a")) == 2
    assert "holds 2 reconstructions: reading the first (2 photos" in caplog.text
    write_reconstruction(tmp_path / "b")
    (tmp_path / "b" / "images" / "IMG_0001.JPG").unlink()
    with pytest.raises(ScanError, match="shot 'IMG_0001.JPG': its photo is neither at"):
        load_photos(tmp_path / "b")
    write_reconstruction(tmp_path / "c")
    Image.new("RGB", (64, 64)).save(tmp_path / "c" / "images" / "IMG_0000.JPG")
    with pytest.raises(ScanError, match="its photo is 64x64, of another shape than its camera's 64x48"):
        load_photos(tmp_path / "c")
    file = write_reconstruction(tmp_path / "d")
    doc = json.loads(file.read_text())
    doc[0]["shots"]["IMG_0000.JPG"]["rotation"] = [0, "x", 0]
    file.write_text(json.dumps(doc))
    with pytest.raises(ScanError, match="shot 'IMG_0000.JPG': no rotation of 3 numbers"):
        load_photos(file)
    write_reconstruction(tmp_path / "e", extra_shots={"P.JPG": {"camera": "nope", "rotation": [0, 0, 0],
                                                                "translation": [0, 0, 0]}})
    with pytest.raises(ScanError, match="shot 'P.JPG': its camera 'nope' is not in the reconstruction's cameras"):
        load_photos(tmp_path / "e")


def test_an_undistorted_reconstruction_finds_its_tiffs(tmp_path):
    """OpenSfM's undistorter writes ``undistorted/images/<name>.tif`` for a shot named ``<name>``."""
    folder = tmp_path / "undistorted"
    write_reconstruction(folder, "perspective")
    for i in range(2):
        (folder / "images" / f"IMG_{i:04d}.JPG").rename(folder / "images" / f"IMG_{i:04d}.JPG.tif")
    assert [p.name for p in load_photos(folder).images] == ["IMG_0000.JPG.tif", "IMG_0001.JPG.tif"]


@pytest.mark.parametrize("kind", ["brown", "fisheye_opencv", "perspective"])
def test_written_and_read_back(tmp_path, kind):
    """:func:`write_opensfm` round trip: the cameras, the lens, the photos' bytes."""
    write_reconstruction(tmp_path / "in", kind)
    photos = load_photos(tmp_path / "in")
    back = load_photos(write_opensfm(photos, tmp_path / "out"))
    assert back.format == "opensfm" and len(back) == 2
    for i in range(2):
        np.testing.assert_allclose(back.cameras[i].K, photos.cameras[i].K, atol=1e-9)
        np.testing.assert_allclose(back.cameras[i].world_to_camera, photos.cameras[i].world_to_camera, atol=1e-12)
        np.testing.assert_allclose(stored_pixel(back, i, POINTS), stored_pixel(photos, i, POINTS), atol=1e-6)
        assert back.images[i].read_bytes() == photos.images[i].read_bytes()


def test_an_audit_s_inputs(tmp_path, caplog):
    """A photo scaled to whole pixels (OpenSfM's undistorter rounds: 5472x3648 at 1024x683) reads; a scantex
    cameras.json beside an opensfm/ stays scantex's, OpenDroneMap's own (camera models, no poses) is said to be so; a
    pose of NaN, a camera that is no object and an id that is no string are refused in one line; an aligned ODM
    project is warned about."""
    from scantex.photos import write_cameras_json

    file = write_reconstruction(tmp_path / "a", "perspective")
    doc = json.loads(file.read_text())
    for camera in doc[0]["cameras"].values():
        camera["width"], camera["height"] = (5472, 3648) if camera["width"] == 64 else (3648, 5472)
    file.write_text(json.dumps(doc))
    Image.new("RGB", (1024, 683)).save(tmp_path / "a" / "images" / "IMG_0000.JPG")
    Image.new("RGB", (683, 1024)).save(tmp_path / "a" / "images" / "IMG_0001.JPG")
    assert [c.width for c in load_photos(file).cameras] == [1024, 683]

    project = tmp_path / "odm"
    write_reconstruction(project / "opensfm", images="../images")
    assert write_cameras_json(load_photos(project / "opensfm"), project) == project / "cameras.json"
    assert detect_format(project) == ("cameras.json", project / "cameras.json")
    assert load_photos(project).format == "cameras.json"
    (project / "cameras.json").write_text(json.dumps({"v2 dji": {"projection_type": "brown", "focal_x": 0.8}}))
    assert detect_format(project)[0] == "opensfm"
    (project / "opensfm" / "reconstruction.json").unlink()
    with pytest.raises(ScanError, match="OpenDroneMap's camera models, without the photos' poses"):
        load_photos(project)
    with pytest.raises(ScanError, match="OpenDroneMap's camera models, without the photos' poses"):
        load_photos(project / "cameras.json")

    for change, message in ((lambda d: d[0]["shots"]["IMG_0000.JPG"].update(rotation=[1e300, 0, 0]),
                             "its pose is not finite"),
                            (lambda d: d[0]["cameras"].update({next(iter(d[0]["cameras"])): 5}),
                             "is not a camera model"),
                            (lambda d: d[0]["shots"]["IMG_0000.JPG"].update(camera=["x"]),
                             "its camera \\['x'\\] is not in the reconstruction's cameras")):
        file = write_reconstruction(tmp_path / "b")
        doc = json.loads(file.read_text())
        change(doc)
        file.write_text(json.dumps(doc))
        with pytest.raises(ScanError, match=message):
            load_photos(file)

    write_reconstruction(tmp_path / "c" / "opensfm", images="../images")
    (tmp_path / "c" / "odm_georeferencing").mkdir()
    (tmp_path / "c" / "odm_georeferencing" / "alignment_matrix.json").write_text("[]")
    with caplog.at_level(logging.WARNING):
        load_photos(tmp_path / "c")
    assert "OpenDroneMap aligned this project (--align" in caplog.text


def test_an_opendronemap_project_is_found_whole(tmp_path):
    """``scantex enhance project/`` on an OpenDroneMap project: its textured 3D mesh (not the 2.5D one, not the
    untextured mesh) and its opensfm/ cameras."""
    import trimesh

    from scantex.io.discover import find_capture

    project = tmp_path / "project"
    write_reconstruction(project / "opensfm", images="../images")
    for mesh, made in (("odm_meshing/odm_mesh.ply", trimesh.creation.box()),
                       ("odm_texturing_25d/odm_textured_model_geo.obj", trimesh.creation.icosphere(3)),  # the larger
                       ("odm_texturing/odm_textured_model_geo.obj", trimesh.creation.box()),
                       ("odm_filterpoints/larger.obj", trimesh.creation.icosphere(3))):
        (project / mesh).parent.mkdir(parents=True, exist_ok=True)
        made.export(project / mesh)
    with find_capture(project) as capture:
        assert capture.mesh == project / "odm_texturing" / "odm_textured_model_geo.obj"
        assert (capture.photos, capture.photo_format) == (project / "opensfm" / "reconstruction.json", "opensfm")
