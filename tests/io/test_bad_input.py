"""Bad input: one clear line naming the file and the problem, exit code 2, nothing written."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from scantex.errors import ScanError
from scantex.io import load_scan, save_scan
from tests.conftest import textured_cube


def write_cube(tmp_path):
    save_scan(textured_cube(materials=1), tmp_path / "cube.obj")
    return tmp_path / "cube.obj"


def case_missing(tmp_path):
    return tmp_path / "nope.obj", "no such file"


def case_folder(tmp_path):
    (tmp_path / "d.obj").mkdir()
    return tmp_path / "d.obj", "is a folder"


def case_wrong_extension(tmp_path):
    (tmp_path / "m.xyz").write_text("1 2 3\n")
    return tmp_path / "m.xyz", "unsupported format"


def case_binary_obj(tmp_path):
    (tmp_path / "m.obj").write_bytes(b"\x89PNG\r\n\x1a\n\x00\x00\x00" + bytes(range(256)))
    return tmp_path / "m.obj", "not a text OBJ"


def case_empty(tmp_path):
    (tmp_path / "m.obj").write_text("")
    return tmp_path / "m.obj", "empty"


def case_no_faces(tmp_path):
    (tmp_path / "m.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\n")
    return tmp_path / "m.obj", "no faces"


def case_nan(tmp_path):
    (tmp_path / "m.obj").write_text("v 0 0 0\nv nan 0 0\nv 0 1 0\nf 1 2 3\n")
    return tmp_path / "m.obj", "NaN or infinite"


def case_inf(tmp_path):
    (tmp_path / "m.obj").write_text("v 0 0 0\nv 1 0 inf\nv 0 1 0\nf 1 2 3\n")
    return tmp_path / "m.obj", "NaN or infinite"


def case_index_out_of_range(tmp_path):
    (tmp_path / "m.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\nf 1 2 9001\n")
    return tmp_path / "m.obj", "face 2 refers to vertex 9001, the file has 3 vertices"


def case_truncated_obj(tmp_path):
    text = write_cube(tmp_path).read_text()
    (tmp_path / "t.obj").write_text(text[: text.rindex("f ") + 5])
    (tmp_path / "t.mtl").write_text((tmp_path / "cube.mtl").read_text())
    return tmp_path / "t.obj", "cannot read face"


def case_truncated_glb(tmp_path):
    save_scan(textured_cube(materials=1), tmp_path / "c.glb")
    data = (tmp_path / "c.glb").read_bytes()
    (tmp_path / "t.glb").write_bytes(data[: len(data) // 2])
    return tmp_path / "t.glb", "cannot read GLB"


def case_garbage_ply(tmp_path):
    (tmp_path / "m.ply").write_bytes(b"ply\nformat ascii 1.0\nelement vertex 3\nend_header\n0 0\n")
    return tmp_path / "m.ply", "cannot read PLY"


def case_texture_not_image(tmp_path):
    obj = write_cube(tmp_path)
    (tmp_path / "cube_tex0.png").write_text("this is not a picture")
    return obj, "cube_tex0.png: texture is not an image"


def case_missing_mtl(tmp_path):
    obj = write_cube(tmp_path)
    (tmp_path / "cube.mtl").unlink()
    return obj, "material library named by cube.obj not found"


CASES = [case_missing, case_folder, case_wrong_extension, case_binary_obj, case_empty, case_no_faces,
         case_nan, case_inf, case_index_out_of_range, case_truncated_obj, case_truncated_glb,
         case_garbage_ply, case_texture_not_image, case_missing_mtl]


@pytest.mark.parametrize("case", CASES, ids=[c.__name__[5:] for c in CASES])
def test_load_raises_scan_error_naming_file(tmp_path, case):
    path, message = case(tmp_path)
    with pytest.raises(ScanError) as err:
        load_scan(path)
    text = str(err.value)
    assert message in text
    assert "\n" not in text
    assert path.name in text or message.split(":")[0] in text


@pytest.mark.parametrize("case", CASES, ids=[c.__name__[5:] for c in CASES])
def test_cli_one_line_error_and_nothing_written(tmp_path, case):
    path, message = case(tmp_path)
    out = tmp_path / "renders"
    proc = subprocess.run([sys.executable, "-m", "scantex", "render", str(path), "--views", "2",
                           "-o", str(out)], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("scantex: error: ") and message in lines[0]
    assert "Traceback" not in proc.stderr
    assert not out.exists()
    assert not list(tmp_path.glob(".renders*"))


def test_debug_shows_traceback(tmp_path):
    proc = subprocess.run([sys.executable, "-m", "scantex", "info", str(tmp_path / "x.obj"), "--debug"],
                          capture_output=True, text=True, timeout=60)
    # the traceback, and the exit status and one line of a run without --debug (it had exited 1, not 2)
    assert proc.returncode == 2 and "Traceback" in proc.stderr
    assert proc.stderr.strip().splitlines()[-1].startswith("scantex: error: ")


def test_missing_texture_is_read_untextured_with_a_warning(tmp_path, caplog):
    """A capture app's export that lost its texture still loads: that material is untextured, and the
    warning names the file and the material."""
    obj = tmp_path / "cube.obj"
    save_scan(textured_cube(materials=2), obj)
    (tmp_path / "cube_tex0.png").unlink()
    with caplog.at_level("WARNING"):
        scan = load_scan(obj)
    messages = [r.getMessage() for r in caplog.records]
    assert any("cube_tex0.png: texture named by material 'mat0' not found: the material is read untextured" in m
               for m in messages)
    assert scan.materials[0].image is None and scan.materials[1].image is not None
    assert scan.is_textured  # the other material keeps its atlas


def test_a_scan_without_colour_and_without_photos_is_refused_before_any_work(tmp_path):
    """An export whose only texture went missing (or a bare fused mesh) has no colour of its own: without photos
    every run would write one plain colour after minutes of training. One line says so and what to give, exit 2,
    nothing written; given photos, or vertex colours, or materials of different colours, it would go on."""
    from scantex.pipeline.enhance import has_colour

    obj = write_cube(tmp_path)
    (tmp_path / "cube_tex0.png").unlink()
    out = tmp_path / "out"
    proc = subprocess.run([sys.executable, "-m", "scantex", "enhance", str(obj), "-o", str(out)],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert lines[-1].startswith("scantex: error: ") and "cube.obj: has no colour to enhance" in lines[-1]
    assert "--photos" in lines[-1] and "Traceback" not in proc.stderr
    assert not out.exists() and not list(tmp_path.glob(".out*"))
    info = subprocess.run([sys.executable, "-m", "scantex", "info", str(obj)], capture_output=True, text=True,
                          timeout=120)
    assert "colour: none: enhance needs the capture's posed photos (--photos)" in info.stdout  # info says so too
    scan = load_scan(obj)
    assert not has_colour(scan)
    V, F = len(scan.positions), len(scan.faces)
    assert has_colour(scan.replace(vertex_colors=np.full((V, 4), 200, np.uint8)))
    assert has_colour(scan.replace(face_colors=np.full((F, 4), 200, np.uint8)))
    assert has_colour(textured_cube(materials=1))


def test_degenerate_and_non_manifold_are_accepted_with_warning(tmp_path, caplog):
    (tmp_path / "m.obj").write_text(
        "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 -1 0\nv 0 0 1\n"
        "f 1 2 3\nf 2 1 4\nf 1 2 5\nf 1 1 3\n")
    scan = load_scan(tmp_path / "m.obj")
    assert scan.n_faces == 4
    assert "1 degenerate faces and 1 non-manifold edges" in caplog.text


def test_scan_rejects_bad_arrays():
    with pytest.raises(ScanError, match="face 1 refers to vertex 5"):
        from scantex.scan import Scan

        Scan(np.zeros((3, 3)), np.array([[0, 1, 4]]))
