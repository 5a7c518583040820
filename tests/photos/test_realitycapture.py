"""RealityCapture's XMP sidecars (:mod:`scantex.photos.realitycapture`), against files written by hand as
RealityCapture writes them and its documented camera (world-to-camera rows, the centre, a 36 mm focal length over the
longer side, Brown's lens with its tangential pair swapped against OpenCV's)."""

from __future__ import annotations

import logging

import numpy as np
import pytest
from PIL import Image
from scipy.spatial.transform import Rotation

from scantex.errors import ScanError
from scantex.photos import detect_format, load_photos, write_realitycapture
from scantex.views.camera import Camera
from tests.photos.projection import stored_pixel

F35 = 30.0
POINTS = np.array([0.5, 0.5, 0.5]) + np.random.default_rng(1).uniform(-0.4, 0.4, (50, 3))
XMP = """<x:xmpmeta xmlns:x="adobe:ns:meta/">
  <rdf:RDF xmlns:rdf="http://www.w3.org/1999/02/22-rdf-syntax-ns#">
    <rdf:Description xmlns:xcr="http://www.capturingreality.com/ns/xcr/1.1#" {attributes}>
      {elements}
    </rdf:Description>
  </rdf:RDF>
</x:xmpmeta>
"""


def pose(eye, roll_deg: float, size) -> tuple[np.ndarray, np.ndarray]:
    """``(R, C)``: a camera at ``eye`` looking at the test points, turned about its axis by ``roll_deg``."""
    cam = Camera.look_at(eye, (0.5, 0.5, 0.5), up=(0, 0, 1), width=size[0], height=size[1])
    return Rotation.from_euler("z", roll_deg, degrees=True).as_matrix() @ cam.R, np.asarray(eye, np.float64)


SIZES = [(64, 48), (48, 64)]  # a landscape photo and a portrait one: the focal length is over the longer side
POSES = [pose((0.5, -2.5, 1.0), 10.0, SIZES[0]), pose((2.8, 1.0, 1.5), -25.0, SIZES[1])]


def write_capture(folder, *, model="perspective", k=(0.0,) * 6, aspect=1.0, u=0.0, v=0.0, rotation_attribute=False,
                  common=False, extra="") -> None:
    """Photos ``IMG_000i.JPG`` with an XMP beside each, as RealityCapture writes them (its calibration as
    attributes, ``Rotation`` and ``Position`` as elements; ``rotation_attribute``: ``Rotation`` as an attribute, as
    its help's sample has it; ``common``: the calibration in ``_common.xmp`` instead)."""
    folder.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(0)
    calibration = (f'xcr:Version="3" xcr:PosePrior="locked" xcr:Coordinates="absolute" '
                   f'xcr:DistortionModel="{model}" xcr:FocalLength35mm="{F35!r}" xcr:Skew="0" '
                   f'xcr:AspectRatio="{aspect!r}" xcr:PrincipalPointU="{u!r}" xcr:PrincipalPointV="{v!r}" '
                   f'xcr:CalibrationPrior="exact" xcr:CalibrationGroup="-1" xcr:DistortionGroup="-1" '
                   f'xcr:InTexturing="1" xcr:InMeshing="1" {extra}')
    coefficients = f"<xcr:DistortionCoeficients>{' '.join(repr(c) for c in k)}</xcr:DistortionCoeficients>"
    if common:
        (folder / "_common.xmp").write_text(XMP.format(attributes=calibration, elements=coefficients))
    for i, ((R, C), (w, h)) in enumerate(zip(POSES, SIZES)):
        Image.fromarray(rng.integers(0, 255, (h, w, 3), dtype=np.uint8)).save(folder / f"IMG_{i:04d}.JPG")
        rows = " ".join(repr(float(x)) for x in R.ravel())
        elements = [f"<xcr:Position>{' '.join(repr(float(x)) for x in C)}</xcr:Position>"]
        attributes = "" if common else calibration
        if rotation_attribute:
            attributes += f' xcr:Rotation="{rows}"'
        else:
            elements.append(f"<xcr:Rotation>{rows}</xcr:Rotation>")
        if not common:
            elements.append(coefficients)
        (folder / f"IMG_{i:04d}.xmp").write_text(XMP.format(attributes=attributes, elements="\n".join(elements)))


def rc_pixel(points, i: int, k=(0.0,) * 6, aspect=1.0, u=0.0, v=0.0, n_radial=4) -> np.ndarray:
    """RealityCapture's projection: ``x = R (X - C)`` normalised, Brown's lens (``t1`` with ``r^2 + 2 x^2`` in x),
    ``fx = f35 / 36 * max(w, h)``, ``fy = fx * aspect``, the principal point ``(u, v) * max(w, h)`` from the image's
    centre ``(w / 2, h / 2)`` (pixel centres at integers), as RealityCapture's own OpenCV export writes it."""
    (R, C), (w, h) = POSES[i], SIZES[i]
    x_cam = R @ (np.asarray(points).T - C[:, None])
    x, y = x_cam[:2] / x_cam[2]
    r2 = x * x + y * y
    radial = 1 + sum(k[j] * r2 ** (j + 1) for j in range(n_radial))
    t1, t2 = k[4], k[5]
    xd = x * radial + t1 * (r2 + 2 * x * x) + 2 * t2 * x * y
    yd = y * radial + t2 * (r2 + 2 * y * y) + 2 * t1 * x * y
    side = max(w, h)
    fx = F35 / 36 * side
    return np.stack([fx * xd + w / 2 + u * side, fx * aspect * yd + h / 2 + v * side], 1)


@pytest.mark.parametrize("model, k, n_radial", [
    ("perspective", (0.0,) * 6, 4),
    ("brown3", (-0.12, 0.03, 0.01, 0.5, 0.2, 0.2), 3),  # brown3 has no k4 nor tangential terms: ignored
    ("brown4t2", (-0.1, 0.02, 0.005, -0.002, 0.004, -0.006), 4),
])
def test_cameras_project_as_realitycapture_projects(tmp_path, model, k, n_radial):
    """World points land where RealityCapture's camera puts them, on a landscape photo and a portrait one, with a
    principal point off the centre and pixels not square; the lens undone when the photos are read."""
    if model == "brown3":
        k_used = (*k[:3], 0.0, 0.0, 0.0)
    else:
        k_used = k
    write_capture(tmp_path, model=model, k=k, aspect=1.01, u=0.012, v=-0.008)
    photos = load_photos(tmp_path)
    assert photos.format == "realitycapture" and len(photos) == 2
    assert (photos.lenses[0] is None) == (model == "perspective")
    for i in range(2):
        np.testing.assert_allclose(stored_pixel(photos, i, POINTS),
                                   rc_pixel(POINTS, i, k_used, 1.01, 0.012, -0.008, n_radial), atol=1e-6)
        w2c = photos.cameras[i].world_to_camera
        np.testing.assert_allclose(-w2c[:3, :3].T @ w2c[:3, 3], POSES[i][1], atol=1e-9)


def test_attribute_forms_common_file_and_detection(tmp_path, caplog):
    """``Rotation`` as an attribute and the calibration in ``_common.xmp`` read alike; a calibration-only XMP is
    skipped with a count; a folder, an XMP and a mesh's folder are found as RealityCapture's."""
    write_capture(tmp_path / "a", rotation_attribute=True)
    write_capture(tmp_path / "b", common=True)
    a, b = load_photos(tmp_path / "a"), load_photos(tmp_path / "b" / "IMG_0001.xmp")
    for i in range(2):
        np.testing.assert_allclose(stored_pixel(a, i, POINTS), rc_pixel(POINTS, i), atol=1e-6)
        np.testing.assert_allclose(stored_pixel(b, i, POINTS), rc_pixel(POINTS, i), atol=1e-6)
    assert detect_format(tmp_path / "a") == ("realitycapture", tmp_path / "a")
    assert detect_format(tmp_path / "a" / "IMG_0000.xmp") == ("realitycapture", tmp_path / "a")
    Image.new("RGB", (64, 48)).save(tmp_path / "b" / "IMG_0002.JPG")
    (tmp_path / "b" / "IMG_0002.xmp").write_text(XMP.format(attributes='xcr:FocalLength35mm="30"', elements=""))
    with caplog.at_level(logging.WARNING):
        assert len(load_photos(tmp_path / "b")) == 2
    assert "1 of its XMPs hold no pose (a calibration alone): skipped" in caplog.text


def test_unread_lenses_and_bad_files(tmp_path, caplog):
    """A lens model scantex does not read skips its photos with the reason, and is refused where no photo is left;
    a pose of one part, a missing photo (found with --images) and a skew are said in one line."""
    write_capture(tmp_path / "div", model="division", k=(-0.2, 0, 0, 0, 0, 0))
    with pytest.raises(ScanError, match="none of its photos can be read: a division lens model"):
        load_photos(tmp_path / "div")
    write_capture(tmp_path / "one")
    text = (tmp_path / "one" / "IMG_0001.xmp").read_text()
    (tmp_path / "one" / "IMG_0001.xmp").write_text(text.replace('xcr:Skew="0"', 'xcr:Skew="0.001"'))
    with caplog.at_level(logging.WARNING):
        assert len(load_photos(tmp_path / "one")) == 1
    assert "1 of its photos skipped: a skewed camera" in caplog.text
    write_capture(tmp_path / "half")
    text = (tmp_path / "half" / "IMG_0000.xmp").read_text()
    (tmp_path / "half" / "IMG_0000.xmp").write_text(text.split("<xcr:Position>")[0] + text.split("</xcr:Position>")[1])
    with pytest.raises(ScanError, match="IMG_0000.xmp: it has a Rotation but no Position"):
        load_photos(tmp_path / "half")
    write_capture(tmp_path / "moved")
    (tmp_path / "elsewhere").mkdir()
    for i in range(2):
        (tmp_path / "moved" / f"IMG_{i:04d}.JPG").rename(tmp_path / "elsewhere" / f"IMG_{i:04d}.JPG")
    with pytest.raises(ScanError, match="no photo of its name beside it \\(name the photos' folder with --images"):
        load_photos(tmp_path / "moved")
    assert len(load_photos(tmp_path / "moved", image_dir=tmp_path / "elsewhere")) == 2
    broken = '<x:xmpmeta xmlns:xcr="http://www.capturingreality.com/ns/xcr/1.1#" broken'
    (tmp_path / "moved" / "IMG_0000.xmp").write_text(broken)
    with pytest.raises(ScanError, match="IMG_0000.xmp: not an XML file scantex can read"):
        load_photos(tmp_path / "moved", image_dir=tmp_path / "elsewhere")


def test_written_and_read_back(tmp_path):
    """:func:`write_realitycapture` round trip: the cameras, the lens (Brown's with its pair), the photos' bytes; a
    skewed camera is refused."""
    import dataclasses

    write_capture(tmp_path / "in", model="brown3t2", k=(-0.1, 0.02, 0.003, 0.0, 0.004, -0.002), aspect=0.99,
                  u=0.01, v=0.02)
    photos = load_photos(tmp_path / "in")
    back = load_photos(write_realitycapture(photos, tmp_path / "out"))
    assert back.format == "realitycapture" and len(back) == 2
    for i in range(2):
        np.testing.assert_allclose(back.cameras[i].K, photos.cameras[i].K, atol=1e-12)
        np.testing.assert_allclose(back.cameras[i].world_to_camera, photos.cameras[i].world_to_camera, atol=1e-12)
        assert back.distortions[i] == dataclasses.replace(photos.distortions[i], model="RealityCapture brown3t2")
        assert back.images[i].read_bytes() == photos.images[i].read_bytes()
    stored = photos.as_stored()
    K = stored.cameras[0].K.copy()
    K[0, 1] = 0.5
    skewed = dataclasses.replace(stored, cameras=(dataclasses.replace(stored.cameras[0], K=K),) + stored.cameras[1:])
    with pytest.raises(ValueError, match="a skewed camera"):
        write_realitycapture(skewed, tmp_path / "skewed")


def test_found_beside_the_mesh(tmp_path):
    """``scantex enhance folder/`` on a RealityCapture export (the mesh, its photos with their XMPs in ``images/``)
    finds the mesh and these cameras."""
    import trimesh

    from scantex.io.discover import find_capture

    write_capture(tmp_path / "images")
    trimesh.creation.box().export(tmp_path / "model.obj")
    with find_capture(tmp_path) as capture:
        assert capture.mesh == tmp_path / "model.obj"
        assert (capture.photos, capture.photo_format) == (tmp_path / "images", "realitycapture")


def test_what_realitycapture_reads_is_read(tmp_path, caplog):
    """As RealityCapture reads a folder: ``IMG_1.xmp`` over an older ``IMG_1.JPG.xmp`` of the same photo (a prior
    left there), a lens model with coefficients all zero (its help's sample: ``division``) as no lens, ``_Common.xmp``
    in any case and without its pose; a Brown lens without coefficients and relative coordinates said."""
    write_capture(tmp_path / "a", model="division")
    (tmp_path / "a" / "IMG_0000.JPG.xmp").write_text((tmp_path / "a" / "IMG_0001.xmp").read_text())
    with caplog.at_level(logging.WARNING):
        photos = load_photos(tmp_path / "a")
    assert [p.name for p in photos.images] == ["IMG_0000.JPG", "IMG_0001.JPG"] and photos.lenses == (None, None)
    np.testing.assert_allclose(stored_pixel(photos, 0, POINTS), rc_pixel(POINTS, 0), atol=1e-6)
    assert "two XMPs for photo IMG_0000.JPG: IMG_0000.xmp read, IMG_0000.JPG.xmp not" in caplog.text
    write_capture(tmp_path / "b", common=True)
    common = (tmp_path / "b" / "_common.xmp").read_text()
    (tmp_path / "b" / "_common.xmp").unlink()
    (tmp_path / "b" / "_Common.xmp").write_text(common.replace("</xcr:DistortionCoeficients>",
                                                               "</xcr:DistortionCoeficients><xcr:Position>9 9 9"
                                                               "</xcr:Position>"))
    photos = load_photos(tmp_path / "b")
    for i in range(2):
        np.testing.assert_allclose(stored_pixel(photos, i, POINTS), rc_pixel(POINTS, i), atol=1e-6)
    write_capture(tmp_path / "c", model="brown3")
    for i in range(2):
        xmp = tmp_path / "c" / f"IMG_{i:04d}.xmp"
        text = xmp.read_text().replace('xcr:Coordinates="absolute"', 'xcr:Coordinates="relative"')
        xmp.write_text(text.split("<xcr:DistortionCoeficients>")[0] + "</rdf:Description>"
                       + text.split("</rdf:Description>")[1] if i == 1 else text)
    caplog.clear()
    with caplog.at_level(logging.WARNING):
        assert len(load_photos(tmp_path / "c")) == 1
    assert "1 of its photos skipped: a brown3 lens without its DistortionCoeficients" in caplog.text
    assert "its poses are in relative coordinates" in caplog.text
