"""Photos taken through a distorting lens, read as pinhole images (:mod:`scantex.photos.lens`)."""

from __future__ import annotations

import json
import logging

import numpy as np
import pytest
from PIL import Image

from scantex.errors import ScanError
from scantex.photos import load_photos
from scantex.photos.lens import pinhole_lens, undistort_depth, undistort_image
from scantex.photos.photoset import Distortion
from scantex.views.camera import Camera

W, H = 160, 120
K0 = np.array([[120.0, 0.0, 81.0], [0.0, 118.0, 58.5], [0.0, 0.0, 1.0]])
LENSES = {"barrel": Distortion("OPENCV", (-0.18, 0.03), (0.002, -0.001)),
          "pincushion": Distortion("OPENCV", (0.12,)),
          "VisualSfM": Distortion("VisualSfM", (0.1,), inverse_radial=(-0.1,)),
          "fisheye": Distortion("OPENCV_FISHEYE", (0.02, -0.01, 0.003, 0.0), projection="equidistant"),
          "equisolid": Distortion("Metashape equisolid_fisheye", (0.01,), (0.001, 0.0), projection="equisolid")}


def pattern(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """A smooth colour pattern over normalised camera coordinates (what the scene looks like): ``(..., 3)``."""
    return np.stack([128 + 100 * np.sin(9 * x) * np.cos(7 * y), 128 + 100 * np.cos(11 * x + 3 * y),
                     128 + 90 * np.sin(6 * (x + y))], axis=-1)


def undistorted_point(distortion: Distortion, xd: np.ndarray, yd: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The undistorted normalised point of each distorted one: fixed-point iteration on the forward model, as
    OpenCV's ``undistortPoints`` solves it (independent of the code under test, which never inverts)."""
    x, y = xd.copy(), yd.copy()
    for _ in range(200):
        fx, fy = distortion.distort(x, y)
        x, y = x + (xd - fx), y + (yd - fy)
    return x, y


def distorted_photo(distortion: Distortion, K: np.ndarray = K0) -> np.ndarray:
    """The pattern as a lens with ``distortion`` and intrinsics ``K`` draws it: ``(H, W, 3) uint8``."""
    u, v = np.meshgrid(np.arange(W, dtype=np.float64), np.arange(H, dtype=np.float64))
    yd = (v - K[1, 2]) / K[1, 1]
    xd = (u - K[0, 2]) / K[0, 0]
    return np.clip(np.round(pattern(*undistorted_point(distortion, xd, yd))), 0, 255).astype(np.uint8)


def pinhole_photo(K: np.ndarray) -> np.ndarray:
    u, v = np.meshgrid(np.arange(W, dtype=np.float64), np.arange(H, dtype=np.float64))
    return pattern((u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1])


@pytest.mark.parametrize("name", list(LENSES))
def test_an_undistorted_photo_is_the_pinhole_view(name):
    """Each pixel of the undistorted photo shows what a pinhole camera of the lens's K sees there (to the
    bilinear sampling's error on a smooth pattern); the photo as stored, taken for that pinhole, does not."""
    distortion = LENSES[name]
    lens = pinhole_lens(Camera(K0, np.eye(4), W, H), distortion, "cameras.json", "frame 0")
    stored = distorted_photo(distortion)
    truth = pinhole_photo(lens.K)
    out = undistort_image(stored, lens)
    assert out.shape == stored.shape and out.dtype == np.uint8
    assert np.abs(out - truth).max() < 4
    assert np.abs(stored - pinhole_photo(K0)).max() > 15
    # the view keeps the principal point and scales the focal lengths alike
    np.testing.assert_allclose(lens.K[:2, 2], K0[:2, 2])
    assert lens.K[0, 0] / K0[0, 0] == pytest.approx(lens.K[1, 1] / K0[1, 1])


@pytest.mark.parametrize("name", list(LENSES))
def test_the_pinhole_view_reaches_the_photos_edges_and_no_further(name):
    """No pixel of the view without a source (COLMAP's ``blank_pixels 0``), and no narrower than that: its
    border touches the photo's edge."""
    distortion = LENSES[name]
    lens = pinhole_lens(Camera(K0, np.eye(4), W, H), distortion, "cameras.json", "frame 0")
    x, y = lens.source_pixels((W, H))
    assert x.min() >= -1e-6 and y.min() >= -1e-6 and x.max() <= W - 1 + 1e-6 and y.max() <= H - 1 + 1e-6
    gap = min(x.min(), y.min(), W - 1 - x.max(), H - 1 - y.max())
    assert gap < 0.01
    # a barrel lens's view is wider than its photo's K (the corners it drew inward are reached), a pincushion's
    # narrower
    expected = {"barrel": lambda s: s < 1, "pincushion": lambda s: s > 1, "VisualSfM": lambda s: s > 1,
                "fisheye": lambda s: 0.5 < s < 1, "equisolid": lambda s: 0.5 < s < 1}
    assert expected[name](lens.K[0, 0] / K0[0, 0])


def test_the_compiled_undistortion_is_its_numpy_twin():
    """The compiled bilinear sampling against ``map_coordinates``: the same levels, including points beyond the
    photo's border (extended)."""
    from scantex import jit
    from scantex.photos.lens import _undistort_kernel, undistort_image_reference

    kernel = jit.compiled(_undistort_kernel)
    if kernel is None:
        pytest.skip("numba is not installed")
    rng = np.random.default_rng(3)
    image = rng.integers(0, 256, (37, 53, 3), dtype=np.uint8)
    x = rng.uniform(-3, 56, (20, 30)).astype(np.float32)
    y = rng.uniform(-3, 40, (20, 30)).astype(np.float32)
    out = np.empty((20, 30, 3), np.uint8)
    kernel(image, x, y, out)
    assert np.abs(out.astype(int) - undistort_image_reference(image, x, y)).max() <= 1


def test_a_depth_map_is_undistorted_with_its_photo():
    """A depth map of the stored photo's view (at half its size) is resampled nearest into the pinhole view:
    each pixel's depth is the stored map's at the point the lens drew it."""
    distortion = LENSES["barrel"]
    lens = pinhole_lens(Camera(K0, np.eye(4), W, H), distortion, "cameras.json", "frame 0")
    h, w = H // 2, W // 2
    depth = np.arange(h * w, dtype=np.float32).reshape(h, w)  # every pixel its own value
    out = undistort_depth(depth, lens)
    x, y = lens.source_pixels((w, h), (w, h))
    expect = depth[np.clip(np.floor(y + 0.5), 0, h - 1).astype(int), np.clip(np.floor(x + 0.5), 0, w - 1).astype(int)]
    assert np.isfinite(out).all()
    np.testing.assert_array_equal(out, expect)


def test_a_fisheye_wider_than_a_pinhole_can_keep_is_cropped(caplog):
    """A fisheye of 230 degrees across (its edges beyond 90 degrees from the axis, where no pinhole sees): the
    pinhole view takes half its focal length, the middle of the photo, with no pixel lacking a source."""
    K = np.array([[40.0, 0.0, 79.5], [0.0, 40.0, 59.5], [0.0, 0.0, 1.0]])
    with caplog.at_level(logging.INFO):
        lens = pinhole_lens(Camera(K, np.eye(4), W, H), Distortion("OPENCV_FISHEYE", (), projection="equidistant"),
                            "cameras.txt", "image 'a.png'")
    assert "draws a wider view than a pinhole of half its focal length keeps: the photo's edges are cropped" in (
        caplog.text)
    assert lens.K[0, 0] == pytest.approx(20.0)
    x, y = lens.source_pixels((W, H))
    assert x.min() > 0 and y.min() > 0 and x.max() < W - 1 and y.max() < H - 1
    stored = distorted_photo(lens.distortion, K)
    middle = np.s_[42:78, 62:98]  # within 45 degrees of the axis: further out the fisheye squeezes the pattern
    assert np.abs(undistort_image(stored, lens)[middle] - pinhole_photo(lens.K)[middle]).max() < 6


def test_a_folding_model_is_refused():
    """Coefficients that fold the view over within the photo describe no lens: one line naming the file."""
    with pytest.raises(ScanError, match=r"cameras.txt: image 'a.png': lens distortion \(OPENCV\) folds"):
        pinhole_lens(Camera(K0, np.eye(4), W, H), Distortion("OPENCV", (-0.9,)), "cameras.txt", "image 'a.png'")


def test_visualsfm_is_solved_exactly():
    """VisualSfM's model maps distorted to undistorted points: :meth:`Distortion.distort` solves it."""
    d = Distortion("VisualSfM", (0.2,), inverse_radial=(-0.2,))
    x, y = np.array([0.3, 0.6, 0.0, -0.7]), np.array([0.2, -0.1, 0.0, 0.4])
    xd, yd = d.distort(x, y)
    r2 = xd * xd + yd * yd
    np.testing.assert_allclose(xd * (1 - 0.2 * r2), x, atol=1e-12)
    np.testing.assert_allclose(yd * (1 - 0.2 * r2), y, atol=1e-12)


# ---- read through the importers ------------------------------------------------------------------------------

def write_distorted_colmap(folder, distortion: Distortion, n: int = 2):
    """A COLMAP text model of ``n`` photos of the pattern through an ``OPENCV`` (``OPENCV_FISHEYE``) lens (COLMAP's
    pixel centres)."""
    (folder / "images").mkdir(parents=True)
    k = (distortion.radial + (0.0,) * 4)[:4]
    p1, p2 = distortion.tangential
    model, params = ("OPENCV_FISHEYE", k) if distortion.is_fisheye else ("OPENCV", (k[0], k[1], p1, p2))
    (folder / "cameras.txt").write_text(f"1 {model} {W} {H} {K0[0, 0]} {K0[1, 1]} {K0[0, 2] + 0.5} {K0[1, 2] + 0.5} "
                                        + " ".join(map(str, params)) + "\n")
    lines = []
    for i in range(n):
        Image.fromarray(distorted_photo(distortion)).save(folder / "images" / f"p{i}.png")
        lines.append(f"{i + 1} 1 0 0 0 0 0 {i} 1 p{i}.png\n\n")
    (folder / "images.txt").write_text("".join(lines))


def test_colmap_photos_through_a_lens_are_read_undistorted(tmp_path, caplog):
    """COLMAP's ``OPENCV`` model straight from ``colmap mapper`` (refused before: 'undistort the photos
    first'): read as pinhole photos, the cameras the view's, each photo its pinhole view."""
    distortion = LENSES["barrel"]
    write_distorted_colmap(tmp_path, distortion)
    assert distortion.max_shift_px(Camera(K0, np.eye(4), W, H)) > 5
    with caplog.at_level(logging.WARNING):
        photos = load_photos(tmp_path)
    assert "distortion" not in caplog.text
    assert len(photos) == 2 and all(lens is not None for lens in photos.lenses)
    assert photos.distortions[0] == distortion
    lens = photos.lenses[0]
    np.testing.assert_allclose(photos.cameras[0].K, lens.K)
    np.testing.assert_allclose(lens.photo_K, K0, atol=1e-12)
    assert np.abs(photos.load_image(1).astype(float) - pinhole_photo(lens.K)).max() < 4
    # within --max-distortion the photo is read as stored, with a warning (as before)
    caplog.clear()
    with caplog.at_level(logging.WARNING):
        ignored = load_photos(tmp_path, max_distortion_px=50)
    assert "ignoring a small lens distortion (OPENCV" in caplog.text
    assert ignored.lenses == (None, None)
    np.testing.assert_array_equal(ignored.load_image(0), distorted_photo(distortion))


def write_visualsfm_scene(folder, distortion: Distortion) -> None:
    """A texrecon scene of one photo of the pattern through VisualSfM's one-term lens (``.cam`` line 2: ``f d0 0
    paspect ppx ppy``, ``f`` over the larger side, the principal point a share from the corner)."""
    folder.mkdir(parents=True)
    Image.fromarray(distorted_photo(distortion)).save(folder / "view.png")
    lens = (K0[0, 0] / W, distortion.inverse_radial[0], 0.0, K0[1, 1] / K0[0, 0], (K0[0, 2] + 0.5) / W,
            (K0[1, 2] + 0.5) / H)
    (folder / "view.cam").write_text("0 0 0 1 0 0 0 1 0 0 0 1\n" + " ".join(repr(float(v)) for v in lens) + "\n")


@pytest.mark.parametrize("name", ["barrel", "fisheye", "VisualSfM"])
def test_writers_keep_an_undistorted_photo_right(tmp_path, name):
    """A format that holds the lens exactly (COLMAP, nerfstudio, Metashape and Meshroom an OpenCV lens or a fisheye,
    cameras.json any) gets the photo as stored with its lens; one that does not (Polycam, 3D Scanner App, MVE,
    texrecon; VisualSfM's inverse model but in cameras.json) gets the undistorted photo with the pinhole camera: read
    back, each gives the same pinhole view as the set it was written from."""
    from scantex.photos import (write_3dscannerapp, write_cameras_json, write_colmap_binary, write_colmap_text,
                                write_meshroom, write_metashape, write_mve, write_mve_scene, write_nerfstudio,
                                write_polycam)

    if name == "VisualSfM":
        write_visualsfm_scene(tmp_path / "in", LENSES[name])
        holding = (write_cameras_json,)
    else:
        write_distorted_colmap(tmp_path / "in", LENSES[name], n=1)
        holding = (write_colmap_text, write_colmap_binary, write_cameras_json, write_nerfstudio, write_metashape,
                   write_meshroom)
    photos = load_photos(tmp_path / "in")
    assert photos.distortions[0].model == LENSES[name].model and photos.lenses[0] is not None
    view = photos.load_image(0).astype(int)
    assert np.abs(view - pinhole_photo(photos.cameras[0].K)).max() < 4
    for writer in (write_colmap_text, write_colmap_binary, write_cameras_json, write_nerfstudio, write_metashape,
                   write_meshroom, write_polycam, write_3dscannerapp, write_mve, write_mve_scene):
        out = writer(photos, tmp_path / writer.__name__)
        again = load_photos(out)
        np.testing.assert_allclose(again.cameras[0].K, photos.cameras[0].K, atol=1e-6, err_msg=writer.__name__)
        assert np.abs(again.load_image(0).astype(int) - view).max() <= 1, writer.__name__
        assert (again.lenses[0] is not None) == (writer in holding), writer.__name__


def test_bad_distortion_in_cameras_json_is_one_line(tmp_path):
    """A ``tangential`` of 3 numbers crashed on unpacking; NaN coefficients were refused as 'no pinhole view'."""
    from tests.io.hostile import write_photos

    cams = write_photos(tmp_path, n=1)
    doc = json.loads(cams.read_text())
    for distortion, message in (({"model": "OPENCV", "tangential": [0, 0, 0]}, "tangential is not 2 numbers"),
                                ({"model": "OPENCV", "radial": [float("nan")]}, "coefficients that are not finite")):
        doc["frames"][0]["distortion"] = distortion
        cams.write_text(json.dumps(doc))
        with pytest.raises(ScanError, match=f"cameras.json: frame 0: .*{message}"):
            load_photos(cams)


def test_a_registered_depth_camera_sees_through_no_colour_lens():
    """A depth map of a depth camera registered to a distorted photo (its own pinhole K): each pixel of the pinhole
    view takes the depth along its ray through that K alone."""
    from scantex.photos.photoset import depth_warp

    lens = pinhole_lens(Camera(K0, np.eye(4), W, H), LENSES["barrel"], "cameras.json", "frame 0")
    K_depth, (w, h) = np.array([[70.0, 0.0, 41.0], [0.0, 70.0, 29.0], [0.0, 0.0, 1.0]]), (80, 60)
    depth = np.arange(w * h, dtype=np.float32).reshape(h, w)
    out = undistort_depth(depth, lens, depth_warp(K_depth, (w, h), K0, (W, H)))
    u = (np.arange(w) + 0.5) * (W / w) - 0.5  # the view's pixels at the map's size, at the photo's
    v = (np.arange(h) + 0.5) * (H / h) - 0.5
    x, y = (u[None, :] - lens.K[0, 2]) / lens.K[0, 0], (v[:, None] - lens.K[1, 2]) / lens.K[1, 1]
    ud, vd = np.floor(K_depth[0, 0] * x + K_depth[0, 2] + 0.5), np.floor(K_depth[1, 1] * y + K_depth[1, 2] + 0.5)
    ud, vd = np.broadcast_arrays(ud, vd)
    inside = (ud >= 0) & (ud < w) & (vd >= 0) & (vd < h)
    expect = np.full((h, w), np.nan, np.float32)
    expect[inside] = depth[vd[inside].astype(int), ud[inside].astype(int)]
    np.testing.assert_array_equal(out, expect)


def test_cli_info_says_the_photos_are_undistorted(tmp_path, capsys):
    from scantex.cli import main
    from tests.io.hostile import write_cube

    write_distorted_colmap(tmp_path, LENSES["barrel"])
    mesh = write_cube(tmp_path / "scan")
    rc = main(["info", str(mesh), "--photos", str(tmp_path)])
    out = capsys.readouterr().out
    assert rc == 0
    assert "lens distortion: 2 photos undistorted when read (OPENCV, the pinhole view's focal length" in out


def test_compare_scores_photos_through_a_lens_as_pinhole_ones(tmp_path, capsys):
    """``scantex compare`` against photos of the demo's truth drawn through a lens: undistorted when read, the
    truth's renders match them as they match pinhole photos (40.2 dB); taken for pinhole photos (within
    ``--max-distortion``), they do not (21.1 dB)."""
    from scantex.io import save_scan
    from scantex.synth import make_wall
    from scantex.views.planning import plan_views
    from scantex.views.render import render
    from scantex.views.raycast import RayCaster
    from tests.io.hostile import run_cli

    demo = make_wall(grid=(12, 10), gt_texture_size=128, scan_texture_size=32, seed=1)
    save_scan(demo.scan, tmp_path / "scan.obj")
    save_scan(demo.ground_truth, tmp_path / "truth.obj")
    distortion = LENSES["barrel"]
    caster = RayCaster(demo.ground_truth.positions, demo.ground_truth.faces)
    frames = []
    (tmp_path / "photos").mkdir()
    for i, cam in enumerate(plan_views(demo.ground_truth, 3, width=W, height=H, fov_deg=60.0, seed=0)):
        # render the pinhole view on a canvas twice as large (the lens draws more than its K's view), then draw it
        # through the lens
        big = Camera(np.array([[cam.K[0, 0], 0, cam.K[0, 2] + W / 2], [0, cam.K[1, 1], cam.K[1, 2] + H / 2],
                               [0, 0, 1]]), cam.world_to_camera, 2 * W, 2 * H)
        rgb, _ = render(demo.ground_truth, big, caster, supersample=2)
        u, v = np.meshgrid(np.arange(W, dtype=np.float64), np.arange(H, dtype=np.float64))
        x, y = undistorted_point(distortion, (u - cam.K[0, 2]) / cam.K[0, 0], (v - cam.K[1, 2]) / cam.K[1, 1])
        from scipy.ndimage import map_coordinates

        bx, by = big.K[0, 0] * x + big.K[0, 2], big.K[1, 1] * y + big.K[1, 2]
        drawn = np.stack([map_coordinates(np.asarray(rgb, np.float64)[..., c], [by, bx], order=1)
                          for c in range(3)], -1)
        scale = 255.0 if np.asarray(rgb).dtype.kind == "f" and np.asarray(rgb).max() <= 1.0 else 1.0
        Image.fromarray(np.clip(np.round(drawn * scale), 0, 255).astype(np.uint8)).save(tmp_path / "photos" /
                                                                                          f"p{i}.png")
        frames.append({"image": f"p{i}.png", "width": W, "height": H, "K": cam.K.tolist(),
                       "world_to_camera": cam.world_to_camera.tolist(),
                       "distortion": {"model": "OPENCV", "radial": list(distortion.radial),
                                      "tangential": list(distortion.tangential)}})
    (tmp_path / "photos" / "cameras.json").write_text(json.dumps({"frames": frames}))

    def truth_psnr(*options) -> float:
        rc, err = run_cli(capsys, "compare", tmp_path / "scan.obj", tmp_path / "truth.obj", "--cameras",
                          tmp_path / "photos", "--samples", "500", "--json", tmp_path / "m.json", *options)
        assert rc == 0, err
        return json.loads((tmp_path / "m.json").read_text())["renders"]["b"]["psnr"]

    undistorted, as_stored = truth_psnr(), truth_psnr("--max-distortion", "100")
    assert undistorted > 30
    assert undistorted > as_stored + 8


def test_the_run_records_and_says_the_photos_it_undistorted(tmp_path):
    """``metrics.json``'s photos say how many were undistorted, through which model, at what focal-length scale; the
    terminal's summary says it in words."""
    from scantex.cli import enhance_summary
    from scantex.photos.lens import lens_summary

    write_distorted_colmap(tmp_path, LENSES["barrel"])
    photos = load_photos(tmp_path)
    summary = lens_summary(photos.lenses)
    scale = photos.lenses[0].K[0, 0] / K0[0, 0]
    assert summary == {"photos": 2, "models": ["OPENCV"], "focal_scale": [round(scale, 4)] * 2}
    assert lens_summary((None, None)) is None
    metrics = {"geometry": {"arrays_identical": True, "vertices": [8, 8], "faces": [12, 12],
                            "distance": {"hausdorff": 0.0, "mean": 0.0}},
               "seam_visibility": {"input": 1.0, "enhanced": 0.5}, "photos": {"undistorted": summary},
               "timings_s": {"total": 1.0}}
    assert f"lens: 2 photos undistorted when read (OPENCV, the pinhole view's focal length {scale:.3f} times" in (
        enhance_summary(metrics))
