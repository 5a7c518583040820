"""End to end through the command line, at toy size, and the cost of ``import scantex``."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
from PIL import Image

from scantex.io import load_scan, save_scan
from scantex.synth import make_wall


def run(*args: str, timeout: int = 300) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "scantex", *args], capture_output=True, text=True, timeout=timeout)


def test_render_and_view_end_to_end(tmp_path):
    demo = make_wall(grid=(24, 18), gt_texture_size=256, scan_texture_size=64)
    save_scan(demo.scan, tmp_path / "wall.obj")
    proc = run("render", str(tmp_path / "wall.obj"), "--views", "3", "--width", "64", "--height", "48",
               "-o", str(tmp_path / "renders"), "-q")
    assert proc.returncode == 0, proc.stderr
    doc = json.loads((tmp_path / "renders" / "cameras.json").read_text())
    assert len(doc["frames"]) == 3
    for frame in doc["frames"]:
        image = np.asarray(Image.open(tmp_path / "renders" / frame["image"]))
        assert image.shape == (48, 64, 3)
        assert (image.max(axis=2) > 0).mean() > 0.2  # the wall is in view
        assert np.array(frame["K"]).shape == (3, 3) and np.array(frame["world_to_camera"]).shape == (4, 4)
    assert {f["split"] for f in doc["frames"]} == {"train", "test"}

    proc = run("view", str(tmp_path / "wall.obj"), "-o", str(tmp_path / "view.html"), "-q")
    assert proc.returncode == 0, proc.stderr
    assert (tmp_path / "view.html").stat().st_size > 1_000_000  # plotly.js embedded

    # an existing output folder is kept unless --overwrite
    proc = run("render", str(tmp_path / "wall.obj"), "--views", "2", "-o", str(tmp_path / "renders"))
    assert proc.returncode == 2 and "already exists" in proc.stderr
    assert len(json.loads((tmp_path / "renders" / "cameras.json").read_text())["frames"]) == 3


def test_demo_scan_room_variant(tmp_path):
    proc = run("demo-scan", "--variant", "room", "--photos", "3", "-o", str(tmp_path / "demo"), "-q")
    assert proc.returncode == 0, proc.stderr
    scan = load_scan(tmp_path / "demo" / "scan.obj")
    truth = load_scan(tmp_path / "demo" / "ground_truth.obj")
    assert np.array_equal(scan.positions, truth.positions) and np.array_equal(scan.faces, truth.faces)
    assert scan.materials[0].image.shape[0] < truth.materials[0].image.shape[0]
    from scantex.photos import load_photos, require_alignment

    photos = load_photos(tmp_path / "demo" / "photos")
    assert len(photos) == 3 and photos.load_image(0).shape == (480, 640, 3)
    assert require_alignment(scan, photos).ok


def test_help_explains_every_command():
    proc = run("--help")
    assert proc.returncode == 0
    for command in ("demo-scan", "render", "view", "info"):
        assert command in proc.stdout
    proc = run("render", "--help")
    assert "--views" in proc.stdout and "OpenCV" in proc.stdout


def test_import_is_cheap():
    code = "import sys, scantex; print(sorted(m for m in ('torch', 'trimesh', 'plotly', 'scipy') if m in sys.modules))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert out.stdout.strip() == "[]"


def test_a_reader_that_goes_away_is_no_error(tmp_path, wall):
    """`scantex info scan.obj | head -1`: the pipe closes before scantex prints; no message blames the file."""
    save_scan(wall, tmp_path / "wall.obj")
    proc = subprocess.Popen([sys.executable, "-m", "scantex", "info", str(tmp_path / "wall.obj")],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    proc.stdout.close()  # long before the scan is read and its summary printed
    stderr = proc.stderr.read().decode()
    assert proc.wait(timeout=120) == 141 and stderr == ""


def test_the_entry_point_exits_with_mains_code_after_freezing_the_heap(monkeypatch):
    """``scantex`` and ``python -m scantex`` run :func:`scantex.cli.run`: main's exit code, and the heap frozen
    first so that the interpreter's shutdown does not collect it all again (0.5 s of a 10 s run); the run itself
    under :data:`scantex.cli.GC_THRESHOLDS`."""
    import gc

    import pytest

    from scantex import cli

    calls = []
    monkeypatch.setattr(cli, "main", lambda catch_sigterm: calls.append(("main", catch_sigterm)) or 3)
    monkeypatch.setattr(gc, "freeze", lambda: calls.append("freeze"))
    monkeypatch.setattr(gc, "set_threshold", lambda *t: calls.append(t))
    with pytest.raises(SystemExit) as exit_:
        cli.run()
    # full collections made rarer for the run (Python's thresholds: 700, 10, 10)
    assert exit_.value.code == 3 and calls == [cli.GC_THRESHOLDS, ("main", True), "freeze"]
    assert cli.GC_THRESHOLDS[2] > gc.get_threshold()[2]
    proc = run("--version")
    assert proc.returncode == 0 and proc.stdout.startswith("scantex ")


def test_diffusion_alone_runs_the_refiner_it_belongs_to(tmp_path, capsys):
    """``--diffusion`` denoises the refiner's views; in mesh-only mode the refiner does not run over the input's
    texels unless asked, so ``--diffusion`` alone ran nothing and said nothing. It now runs the refiner, and
    ``--no-refine --diffusion`` is refused in one line."""
    import dataclasses

    from scantex.refine.config import RefineConfig
    from tests.io.hostile import TINY, assert_clean_error, run_cli, write_cube, write_tiny_config

    mesh = write_cube(tmp_path / "scan")
    tiny = dataclasses.replace(TINY, views=dataclasses.replace(TINY.views, width=96, height=72),
                               refine=RefineConfig(enabled=False, steps=2, batch=2, crop=32, max_views=2,
                                                   diffusion_steps=2))
    config = write_tiny_config(tmp_path / "tiny.json", tiny)
    rc, err = run_cli(capsys, "enhance", mesh, "-o", tmp_path / "out", "--config", config, "--diffusion", "-q")
    assert rc == 0, err
    metrics = json.loads((tmp_path / "out" / "metrics.json").read_text())
    written = json.loads((tmp_path / "out" / "config.json").read_text())["refine"]
    assert written["enabled"] and written["over_input"] and written["diffusion"]
    assert "refine" in metrics or "refine_discarded" in metrics["bake"].get("safety", {})  # it ran
    assert_clean_error(*run_cli(capsys, "enhance", mesh, "-o", tmp_path / "out2", "--config", config,
                                "--diffusion", "--no-refine", "-q"), "--no-refine")


def test_refine_with_photos_says_photo_mode_skips_the_refiner(tmp_path, capsys, caplog, monkeypatch):
    """Photo mode does not run the refiner unless refine.with_photos: --refine there changed nothing, silently."""
    import scantex.pipeline.enhance as pipeline
    from scantex.errors import ScanError
    from tests.io.hostile import run_cli, write_cube, write_photos, write_tiny_config

    def stop(*args, **kwargs):
        raise ScanError(None, "stopped here: the test needs only what comes before the run")

    monkeypatch.setattr(pipeline, "enhance", stop)
    mesh = write_cube(tmp_path / "scan")
    config = write_tiny_config(tmp_path / "tiny.json")
    photos = write_photos(tmp_path / "photos")
    with caplog.at_level("WARNING"):
        run_cli(capsys, "enhance", mesh, "--photos", photos, "-o", tmp_path / "out", "--config", config, "--refine")
    assert "--refine: photo mode does not run the refiner" in caplog.text


def test_texture_format_jpeg_writes_smaller_atlases_and_says_their_loss(tmp_path, capsys):
    """``--texture-format jpeg``: the OBJ's atlases are JPEGs its MTL names, metrics.json and the summary give
    the codec's loss against the atlas scored, config.json records the choice (a rerun with --config writes
    JPEG again), and a quality out of range is refused in one line. The geometry is identical, as always."""
    from tests.io.hostile import TINY, assert_clean_error, run_cli, write_cube, write_tiny_config

    mesh = write_cube(tmp_path / "scan")
    config = write_tiny_config(tmp_path / "tiny.json", TINY)
    capsys.readouterr()
    from scantex.cli import main

    assert main([str(a) for a in ("enhance", mesh, "-o", tmp_path / "out", "--config", config,
                                  "--texture-format", "jpeg", "--jpeg-quality", "80")]) == 0
    out = capsys.readouterr().out
    folder = tmp_path / "out"
    metrics = json.loads((folder / "metrics.json").read_text())
    assert metrics["geometry"]["arrays_identical"]
    assert metrics["output"]["texture_format"] == "jpeg" and metrics["output"]["jpeg_quality"] == 80
    psnr = list(metrics["output"]["atlas_psnr_db"].values())
    assert psnr and all(20 < p < 100 for p in psnr)
    assert f"atlas written as JPEG, quality 80: {min(psnr):.1f} dB PSNR against the lossless atlas" in out
    jpgs = sorted(p.name for p in folder.glob("enhanced_*.jpg"))
    assert jpgs and not list(folder.glob("enhanced_*.png"))
    assert all(f"map_Kd {name}" in (folder / "enhanced.mtl").read_text() for name in jpgs)
    written = json.loads((folder / "config.json").read_text())["output"]
    assert written == {"texture_format": "jpeg", "jpeg_quality": 80}
    rc, err = run_cli(capsys, "enhance", mesh, "-o", tmp_path / "again", "--config", folder / "config.json", "-q")
    assert rc == 0, err
    assert list((tmp_path / "again").glob("enhanced_*.jpg"))
    assert_clean_error(*run_cli(capsys, "enhance", mesh, "-o", tmp_path / "bad", "--jpeg-quality", "101", "-q"),
                       "--jpeg-quality")
    assert_clean_error(*run_cli(capsys, "enhance", mesh, "-o", tmp_path / "bad", "--texture-format", "png",
                                "--jpeg-quality", "70", "-q"), "--jpeg-quality", "not png")
    assert not (tmp_path / "bad").exists()
    rc, err = run_cli(capsys, "enhance", mesh, "-o", tmp_path / "q", "--config", config, "--jpeg-quality", "70", "-q")
    assert rc == 0, err  # a quality alone asks for JPEG
    rc, err = run_cli(capsys, "enhance", mesh, "-o", tmp_path / "jpg", "--config", config, "--texture-format", "jpg",
                      "-q")
    assert rc == 0 and list((tmp_path / "jpg").glob("enhanced_*.jpg")), err  # the files' own suffix is understood
    assert json.loads((tmp_path / "q" / "config.json").read_text())["output"] == {"texture_format": "jpeg",
                                                                                 "jpeg_quality": 70}
    # PNG, the default: no such line, no output entry
    assert main([str(a) for a in ("enhance", mesh, "-o", tmp_path / "png", "--config", config)]) == 0
    out = capsys.readouterr().out
    assert "enhanced scan written" in out and "JPEG" not in out
    assert "output" not in json.loads((tmp_path / "png" / "metrics.json").read_text())
    assert list((tmp_path / "png").glob("enhanced_*.png"))


def test_a_png_atlas_far_larger_than_the_inputs_jpeg_says_how_to_write_a_smaller_one(tmp_path, capsys):
    """A capture app's heavily compressed JPEG atlas comes back as a PNG several times its size: the summary
    says so and names --texture-format jpeg; not for a PNG input, nor once JPEG is asked for."""
    import dataclasses

    from scantex.cli import main
    from scantex.io.images import TextureEncoder
    from tests.conftest import grid_wall
    from tests.io.hostile import TINY, write_tiny_config

    rng = np.random.default_rng(0)
    noisy = rng.integers(0, 256, (256, 256, 3), dtype=np.uint8)  # PNG cannot shrink noise; JPEG at 20 can
    wall = grid_wall(8, 6)
    wall = wall.replace(materials=(dataclasses.replace(wall.materials[0], image=noisy),))
    save_scan(wall, tmp_path / "app" / "scan.obj", encoder=TextureEncoder("jpeg", 20))
    save_scan(wall, tmp_path / "png" / "scan.obj")
    config = write_tiny_config(tmp_path / "tiny.json", TINY.override(bake__texture_size=256))

    def summary(mesh, out, *extra):
        capsys.readouterr()
        assert main([str(a) for a in ("enhance", mesh, "-o", tmp_path / out, "--config", config, *extra)]) == 0
        return capsys.readouterr().out

    said = summary(tmp_path / "app" / "scan.obj", "a")
    line = next(ln for ln in said.splitlines() if ln.startswith("atlas written losslessly as PNG"))
    assert "the input's JPEG" in line and line.endswith("--texture-format jpeg writes a smaller one")
    assert "losslessly" not in summary(tmp_path / "png" / "scan.obj", "b")
    save_scan(wall, tmp_path / "glb" / "scan.glb", encoder=TextureEncoder("jpeg", 20))  # its atlas inside it
    said = summary(tmp_path / "glb" / "scan.glb", "g")
    line = next(ln for ln in said.splitlines() if ln.startswith("enhanced.glb holds its atlas as a lossless PNG"))
    assert "the input GLB" in line and line.endswith("--texture-format jpeg writes a smaller one")
    assert "lossless PNG" not in summary(tmp_path / "glb" / "scan.glb", "h", "--texture-format", "jpeg")
    assert "losslessly" not in summary(tmp_path / "app" / "scan.obj", "c", "--texture-format", "jpeg")


def test_repeated_warnings_are_counted_not_each_shown(capsys):
    """A warning of one kind (one module's message, whatever its values) is shown 3 times, the rest counted in
    one line at the end: a capture's hundred depth maps in centimetres gave a hundred lines of one warning."""
    import io
    import logging

    from scantex.cli import RepeatedWarnings

    stream = io.StringIO()
    handler = logging.StreamHandler(stream)
    handler.setFormatter(logging.Formatter("%(levelname)s: %(message)s"))
    root = logging.getLogger()
    root.addHandler(handler)
    log = logging.getLogger("scantex.photos.training")
    try:
        repeated = RepeatedWarnings.attach()
        for k in range(7):
            log.warning("%s: the depth map is %.4g times the mesh's depth", f"d{k}.png", 0.1 + k / 1000)
        log.warning("another warning")
        repeated.detach()
        log.warning("%s: the depth map is %.4g times the mesh's depth", "after.png", 0.1)  # detached: shown
    finally:
        root.removeHandler(handler)
    shown = stream.getvalue().splitlines()
    first = [f"WARNING: d{k}.png: the depth map is {0.1 + k / 1000:.4g} times the mesh's depth" for k in range(3)]
    after = "WARNING: after.png: the depth map is 0.1 times the mesh's depth"
    assert shown == [*first, "WARNING: another warning", after]
    assert capsys.readouterr().err.strip() == \
        'WARNING: 4 more like "the depth map is 0.1 times the mesh\'s depth ..." (--debug shows each)'
