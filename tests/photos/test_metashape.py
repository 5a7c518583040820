"""Agisoft Metashape's cameras XML (:mod:`scantex.photos.metashape`), against files written by hand as Metashape
writes them and its manual's camera model."""

from __future__ import annotations

import logging

import numpy as np
import pytest
from PIL import Image
from scipy.spatial.transform import Rotation

from scantex.photos import detect_format, load_photos
from tests.photos.projection import stored_pixel

W, H = 64, 48
CALIB = {"f": 52.0, "cx": 1.75, "cy": -2.25, "b1": 0.8, "b2": -0.3, "k1": -0.12, "k2": 0.05, "k3": 0.0, "k4": 0.004,
         "p1": 0.0015, "p2": -0.0008}
#: the chunk's frame to the world: X = s R x + t
CHUNK_R = Rotation.from_euler("xyz", [20, -35, 110], degrees=True).as_matrix()
CHUNK_T = np.array([3.0, -1.5, 0.25])
CHUNK_S = 2.5


def chunk_camera(eye_world, target_world) -> np.ndarray:
    """A camera's 4x4 camera-to-chunk transform (OpenCV axes) looking from ``eye_world`` at ``target_world``."""
    to_chunk = lambda p: CHUNK_R.T @ (np.asarray(p, float) - CHUNK_T) / CHUNK_S  # noqa: E731
    eye, target = to_chunk(eye_world), to_chunk(target_world)
    z = (target - eye) / np.linalg.norm(target - eye)
    x = np.cross(z, CHUNK_R.T @ [0, 0, -1.0])
    x /= np.linalg.norm(x)
    c2w = np.eye(4)
    c2w[:3, :3] = np.stack([x, np.cross(z, x), z], 1)
    c2w[:3, 3] = eye
    return c2w


EYES = [((0.5, -3.0, 1.0), (0.5, 0.5, 0.5)), ((3.0, 1.0, 1.5), (0.5, 0.5, 0.5))]


def write_xml(folder, *, version="1.8.4", sensor_type="frame", extra_cameras="", calib=None, components=False,
              labels=("IMG_0001", "IMG_0002")) -> None:
    """A cameras XML as Metashape writes it (1.x: a chunk transform; 2.x with ``components``: a component's), with
    ``W x H`` photos beside it in ``images/``."""
    (folder / "images").mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(0)
    calib = CALIB if calib is None else calib
    tags = "".join(f"<{k}>{v!r}</{k}>" for k, v in calib.items())
    transform = (f"<transform><rotation locked=\"true\">{' '.join(repr(float(v)) for v in CHUNK_R.ravel())}</rotation>"
                 f"<translation locked=\"true\">{' '.join(repr(float(v)) for v in CHUNK_T)}</translation>"
                 f"<scale locked=\"true\">{CHUNK_S!r}</scale></transform>")
    cams = []
    for i, ((eye, target), label) in enumerate(zip(EYES, labels)):
        Image.fromarray(rng.integers(0, 255, (H, W, 3), dtype=np.uint8)).save(folder / "images" / f"IMG_000{i + 1}.JPG")
        m = " ".join(repr(float(v)) for v in chunk_camera(eye, target).ravel())
        cams.append(f'<camera id="{i}" sensor_id="0" component_id="0" label="{label}"><transform>{m}</transform>'
                    f'<orientation>1</orientation></camera>')
    parts = [f'<?xml version="1.0" encoding="UTF-8"?>\n<document version="{version}"><chunk label="Chunk 1" '
             f'enabled="true"><sensors next_id="1"><sensor id="0" label="test (24mm)" type="{sensor_type}">'
             f'<resolution width="{W}" height="{H}"/><property name="pixel_width" value="0.004"/>'
             f'<calibration type="{sensor_type}" class="adjusted"><resolution width="{W}" height="{H}"/>{tags}'
             f'</calibration></sensor></sensors>']
    if components:
        parts.append(f'<components next_id="1" active_id="0"><component id="0" label="Component 1">{transform}'
                     f'</component></components>')
    parts.append(f'<cameras next_id="9" next_group_id="1"><group id="0" label="Group 1" type="folder">'
                 f'{"".join(cams)}</group>{extra_cameras}</cameras>')
    if not components:
        parts.append(transform)
    parts.append("<region/><settings/></chunk></document>\n")
    (folder / "cameras.xml").write_text("".join(parts))


def metashape_pixel(X_world, c2chunk: np.ndarray, sensor_type: str = "frame") -> np.ndarray:
    """Metashape's manual's projection of world points (appendix "camera models": frame cameras; fisheye cameras
    first take ``x0 = X / Z`` to ``x0 atan(r0) / r0``), in scantex's pixels (the top-left pixel's centre at 0, where
    Metashape puts it at 0.5)."""
    c = CALIB
    x_chunk = (CHUNK_R.T @ (np.asarray(X_world).T - CHUNK_T[:, None])) / CHUNK_S
    x_cam = np.linalg.inv(c2chunk)[:3, :3] @ x_chunk + np.linalg.inv(c2chunk)[:3, 3:]
    x, y = x_cam[0] / x_cam[2], x_cam[1] / x_cam[2]
    if sensor_type == "fisheye":
        r0 = np.hypot(x, y)
        x, y = x * np.arctan(r0) / r0, y * np.arctan(r0) / r0
    r2 = x * x + y * y
    radial = 1 + c["k1"] * r2 + c["k2"] * r2**2 + c["k3"] * r2**3 + c["k4"] * r2**4
    xd = x * radial + c["p1"] * (r2 + 2 * x * x) + 2 * c["p2"] * x * y
    yd = y * radial + c["p2"] * (r2 + 2 * y * y) + 2 * c["p1"] * x * y
    u = W * 0.5 + c["cx"] + xd * c["f"] + xd * c["b1"] + yd * c["b2"]
    v = H * 0.5 + c["cy"] + yd * c["f"]
    return np.stack([u - 0.5, v - 0.5], 1)


@pytest.mark.parametrize("components, sensor_type", [(False, "frame"), (True, "frame"), (False, "fisheye")],
                         ids=["1.x chunk transform", "2.x component transform", "fisheye"])
def test_cameras_project_as_metashape_projects(tmp_path, components, sensor_type):
    """World points land where Metashape's own model puts them (its f, cx, cy from the centre, b1, b2, k1-k4, its
    tangential terms swapped against OpenCV's, the chunk's similarity; a fisheye's angle), to a millionth of a
    pixel."""
    write_xml(tmp_path, components=components, sensor_type=sensor_type)
    photos = load_photos(tmp_path)
    assert photos.format == "metashape" and len(photos) == 2
    assert [p.name for p in photos.images] == ["IMG_0001.JPG", "IMG_0002.JPG"]
    rng = np.random.default_rng(1)
    points = np.array([0.5, 0.5, 0.5]) + rng.uniform(-0.4, 0.4, (50, 3))
    for i, (eye, target) in enumerate(EYES):
        np.testing.assert_allclose(stored_pixel(photos, i, points),
                                   metashape_pixel(points, chunk_camera(eye, target), sensor_type), atol=1e-6)
        # the camera sits where it was put in the world (the chunk's scale taken out of the pose)
        w2c = photos.cameras[i].world_to_camera
        np.testing.assert_allclose(-w2c[:3, :3].T @ w2c[:3, 3], eye, atol=1e-9)
    assert photos.lenses[0] is not None  # a distortion of several pixels, undone when read


def test_cameras_not_aligned_or_disabled_are_skipped(tmp_path, caplog):
    extra = ('<camera id="5" sensor_id="0" label="IMG_0003"/>'
             '<camera id="6" sensor_id="0" label="IMG_0004" enabled="false"><transform>'
             + " ".join(["1", "0", "0", "0"] * 4) + "</transform></camera>")
    write_xml(tmp_path, extra_cameras=extra)
    with caplog.at_level(logging.WARNING):
        photos = load_photos(tmp_path / "cameras.xml")
    assert len(photos) == 2
    assert "1 of its cameras are not aligned (no transform): skipped" in caplog.text
    assert "1 of its cameras are disabled: skipped" in caplog.text


def test_labels_with_extension_or_path_and_photoscan_calibration(tmp_path):
    """A label naming the file with its extension, or by a path elsewhere, finds it in ``images/``; PhotoScan's
    ``fx``, ``fy``, ``cx``, ``cy`` (the principal point from the corner) are read as such."""
    calib = {"fx": 50.0, "fy": 49.0, "cx": 33.0, "cy": 23.5}
    write_xml(tmp_path, version="1.2.0", calib=calib, labels=("IMG_0001.JPG", "C:/survey/day1/IMG_0002.JPG"))
    photos = load_photos(tmp_path)
    assert [p.name for p in photos.images] == ["IMG_0001.JPG", "IMG_0002.JPG"]
    np.testing.assert_allclose(photos.cameras[0].K, [[50, 0, 32.5], [0, 49, 23], [0, 0, 1]])
    assert photos.lenses == (None, None) and photos.distortions == (None, None)


def test_cameras_of_a_sensor_scantex_does_not_read_are_skipped(tmp_path, caplog):
    """A 360-degree camera beside the frame cameras (a spherical sensor): its cameras are left out, with a warning."""
    write_xml(tmp_path)
    text = (tmp_path / "cameras.xml").read_text()
    sphere = ('<sensor id="1" label="360" type="spherical"><resolution width="64" height="32"/>'
              '<calibration type="spherical" class="adjusted"><resolution width="64" height="32"/><f>10</f>'
              '</calibration></sensor></sensors>')
    text = text.replace("</sensors>", sphere, 1).replace(
        '</group>', '<camera id="7" sensor_id="1" label="IMG_0001"><transform>'
        + " ".join(map(str, np.eye(4).ravel())) + '</transform></camera></group>', 1)
    (tmp_path / "cameras.xml").write_text(text)
    with caplog.at_level(logging.WARNING):
        photos = load_photos(tmp_path)
    assert len(photos) == 2
    assert "1 of its cameras skipped: sensor '360' is a spherical camera; scantex reads frame and fisheye" in (
        caplog.text)


def test_a_georeferenced_chunk_is_said(tmp_path, caplog, monkeypatch):
    import tests.photos.test_metashape as me

    monkeypatch.setattr(me, "CHUNK_T", np.array([4.2e6, 1.1e6, 4.7e6]))
    monkeypatch.setattr(me, "EYES", [((4.2e6, 1.1e6 - 3, 4.7e6), (4.2e6, 1.1e6, 4.7e6))] * 2)
    write_xml(tmp_path)
    with caplog.at_level(logging.WARNING):
        load_photos(tmp_path)
    assert "a georeferenced chunk's geocentric coordinates; the mesh must be exported in that frame" in caplog.text


def test_found_in_a_folder_and_beside_a_mesh(tmp_path):
    from scantex.io.discover import find_capture
    from tests.io.hostile import write_cube

    write_xml(tmp_path / "survey")
    assert detect_format(tmp_path / "survey") == ("metashape", tmp_path / "survey" / "cameras.xml")
    write_cube(tmp_path / "survey", "model.obj")
    capture = find_capture(tmp_path / "survey")
    assert capture.photo_format == "metashape" and capture.photos == tmp_path / "survey" / "cameras.xml"


def spherical(tmp_path):
    write_xml(tmp_path, sensor_type="spherical")
    return tmp_path, ("cameras.xml: none of its cameras can be read: sensor 'test (24mm)' is a spherical camera; "
                      "scantex reads frame and fisheye cameras")


def missing_component(tmp_path):
    write_xml(tmp_path, components=True)
    text = (tmp_path / "cameras.xml").read_text()
    (tmp_path / "cameras.xml").write_text(text.replace('component_id="0" label="IMG_0002"',
                                                       'component_id="7" label="IMG_0002"'))
    return tmp_path, "cameras.xml: camera 'IMG_0002': its component '7' is not in the file"


def not_xml(tmp_path):
    tmp_path.mkdir()
    (tmp_path / "cameras.xml").write_text("<document><chunk><sensors>")
    return tmp_path / "cameras.xml", "cameras.xml: not an XML file scantex can read"


def missing_photo(tmp_path):
    write_xml(tmp_path, labels=("IMG_0001", "IMG_0009"))
    return tmp_path, "cameras.xml: camera 'IMG_0009': its photo is not in"


def bad_transform(tmp_path):
    write_xml(tmp_path)
    text = (tmp_path / "cameras.xml").read_text()
    (tmp_path / "cameras.xml").write_text(text.replace("<transform>", "<transform>1 2 ", 1))
    return tmp_path, "cameras.xml: camera 'IMG_0001''s transform is not 16 finite numbers (got 18)"


def no_f(tmp_path):
    write_xml(tmp_path, calib={"cx": 0.0, "cy": 0.0})
    return tmp_path, "cameras.xml: sensor 'test (24mm)': no <fx>"


def p3(tmp_path):
    write_xml(tmp_path, calib=dict(CALIB, p3=0.01))
    return tmp_path, "sensor 'test (24mm)' has p3/p4 tangential terms"


@pytest.mark.parametrize("make", [spherical, missing_component, not_xml, missing_photo, bad_transform, no_f, p3])
def test_bad_files_are_one_line_naming_the_file(tmp_path, make, capsys):
    from tests.io.hostile import assert_photos_refused

    assert_photos_refused(capsys, tmp_path, *make(tmp_path / "capture"))


def test_photos_elsewhere_are_named_by_images(tmp_path, capsys, caplog):
    """A Metashape project's photos stay where they were taken: ``--images DIR`` names that folder (an error named
    the folders looked in); a format that names its photos' files itself says the option is not used."""
    from scantex.cli import main
    from tests.io.hostile import write_cube, write_photos

    write_xml(tmp_path / "export")
    (tmp_path / "export" / "images").rename(tmp_path / "DCIM")
    mesh = write_cube(tmp_path / "scan")
    assert main(["info", str(mesh), "--photos", str(tmp_path / "export")]) == 2
    assert "name the photos' folder with --images DIR)" in capsys.readouterr().err
    assert main(["info", str(mesh), "--photos", str(tmp_path / "export"), "--images", str(tmp_path / "DCIM")]) == 0
    assert "2 photos (metashape)" in capsys.readouterr().out
    assert main(["info", str(mesh), "--photos", str(tmp_path / "export"), "--images", str(tmp_path / "nope")]) == 2
    assert "nope: no such folder (the photos' folder)" in capsys.readouterr().err
    cams = write_photos(tmp_path / "json", n=2)
    with caplog.at_level(logging.WARNING):
        photos = load_photos(cams, image_dir=tmp_path / "DCIM")
    assert len(photos) == 2 and "cameras name their photos' files themselves" in caplog.text
