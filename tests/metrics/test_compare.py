"""``compare`` and ``scantex compare``: geometry and texture of B against A."""

from __future__ import annotations

import dataclasses
import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from scantex.errors import ScanError
from scantex.io import save_scan
from scantex.metrics.compare import compare, summary_lines
from scantex.photos import load_photos
from scantex.synth import make_wall
from scantex.views.planning import plan_views
from scantex.views.viewset import render_views, write_views
from tests.io.hostile import assert_clean_error, run_cli


@pytest.fixture(scope="module")
def demo():
    return make_wall(grid=(12, 10), gt_texture_size=128, scan_texture_size=32, seed=1)


def test_compare_same_geometry(demo):
    r = compare(demo.scan, demo.ground_truth, n_views=2, width=48, height=36, samples=2000)
    assert r["geometry"]["distance"]["hausdorff"] == 0.0
    assert r["geometry"]["volume"][0]["volume"] is None
    assert np.isfinite(r["atlas"]["psnr"]) and r["atlas"]["texels"] > 0
    assert r["renders"]["reference"] == "renders of a" and r["renders"]["b"]["views"] >= 1
    assert "Hausdorff 0" in summary_lines(r)
    json.dumps(r)


def test_compare_moved_vertex_and_other_layout(demo):
    positions = demo.scan.positions.copy()
    positions[20, 1] -= 0.1
    other = dataclasses.replace(demo.scan, positions=positions, uvs=demo.scan.uvs * 0.5)
    r = compare(demo.scan, other, n_views=2, width=48, height=36, samples=2000)
    assert r["geometry"]["distance"]["hausdorff"] == pytest.approx(0.1, rel=0.05)
    assert "skipped" in r["atlas"]


def test_cli_compare_refuses_missing_cameras(tmp_path, capsys, demo):
    save_scan(demo.scan, tmp_path / "scan.obj")
    rc, err = run_cli(capsys, "compare", tmp_path / "scan.obj", tmp_path / "scan.obj", "--cameras",
                      tmp_path / "nope.json")
    assert_clean_error(rc, err, "nope.json", "no such file or folder")
    (tmp_path / "bad.json").write_text('{"frames": [{"image": "a.png"}]}')
    rc, err = run_cli(capsys, "compare", tmp_path / "scan.obj", tmp_path / "scan.obj", "--cameras",
                      tmp_path / "bad.json")
    assert_clean_error(rc, err, "bad.json", "a JSON file of no known camera layout")


def test_cli_compare_against_photos(tmp_path, demo):
    save_scan(demo.scan, tmp_path / "scan.obj")
    save_scan(demo.ground_truth, tmp_path / "truth.obj")
    run = [sys.executable, "-m", "scantex"]
    # 'photos': unlit renders of the ground truth, as a capture's frames would be
    subprocess.run(run + ["render", str(tmp_path / "truth.obj"), "--views", "3", "--width", "64", "--height", "48",
                          "--unlit", "-o", str(tmp_path / "photos"), "-q"], check=True, timeout=300)
    proc = subprocess.run(run + ["compare", str(tmp_path / "scan.obj"), str(tmp_path / "truth.obj"),
                                 "--cameras", str(tmp_path / "photos" / "cameras.json"), "--samples", "2000",
                                 "--json", str(tmp_path / "m.json")], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    assert "renders of b vs photos" in proc.stdout
    m = json.loads((tmp_path / "m.json").read_text())
    assert m["renders"]["reference"] == "photos"
    # the truth's renders match the photos made from it far better than the degraded scan's
    assert m["renders"]["b"]["psnr"] > m["renders"]["a"]["psnr"] + 10
    assert m["geometry"]["distance"]["hausdorff"] == 0.0

    from PIL import Image

    Image.new("RGB", (10, 10)).save(tmp_path / "photos" / "view_000.png")
    with pytest.raises(ScanError, match="frame 0: view_000.png is 10x10 but its camera is 64x48"):
        load_photos(tmp_path / "photos" / "cameras.json")


@pytest.fixture(scope="module")
def capture(tmp_path_factory, demo):
    """The demo scan and its ground truth on disk, with 'photos': unlit renders of the truth from 4 cameras
    (``photos/cameras.json``)."""
    folder = tmp_path_factory.mktemp("capture")
    save_scan(demo.scan, folder / "scan.obj")
    save_scan(demo.ground_truth, folder / "truth.obj")
    cameras = plan_views(demo.ground_truth, 4, width=64, height=48, fov_deg=60.0, seed=0)
    write_views(render_views(demo.ground_truth, cameras, supersample=2), folder / "photos")
    return folder


def edited_capture(capture, tmp_path, edit) -> Path:
    """A copy of ``capture`` whose ``photos/cameras.json`` frames are ``edit(frames)``; returns the copy."""
    shutil.copytree(capture, tmp_path / "capture")
    cameras = tmp_path / "capture" / "photos" / "cameras.json"
    doc = json.loads(cameras.read_text())
    doc["frames"] = edit(doc["frames"])
    cameras.write_text(json.dumps(doc))
    return tmp_path / "capture"


def turned_away(frame: dict) -> dict:
    """``frame`` with its camera turned half a turn about its own y axis: it looks away from the wall."""
    flip = np.diag([-1.0, 1.0, -1.0, 1.0])
    return frame | {"world_to_camera": (flip @ np.asarray(frame["world_to_camera"])).tolist()}


def compare_cli(capsys, folder: Path, cameras: Path, *options) -> tuple[int, str, dict | None]:
    """``(exit status, stderr, metrics.json)`` of ``scantex compare scan.obj truth.obj --cameras CAMERAS``."""
    rc, err = run_cli(capsys, "compare", folder / "scan.obj", folder / "truth.obj", "--cameras", cameras,
                      "--samples", "2000", "--json", folder / "m.json", *options)
    return rc, err, json.loads((folder / "m.json").read_text()) if rc == 0 else None


@pytest.mark.parametrize("how", ["without width and height", "a folder"])
def test_cli_compare_reads_photos_as_enhance_does(tmp_path, capsys, capture, how):
    """A cameras.json without width/height (the images' sizes) and a folder holding one are read, as
    ``enhance --photos`` reads them."""
    if how == "without width and height":
        folder = edited_capture(capture, tmp_path, lambda frames: [
            {k: v for k, v in f.items() if k not in ("width", "height")} for f in frames])
        cameras = folder / "photos" / "cameras.json"
    else:
        folder = edited_capture(capture, tmp_path, lambda frames: frames)
        cameras = folder / "photos"
    rc, err, m = compare_cli(capsys, folder, cameras)
    assert rc == 0, err
    r = m["renders"]
    assert r["reference"] == "photos" and r["a"]["views"] == r["b"]["views"] == 4 and r["photos_left_out"] == 0
    assert r["b"]["psnr"] > r["a"]["psnr"] + 10  # the truth's renders match the photos made from it


def test_cli_compare_scores_a_repeated_photo_once(tmp_path, capsys, caplog, capture):
    folder = edited_capture(capture, tmp_path, lambda frames: frames + [frames[1]])
    with caplog.at_level("WARNING"):
        rc, err, m = compare_cli(capsys, folder, folder / "photos" / "cameras.json")
    assert rc == 0, err
    assert m["renders"]["a"]["views"] == m["renders"]["b"]["views"] == 4
    assert "1 frames name a photo an earlier frame names (e.g. view_001.png)" in caplog.text


def test_cli_compare_takes_max_distortion(tmp_path, capsys, caplog):
    """Lens distortion as enhance reads it: undone beyond --max-distortion (1 px by default), within it ignored
    with a warning (the photos are taken for pinhole images)."""
    from tests.io.hostile import write_cube
    from tests.photos.test_importers import write_opencv_colmap

    write_opencv_colmap(tmp_path, k1=0.2)
    mesh = write_cube(tmp_path / "scan")
    with caplog.at_level("WARNING"):
        rc, err = run_cli(capsys, "compare", mesh, mesh, "--cameras", tmp_path, "--samples", "100")
    assert rc == 0, err
    assert "lens distortion" not in caplog.text
    with caplog.at_level("WARNING"):
        rc, err = run_cli(capsys, "compare", mesh, mesh, "--cameras", tmp_path, "--samples", "100",
                          "--max-distortion", "3")
    assert rc == 0, err
    assert "ignoring a small lens distortion" in caplog.text


@pytest.mark.parametrize("blind", [[2], [0, 1, 3]])
def test_cli_compare_leaves_out_photos_that_see_no_mesh(tmp_path, capsys, caplog, capture, blind):
    """Photos that see none of A are left out with one warning naming them; when most are, it says what may be
    wrong with the poses (the bolster's camera-to-world poses read as world-to-camera: 13 of its 14)."""
    folder = edited_capture(capture, tmp_path, lambda frames: [turned_away(f) if i in blind else f
                                                               for i, f in enumerate(frames)])
    with caplog.at_level("WARNING"):
        rc, err, m = compare_cli(capsys, folder, folder / "photos" / "cameras.json")
    assert rc == 0, err
    r = m["renders"]
    assert r["a"]["views"] == r["b"]["views"] == 4 - len(blind) and r["photos_left_out"] == len(blind)
    (warning,) = [rec.getMessage() for rec in caplog.records if "see none of" in rec.getMessage()]
    names = ", ".join(f"view_{i:03d}.png" for i in blind)
    assert f"{len(blind)} of its 4 photos see none of the mesh scan.obj, left out of the scores: {names}" in warning
    assert ("world-to-camera" in warning) == (len(blind) > 2) and "\n" not in warning
    assert f"({4 - len(blind)} views; {len(blind)} photo" in summary_lines(m)


def test_cli_compare_refuses_photos_that_see_no_mesh(tmp_path, capsys, capture):
    """Camera-to-world poses given for world-to-camera (or a mesh out of the cameras' frame): no photo sees the
    mesh, and nothing is scored on no pixels."""
    folder = edited_capture(capture, tmp_path, lambda frames: [turned_away(f) for f in frames])
    rc, err, _ = compare_cli(capsys, folder, folder / "photos" / "cameras.json")
    assert_clean_error(rc, err, "cameras.json", "none of its 4 photos sees the mesh scan.obj",
                       "not in the cameras' frame", "world-to-camera")
    assert not (folder / "m.json").exists()


def test_cli_compare_warns_when_the_photos_do_not_fit_the_mesh(tmp_path, capsys, caplog):
    """Intrinsics for another image size pass the photos' reading and every photo sees the mesh: the scores meant
    nothing, silently. The alignment check (enhance's, which refuses) says so; --no-alignment-check skips it."""
    from scantex.photos.cameras_json import write_cameras_json
    from tests.photos.test_alignment import partial_wall_scan

    part, photos = partial_wall_scan(tmp_path)
    save_scan(part, tmp_path / "wall.obj")
    aligned = write_cameras_json(photos, tmp_path / "aligned")
    shrunk = json.loads(aligned.read_text())
    for f in shrunk["frames"]:
        f["K"] = (np.diag([2 / 3, 2 / 3, 1.0]) @ np.asarray(f["K"])).tolist()
    (tmp_path / "shrunk").mkdir()
    for f in shrunk["frames"]:
        shutil.copy(tmp_path / "aligned" / f["image"], tmp_path / "shrunk" / f["image"])
    (tmp_path / "shrunk" / "cameras.json").write_text(json.dumps(shrunk))

    def warned(cameras, *options) -> bool:
        caplog.clear()
        with caplog.at_level("WARNING"):
            rc, err = run_cli(capsys, "compare", tmp_path / "wall.obj", tmp_path / "wall.obj", "--cameras", cameras,
                              "--samples", "1000", *options)
        assert rc == 0, err
        return "does not look aligned with these photos" in caplog.text

    assert not warned(aligned)
    assert warned(tmp_path / "shrunk") and "intrinsics for the photos' own size" in caplog.text
    assert not warned(tmp_path / "shrunk", "--no-alignment-check")
