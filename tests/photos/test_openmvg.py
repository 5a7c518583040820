"""OpenMVG's ``sfm_data.json`` (:mod:`scantex.photos.openmvg`), against files written by hand as OpenMVG's cereal
archive writes them (the layout of a real one: OpenMVG's ``SfMInit_ImageListing`` output for the Sceaux castle) and
OpenMVG's camera models."""

from __future__ import annotations

import json
import logging

import numpy as np
import pytest
from PIL import Image
from scipy.spatial.transform import Rotation

from scantex.photos import detect_format, load_photos
from scantex.photos.photoset import PhotoSet
from scantex.views.camera import Camera
from tests.photos.projection import stored_pixel

W, H = 64, 48
F, PP = 55.0, (33.25, 22.75)
POSES = [(Rotation.from_euler("xyz", [100, 10, -20], degrees=True).as_matrix(), np.array([0.5, -3.0, 1.0])),
         (Rotation.from_euler("xyz", [95, -30, 60], degrees=True).as_matrix(), np.array([3.0, 1.0, 1.5]))]
MODELS = {"pinhole": (None, []), "pinhole_radial_k1": ("disto_k1", [-0.12]),
          "pinhole_radial_k3": ("disto_k3", [-0.1, 0.02, 0.001]),
          "pinhole_brown_t2": ("disto_t2", [-0.08, 0.01, 0.0, 0.002, -0.0015]),
          "fisheye": ("fisheye", [0.03, -0.01, 0.0, 0.0])}
FIRST = 0x80000000


def write_sfm_data(folder, *, model="pinhole_radial_k3", root=None, unposed=0, spherical=False) -> None:
    """An ``sfm_data.json`` as OpenMVG writes it for two photos of ``W x H`` sharing one intrinsic (and, with
    ``spherical``, a third photo of a spherical camera), the photos in ``folder`` (``root``: the ``root_path``
    recorded, where OpenMVG ran; default ``folder``). cereal numbers the shared pointers in the order it writes
    them (the views', then the intrinsics') with the high bit set where the object follows, and names a
    polymorphic type at its first object only."""
    folder.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(0)
    views, extrinsics = [], []
    n = len(POSES) + unposed + spherical
    for i in range(n):
        name = f"IMG_{i:04d}.JPG"
        Image.fromarray(rng.integers(0, 255, (H, W, 3), dtype=np.uint8)).save(folder / name)
        views.append({"key": i, "value": {"polymorphic_id": 1073741824, "ptr_wrapper": {"id": FIRST | (i + 1), "data": {
            "local_path": "", "filename": name, "width": W, "height": H, "id_view": i,
            "id_intrinsic": 1 if spherical and i == n - 1 else 0, "id_pose": i}}}})
    for i, (R, C) in enumerate(POSES + ([POSES[0]] if spherical else [])):
        extrinsics.append({"key": i if i < len(POSES) else n - 1,
                           "value": {"rotation": R.tolist(), "center": C.tolist()}})
    key, params = MODELS[model]
    data = {"width": W, "height": H, "focal_length": F, "principal_point": list(PP)}
    if key:
        data[key] = params
    intrinsics = [{"key": 0, "value": {"polymorphic_id": FIRST | 1, "polymorphic_name": model,
                                       "ptr_wrapper": {"id": FIRST | (n + 1), "data": data}}}]
    if spherical:
        intrinsics.append({"key": 1, "value": {"polymorphic_id": FIRST | 2, "polymorphic_name": "spherical",
                                               "ptr_wrapper": {"id": FIRST | (n + 2),
                                                               "data": {"width": W, "height": H}}}})
    doc = {"sfm_data_version": "0.3", "root_path": str(root or folder), "views": views, "intrinsics": intrinsics,
           "extrinsics": extrinsics, "structure": [], "control_points": []}
    (folder / "sfm_data.json").write_text(json.dumps(doc, indent=4))


def openmvg_pixel(points, i: int, model: str, params=None) -> np.ndarray:
    """OpenMVG's projection (``Pose3``: ``R (X - C)``; ``cam2ima(add_disto(x))``: the focal length times the
    distorted point plus the principal point; ``Camera_Common.hpp``'s models)."""
    R, C = POSES[i]
    x_cam = R @ (np.asarray(points).T - C[:, None])
    x, y = x_cam[0] / x_cam[2], x_cam[1] / x_cam[2]
    d = MODELS[model][1] if params is None else params
    if model == "fisheye":
        r = np.hypot(x, y)
        t = np.arctan(r)
        scale = (t + d[0] * t**3 + d[1] * t**5 + d[2] * t**7 + d[3] * t**9) / r
        x, y = x * scale, y * scale
    elif model != "pinhole":
        k = (list(d) + [0.0, 0.0])[:3]
        r2 = x * x + y * y
        radial = 1 + k[0] * r2 + k[1] * r2**2 + k[2] * r2**3
        t1, t2 = (d[3], d[4]) if model == "pinhole_brown_t2" else (0.0, 0.0)
        x, y = x * radial + t2 * (r2 + 2 * x * x) + 2 * t1 * x * y, y * radial + t1 * (r2 + 2 * y * y) + 2 * t2 * x * y
    return np.stack([F * x + PP[0], F * y + PP[1]], 1)


@pytest.mark.parametrize("model", list(MODELS))
def test_cameras_project_as_openmvg_projects(tmp_path, model):
    """World points land where OpenMVG puts them: one focal length, the principal point from the corner, the
    rotation's rows as written, each lens model's formula (the Brown model's t1, t2 OpenCV's p1, p2)."""
    write_sfm_data(tmp_path, model=model)
    photos = load_photos(tmp_path)
    assert photos.format == "openmvg" and len(photos) == 2
    assert (photos.lenses[0] is None) == (model == "pinhole")
    rng = np.random.default_rng(1)
    points = np.array([0.5, 0.5, 0.5]) + rng.uniform(-0.4, 0.4, (50, 3))
    for i in range(2):
        np.testing.assert_allclose(stored_pixel(photos, i, points), openmvg_pixel(points, i, model), atol=1e-6)
        w2c = photos.cameras[i].world_to_camera
        np.testing.assert_allclose(-w2c[:3, :3].T @ w2c[:3, 3], POSES[i][1], atol=1e-9)


def test_unposed_and_spherical_views_are_skipped_and_photos_found_by_name(tmp_path, caplog):
    """The photos are looked for by name beside the file when ``root_path`` is the machine OpenMVG ran on; a view
    the reconstruction left out (no pose) and a spherical camera's are skipped, with a count."""
    write_sfm_data(tmp_path, root="/home/someone/castle/images", unposed=1, spherical=True)
    with caplog.at_level(logging.WARNING):
        photos = load_photos(tmp_path / "sfm_data.json")
    assert [p.name for p in photos.images] == ["IMG_0000.JPG", "IMG_0001.JPG"]
    assert "1 of its 4 views have no pose (not reconstructed): skipped" in caplog.text
    assert "1 of its 4 views are spherical (360) photos" in caplog.text


def test_found_in_a_folder_and_in_its_reconstruction(tmp_path):
    write_sfm_data(tmp_path / "out" / "reconstruction_sequential")
    assert detect_format(tmp_path / "out") == ("openmvg", tmp_path / "out" / "reconstruction_sequential" /
                                               "sfm_data.json")
    (tmp_path / "out" / "reconstruction_sequential" / "sfm_data.json").rename(tmp_path / "out" / "scene.json")
    assert detect_format(tmp_path / "out" / "scene.json")[0] == "openmvg"


def test_written_and_read_back(tmp_path):
    """:func:`write_openmvg` round trip: the cameras, each lens model, the photos' bytes; cereal's type names at
    their first object only (two cameras of one model, one of another)."""
    from scantex.photos import write_openmvg
    from scantex.photos.photoset import Distortion

    write_sfm_data(tmp_path / "in", model="pinhole_brown_t2")
    photos = load_photos(tmp_path / "in")
    extra = Camera(np.array([[60.0, 0, 31.5], [0, 60.0, 23.5], [0, 0, 1]]), photos.cameras[0].world_to_camera, W, H)
    three = PhotoSet(cameras=photos.as_stored().cameras + (extra,), images=photos.images + photos.images[:1],
                     source=photos.source, format="x",
                     distortions=photos.distortions + (Distortion("pinhole_radial_k1", (-0.1,)),))
    out = write_openmvg(three, tmp_path / "out")
    doc = json.loads(out.read_text())
    assert [i["value"].get("polymorphic_name") for i in doc["intrinsics"]] == ["pinhole_brown_t2", None,
                                                                                "pinhole_radial_k1"]
    back = load_photos(out)
    assert back.format == "openmvg" and len(back) == 3
    for i in range(3):
        np.testing.assert_allclose(back.as_stored().cameras[i].K, three.cameras[i].K, atol=1e-12)
        np.testing.assert_allclose(back.cameras[i].world_to_camera, three.cameras[i].world_to_camera, atol=1e-12)
        assert back.distortions[i] == three.distortions[i]
        assert back.images[i].read_bytes() == three.images[i].read_bytes()
    with pytest.raises(ValueError, match="one focal length"):
        skewed = Camera(np.array([[60.0, 0, 31.5], [0, 50.0, 23.5], [0, 0, 1]]), extra.world_to_camera, W, H)
        write_openmvg(PhotoSet(cameras=(skewed,), images=photos.images[:1], source=photos.source, format="x"),
                      tmp_path / "bad")


def edited(tmp_path, edit, **options):
    """An ``sfm_data.json`` (:func:`write_sfm_data`) whose parsed document ``edit`` changes in place; returns the
    folder."""
    write_sfm_data(tmp_path, **options)
    doc = json.loads((tmp_path / "sfm_data.json").read_text())
    edit(doc)
    (tmp_path / "sfm_data.json").write_text(json.dumps(doc))
    return tmp_path


def unsupported_model(tmp_path):
    def edit(doc):
        doc["intrinsics"][0]["value"]["polymorphic_name"] = "pinhole_radial_k2"
    return edited(tmp_path, edit), "camera model 'pinhole_radial_k2' is not supported"


def bad_rotation(tmp_path):
    return (edited(tmp_path, lambda doc: doc["extrinsics"][0]["value"]["rotation"][0].__setitem__(0, 2.0)),
            "view 0 (IMG_0000.JPG): its rotation is no rotation")


def missing_photo(tmp_path):
    write_sfm_data(tmp_path, root="/elsewhere")
    (tmp_path / "IMG_0001.JPG").unlink()
    return tmp_path, "view 1 (IMG_0001.JPG): its photo is neither at /elsewhere/IMG_0001.JPG nor in"


def wrong_parameters(tmp_path):
    return (edited(tmp_path, lambda doc: doc["intrinsics"][0]["value"]["ptr_wrapper"]["data"].update(
        disto_k3=[0.1, 0.2])), "disto_k3 is not 3 finite numbers")


def not_reconstructed(tmp_path):
    return edited(tmp_path, lambda doc: doc.update(extrinsics=[])), "none of its views has a pose"


def binary(tmp_path):
    tmp_path.mkdir(parents=True)
    (tmp_path / "sfm_data.bin").write_bytes(b"\x00" * 64)
    return tmp_path / "sfm_data.bin", "OpenMVG's binary sfm_data: scantex reads its JSON"


def unnamed_type(tmp_path):
    def edit(doc):
        doc["intrinsics"][0]["value"]["polymorphic_id"] = 7
    return edited(tmp_path, edit), "an intrinsic's type 7 is named by no earlier intrinsic"


def dangling_pointer(tmp_path):
    def edit(doc):
        doc["views"][1]["value"]["ptr_wrapper"] = {"id": 40}
    return edited(tmp_path, edit), "view 1: it points to object 40, which no earlier entry holds"


def not_a_map(tmp_path):
    return edited(tmp_path, lambda doc: doc.update(extrinsics={"0": {}})), "'extrinsics' is not a list"


@pytest.mark.parametrize("make", [unsupported_model, bad_rotation, missing_photo, wrong_parameters, not_reconstructed,
                                  binary, unnamed_type, dangling_pointer, not_a_map])
def test_bad_files_are_one_line_naming_the_file(tmp_path, make, capsys):
    from tests.io.hostile import assert_photos_refused

    path, message = make(tmp_path / "capture")
    assert_photos_refused(capsys, tmp_path, path, "sfm_data.")
    assert_photos_refused(capsys, tmp_path, path, message)


def test_a_fisheye_without_coefficients_is_still_a_fisheye(tmp_path):
    """OpenMVG's ``fisheye`` of four zeros projects through ``theta = atan r`` (as Meshroom's ``fisheye4`` does): it
    was read as a pinhole, 9 px off at the edges of an 80x60 photo."""
    write_sfm_data(tmp_path, model="fisheye")
    doc = json.loads((tmp_path / "sfm_data.json").read_text())
    doc["intrinsics"][0]["value"]["ptr_wrapper"]["data"]["fisheye"] = [0.0] * 4
    (tmp_path / "sfm_data.json").write_text(json.dumps(doc))
    photos = load_photos(tmp_path)
    assert photos.lenses[0] is not None and photos.distortions[0].projection == "equidistant"
    rng = np.random.default_rng(1)
    points = np.array([0.5, 0.5, 0.5]) + rng.uniform(-0.4, 0.4, (50, 3))
    np.testing.assert_allclose(stored_pixel(photos, 0, points), openmvg_pixel(points, 0, "fisheye", [0.0] * 4),
                               atol=1e-6)


def test_a_relative_root_path_is_the_capture_s_not_the_working_folder(tmp_path, monkeypatch):
    """``SfMInit_ImageListing -i images/`` records ``root_path: "images/"``, relative to where OpenMVG ran (the
    reconstruction's folder's parent): the photos are found there, never in scantex's working folder, where another
    capture's ``images/IMG_0000.JPG`` was taken silently."""
    project = tmp_path / "castle"
    write_sfm_data(project / "images", root="images")
    (project / "reconstruction_sequential").mkdir()
    (project / "images" / "sfm_data.json").rename(project / "reconstruction_sequential" / "sfm_data.json")
    other = tmp_path / "other"
    (other / "images").mkdir(parents=True)
    for name in ("IMG_0000.JPG", "IMG_0001.JPG"):
        Image.fromarray(np.zeros((H, W, 3), np.uint8)).save(other / "images" / name)
    monkeypatch.chdir(other)
    photos = load_photos(project)
    assert [p.resolve() for p in photos.images] == [(project / "images" / f"IMG_000{i}.JPG").resolve()
                                                     for i in range(2)]


def test_only_the_binary_in_a_folder_says_how_to_convert_it(tmp_path):
    (tmp_path / "reconstruction_sequential").mkdir()
    (tmp_path / "reconstruction_sequential" / "sfm_data.bin").write_bytes(b"\x00" * 64)
    with pytest.raises(Exception, match="openMVG_main_ConvertSfM_DataFormat"):
        load_photos(tmp_path)


def duplicate_key(tmp_path):
    def edit(doc):
        doc["extrinsics"].append(dict(doc["extrinsics"][0]))
    return edited(tmp_path, edit), "key 0 appears twice in 'extrinsics'"


def unnamed_first_type(tmp_path):
    def edit(doc):
        doc["intrinsics"][0]["value"].pop("polymorphic_name")
    return edited(tmp_path, edit), "has no polymorphic_name"


@pytest.mark.parametrize("make", [duplicate_key, unnamed_first_type])
def test_more_bad_files_are_one_line_naming_the_file(tmp_path, make, capsys):
    from tests.io.hostile import assert_photos_refused

    path, message = make(tmp_path / "capture")
    assert_photos_refused(capsys, tmp_path, path, message)
