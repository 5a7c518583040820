"""Posed-photo importers: conventions against hand-made files, synthetic round trips through every
writer (render, write, read, render again: the same pixels), bad input, and the real bolster capture."""

from __future__ import annotations

import dataclasses
import json
import logging
import math
import struct
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from scantex.errors import ScanError
from scantex.photos.photoset import Distortion, depth_warp
from scantex.photos import (
    PhotoSet,
    detect_format,
    load_photos,
    write_3dscannerapp,
    write_cameras_json,
    write_colmap_binary,
    write_colmap_text,
    write_meshroom,
    write_metashape,
    write_mve,
    write_mve_scene,
    write_nerfstudio,
    write_openmvs,
    write_polycam,
)
from scantex.views.camera import Camera
from scantex.views.raycast import RayCaster, cast_gbuffer
from scantex.views.render import render, to_uint8
from tests.conftest import shared_scan, textured_cube

W, H = 48, 36


# ---- a small posed capture made in code ---------------------------------------------------------

def capture_cameras() -> list[Camera]:
    """Four views of the unit cube, with off-centre principal points and non-square pixels."""
    eyes = [(2.6, -1.8, 1.9), (-1.6, -2.2, 1.4), (2.4, 2.0, 2.2), (0.4, -2.6, 0.3)]
    cams = []
    for k, eye in enumerate(eyes):
        cam = Camera.look_at(eye, (0.5, 0.5, 0.5), up=(0, 0, 1), fov_deg=55, width=W, height=H)
        K = cam.K.copy()
        K[0, 0] *= 1.0 + 0.05 * k       # fx != fy
        K[1, 1] *= 1.0 - 0.03 * k
        K[0, 2] += 2.75 - 1.5 * k       # off-centre principal point, fractional
        K[1, 2] += -1.25 + 0.8 * k
        cams.append(dataclasses.replace(cam, K=K))
    return cams


@pytest.fixture(scope="module")
def capture(tmp_path_factory):
    """``(scan, photos, renders, depths_mm)``: PNG photos rendered from known cameras, with depth."""
    scan = textured_cube()
    caster = RayCaster(scan.positions, scan.faces)
    folder = tmp_path_factory.mktemp("capture")
    cams = capture_cameras()
    renders, images, depth_files, depths = [], [], [], []
    for i, cam in enumerate(cams):
        rgb = to_uint8(render(scan, cam, caster)[0])
        depth = cast_gbuffer(caster, cam, scan.face_normals).depth
        mm = np.where(np.isfinite(depth), np.rint(depth * 1000), 0).astype(np.uint16)
        Image.fromarray(rgb).save(folder / f"photo_{i}.png")
        Image.fromarray(mm).save(folder / f"depth_{i}.png")
        renders.append(rgb)
        depths.append(mm)
        images.append(folder / f"photo_{i}.png")
        depth_files.append(folder / f"depth_{i}.png")
    photos = PhotoSet(cameras=tuple(cams), images=tuple(images), depths=tuple(depth_files),
                      source=folder, format="rendered")
    return scan, photos, renders, depths


WRITERS = [  # writer, format read back, keeps depth
    (write_nerfstudio, "nerfstudio", True),
    (write_colmap_text, "colmap-text", False),
    (write_colmap_binary, "colmap-binary", False),
    (write_3dscannerapp, "3dscannerapp", True),
    (write_polycam, "polycam", True),
    (write_cameras_json, "cameras.json", True),
    (write_mve, "texrecon", False),
    (write_mve_scene, "mve", False),
    (write_metashape, "metashape", False),
    (write_meshroom, "meshroom", False),
    (write_openmvs, "openmvs", False),
]


@pytest.mark.parametrize("writer, fmt, keeps_depth", WRITERS, ids=[w[1] for w in WRITERS])
def test_round_trip_renders_the_same_pixels(capture, tmp_path, writer, fmt, keeps_depth):
    scan, photos, renders, depths = capture
    written = writer(photos, tmp_path / "out")
    for where in (written, tmp_path / "out"):  # the file the writer names, and the folder
        back = load_photos(where)
        assert back.format == fmt and len(back) == len(photos)
    caster = RayCaster(scan.positions, scan.faces)
    for i, (cam, ref) in enumerate(zip(photos.cameras, back.cameras)):
        assert (ref.width, ref.height) == (cam.width, cam.height)
        np.testing.assert_allclose(ref.K, cam.K, rtol=0, atol=1e-9)
        np.testing.assert_allclose(ref.world_to_camera, cam.world_to_camera, rtol=0, atol=1e-9)
        assert np.array_equal(back.load_image(i), renders[i])
        again = to_uint8(render(scan, ref, caster)[0])
        diff = np.abs(again.astype(int) - renders[i].astype(int))
        assert diff.max() <= 1, f"photo {i}: re-rendered pixels differ by up to {diff.max()}"
        assert (diff == 0).mean() > 0.999  # float64 poses: in practice every pixel is identical
        if keeps_depth:
            depth = back.load_depth(i)
            expected = np.where(depths[i] > 0, depths[i] * np.float32(0.001), np.nan).astype(np.float32)
            np.testing.assert_array_equal(depth, expected)
        else:
            assert back.load_depth(i) is None


# ---- conventions, against files written by hand --------------------------------------------------

def reference_camera() -> Camera:
    """At (0, -4, 0) looking at the origin, +z up: camera +x = world +x, camera +y (down) = world -z,
    camera +z (forward) = world +y. Principal point at the image centre, fx 50, fy 40."""
    cam = Camera.look_at((0, -4, 0), (0, 0, 0), up=(0, 0, 1), width=W, height=H)
    R = np.array([[1.0, 0, 0], [0, 0, -1], [0, 1, 0]])
    assert np.allclose(cam.R, R) and np.allclose(cam.t, [0, 0, 4])
    K = np.array([[50.0, 0, (W - 1) / 2], [0, 40.0, (H - 1) / 2], [0, 0, 1]])
    return dataclasses.replace(cam, K=K)


# the same camera, OpenGL camera-to-world: columns are camera right, up, back in world coordinates
GL_C2W = [[1.0, 0, 0, 0], [0, 0, -1, -4], [0, 1, 0, 0], [0, 0, 0, 1]]


def blank_png(path, w=W, h=H):
    Image.fromarray(np.zeros((h, w, 3), np.uint8)).save(path)


def assert_reference(photos):
    ref = reference_camera()
    cam = photos.cameras[0]
    np.testing.assert_allclose(cam.K, ref.K, atol=1e-12)
    np.testing.assert_allclose(cam.world_to_camera, ref.world_to_camera, atol=1e-12)
    # the world point 1 m right of and 1 m above the target lands right of and above the centre
    pix, z = cam.project(np.array([[1.0, 0.0, 1.0]]))
    np.testing.assert_allclose(pix[0], [(W - 1) / 2 + 50 / 4, (H - 1) / 2 - 40 / 4])
    assert z[0] == pytest.approx(4.0)


def test_nerfstudio_convention(tmp_path):
    blank_png(tmp_path / "a.png")
    doc = {"camera_model": "OPENCV", "fl_x": 50, "fl_y": 40, "cx": W / 2, "cy": H / 2, "w": W, "h": H,
           "frames": [{"file_path": "a.png", "transform_matrix": GL_C2W}]}
    (tmp_path / "transforms.json").write_text(json.dumps(doc))
    assert_reference(load_photos(tmp_path))


def test_nerfstudio_blender_layout(tmp_path):
    """``camera_angle_x``, no intrinsics, an extensionless file_path."""
    (tmp_path / "train").mkdir()
    blank_png(tmp_path / "train" / "r_0.png")
    angle = 2 * math.atan(W / 2 / 50)
    doc = {"camera_angle_x": angle, "frames": [{"file_path": "./train/r_0", "transform_matrix": GL_C2W}]}
    (tmp_path / "transforms.json").write_text(json.dumps(doc))
    cam = load_photos(tmp_path / "transforms.json").cameras[0]
    np.testing.assert_allclose(cam.K, [[50, 0, (W - 1) / 2], [0, 50, (H - 1) / 2], [0, 0, 1]], atol=1e-9)


def test_nerfstudio_applied_transform_can_be_undone(tmp_path):
    from scantex.photos import load_nerfstudio

    blank_png(tmp_path / "a.png")
    shift = np.eye(4)
    shift[:3, 3] = [1.0, 2.0, 3.0]
    moved = (shift @ np.array(GL_C2W)).tolist()
    doc = {"fl_x": 50, "fl_y": 40, "cx": W / 2, "cy": H / 2, "w": W, "h": H,
           "applied_transform": shift[:3].tolist(),
           "frames": [{"file_path": "a.png", "transform_matrix": moved}]}
    (tmp_path / "transforms.json").write_text(json.dumps(doc))
    assert_reference(load_nerfstudio(tmp_path, undo_applied_transform=True))
    assert np.allclose(load_nerfstudio(tmp_path).cameras[0].center, [1.0, -2.0, 3.0])


def test_colmap_text_convention(tmp_path):
    (tmp_path / "images").mkdir()
    blank_png(tmp_path / "images" / "a.png")
    model = tmp_path / "sparse" / "0"
    model.mkdir(parents=True)
    (model / "cameras.txt").write_text(f"# comment\n1 PINHOLE {W} {H} 50 40 {W / 2} {H / 2}\n")
    s = math.sqrt(0.5)  # world-to-camera rotation: +90 degrees about x
    (model / "images.txt").write_text(f"# comment\n1 {s} {s} 0 0 0 0 4 1 a.png\n\n")
    photos = load_photos(tmp_path)
    assert photos.format == "colmap-text"
    assert_reference(photos)


def test_colmap_binary_matches_text(tmp_path, capture):
    """The two COLMAP writers read back to the same cameras, and the binary layout is COLMAP's."""
    _, photos, _, _ = capture
    write_colmap_text(photos, tmp_path / "t")
    model = write_colmap_binary(photos, tmp_path / "b")
    a, b = load_photos(tmp_path / "t"), load_photos(tmp_path / "b")
    for ca, cb in zip(a.cameras, b.cameras):
        assert np.allclose(ca.K, cb.K, atol=1e-12)
        assert np.allclose(ca.world_to_camera, cb.world_to_camera, atol=1e-12)
    data = (model / "cameras.bin").read_bytes()
    count, cid, model_id, w, h = struct.unpack_from("<QiiQQ", data)
    assert count == 4 and (cid, model_id, w, h) == (1, 1, W, H)  # 4 intrinsics; PINHOLE is model 1


def test_3dscannerapp_convention_and_frames_without_photos(tmp_path):
    blank_png(tmp_path / "frame_00003.png")
    doc = {"cameraPoseARFrame": np.array(GL_C2W).reshape(-1).tolist(),
           "intrinsics": [50, 0, W / 2, 0, 40, H / 2, 0, 0, 1], "frame_index": 3}
    (tmp_path / "frame_00003.json").write_text(json.dumps(doc))
    (tmp_path / "frame_00001.json").write_text(json.dumps(doc))  # a pose-only frame: skipped
    photos = load_photos(tmp_path / "frame_00003.json")
    assert photos.format == "3dscannerapp" and len(photos) == 1
    assert_reference(photos)


def test_polycam_convention(tmp_path):
    root = tmp_path / "keyframes"
    (root / "images").mkdir(parents=True)
    (root / "cameras").mkdir()
    blank_png(root / "images" / "1700.jpg")
    blank_png(root / "images" / "1700(1).jpg")  # unzip duplicate: ignored
    doc = {"fx": 50, "fy": 40, "cx": W / 2, "cy": H / 2, "width": W, "height": H, "blur_score": 3.0}
    doc.update({f"t_{r}{c}": GL_C2W[r][c] for r in range(3) for c in range(4)})
    (root / "cameras" / "1700.json").write_text(json.dumps(doc))
    photos = load_photos(tmp_path)
    assert photos.format == "polycam" and len(photos) == 1
    assert_reference(photos)


def test_cameras_json_convention_is_scantex_own(tmp_path):
    """world_to_camera is the pose; R and C of no pose beside it are not read as one."""
    blank_png(tmp_path / "a.png")
    ref = reference_camera()
    frame = {"image": "a.png", **ref.to_dict(), "R": "ignored", "C": [0, 0, 0]}
    (tmp_path / "cameras.json").write_text(json.dumps({"frames": [frame]}))
    assert_reference(load_photos(tmp_path / "cameras.json"))


def test_detect_format(tmp_path, capture):
    _, photos, _, _ = capture
    write_colmap_binary(photos, tmp_path / "c")
    assert detect_format(tmp_path / "c") == ("colmap", tmp_path / "c" / "sparse" / "0")
    assert detect_format(tmp_path / "c" / "sparse" / "0" / "images.bin")[0] == "colmap"
    write_polycam(photos, tmp_path / "p")
    assert detect_format(tmp_path / "p" / "keyframes" / "cameras" / "1.json")[0] == "polycam"


def cam_file(folder: Path, name: str, line2: str | None, cam: Camera | None = None, w: int = W, h: int = H) -> Path:
    """``name.png`` (``w`` x ``h``) beside ``name.cam``: ``cam``'s pose (the reference camera's) and ``line2``."""
    cam = cam or reference_camera()
    blank_png(folder / f"{name}.png", w, h)
    pose = " ".join(str(float(v)) for v in [*cam.t, *cam.R.reshape(-1)])
    (folder / f"{name}.cam").write_text(pose + "\n" + ("" if line2 is None else line2 + "\n"))
    return folder / f"{name}.cam"


def test_mve_convention(tmp_path):
    """texrecon's .cam: the focal length over the larger side, fy = fx * paspect, the principal point over the
    image's size from its corner; a .cam file names its folder; the photos in natural order of their names."""
    cam_file(tmp_path, "view_10", f"{50 / W} 0 0 {40 / 50} 0.5 0.5")
    cam_file(tmp_path, "view_2", f"{50 / W} 0 0 {40 / 50} {0.5 + 2 / W} 0.5")
    (tmp_path / "notes.cam.txt").write_text("not a camera")
    blank_png(tmp_path / "lone.png")  # an image without a .cam: not a photo of the set
    assert detect_format(tmp_path / "view_10.cam") == ("texrecon", tmp_path)
    photos = load_photos(tmp_path)
    assert photos.format == "texrecon" and [p.name for p in photos.images] == ["view_2.png", "view_10.png"]
    assert_reference(photos.subset([1]))
    assert photos.cameras[0].K[0, 2] == pytest.approx((W - 1) / 2 + 2)


def test_mve_portrait_and_defaults(tmp_path):
    """A portrait image's focal length is over its height (fx = fy / paspect); a line 2 in pixels (G2LTex's); line
    2 of f alone: square pixels, the principal point at the centre, no distortion."""
    cam_file(tmp_path, "a", f"{40 / W} 0 0 {40 / 50}", w=H, h=W)  # 36 x 48: fy = 40, fx = 50
    K = load_photos(tmp_path).cameras[0].K
    np.testing.assert_allclose(K, [[50, 0, (H - 1) / 2], [0, 40, (W - 1) / 2], [0, 0, 1]], atol=1e-12)
    cam_file(tmp_path, "a", f"50 0 0 0.8 {(W - 1) / 2} {(H - 1) / 2}")  # in pixels, as G2LTex writes some
    assert_reference(load_photos(tmp_path))
    cam_file(tmp_path, "a", "0.5")
    photos = load_photos(tmp_path)
    np.testing.assert_allclose(photos.cameras[0].K, [[24, 0, (W - 1) / 2], [0, 24, (H - 1) / 2], [0, 0, 1]])
    assert photos.distortions == (None,)


def test_mve_distortion_ignored_when_small_and_undone_when_strong(tmp_path, caplog):
    cam_file(tmp_path, "a", "1.0 0.0005 0.0001 1 0.5 0.5")
    with caplog.at_level(logging.WARNING):
        photos = load_photos(tmp_path)
    assert "ignoring a small lens distortion (MVE k2k4" in caplog.text
    assert photos.distortions[0].radial == (0.0005, 0.0001) and photos.lenses == (None,)
    cam_file(tmp_path, "a", "1.0 -0.2 0 1 0.5 0.5")  # VisualSfM's one term: undistorts by 1 - 0.2 r^2
    photos = load_photos(tmp_path)
    assert photos.distortions[0].radial == (0.2,) and photos.distortions[0].inverse_radial == (-0.2,)
    assert photos.lenses[0] is not None and photos.lenses[0].distortion == photos.distortions[0]
    assert load_photos(tmp_path, max_distortion_px=20).lenses == (None,)


def test_g2ltex_one_line_cam_takes_the_configuration_and_depth(tmp_path):
    """G2LTex's .cam holds the pose alone; its intrinsics are the colour camera's in its .yml (beside the photos'
    folder), its depth maps depth_NN.png beside color_NN.jpg."""
    folder = tmp_path / "textureimages"
    folder.mkdir()
    cam_file(folder, "color_00", None)
    Image.fromarray(np.full((H // 2, W // 2), 4000, np.uint16)).save(folder / "depth_00.png")
    with pytest.raises(ScanError, match="color_00.cam: holds the pose alone .* add texrecon's second line"):
        load_photos(folder)
    (tmp_path / "config_G2LTex.yml").write_text(
        "%YAML:1.0\n\n%Apt0\n%RGB_fx: 1\n\ndepth_fx: 25\nRGB_fx: 50\nRGB_fy: 40\n"
        f"RGB_cx: {(W - 1) / 2}\nRGB_cy: {(H - 1) / 2}\nRGB_width: {W}\nRGB_height: {H}\n")
    photos = load_photos(folder)
    assert_reference(photos)
    assert photos.load_depth(0).shape == (H // 2, W // 2) and np.nanmedian(photos.load_depth(0)) == pytest.approx(4)
    (tmp_path / "config_G2LTex.yml").write_text("RGB_fx: 50\nRGB_fy: 40\nRGB_cx: 23.5\nRGB_cy: 17.5\n"
                                               "RGB_width: 640\nRGB_height: 480\n")
    with pytest.raises(ScanError, match=r"color_00.png is 48x36 but the intrinsics of the G2LTex configuration "
                                        r".*config_G2LTex.yml are for 640x480: another capture's"):
        load_photos(folder)


def scannet_export(root: Path, numbers=(0, 2, 10), lost=()) -> Path:
    """A ScanNet export (SensReader's layout) of the reference camera: its frames ``numbers``, those in ``lost``
    with a pose of -inf (tracking lost), a depth map beside frame 0."""
    for sub in ("color", "depth", "pose", "intrinsic"):
        (root / sub).mkdir(parents=True, exist_ok=True)
    K = np.eye(4)
    K[:3, :3] = reference_camera().K
    np.savetxt(root / "intrinsic" / "intrinsic_color.txt", K)
    c2w = np.linalg.inv(reference_camera().world_to_camera)
    for n in numbers:
        blank_png(root / "color" / f"{n}.png")
        np.savetxt(root / "pose" / f"{n}.txt", np.full((4, 4), -np.inf) if n in lost else c2w)
    Image.fromarray(np.full((H // 2, W // 2), 2500, np.uint16)).save(root / "depth" / "0.png")
    return root


def test_scannet_convention_order_lost_frames_and_depth(tmp_path, caplog):
    """pose/N.txt camera-to-world in OpenCV's axes, K from intrinsic_color.txt; the frames in the order of their
    numbers, those whose tracking was lost (-inf) skipped with a warning; depth/N.png the depth map."""
    root = scannet_export(tmp_path / "scene0000_00", lost=(2,))
    blank_png(root / "color" / "5.png")  # a photo without a pose: not a frame
    for where in (root, root / "pose", root / "intrinsic" / "intrinsic_color.txt", root / "pose" / "0.txt",
                  root / "color" / "10.png"):
        assert detect_format(where) == ("scannet", root)
    with caplog.at_level(logging.WARNING):
        photos = load_photos(root)
    assert "1 frames have no pose (tracking lost: -inf): skipped" in caplog.text
    assert photos.format == "scannet" and [p.name for p in photos.images] == ["0.png", "10.png"]
    assert_reference(photos)
    assert photos.load_depth(0).shape == (H // 2, W // 2) and np.nanmedian(photos.load_depth(0)) == pytest.approx(2.5)
    assert photos.depths[1] is None


def rgbd_frames_folder(root: Path, numbers=(0, 2, 10), lost=(), intrinsics="intrinsic3d", depth_units=1000,
                       prefix="frame-", suffix=".png", depth_suffix=".png") -> Path:
    """RGB-D frames as files of the reference camera (``frame-000000.color.png`` + ``.pose.txt``, a depth map
    beside frame 0 at half size) with the intrinsics of Intrinsic3D (4x4 files), a .sens export (``_info.txt``) or
    3DMatch (a 3x3 ``camera-intrinsics.txt`` in the folder above)."""
    root.mkdir(parents=True, exist_ok=True)
    K4 = np.eye(4)
    K4[:3, :3] = reference_camera().K
    half = reference_camera().scaled(0.5).K
    if intrinsics in ("intrinsic3d", "lower case"):
        names = ("colorIntrinsics.txt", "depthIntrinsics.txt")
        names = [n.lower() for n in names] if intrinsics == "lower case" else names
        np.savetxt(root / names[0], K4)
        K4d = np.eye(4)
        K4d[:3, :3] = half
        K4d[0, 2] += 1  # the depth camera's principal point a pixel right of the photo's, halved
        np.savetxt(root / names[1], K4d)
    elif intrinsics == "sens":
        row = " ".join
        (root / "_info.txt").write_text(
            f"m_versionNumber = 4\nm_sensorName = StructureSensor\nm_colorWidth = {W}\nm_colorHeight = {H}\n"
            f"m_depthWidth = {W // 2}\nm_depthHeight = {H // 2}\nm_depthShift = {depth_units}\n"
            f"m_calibrationColorIntrinsic = {row(map(str, K4.ravel()))} \n"
            f"m_calibrationColorExtrinsic = {row(map(str, np.eye(4).ravel()))} \n"
            f"m_calibrationDepthIntrinsic = {row(map(str, np.r_[half[0], 0, half[1], 0, half[2], 0, 0, 0, 0, 1]))}\n"
            f"m_calibrationDepthExtrinsic = {row(map(str, np.eye(4).ravel()))} \nm_frames.size = {len(numbers)}\n")
    else:
        np.savetxt(root.parent / "camera-intrinsics.txt", reference_camera().K)
    c2w = np.linalg.inv(reference_camera().world_to_camera)
    for n in numbers:
        blank_png(root / f"{prefix}{n:06d}.color{suffix}")
        np.savetxt(root / f"{prefix}{n:06d}.pose.txt", np.full((4, 4), -np.inf) if n in lost else c2w)
    Image.fromarray(np.full((H // 2, W // 2), round(2.5 * depth_units), np.uint16)).save(
        root / f"{prefix}{numbers[0]:06d}.depth{depth_suffix}")
    return root


@pytest.mark.parametrize("intrinsics", ["intrinsic3d", "lower case", "sens", "3dmatch"])
def test_rgbd_frames_convention_order_lost_frames_and_depth(tmp_path, caplog, intrinsics):
    """frame-NNNNNN.pose.txt camera-to-world in OpenCV's axes, K from Intrinsic3D's colorIntrinsics.txt, a .sens
    export's _info.txt or 3DMatch's camera-intrinsics.txt one folder up; frames in the order of their numbers,
    those whose tracking was lost skipped with a warning, a photo without a pose no frame; .depth.png the depth
    map, in the units _info.txt says."""
    root = rgbd_frames_folder(tmp_path / "seq-01", lost=(2,), intrinsics=intrinsics,
                              depth_units=5000 if intrinsics == "sens" else 1000,
                              depth_suffix=".pgm" if intrinsics == "sens" else ".png")  # as ScanNet's SensReader
    blank_png(root / "frame-000005.color.png")  # a photo without a pose: not a frame
    for where in (root, root / "frame-000000.pose.txt", root / "frame-000010.color.png"):
        assert detect_format(where) == ("rgbd-frames", root)
    with caplog.at_level(logging.WARNING):
        photos = load_photos(root)
    assert "1 frames have no pose (tracking lost: -inf): skipped" in caplog.text
    assert photos.format == "rgbd-frames"
    assert [p.name for p in photos.images] == ["frame-000000.color.png", "frame-000010.color.png"]
    assert_reference(photos)
    depth = photos.load_depth(0)
    assert depth.shape == (H // 2, W // 2) and np.nanmedian(depth) == pytest.approx(2.5)
    if intrinsics in ("intrinsic3d", "lower case"):  # the depth camera looked a pixel left of the photo's view
        assert np.isnan(depth[:, -1]).all() and np.isfinite(depth[:, :-1]).all()
    else:  # the depth camera's K is the photo's, halved (or none): the map covers the photo's view
        assert np.isfinite(depth).all()
    assert photos.depths[1] is None


def test_rgbd_frames_depth_lens_that_fits_no_map_and_another_programs_info(tmp_path, caplog):
    """A depth K that is no pinhole's for the maps (an unset calibration: the identity) leaves the depth maps out
    with a warning, the photos read; an info.txt of another program beside the frames is passed over for the
    intrinsics above; a pose that is no rigid motion is one clear line."""
    root = rgbd_frames_folder(tmp_path / "scan" / "seq", intrinsics="sens")
    info = root / "_info.txt"
    text = info.read_text()
    start = text.index("m_calibrationDepthIntrinsic")
    end = text.index("\n", start)
    unset = "m_calibrationDepthIntrinsic = " + " ".join(map(str, np.eye(4).ravel()))
    info.write_text(text[:start] + unset + text[end:])
    with caplog.at_level(logging.WARNING):
        photos = load_photos(root)
    assert "the depth maps are not used" in caplog.text and set(photos.depths) == {None}
    assert_reference(photos)
    info.unlink()
    np.savetxt(tmp_path / "scan" / "camera-intrinsics.txt", reference_camera().K)
    (root / "info.txt").write_text("captured with some app, 3 frames\n")
    assert_reference(load_photos(root))
    (root / "frame-000000.pose.txt").write_text("0 0 0 0\n" * 4)
    with pytest.raises(ScanError, match="frame-000000.pose.txt: pose: pose's last row"):
        load_photos(root)


def test_rgbd_frames_of_another_name_and_jpeg(tmp_path):
    """3RScan and others write a frame's files under another name than frame-, photos as JPEG."""
    root = rgbd_frames_folder(tmp_path / "sequence", numbers=(1, 3), intrinsics="sens", prefix="scan-", suffix=".jpg")
    photos = load_photos(root)
    assert [p.name for p in photos.images] == ["scan-000001.color.jpg", "scan-000003.color.jpg"]
    assert photos.depths[0].name == "scan-000001.depth.png"


def test_a_depth_camera_with_its_own_lens_is_resampled_into_the_photo_view(tmp_path):
    """A depth map taken through a lens of its own (another focal length, principal point and size, at the colour
    camera's centre, looking its way) is read into the photo's view: it matches the depth the photo's camera sees,
    where read as if it covered the photo's view it does not. Written through each writer, it is written resampled."""
    scan = textured_cube()
    caster = RayCaster(scan.positions, scan.faces)
    cam = capture_cameras()[0]
    depth_cam = cam.scaled(2.0)
    K = depth_cam.K.copy()
    K[0, 0] *= 0.8
    K[1, 1] *= 0.85
    K[0, 2] += 6.0
    K[1, 2] -= 4.0
    depth_cam = dataclasses.replace(depth_cam, K=K)
    measured = cast_gbuffer(caster, depth_cam, scan.face_normals).depth
    Image.fromarray(np.where(np.isfinite(measured), np.rint(measured * 1000), 0).astype(np.uint16)).save(
        tmp_path / "d.png")
    Image.fromarray(to_uint8(render(scan, cam, caster)[0])).save(tmp_path / "p.png")
    warp = depth_warp(K, (depth_cam.width, depth_cam.height), cam.K, (cam.width, cam.height))
    photos = PhotoSet(cameras=(cam,), images=(tmp_path / "p.png",), depths=(tmp_path / "d.png",),
                      depth_warps=(warp,), source=tmp_path, format="test")
    truth = cast_gbuffer(caster, cam.scaled(2.0), scan.face_normals).depth
    read = photos.load_depth(0)
    assert read.shape == truth.shape
    both = np.isfinite(read) & np.isfinite(truth)
    assert both.sum() > 0.9 * np.isfinite(truth).sum()  # the wider depth camera saw all the photo sees
    error = np.abs(read[both] - truth[both])  # nearest sampling: within a depth pixel's slope of the faces
    as_stored = dataclasses.replace(photos, depth_warps=(None,)).load_depth(0)
    seen = np.isfinite(as_stored) & np.isfinite(truth)
    error_as_stored = np.abs(as_stored[seen] - truth[seen])
    assert np.median(error) < 0.02 and np.median(error_as_stored) > 0.1
    assert np.mean(error > 0.05) < 0.05 and np.mean(error_as_stored > 0.05) > 0.9
    # fixed when the photos are read: a focal length refined later takes the map along, as with any map
    refined = dataclasses.replace(cam, K=cam.K * np.array([[1.02], [1.02], [1.0]]))
    np.testing.assert_array_equal(dataclasses.replace(photos, cameras=(refined,)).load_depth(0), read)
    for writer in (write_cameras_json, write_nerfstudio, write_polycam, write_3dscannerapp):
        back = load_photos(writer(photos, tmp_path / writer.__name__))
        assert back.depth_warps[0] is None
        np.testing.assert_allclose(back.load_depth(0), read, atol=6e-4)  # millimetres


def test_scannet_depth_intrinsics_are_read(tmp_path):
    """ScanNet's intrinsic_depth.txt is the depth camera's lens: its maps are resampled into the photos' view."""
    root = scannet_export(tmp_path / "scene", numbers=(0,))
    photos = load_photos(root)
    assert photos.depth_warps[0] is None
    K = np.eye(4)
    K[:3, :3] = reference_camera().scaled(0.5).K
    K[0, 2] += 2  # the depth camera's principal point 2 px right of the photo's, halved
    np.savetxt(root / "intrinsic" / "intrinsic_depth.txt", K)
    photos = load_photos(root)
    assert photos.depth_warps[0] is not None
    assert np.isnan(photos.load_depth(0)[:, -2:]).all() and np.isfinite(photos.load_depth(0)[:, :-2]).all()


def arkitscenes_capture(video: Path, times=(100.0, 100.1, 500.0), stream="lowres_wide", poses=None,
                        frames_folder=True) -> Path:
    """An ARKitScenes capture of the reference camera: ``<video>/<video>_frames/`` (or the video folder itself, as
    the raw subset) with ``lowres_wide.traj`` (the reference pose at 100.0 and 100.1 s, or ``poses`` {time: world
    to camera}), frames of ``stream`` at ``times`` with their .pincam (ARKit's corner convention), a LiDAR depth map
    beside the first."""
    from scipy.spatial.transform import Rotation

    folder = video / f"{video.name}_frames" if frames_folder else video
    for sub in (stream, f"{stream}_intrinsics", "lowres_depth"):
        (folder / sub).mkdir(parents=True, exist_ok=True)
    poses = poses or {100.0: reference_camera().world_to_camera, 100.1: reference_camera().world_to_camera}
    lines = [f"{t:.6f} " + " ".join(f"{v:.17g}" for v in (*Rotation.from_matrix(m[:3, :3]).as_rotvec(), *m[:3, 3]))
             for t, m in poses.items()]
    (folder / "lowres_wide.traj").write_text("\n".join(lines) + "\n")
    K = reference_camera().K
    for t in times:
        stem = f"{video.name}_{t:.3f}"
        blank_png(folder / stream / f"{stem}.png")
        (folder / f"{stream}_intrinsics" / f"{stem}.pincam").write_text(
            f"{W} {H} {K[0, 0]} {K[1, 1]} {K[0, 2] + 0.5} {K[1, 2] + 0.5}\n")
    Image.fromarray(np.full((H // 2, W // 2), 1800, np.uint16)).save(
        folder / "lowres_depth" / f"{video.name}_{times[0]:.3f}.png")
    return folder


def test_arkitscenes_convention_frames_without_a_pose_and_depth(tmp_path, caplog):
    """lowres_wide.traj: world-to-camera as axis-angle and translation, OpenCV's axes; .pincam: width height fx fy cx
    cy from the image's corner; a frame far from every pose skipped with a warning, one without a .pincam too;
    lowres_depth/ the depth map at the frame's timestamp."""
    folder = arkitscenes_capture(tmp_path / "41069021")
    blank_png(folder / "lowres_wide" / "41069021_300.000.png")  # no .pincam
    for where in (tmp_path / "41069021", folder, folder / "lowres_wide.traj",
                  folder / "lowres_wide_intrinsics" / "41069021_100.000.pincam"):
        assert detect_format(where) == ("arkitscenes", folder)
    with caplog.at_level(logging.WARNING):
        photos = load_photos(tmp_path / "41069021")
    assert "1 of the 4 lowres_wide frames lie outside the trajectory's poses" in caplog.text
    assert "1 of the 4 lowres_wide frames have no .pincam" in caplog.text
    with (folder / "lowres_wide.traj").open("a") as f:
        f.write("300.0 nan 0 0 0 0 0\n")  # a lost pose: left out, the frame at 300 s has none
    with caplog.at_level(logging.WARNING):
        assert len(load_photos(folder)) == 2
    assert "1 of its 3 poses hold non-finite numbers (tracking lost): left out" in caplog.text
    assert photos.format == "arkitscenes"
    assert [p.name for p in photos.images] == ["41069021_100.000.png", "41069021_100.100.png"]
    assert_reference(photos)
    assert np.nanmedian(photos.load_depth(0)) == pytest.approx(1.8) and photos.depths[1] is None


def test_arkitscenes_a_stream_without_intrinsics_gives_way(tmp_path, caplog):
    """A partial download: wide/ frames without wide_intrinsics/; the lowres_wide frames are read, with a warning.
    A frame's file names its capture, a JPEG too."""
    import shutil

    folder = arkitscenes_capture(tmp_path / "5", times=(100.0,), stream="wide")
    arkitscenes_capture(tmp_path / "5", times=(100.1,), stream="lowres_wide")
    shutil.rmtree(folder / "wide_intrinsics")
    with caplog.at_level(logging.WARNING):
        photos = load_photos(tmp_path / "5")
    assert [p.parent.name for p in photos.images] == ["lowres_wide"]
    assert "none of its 1 wide frames has both a pose" in caplog.text
    assert "reading its lowres_wide frames" in caplog.text
    blank_png(folder / "lowres_wide" / "5_100.200.jpg")
    assert detect_format(folder / "lowres_wide" / "5_100.200.jpg") == ("arkitscenes", folder)


def test_arkitscenes_pose_between_two_is_interpolated_and_the_sharpest_stream_read(tmp_path):
    """A raw video's frame between two of the trajectory's poses takes their interpolation (the centre linearly,
    the rotation halfway); the wide camera's sharpest stream is read when the capture holds several."""
    a = reference_camera()
    turn = np.array([[np.cos(0.2), 0, np.sin(0.2)], [0, 1, 0], [-np.sin(0.2), 0, np.cos(0.2)]])
    b = np.eye(4)
    b[:3, :3] = turn @ a.R
    b[:3, 3] = -b[:3, :3] @ (a.center + [0.3, 0.0, 0.0])
    poses = {10.0: a.world_to_camera, 10.2: b}
    arkitscenes_capture(tmp_path / "7", times=(10.1, 10.6), stream="lowres_wide", poses=poses, frames_folder=False)
    folder = arkitscenes_capture(tmp_path / "7", times=(10.1,), stream="wide", poses=poses, frames_folder=False)
    photos = load_photos(folder)
    assert [p.parent.name for p in photos.images] == ["wide"]  # the 10.6 s frame of lowres_wide is not read
    cam = photos.cameras[0]
    np.testing.assert_allclose(cam.center, a.center + [0.15, 0.0, 0.0], atol=1e-9)
    half = np.degrees(np.arccos((np.trace(cam.R @ a.R.T) - 1) / 2))
    assert half == pytest.approx(np.degrees(0.1), abs=1e-6)
    with pytest.raises(ScanError, match="none of its 1 lowres_wide frames has both a pose"):
        load_photos(arkitscenes_capture(tmp_path / "8", times=(11.0,), poses={10.0: a.world_to_camera,
                                                                               11.5: b}))


def mve_view(views: Path, n: int, focal: float, image: str | None = "undistorted.png", extra: str = "") -> Path:
    """``views/view_<n>.mve/`` of the reference camera (``focal``: MVE's focal length; 0: no camera)."""
    folder = views / f"view_{n:04d}.mve"
    folder.mkdir(parents=True)
    cam = reference_camera()
    R, t = cam.world_to_camera[:3, :3], cam.world_to_camera[:3, 3]
    (folder / "meta.ini").write_text(
        f"# MVE view meta data\n\n[camera]\nfocal_length = {focal}\npixel_aspect = 0.8\nprincipal_point = 0.5 0.5\n"
        f"radial_distortion = 0 0\nrotation = {' '.join(map(str, R.ravel()))}\n"
        f"translation = {' '.join(map(str, t))}\n{extra}\n[view]\nid = {n}\nname = {n:04d}\n")
    if image:
        blank_png(folder / image)
    return folder


def test_mve_scene_convention_views_without_a_camera_and_order(tmp_path, caplog):
    """meta.ini: MVE's camera (world-to-camera rotation and translation, the focal length over the larger side,
    the pixel aspect, the principal point a share from the corner); a view whose focal length is 0 skipped with a
    warning; the undistorted image, else the original; views in the order of their numbers."""
    views = tmp_path / "scene" / "views"
    mve_view(views, 10, 50 / W)
    mve_view(views, 2, 50 / W, image="original.jpg")
    mve_view(views, 0, 0.0)
    for where in (tmp_path / "scene", views, views / "view_0002.mve" / "meta.ini"):
        assert detect_format(where) == ("mve", views)
    with caplog.at_level(logging.WARNING):
        photos = load_photos(tmp_path / "scene")
    assert "1 of its 3 views have no camera (focal length 0" in caplog.text
    assert photos.format == "mve"
    assert [p.parent.name + "/" + p.name for p in photos.images] == ["view_0002.mve/original.jpg",
                                                                     "view_0010.mve/undistorted.png"]
    assert_reference(photos)


def test_mve_writers_say_what_they_cannot_hold(capture, tmp_path, caplog):
    """MVE's cameras hold no skew and texrecon's no OpenCV distortion: both writers warn, naming the photo."""
    _, photos, _, _ = capture
    K = photos.cameras[1].K.copy()
    K[0, 1] = 0.5
    odd = dataclasses.replace(photos, cameras=(photos.cameras[0], dataclasses.replace(photos.cameras[1], K=K),
                                               *photos.cameras[2:]),
                              distortions=(Distortion("OPENCV", (0.01, 0.0)), None, None, None))
    with caplog.at_level(logging.WARNING):
        write_mve(odd, tmp_path / "texrecon")
        write_mve_scene(odd, tmp_path / "mve")
    for where in ("the .cam file", "meta.ini"):
        assert f"photo 0: its lens distortion is not written to {where}" in caplog.text
        assert f"photo 1: its skew is not written to {where}" in caplog.text


def test_mve_scene_distortion_is_the_original_photos(tmp_path):
    """MVE's radial distortion (k2k4) is the original photo's: a view read through its undistorted image has none
    left; one read through its original has it checked (and undone when strong)."""
    views = tmp_path / "views"
    strong = "radial_distortion = -0.2 0.05"
    for n, image in ((0, "undistorted.png"), (1, "original.jpg")):
        folder = mve_view(views, n, 50 / W, image=image)
        (folder / "meta.ini").write_text((folder / "meta.ini").read_text().replace("radial_distortion = 0 0", strong))
    photos = load_photos(views)
    assert photos.lenses[0] is None and photos.lenses[1].distortion == Distortion("MVE k2k4", (-0.2, 0.05))
    (views / "view_0001.mve" / "original.jpg").rename(views / "view_0001.mve" / "undistorted.jpg")
    photos = load_photos(views)
    assert photos.distortions == (None, None)
    assert detect_format(views / "view_0001.mve" / "undistorted.jpg") == ("mve", views)


# ---- lens distortion -----------------------------------------------------------------------------

def write_opencv_colmap(tmp_path, k1):
    (tmp_path / "images").mkdir()
    blank_png(tmp_path / "images" / "a.png")
    (tmp_path / "cameras.txt").write_text(f"1 OPENCV {W} {H} 50 40 24 18 {k1} 0 0 0\n")
    (tmp_path / "images.txt").write_text("1 1 0 0 0 0 0 4 1 a.png\n\n")


def test_a_frame_listed_twice_is_used_once(tmp_path, caplog):
    """A camera file that lists a photo twice: a held-out copy would be scored on a photo the texture was made
    from (a helper's run scored 26.83 dB against 23.22 for the same capture listed once)."""
    import json

    from tests.io.hostile import write_photos

    cams = write_photos(tmp_path, n=3)
    doc = json.loads(cams.read_text())
    doc["frames"] = doc["frames"] + [dict(doc["frames"][1]), dict(doc["frames"][0])]
    cams.write_text(json.dumps(doc))
    with caplog.at_level(logging.WARNING):
        photos = load_photos(cams)
    assert [p.name for p in photos.images] == ["p0.png", "p1.png", "p2.png"]
    assert "2 frames name a photo an earlier frame names (e.g. p1.png): each photo" in caplog.text
    # a copy at another pose: said so (the file list or the poses are wrong), the first frame's pose kept
    moved = dict(doc["frames"][0])
    moved["world_to_camera"] = [row[:3] + [row[3] + 0.1] for row in moved["world_to_camera"][:3]] + [[0, 0, 0, 1]]
    doc["frames"] = doc["frames"][:3] + [moved]
    cams.write_text(json.dumps(doc))
    caplog.clear()
    with caplog.at_level(logging.WARNING):
        photos = load_photos(cams)
    assert "1 frames name a photo an earlier frame names (e.g. p0.png), 1 of them at another pose" in caplog.text
    assert np.array_equal(photos.cameras[0].world_to_camera, np.asarray(doc["frames"][0]["world_to_camera"]))


def test_strong_distortion_is_undone(tmp_path):
    """Refused before ('undistort the photos first'): read through a lens (:mod:`scantex.photos.lens`), unless
    ``max_distortion_px`` takes it for small."""
    write_opencv_colmap(tmp_path, k1=0.2)
    photos = load_photos(tmp_path)
    assert photos.lenses[0] is not None and photos.cameras[0].K[0, 0] > 50  # a pincushion's narrower view
    assert load_photos(tmp_path, max_distortion_px=10).lenses == (None,)


def test_the_cli_reads_a_strong_distortion_and_takes_max_distortion(tmp_path, capsys, caplog):
    """The command line reads the photos through their lens; ``--max-distortion`` ignores one up to that many
    pixels, with a warning."""
    from tests.io.hostile import run_cli, write_cube

    write_opencv_colmap(tmp_path, k1=0.2)
    mesh = write_cube(tmp_path / "scan")
    with caplog.at_level(logging.WARNING):
        run_cli(capsys, "enhance", mesh, "--photos", tmp_path, "-o", tmp_path / "out", "-q")
    assert "distortion" not in caplog.text  # the photos are read; what stops this toy capture comes later
    with caplog.at_level(logging.WARNING):
        run_cli(capsys, "enhance", mesh, "--photos", tmp_path, "-o", tmp_path / "out", "-q", "--max-distortion", "3")
    assert "ignoring a small lens distortion" in caplog.text


def test_small_distortion_is_ignored_with_a_warning(tmp_path, caplog):
    write_opencv_colmap(tmp_path, k1=0.001)
    with caplog.at_level(logging.WARNING):
        photos = load_photos(tmp_path)
    assert "ignoring a small lens distortion" in caplog.text
    assert photos.distortions[0].model == "OPENCV" and photos.distortions[0].radial == (0.001, 0.0)


def test_distortion_shift_against_a_direct_evaluation():
    from scantex.photos import Distortion

    cam = reference_camera()
    d = Distortion("OPENCV", (0.01, 0.0), (0.0, 0.0))
    # the corner pixel (0, 0): x = -23.5/50, y = -17.5/40; shift = f * x * k1 * r^2 per axis
    x, y = -23.5 / 50, -17.5 / 40
    r2 = x * x + y * y
    expected = math.hypot(50 * x * 0.01 * r2, 40 * y * 0.01 * r2)
    assert d.max_shift_px(cam) == pytest.approx(expected)


def bad_cam_line(tmp_path):
    blank_png(tmp_path / "a.png")
    (tmp_path / "a.cam").write_text("0 0 4 1 0 0 0 0 -1 0 1\n1 0 0 1 0.5 0.5\n")
    return tmp_path, "a.cam: not a .cam file: line 1 has 11 numbers, expected 12"


def bad_cam_words(tmp_path):
    blank_png(tmp_path / "a.png")
    (tmp_path / "a.cam").write_text("translation 0 0 4\n")
    return tmp_path / "a.cam", "a.cam: not a .cam file: its first two lines are not numbers"


def bad_cam_focal(tmp_path):
    cam_file(tmp_path, "a", "0 0 0 1 0.5 0.5")
    return tmp_path, "a.cam: line 2: the focal length and the pixel aspect must be positive numbers"


def bad_scannet_pose(tmp_path):
    scannet_export(tmp_path, numbers=(0,))
    (tmp_path / "pose" / "0.txt").write_text("1 0 0\n0 1 0\n")
    return tmp_path, "0.txt: not a 4x4 camera-to-world pose: 2x3 numbers, expected 4x4"


def bad_scannet_all_lost(tmp_path):
    scannet_export(tmp_path, numbers=(0, 1), lost=(0, 1))
    return tmp_path, "none of its 2 pose/N.txt files has both a finite pose and its photo"


def bad_frames_without_intrinsics(tmp_path):
    rgbd_frames_folder(tmp_path / "seq", intrinsics="3dmatch")
    (tmp_path / "camera-intrinsics.txt").unlink()
    return tmp_path / "seq", "no intrinsics for its frames: expected colorIntrinsics.txt, _info.txt"


def bad_frames_colour_extrinsic(tmp_path):
    root = rgbd_frames_folder(tmp_path, intrinsics="sens")
    info = root / "_info.txt"
    info.write_text(info.read_text().replace("m_calibrationColorExtrinsic = 1.0 0.0 0.0 0.0",
                                             "m_calibrationColorExtrinsic = 1.0 0.0 0.0 0.05"))
    return root, "_info.txt: m_calibrationColorExtrinsic is not the identity"


def bad_frames_info_of_another_size(tmp_path):
    root = rgbd_frames_folder(tmp_path, intrinsics="sens")
    info = root / "_info.txt"
    info.write_text(info.read_text().replace(f"m_colorWidth = {W}", "m_colorWidth = 1296"))
    return root, f"_info.txt: its colour camera is 1296x{H} but frame-000000.color.png is {W}x{H}"


def bad_frames_depth_shift(tmp_path):
    root = rgbd_frames_folder(tmp_path, intrinsics="sens")
    info = root / "_info.txt"
    info.write_text(info.read_text().replace("m_depthShift = 1000", "m_depthShift = zero"))
    return root, "m_depthShift is 'zero', expected depth units per metre"


def bad_frames_pose(tmp_path):
    root = rgbd_frames_folder(tmp_path, numbers=(0,))
    (root / "frame-000000.pose.txt").write_text("1 0 0 0\n0 1 0 0\n")
    return root, "frame-000000.pose.txt: not a 4x4 camera-to-world pose: 2x4 numbers, expected 4x4"


def bad_arkitscenes_trajectory(tmp_path):
    folder = arkitscenes_capture(tmp_path / "9")
    (folder / "lowres_wide.traj").write_text("100.0 0 0 0 1 2\n")
    return folder, "lowres_wide.traj: not a trajectory: 6 numbers a line, expected 7"


def bad_arkitscenes_no_frames(tmp_path):
    folder = arkitscenes_capture(tmp_path / "9", times=(100.0,))
    (folder / "lowres_wide" / "9_100.000.png").unlink()
    return folder, "no frames in lowres_wide/: expected <video_id>_<timestamp>.png"


def bad_arkitscenes_pincam(tmp_path):
    folder = arkitscenes_capture(tmp_path / "9", times=(100.0,))
    (folder / "lowres_wide_intrinsics" / "9_100.000.pincam").write_text("48 36 50 40\n")
    return folder, "9_100.000.pincam: not a .pincam file: 4 numbers, expected 6"


def bad_mve_meta(tmp_path):
    mve_view(tmp_path / "views", 0, 50 / W)
    (tmp_path / "views" / "view_0000.mve" / "meta.ini").write_text("focal_length = 1\n")
    return tmp_path, "meta.ini: not an MVE meta.ini (File contains no section headers."


def bad_mve_rotation(tmp_path):
    folder = mve_view(tmp_path / "views", 0, 50 / W)
    text = (folder / "meta.ini").read_text().replace("rotation = ", "rotation = 2 ")
    (folder / "meta.ini").write_text(text)
    return tmp_path, "meta.ini: [camera] rotation has 10 numbers, expected 9"


# ---- bad input -----------------------------------------------------------------------------------

def bad_missing(tmp_path):
    return tmp_path / "nope", "no such file"


def bad_unknown_layout(tmp_path):
    (tmp_path / "stuff").mkdir()
    (tmp_path / "stuff" / "notes.txt").write_text("hi")
    return tmp_path / "stuff", "no posed photos found"


def bad_json(tmp_path):
    (tmp_path / "transforms.json").write_text('{"frames": [{"file_path": "a.png",')
    return tmp_path, "not valid JSON"


def bad_missing_image(tmp_path):
    doc = {"fl_x": 50, "fl_y": 40, "cx": 24, "cy": 18, "w": W, "h": H,
           "frames": [{"file_path": "gone.png", "transform_matrix": GL_C2W}]}
    (tmp_path / "transforms.json").write_text(json.dumps(doc))
    return tmp_path, "gone.png does not exist"


def bad_nan_pose(tmp_path):
    blank_png(tmp_path / "a.png")
    pose = [row[:] for row in GL_C2W]
    pose[0][3] = float("nan")
    doc = {"fl_x": 50, "fl_y": 40, "cx": 24, "cy": 18, "w": W, "h": H,
           "frames": [{"file_path": "a.png", "transform_matrix": pose}]}
    (tmp_path / "transforms.json").write_text(json.dumps(doc))
    return tmp_path, "non-finite"


def bad_scaled_pose(tmp_path):
    blank_png(tmp_path / "a.png")
    frame = {"image": "a.png", **reference_camera().to_dict()}
    frame["world_to_camera"] = (2 * np.array(frame["world_to_camera"])).tolist()
    (tmp_path / "cameras.json").write_text(json.dumps({"frames": [frame]}))
    return tmp_path, "last row"


def bad_truncated_binary(tmp_path):
    photos = PhotoSet(cameras=(reference_camera(),), images=(tmp_path / "a.png",), source=tmp_path,
                      format="test")
    blank_png(tmp_path / "a.png")
    model = write_colmap_binary(photos, tmp_path / "c")
    data = (model / "images.bin").read_bytes()
    (model / "images.bin").write_bytes(data[:40])
    return tmp_path / "c", "COLMAP binary file"


def bad_thin_prism(tmp_path):
    blank_png(tmp_path / "a.png")
    (tmp_path / "cameras.txt").write_text(f"1 THIN_PRISM_FISHEYE {W} {H} 50 40 24 18 0 0 0 0 0 0 0 0\n")
    (tmp_path / "images.txt").write_text("1 1 0 0 0 0 0 4 1 a.png\n\n")
    return tmp_path, "THIN_PRISM_FISHEYE is not supported"


def bad_image_size(tmp_path):
    blank_png(tmp_path / "a.png", w=2 * W, h=2 * H)
    frame = {"image": "a.png", **reference_camera().to_dict()}
    (tmp_path / "cameras.json").write_text(json.dumps({"frames": [frame]}))
    return tmp_path, f"a.png is {2 * W}x{2 * H} but its camera is {W}x{H}"


def bad_polycam_without_camera(tmp_path):
    (tmp_path / "keyframes" / "images").mkdir(parents=True)
    (tmp_path / "keyframes" / "cameras").mkdir()
    blank_png(tmp_path / "keyframes" / "images" / "5.jpg")
    return tmp_path, "keyframe 5.jpg has no camera file"


def bad_intrinsics_of_another_size(tmp_path):
    """3D Scanner App frames resized to half after capture, their intrinsics as the app wrote them: the
    principal point at the photo's corner (the run had been refused as misaligned, the cause unnamed)."""
    from scantex.photos.scannerapp import write_3dscannerapp

    full = reference_camera()
    blank_png(tmp_path / "a.png")
    write_3dscannerapp(PhotoSet(cameras=(full,), images=(tmp_path / "a.png",), source=tmp_path, format="test"),
                       tmp_path / "app")
    image = next((tmp_path / "app").glob("frame_*.jpg"), None) or next((tmp_path / "app").glob("frame_*.png"))
    Image.open(image).resize((W // 2, H // 2)).save(image)
    return tmp_path / "app", "the intrinsics are for another image size"


def bad_photo_turned(tmp_path):
    """A photo turned upright after capture (a phone's portrait photo), its size read from the file, its
    intrinsics the sensor's: it had been textured from, 90 degrees off (the principal point's offset, 39 % of
    the width, passed the check for intrinsics of another size)."""
    cam = reference_camera()
    blank_png(tmp_path / "a.png", w=H, h=W)
    frame = {"image": "a.png", "K": cam.K.tolist(), "world_to_camera": cam.world_to_camera.tolist()}
    (tmp_path / "cameras.json").write_text(json.dumps({"frames": [frame]}))
    return tmp_path, f"the intrinsics are for a {W}x{H} image, the photo is {H}x{W}: it was turned by 90 degrees"


def cameras_file(tmp_path, **changes):
    """A one-frame cameras.json of the reference camera, its frame's keys changed (``None``: removed)."""
    blank_png(tmp_path / "a.png")
    frame = {"image": "a.png", **reference_camera().to_dict()}
    frame.update(changes)
    frame = {k: v for k, v in frame.items() if v is not None}
    (tmp_path / "cameras.json").write_text(json.dumps({"frames": [frame]}))
    return tmp_path / "cameras.json"


def bad_empty_frames(tmp_path):
    (tmp_path / "cameras.json").write_text(json.dumps({"frames": []}))
    return tmp_path / "cameras.json", "its 'frames' list is empty"


def bad_frame_without_pose(tmp_path):
    """Was "a JSON file of no known camera layout": the file's layout is known, a frame misses its pose."""
    return cameras_file(tmp_path, world_to_camera=None), "frame 0: missing 'world_to_camera'"


def bad_empty_image_path(tmp_path):
    return cameras_file(tmp_path, image=""), "frame 0's image: no file named"


def bad_image_path_a_folder(tmp_path):
    (tmp_path / "sub").mkdir()
    return cameras_file(tmp_path, image="sub"), "sub is a folder, not a file"


BAD = [bad_missing, bad_unknown_layout, bad_json, bad_missing_image, bad_nan_pose, bad_scaled_pose,
       bad_truncated_binary, bad_thin_prism, bad_image_size, bad_polycam_without_camera, bad_intrinsics_of_another_size,
       bad_photo_turned, bad_empty_frames, bad_frame_without_pose, bad_empty_image_path,
       bad_image_path_a_folder, bad_cam_line, bad_cam_words, bad_cam_focal, bad_scannet_pose, bad_scannet_all_lost,
       bad_frames_without_intrinsics, bad_frames_colour_extrinsic, bad_frames_info_of_another_size,
       bad_frames_depth_shift, bad_frames_pose, bad_arkitscenes_trajectory, bad_arkitscenes_pincam,
       bad_arkitscenes_no_frames, bad_mve_meta, bad_mve_rotation]


def test_cameras_json_pose_as_r_and_c_and_a_byte_order_mark(tmp_path, caplog):
    """A frame may give its pose as R and C (the camera's centre; or t) alone, as the bolster's file does beside
    world_to_camera; a file saved with a byte-order mark (Windows' editors) is read; a folder holding both a
    transforms.json and a cameras.json says which it reads."""
    import logging

    cam = reference_camera()
    path = cameras_file(tmp_path, world_to_camera=None, R=cam.R.tolist(), C=[0.0, -4.0, 0.0])
    assert_reference(load_photos(path))
    path.write_text(json.dumps({"frames": [{"image": "a.png", **cam.to_dict(), "R": cam.R.tolist(),
                                            "t": cam.t.tolist()}]}), encoding="utf-8-sig")
    assert path.read_bytes().startswith(b"\xef\xbb\xbf")
    assert_reference(load_photos(path))
    # both, of two poses: world_to_camera is used, and the warning says so (it had been taken silently)
    cameras_file(tmp_path, R=cam.R.tolist(), C=[0.0, -4.0, 0.5])
    with caplog.at_level(logging.WARNING):
        assert_reference(load_photos(path))
    assert "1 of 1 frames give R and C (or t) of another pose than their world_to_camera" in caplog.text
    caplog.clear()
    nerfstudio = {"fl_x": 50, "fl_y": 40, "cx": 24, "cy": 18, "w": W, "h": H,
                  "frames": [{"file_path": "a.png", "transform_matrix": GL_C2W}]}
    (tmp_path / "transforms.json").write_text(json.dumps(nerfstudio))
    with caplog.at_level(logging.WARNING):
        assert load_photos(tmp_path).format == "nerfstudio"
    assert "holds transforms.json and cameras.json: reading transforms.json" in caplog.text


@pytest.mark.parametrize("case", BAD, ids=[c.__name__ for c in BAD])
def test_bad_input_is_one_clear_line(tmp_path, case):
    path, message = case(tmp_path)
    with pytest.raises(ScanError) as err:
        load_photos(path)
    assert message in str(err.value)
    assert "\n" not in str(err.value)
    assert err.value.path is not None


def test_load_image_checks_the_file(tmp_path):
    blank_png(tmp_path / "a.png")
    photos = PhotoSet(cameras=(reference_camera(),), images=(tmp_path / "a.png",), source=tmp_path,
                      format="test")
    assert photos.load_image(0).shape == (H, W, 3) and photos.load_depth(0) is None
    (tmp_path / "a.png").write_bytes(b"not a png")
    with pytest.raises(ScanError, match="not an image"):
        photos.load_image(0)


def test_photos_are_decoded_once_when_they_all_fit(tmp_path):
    from scantex.photos.photoset import ImageCache

    blank_png(tmp_path / "a.png")
    photos = PhotoSet(cameras=(reference_camera(),), images=(tmp_path / "a.png",), source=tmp_path,
                      format="test")
    first = photos.load_image(0)
    assert not first.flags.writeable  # shared with the later readers: no one may change it
    refined = dataclasses.replace(photos, cameras=(reference_camera(),))
    assert refined.load_image(0) is first and photos.load_image(0) is first
    # a set whose photos do not all fit is read from the files each time (the stages read the photos in
    # turn: a cache holding the last few would never be hit)
    small = dataclasses.replace(photos, image_cache=ImageCache(budget_mb=W * H * 3 / 2**20 / 2))
    assert small.load_image(0) is not small.load_image(0)
    np.testing.assert_array_equal(small.load_image(0), first)


def test_prefetched_photos_and_depth_maps_are_decoded_once(tmp_path):
    """:meth:`PhotoSet.prefetch` decodes every photo and depth map into the cache on a thread; the stages get
    those very arrays (read-only), and a photo asked for while it is being decoded is waited for, not decoded
    again. A file that cannot be read stops the prefetch quietly and fails where a stage reads it."""
    import threading
    import time

    from scantex.photos.photoset import ImageCache

    for k in range(3):
        Image.fromarray(np.full((H, W, 3), 40 * k, np.uint8)).save(tmp_path / f"{k}.png")
        Image.fromarray(np.full((H // 2, W // 2), 1000 + k, np.uint16)).save(tmp_path / f"d{k}.png")
    photos = PhotoSet(cameras=(reference_camera(),) * 3, images=[tmp_path / f"{k}.png" for k in range(3)],
                      depths=[tmp_path / f"d{k}.png" for k in range(3)], source=tmp_path, format="test")
    thread = photos.prefetch()
    thread.join(timeout=30)
    assert not thread.is_alive()
    cached = [photos.image_cache.get(tmp_path / f"{k}.png") for k in range(3)]
    depths = [photos.image_cache.get(tmp_path / f"d{k}.png", "depth") for k in range(3)]
    for k in range(3):
        assert photos.load_image(k) is cached[k] and cached[k][0, 0, 0] == 40 * k
        # the cache keeps the map's integers; each read is in metres, at the set's own scale
        assert depths[k].dtype.kind in "ui" and depths[k].shape == (H // 2, W // 2) and (depths[k] == 1000 + k).all()
        assert np.allclose(photos.load_depth(k), (1000 + k) / 1000)
        assert np.allclose(dataclasses.replace(photos, depth_scale=1e-4).load_depth(k), (1000 + k) / 10000)

    # a decode in flight is waited for: two threads asking at once decode the file once
    cache, calls, started = ImageCache(), [], threading.Event()

    def slow():
        calls.append(1)
        started.set()
        time.sleep(0.2)
        return np.zeros((2, 2, 3), np.uint8)

    first = []
    other = threading.Thread(target=lambda: first.append(cache.get_or_decode(tmp_path / "0.png", slow)))
    other.start()
    started.wait(5)
    second = cache.get_or_decode(tmp_path / "0.png", slow)
    other.join()
    assert len(calls) == 1 and second is first[0]

    # a set too large for its cache is not prefetched, and each read decodes again
    small = dataclasses.replace(photos, image_cache=ImageCache(budget_mb=W * H * 3 / 2**20))
    assert small.prefetch() is None and small.load_image(0) is not small.load_image(0)
    # a broken photo: the prefetch stops, the read raises
    (tmp_path / "1.png").write_bytes(b"not a png")
    fresh = dataclasses.replace(photos, image_cache=ImageCache())
    fresh.prefetch().join(timeout=30)
    assert fresh.image_cache.get(tmp_path / "0.png") is not None
    assert fresh.image_cache.get(tmp_path / "2.png") is None
    with pytest.raises(ScanError, match="not an image"):
        fresh.load_image(1)


def test_float_depth_maps_are_read_in_metres(tmp_path):
    """A float depth map (a 32-bit TIFF, a ``.npy``) is in metres whatever the set's ``depth_scale`` (which is for
    integer maps); zero, negative and NaN depths are no measurement. A map of more than one channel is refused
    with a one-line error naming the file."""
    depth = np.full((H // 2, W // 2), 1.25, np.float32)
    depth[0, 0], depth[0, 1], depth[0, 2] = 0.0, -1.0, np.nan
    Image.fromarray(np.zeros((H, W, 3), np.uint8)).save(tmp_path / "p.png")
    Image.fromarray(depth, mode="F").save(tmp_path / "d.tiff")
    np.save(tmp_path / "d.npy", depth.astype(np.float64))
    np.save(tmp_path / "bad.npy", np.ones((4, 4, 3), np.float32))
    for name in ("d.tiff", "d.npy"):
        photos = PhotoSet(cameras=(reference_camera(),), images=[tmp_path / "p.png"], depths=[tmp_path / name],
                          depth_scale=1e-4, source=tmp_path, format="test")
        read = photos.load_depth(0)
        assert read.dtype == np.float32 and read.shape == depth.shape
        assert np.isnan(read[0, :3]).all() and np.allclose(read[0, 3:], 1.25) and np.allclose(read[1:], 1.25)
        # written with the photos copied, the map keeps its format: read back the same
        back = load_photos(write_cameras_json(photos, tmp_path / f"copy_{name}", copy_images=True))
        assert back.depths[0].suffix == (tmp_path / name).suffix
        np.testing.assert_array_equal(back.load_depth(0), read)
        # a 3D Scanner App folder holds uint16 millimetre PNGs only: the float map is converted
        app = load_photos(write_3dscannerapp(photos, tmp_path / f"app_{name}"))
        assert app.depths[0].suffix == ".png" and app.stored_depth(0).dtype == np.uint16
        np.testing.assert_array_equal(app.load_depth(0), read)
    bad = PhotoSet(cameras=(reference_camera(),), images=[tmp_path / "p.png"], depths=[tmp_path / "bad.npy"],
                   source=tmp_path, format="test")
    with pytest.raises(ScanError, match=r"bad\.npy.*not a single-channel"):
        bad.load_depth(0)
    (tmp_path / "broken.npy").write_bytes(b"not numpy")
    broken = dataclasses.replace(bad, depths=(tmp_path / "broken.npy",))
    with pytest.raises(ScanError, match="cannot read the depth map"):
        broken.load_depth(0)
    # a depth map naming the photo's own file, read after the photo (which the cache then holds): the file is
    # checked as a depth map, not handed over as the photo's pixels (a stage crashed on them)
    mixed = dataclasses.replace(bad, depths=(tmp_path / "p.png",))
    mixed.load_image(0)
    with pytest.raises(ScanError, match=r"p\.png.*not a single-channel"):
        mixed.load_depth(0)


def test_integer_depth_in_other_units_is_written_in_millimetres(tmp_path):
    """An integer depth map in other units than millimetres (``depth_scale`` set in code: say a Kinect's 0.2 mm) is
    written as millimetres by every writer that keeps depth, whether the photos are copied or not: the formats read
    integers as millimetres, and the same map copied as it is would be read five times too far. A millimetre PNG is
    copied as it is."""
    raw = np.full((H // 2, W // 2), 6250, np.uint16)  # 1.25 m in units of 0.2 mm
    raw[0, 0] = 0
    Image.fromarray(np.zeros((H, W, 3), np.uint8)).save(tmp_path / "p.png")
    Image.fromarray(raw).save(tmp_path / "d.png")
    photos = PhotoSet(cameras=(reference_camera(),), images=[tmp_path / "p.png"], depths=[tmp_path / "d.png"],
                      depth_scale=2e-4, source=tmp_path, format="test")
    read = photos.load_depth(0)
    assert np.isnan(read[0, 0]) and np.allclose(read.flat[1:], 1.25)
    written = [write_cameras_json(photos, tmp_path / "copied"), write_cameras_json(photos, tmp_path / "referred",
                                                                                 copy_images=False),
               write_3dscannerapp(photos, tmp_path / "app"), write_nerfstudio(photos, tmp_path / "ns"),
               write_polycam(photos, tmp_path / "polycam")]
    for path in written:
        back = load_photos(path)
        assert Path(path if path.is_dir() else path.parent) in back.depths[0].parents
        np.testing.assert_allclose(back.load_depth(0), read)
    millimetres = dataclasses.replace(photos, depth_scale=1e-3)
    back = load_photos(write_3dscannerapp(millimetres, tmp_path / "app_mm"))
    assert back.depths[0].read_bytes() == (tmp_path / "d.png").read_bytes()


# ---- the real bolster capture (skipped without ../shared/data) ---------------------------------

def test_bolster_cameras_json():
    from scantex.io import load_scan

    folder = shared_scan("bolster_rgbd_posed")
    photos = load_photos(folder / "cameras.json")
    assert photos.format == "cameras.json" and len(photos) == 14
    assert all((c.width, c.height) == (1920, 1080) for c in photos.cameras)
    assert photos.load_image(0).shape == (1080, 1920, 3)
    depth = photos.load_depth(0)
    assert depth.shape == (540, 960) and 0.3 < np.nanmedian(depth) < 5.0  # metres
    # the file's R and C agree with world_to_camera, which is what scantex reads
    doc = json.loads((folder / "cameras.json").read_text())
    for frame, cam in zip(doc["frames"], photos.cameras):
        assert np.allclose(cam.R, frame["R"], atol=1e-6)
        assert np.allclose(cam.center, frame["C"], atol=1e-4)
    scan = load_scan(folder / "bloster.ply")
    good = 0
    for cam in photos.cameras:
        pix, z = cam.project(scan.positions)
        inside = (z > 0) & (pix[:, 0] > -0.5) & (pix[:, 0] < cam.width - 0.5) \
            & (pix[:, 1] > -0.5) & (pix[:, 1] < cam.height - 0.5)
        assert (z > 0).mean() > 0.99
        good += inside.mean() > 0.9
    assert good >= 12


def test_bolster_texrecon_folder_is_its_cameras_json():
    """The bolster's textureimages/ (G2LTex: one-line .cam files, the intrinsics in ../config_G2LTex.yml, depth
    maps beside the photos) reads as the same photos, poses, intrinsics and depth maps as its cameras.json."""
    folder = shared_scan("bolster_rgbd_posed")
    mve, ref = load_photos(folder / "textureimages"), load_photos(folder / "cameras.json")
    assert mve.format == "texrecon" and len(mve) == len(ref) == 14
    for i, (a, b) in enumerate(zip(mve.cameras, ref.cameras)):
        assert mve.images[i].resolve() == ref.images[i].resolve() and mve.depths[i].resolve() == ref.depths[i].resolve()
        np.testing.assert_array_equal(a.K, b.K)
        np.testing.assert_allclose(a.world_to_camera, b.world_to_camera, rtol=0, atol=1e-12)


def test_a_subset_of_numbered_photos_keeps_their_numbers():
    """A photo set's subset is numbered by position unless its photos carry their numbers in the capture (a tile's
    photos): then those, through any further subset."""
    cam = Camera.look_at((0, -1, 0), (0, 0, 0), width=6, height=4)
    photos = PhotoSet(cameras=(cam,) * 5, images=[Path(f"{i}.png") for i in range(5)], source=".", format="test")
    assert [photos.subset([1, 3, 4]).number(k) for k in range(3)] == [0, 1, 2]
    tile = dataclasses.replace(photos.subset([1, 3, 4]), numbers=(1, 3, 4))
    assert [tile.number(k) for k in range(3)] == [1, 3, 4] and tile.subset([2, 0]).numbers == (4, 1)
    with pytest.raises(ValueError, match="2 numbers for 3 cameras"):
        dataclasses.replace(tile, numbers=(1, 3))
