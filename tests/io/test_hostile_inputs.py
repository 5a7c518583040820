"""Every finding of the hostile-user fuzzing (issue 15), one test per class, through the CLI entry.

Inputs are never touched whatever -o and --overwrite say; a failed run leaves nothing behind; every
bad input gets one clean line and exit status 2; invalid files are refused rather than read as other
geometry; valid files that were refused are read.
"""

from __future__ import annotations

import dataclasses
import json
import os
import struct

import numpy as np
import pytest

from scantex.errors import ScanError
from scantex.io import load_scan
from tests.io.hostile import (TINY, assert_clean_error, fingerprint, png_claiming, run_cli, write_cube,
                              write_glb, write_photos, write_tiny_config)

RENDER = ["--views", "1", "--width", "16", "--height", "16", "--supersample", "1", "-q"]


# -- 1. inputs are never touched -----------------------------------------------------------------


@pytest.mark.parametrize("target", ["folder", "parent", "mesh", "texture", "mtl"])
def test_render_never_replaces_an_input(tmp_path, capsys, monkeypatch, target):
    monkeypatch.chdir(tmp_path)
    scan_dir = tmp_path / "a" / "scan"
    scan_dir.mkdir(parents=True)
    mesh = write_cube(scan_dir)
    before = fingerprint(tmp_path / "a")
    out = {"folder": scan_dir, "parent": tmp_path / "a", "mesh": mesh, "texture": scan_dir / "m_tex0.png",
           "mtl": scan_dir / "m.mtl"}[target]
    rc, err = run_cli(capsys, "render", mesh, "-o", out, "--overwrite", *RENDER)
    assert_clean_error(rc, err)
    assert fingerprint(tmp_path / "a") == before


def test_view_and_compare_never_replace_an_input(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    mesh = write_cube(tmp_path)
    before = fingerprint(tmp_path)
    assert_clean_error(*run_cli(capsys, "view", mesh, "-o", mesh, "-q"), "input file")
    assert_clean_error(*run_cli(capsys, "compare", mesh, mesh, "--json", tmp_path / "m_tex0.png", "-q"))
    assert fingerprint(tmp_path) == before


def test_compare_never_writes_its_json_over_a_photo(tmp_path, capsys, monkeypatch):
    """``compare --cameras cameras.json --json photos/p0.png``: the photos the cameras file names are inputs too."""
    monkeypatch.chdir(tmp_path)
    mesh = write_cube(tmp_path / "scan")
    cams = write_photos(tmp_path / "photos")
    before = fingerprint(tmp_path)
    rc, err = run_cli(capsys, "compare", mesh, mesh, "--cameras", cams, "--json", tmp_path / "photos" / "p0.png",
                      "-q")
    assert_clean_error(rc, err, "p0.png")
    assert fingerprint(tmp_path) == before


def test_demo_scan_never_replaces_the_current_folder(tmp_path, capsys, monkeypatch):
    (tmp_path / "keep.txt").write_text("mine")
    monkeypatch.chdir(tmp_path)
    assert_clean_error(*run_cli(capsys, "demo-scan", "--variant", "room", "-o", ".", "--overwrite", "-q"), "current folder")
    assert (tmp_path / "keep.txt").read_text() == "mine"


def test_overwrite_replaces_only_an_earlier_output(tmp_path, capsys, monkeypatch):
    """``-o ~/Documents --overwrite`` by mistake: a folder scantex did not write is refused and kept whole; an
    earlier output (its marker, or an older version's files) and an empty folder are replaced."""
    monkeypatch.chdir(tmp_path)
    mesh = write_cube(tmp_path / "scan")
    mine = tmp_path / "documents"
    (mine / "letters").mkdir(parents=True)
    (mine / "letters" / "keep.txt").write_text("mine")
    (mine / "notes.txt").write_text("mine too")
    before = fingerprint(mine)
    assert_clean_error(*run_cli(capsys, "render", mesh, "-o", mine, "--overwrite", *RENDER), "documents",
                       "not an output of scantex")
    assert fingerprint(mine) == before

    out = tmp_path / "renders"
    assert run_cli(capsys, "render", mesh, "-o", out, *RENDER)[0] == 0
    assert (out / ".scantex").is_file()
    (out / "view_000.png").unlink()  # the marker alone makes it an output
    assert run_cli(capsys, "render", mesh, "-o", out, "--overwrite", *RENDER)[0] == 0
    assert (out / "view_000.png").is_file()

    (tmp_path / "empty").mkdir()
    assert run_cli(capsys, "render", mesh, "-o", tmp_path / "empty", "--overwrite", *RENDER)[0] == 0
    # an output written before the marker existed: known by the files its command always writes
    (out / ".scantex").unlink()
    (out / "extra.txt").write_text("an earlier output's neighbour file")
    assert run_cli(capsys, "render", mesh, "-o", out, "--overwrite", *RENDER)[0] == 0
    assert not (out / "extra.txt").exists()


def test_enhance_work_folder_is_never_the_input_folder(tmp_path, capsys, monkeypatch):
    """``enhance cap.partial/m.obj -o cap`` used to delete cap.partial (the input folder) at the end."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "cap.partial").mkdir()
    mesh = write_cube(tmp_path / "cap.partial")
    config = write_tiny_config(tmp_path / "tiny.json")
    before = fingerprint(tmp_path / "cap.partial")
    rc, err = run_cli(capsys, "enhance", mesh, "-o", tmp_path / "cap", "--config", config, "-q")
    assert_clean_error(rc, err, "work folder")
    assert fingerprint(tmp_path / "cap.partial") == before
    assert not (tmp_path / "cap").exists()


@pytest.mark.parametrize("target", ["photos", "mesh_folder", "config"])
def test_enhance_never_replaces_an_input(tmp_path, capsys, monkeypatch, target):
    monkeypatch.chdir(tmp_path)
    mesh = write_cube(tmp_path / "scan")
    cams = write_photos(tmp_path / "photos")
    # the photos are noise: without the alignment check the run gets as far as writing its output
    config = write_tiny_config(tmp_path / "cfg" / "tiny.json", dataclasses.replace(
        TINY, photos=dataclasses.replace(TINY.photos, check_alignment=False)))
    out = {"photos": tmp_path / "photos", "mesh_folder": tmp_path / "scan", "config": config}[target]
    before = fingerprint(tmp_path)
    rc, err = run_cli(capsys, "enhance", mesh, "--photos", cams, "-o", out, "--config", config, "--overwrite", "-q")
    assert_clean_error(rc, err)
    assert fingerprint(tmp_path) == before


def test_an_output_inside_a_photos_folder_named_by_photos_is_refused(tmp_path, capsys, monkeypatch):
    """``--photos photos/ -o photos/out``: the README says an output may not lie inside the folder of photos
    --photos names; it was written there (the set's source is its cameras file, not the folder)."""
    monkeypatch.chdir(tmp_path)
    mesh = write_cube(tmp_path / "scan")
    write_photos(tmp_path / "photos")
    config = write_tiny_config(tmp_path / "cfg" / "tiny.json", dataclasses.replace(
        TINY, photos=dataclasses.replace(TINY.photos, check_alignment=False)))
    before = fingerprint(tmp_path)
    rc, err = run_cli(capsys, "enhance", mesh, "--photos", tmp_path / "photos", "-o", tmp_path / "photos" / "out",
                      "--config", config, "-q")
    assert_clean_error(rc, err, "input folder")
    assert fingerprint(tmp_path) == before


def test_an_output_inside_the_capture_folder_is_written_beside_its_inputs(tmp_path, capsys, monkeypatch):
    """``cd capture && scantex enhance scan.obj --photos cameras.json -o out``: the output lies in the folder
    of the poses file, holding none of the inputs, which stay byte for byte as they were."""
    capture = tmp_path / "capture"
    mesh = write_cube(capture)
    cams = write_photos(capture)
    config = write_tiny_config(tmp_path / "tiny.json", dataclasses.replace(
        TINY, photos=dataclasses.replace(TINY.photos, check_alignment=False)))
    monkeypatch.chdir(capture)
    before = fingerprint(capture)
    rc, err = run_cli(capsys, "enhance", mesh.name, "--photos", cams.name, "-o", "out", "--config", config, "-q")
    assert rc == 0, err
    after = fingerprint(capture)
    assert {k: v for k, v in after.items() if not k.startswith("out/")} == before
    assert any(k.startswith("out/") and k.endswith(".obj") for k in after)


# -- 2. leftovers ---------------------------------------------------------------------------------


def test_failed_enhance_leaves_no_work_folder(tmp_path, capsys, monkeypatch):
    """A near-collinear mesh fails after the work folder was made (no view sees any surface)."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "col.obj").write_text("v 0 0 0\nv 1 0 0\nv 2 1e-9 0\nv 3 0 1e-9\nf 1 2 3\nf 1 3 4\n")
    config = write_tiny_config(tmp_path / "tiny.json")
    rc, err = run_cli(capsys, "enhance", tmp_path / "col.obj", "-o", tmp_path / "out", "--config", config, "-q")
    assert_clean_error(rc, err, "col.obj")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["col.obj", "tiny.json"]


def test_stale_temporary_is_removed_by_the_next_success(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    mesh = write_cube(tmp_path / "scan")
    stale = tmp_path / ".result.k3x_9q2a.tmp"  # what a kill -9 during writing leaves
    stale.mkdir()
    (stale / "view_000.png").write_bytes(b"half")
    rc, err = run_cli(capsys, "render", mesh, "-o", tmp_path / "result", *RENDER)
    assert rc == 0, err
    assert not stale.exists() and (tmp_path / "result" / "cameras.json").is_file()


def test_resume_with_a_damaged_or_foreign_checkpoint(tmp_path, capsys, monkeypatch):
    import torch

    monkeypatch.chdir(tmp_path)
    mesh = write_cube(tmp_path / "scan")
    config = write_tiny_config(tmp_path / "tiny.json")
    work = tmp_path / "out.partial"
    work.mkdir()
    (work / "field.pt").write_bytes(b"not a checkpoint at all")
    rc, err = run_cli(capsys, "enhance", mesh, "-o", tmp_path / "out", "--config", config, "--resume", "-q")
    assert_clean_error(rc, err, "field.pt", "without --resume")
    torch.save({"field": {"weight": torch.zeros(3)}, "step": 2}, work / "field.pt")  # another program's
    rc, err = run_cli(capsys, "enhance", mesh, "-o", tmp_path / "out", "--config", config, "--resume", "-q")
    assert_clean_error(rc, err, "field.pt", "without --resume")
    # a real checkpoint of the same settings, but of another scan: the field would fit, the run is not this one
    from scantex.pipeline.enhance import enhance
    from tests.conftest import textured_cube

    enhance(textured_cube(materials=1, seed=1), TINY, work_dir=work)
    assert torch.load(work / "field.pt", weights_only=True)["step"] == 2
    rc, err = run_cli(capsys, "enhance", mesh, "-o", tmp_path / "out", "--config", config, "--resume", "-q")
    assert_clean_error(rc, err, "field.pt", "another input")
    assert not (tmp_path / "out").exists()
    # the advice works: a fresh run succeeds and cleans up
    rc, err = run_cli(capsys, "enhance", mesh, "-o", tmp_path / "out", "--config", config, "-q")
    assert rc == 0, err
    assert not work.exists()


def test_enhance_resume_finishes_with_identical_geometry(tmp_path, capsys, monkeypatch):
    """A run killed after a checkpoint (simulated: the checkpoint of an identical run is left in the
    work folder) resumes to the same geometry."""
    from scantex.pipeline.enhance import enhance

    monkeypatch.chdir(tmp_path)
    mesh = write_cube(tmp_path / "scan")
    config = write_tiny_config(tmp_path / "tiny.json")
    work = tmp_path / "out.partial"
    work.mkdir()
    enhance(load_scan(mesh), TINY, work_dir=work)  # leaves field.pt at step 2 of 4
    assert (work / "field.pt").is_file()
    rc, err = run_cli(capsys, "enhance", mesh, "-o", tmp_path / "out", "--config", config, "--resume", "-q")
    assert rc == 0, err
    before, after = load_scan(mesh), load_scan(tmp_path / "out" / "enhanced.obj")
    assert np.array_equal(before.positions, after.positions) and np.array_equal(before.faces, after.faces)
    assert not work.exists()


# -- 3. internal errors become clean ones -------------------------------------------------------


def _obj(tmp_path, text):
    (tmp_path / "m.obj").write_text(text)
    return tmp_path / "m.obj"


def _cube_with_mtl_line(tmp_path, line):
    mesh = write_cube(tmp_path)
    mtl = tmp_path / "m.mtl"
    mtl.write_text(mtl.read_text().replace("illum 1", f"illum 1\n{line}"))
    return mesh


def _cube_with_texture(tmp_path, data):
    mesh = write_cube(tmp_path)
    (tmp_path / "m_tex0.png").write_bytes(data)
    return mesh


TRI = "v 0 0 0\nv 1 0 0\nv 0 1 0\n"
LOAD_CASES = {
    "obj_index_2_63": lambda t: _obj(t, TRI + "f 1 2 9223372036854775809\n"),
    "obj_index_2_64": lambda t: _obj(t, TRI + "f 1 2/18446744073709551617 3\n"),
    "obj_index_minus_1e23": lambda t: _obj(t, TRI + "f 1 2 -99999999999999999999999\n"),
    "mtl_d_abc": lambda t: _cube_with_mtl_line(t, "d abc"),
    "mtl_bare_d": lambda t: _cube_with_mtl_line(t, "d"),
    "texture_bomb_30000": lambda t: _cube_with_texture(t, png_claiming(30000, 30000)),
    "texture_bomb_100000": lambda t: _cube_with_texture(t, png_claiming(100000, 100000)),
    "coordinates_1e308": lambda t: _obj(t, "v 0 0 0\nv 1e308 0 0\nv 0 -1e308 0\nf 1 2 3\n"),
}


@pytest.mark.parametrize("case", LOAD_CASES, ids=list(LOAD_CASES))
def test_bad_mesh_is_one_clean_line(tmp_path, capsys, case):
    mesh = LOAD_CASES[case](tmp_path)
    rc, err = run_cli(capsys, "render", mesh, "-o", tmp_path / "out", *RENDER)
    assert_clean_error(rc, err)
    assert not (tmp_path / "out").exists()


def _truncated_depth(folder):
    cams = write_photos(folder, depth=True)
    data = (folder / "d0.png").read_bytes()
    (folder / "d0.png").write_bytes(data[: len(data) // 2])
    return cams


PHOTO_CASES = {
    "width_abc": lambda f: write_photos(f, width="abc"),
    "width_list": lambda f: write_photos(f, width=[4]),
    "width_1e400": lambda f: write_photos(f).write_text(
        write_photos(f).read_text().replace('"width": 64', '"width": 1e400')) and f / "cameras.json",
    "nested_json": lambda f: (f.mkdir(parents=True, exist_ok=True),
                              (f / "cameras.json").write_text('{"frames": ' + "[" * 100000 + "]" * 100000 + "}"),
                              f / "cameras.json")[2],
    "camera_angle_x_0": lambda f: (f.mkdir(parents=True, exist_ok=True), write_photos(f),
                                   (f / "transforms.json").write_text(json.dumps(
                                       {"camera_angle_x": 0, "frames": [{"file_path": "p0.png",
                                                                         "transform_matrix": np.eye(4).tolist()}]})),
                                   f / "transforms.json")[3],
    "photo_bomb": lambda f: (write_photos(f), (f / "p1.png").write_bytes(png_claiming(30000, 30000)),
                             f / "cameras.json")[2],
    "depth_bomb": lambda f: (write_photos(f, depth=True), (f / "d1.png").write_bytes(png_claiming(100000, 100000, 0, 16)),
                             f / "cameras.json")[2],
    "truncated_depth": _truncated_depth,
}


@pytest.mark.parametrize("case", PHOTO_CASES, ids=list(PHOTO_CASES))
def test_bad_photos_are_one_clean_line(tmp_path, capsys, monkeypatch, case):
    monkeypatch.chdir(tmp_path)
    mesh = write_cube(tmp_path / "scan")
    config = write_tiny_config(tmp_path / "tiny.json")
    cams = PHOTO_CASES[case](tmp_path / "photos")
    rc, err = run_cli(capsys, "enhance", mesh, "--photos", cams, "-o", tmp_path / "out", "--config", config, "-q")
    assert_clean_error(rc, err)
    assert not (tmp_path / "out").exists() and not (tmp_path / "out.partial").exists()


BAD_CONFIGS = [{"views": {"n_views": 0}}, {"views": {"n_views": 1}}, {"views": {"fov_deg": 0}},
               {"views": {"width": -5}}, {"views": {"supersample": 0}}, {"views": {"mode": "sideways"}},
               {"train": {"steps": 0}}, {"train": {"lr": "fast"}}, {"train": {"batch_rays": 1.5}},
               {"field": {"encoding": "magic"}}, {"field": {"hidden": 0}}, {"bake": {"texture_size": -1}},
               {"seed": -1}, {"views": 3}, [1, 2], {"photos": {"holdout": -1}}, {"uv": {"mode": None}},
               {"views": {"adaptive": "yes"}}, {"train": {"start_levels": 40}},
               # a softmax at temperature 0 divided by zero: a 65 %-black atlas, exit 0
               {"photos": {"temperature": 0}}, {"photos": {"temperature": -5}}, {"bake": {"denoise": -1}},
               {"bake": {"texture_size": 3}}, {"photos": {"holdout": 1.5}}]


@pytest.mark.parametrize("bad", BAD_CONFIGS, ids=[json.dumps(b)[:40] for b in BAD_CONFIGS])
def test_bad_config_is_one_clean_line(tmp_path, capsys, monkeypatch, bad):
    monkeypatch.chdir(tmp_path)
    mesh = write_cube(tmp_path / "scan")
    doc = bad
    if isinstance(bad, dict):  # one bad value in an otherwise tiny config (a run never takes long)
        doc = TINY.to_dict()
        for key, value in bad.items():
            doc[key] = {**doc[key], **value} if isinstance(value, dict) else value
    (tmp_path / "c.json").write_text(json.dumps(doc))
    rc, err = run_cli(capsys, "enhance", mesh, "-o", tmp_path / "out", "--config", tmp_path / "c.json", "-q")
    assert_clean_error(rc, err, "c.json")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["c.json", "scan"]


def test_nested_config_is_one_clean_line(tmp_path, capsys):
    mesh = write_cube(tmp_path / "scan")
    (tmp_path / "c.json").write_text("[" * 100000 + "]" * 100000)
    assert_clean_error(*run_cli(capsys, "enhance", mesh, "-o", tmp_path / "out", "--config", tmp_path / "c.json"))


BAD_NUMBERS = [["render", "--views", "0"], ["render", "--fov", "nan"], ["render", "--supersample", "0"],
               ["render", "--seed", "-1"], ["render", "--width", "0"], ["enhance", "--views", "1"],
               ["enhance", "--seed", "-1"], ["enhance", "--steps", "0"], ["enhance", "--holdout", "inf"],
               ["enhance", "--texture-size", "-3"], ["compare", "--samples", "0"], ["view", "--max-faces", "0"],
               # NaN overlap wrote an all-black atlas; 0 faces a tile divided by zero; negative workers waited forever
               ["enhance", "--tile-overlap", "nan"], ["enhance", "--tile-faces", "0"], ["enhance", "--workers", "-3"],
               ["enhance", "--photos", "cameras.json", "--no-photos"],
               # the config was taken and the preset dropped without a word
               ["enhance", "--preset", "fast"], ["batch", "--preset", "best", "--config", "tiny.json"],
               ["batch", "--views", "1"], ["batch", "--seed", "-1"], ["batch", "--texture-size", "3"],
               ["batch", "--workers", "-1"]]


@pytest.mark.parametrize("argv", BAD_NUMBERS, ids=[" ".join(a) for a in BAD_NUMBERS])
def test_bad_cli_number_is_one_clean_line(tmp_path, capsys, argv):
    mesh = write_cube(tmp_path)
    command, rest = argv[0], argv[1:]
    if command == "enhance":
        rest = rest + ["--config", write_tiny_config(tmp_path / "cfg" / "tiny.json")]
    meshes = [mesh, mesh] if command == "compare" else [mesh]
    out = ["-o", tmp_path / ("out.html" if command == "view" else "out")] if command != "compare" else []
    rc, err = run_cli(capsys, command, *meshes, *out, *rest)
    assert_clean_error(rc, err, rest[0])
    assert not (tmp_path / "out").exists() and not (tmp_path / "out.html").exists()


@pytest.mark.skipif(os.geteuid() == 0, reason="root writes into read-only folders")
def test_read_only_folder_is_one_clean_line(tmp_path, capsys):
    mesh = write_cube(tmp_path / "scan")
    (tmp_path / "ro").mkdir()
    os.chmod(tmp_path / "ro", 0o555)
    try:
        rc, err = run_cli(capsys, "render", mesh, "-o", tmp_path / "ro" / "out", *RENDER)
    finally:
        os.chmod(tmp_path / "ro", 0o755)
    assert_clean_error(rc, err, f"{os.sep}ro{os.sep}")


def test_output_under_a_file_and_overlong_name_are_one_clean_line(tmp_path, capsys):
    mesh = write_cube(tmp_path / "scan")
    (tmp_path / "afile").write_text("x")
    assert_clean_error(*run_cli(capsys, "render", mesh, "-o", tmp_path / "afile" / "out", *RENDER), "afile")
    assert_clean_error(*run_cli(capsys, "render", mesh, "-o", tmp_path / "afile", "--overwrite", *RENDER), "afile")
    assert (tmp_path / "afile").read_text() == "x"
    assert_clean_error(*run_cli(capsys, "render", mesh, "-o", tmp_path / ("n" * 300), *RENDER))


def test_full_disk_is_one_clean_line(tmp_path, capsys, monkeypatch):
    """A write failing with ENOSPC (simulated: no test can fill the disk) names the output, nothing is left."""
    import errno

    import scantex.views.viewset as viewset

    def full(*args, **kwargs):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(viewset, "write_views", full)
    mesh = write_cube(tmp_path / "scan")
    rc, err = run_cli(capsys, "render", mesh, "-o", tmp_path / "out", *RENDER)
    assert_clean_error(rc, err, "out", "No space left on device")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["scan"]


# -- 4. invalid input is refused, never read as other geometry -----------------------------------

PLY_HEAD = ("ply\nformat ascii 1.0\n{comment}element vertex {nv}\nproperty float x\nproperty float y\n"
            "property float z\nproperty float s\nproperty float t\nelement face {nf}\n"
            "property list uchar int vertex_indices\nend_header\n")
PLY_VERTS = "0 0 0 0 0\n1 0 0 1 0\n0 1 0 0 1\n1 1 0 1 1\n"
PLY_CASES = {
    "minus_one_index": PLY_HEAD.format(comment="", nv=4, nf=2) + PLY_VERTS + "3 0 1 2\n3 1 3 -1\n",
    "header_says_more_vertices": PLY_HEAD.format(comment="", nv=5, nf=2) + PLY_VERTS + "3 0 1 2\n3 1 3 2\n",
    "header_says_fewer_vertices": PLY_HEAD.format(comment="", nv=3, nf=2) + PLY_VERTS + "3 0 1 2\n3 1 3 2\n",
    "header_says_fewer_faces": PLY_HEAD.format(comment="", nv=4, nf=1) + PLY_VERTS + "3 0 1 2\n3 1 3 2\n",
    "truncated_mid_face": PLY_HEAD.format(comment="", nv=4, nf=2) + PLY_VERTS + "3 0 1 2\n3 1",
    "truncated_face_missing": PLY_HEAD.format(comment="", nv=4, nf=2) + PLY_VERTS + "3 0 1 2\n",
    "face_of_0_corners": PLY_HEAD.format(comment="", nv=4, nf=2) + PLY_VERTS + "3 0 1 2\n0\n",
    "face_of_2_corners": PLY_HEAD.format(comment="", nv=4, nf=2) + PLY_VERTS + "3 0 1 2\n2 1 3\n",
    "broken_texture": PLY_HEAD.format(comment="comment TextureFile tex.png\n", nv=4, nf=2) + PLY_VERTS
                      + "3 0 1 2\n3 1 3 2\n",
}


@pytest.mark.parametrize("case", PLY_CASES, ids=list(PLY_CASES))
def test_invalid_ply_is_refused(tmp_path, capsys, case):
    (tmp_path / "m.ply").write_text(PLY_CASES[case])
    (tmp_path / "tex.png").write_text("not a picture")
    assert_clean_error(*run_cli(capsys, "info", tmp_path / "m.ply"))


def test_binary_ply_with_lying_counts_is_refused(tmp_path, capsys):
    head = ("ply\nformat binary_little_endian 1.0\nelement vertex {nv}\nproperty float x\nproperty float y\n"
            "property float z\nelement face {nf}\nproperty list uchar int vertex_indices\nend_header\n")
    verts = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]], np.float32).tobytes()
    faces = b"".join(struct.pack("<B3i", 3, *f) for f in [(0, 1, 2), (1, 3, 2)])
    (tmp_path / "ok.ply").write_bytes(head.format(nv=4, nf=2).encode() + verts + faces)
    assert load_scan(tmp_path / "ok.ply").n_faces == 2
    for name, nv, nf, tail in [("more.ply", 4, 3, b""), ("fewer.ply", 3, 2, b""), ("cut.ply", 4, 2, None)]:
        body = verts + faces if tail is not None else (verts + faces)[:-7]
        (tmp_path / name).write_bytes(head.format(nv=nv, nf=nf).encode() + body)
        assert_clean_error(*run_cli(capsys, "info", tmp_path / name), name)


@pytest.mark.parametrize("damage", ["signature", "pixels"])
def test_unreadable_glb_texture_is_refused(tmp_path, capsys, damage):
    glb = write_glb(tmp_path)
    data = bytearray(glb.read_bytes())
    if damage == "signature":  # trimesh cannot even open it, and used to drop it without a word
        at = data.find(b"\x89PNG")
        data[at:at + 8] = b"XXXXXXXX"
    else:
        at = data.find(b"IDAT")
        data[at + 8:at + 40] = bytes(32)  # the embedded PNG's pixel data is destroyed
    (tmp_path / "bad.glb").write_bytes(bytes(data))
    assert_clean_error(*run_cli(capsys, "info", tmp_path / "bad.glb"), "embedded texture image")


def test_glb_texture_bomb_is_refused(tmp_path, capsys):
    glb = write_glb(tmp_path)
    data = bytearray(glb.read_bytes())
    at = data.find(b"IHDR")
    data[at + 4:at + 12] = struct.pack(">II", 100000, 100000)  # CRC left wrong too: either way, refused
    (tmp_path / "bomb.glb").write_bytes(bytes(data))
    assert_clean_error(*run_cli(capsys, "info", tmp_path / "bomb.glb"))


def test_out_of_range_negative_vt_is_refused(tmp_path, capsys):
    _obj(tmp_path, TRI + "vt 0 0\nvt 1 0\nf 1/1 2/2 3/-3\n")
    assert_clean_error(*run_cli(capsys, "info", tmp_path / "m.obj"), "line 6")


# -- 5. valid input is read ---------------------------------------------------------------------


def test_tab_separated_obj(tmp_path):
    mesh = write_cube(tmp_path)
    text = mesh.read_text()
    (tmp_path / "tab.obj").write_text("\n".join(
        ln.replace(" ", "\t") if ln[:2] in ("v ", "vt", "f ", "us", "mt") else ln for ln in text.splitlines()))
    a, b = load_scan(mesh), load_scan(tmp_path / "tab.obj")
    assert np.array_equal(a.positions, b.positions) and np.array_equal(a.faces, b.faces)
    assert np.array_equal(a.uvs, b.uvs) and b.materials[0].image is not None


@pytest.mark.parametrize("line", ["map_Kd -clamp on m_tex0.png", "map_Kd -blendu off -s 1 1 -o 0.5 m_tex0.png",
                                  "map_Kd -imfchan r -mm 0 1 -bm 0.5 -texres 512 m_tex0.png"])
def test_map_kd_options_before_the_file_name(tmp_path, line):
    mesh = write_cube(tmp_path)
    mtl = tmp_path / "m.mtl"
    mtl.write_text(mtl.read_text().replace("map_Kd m_tex0.png", line))
    assert load_scan(mesh).materials[0].image is not None


@pytest.mark.parametrize("line", ["map_Kd M_TEX0.png", "map_Kd C:\\Users\\me\\scans\\m_tex0.png",
                                  "map_Kd /home/someone/else/m_tex0.png", 'map_Kd "m_tex0.png"'])
def test_map_kd_as_other_machines_write_it(tmp_path, line):
    """A texture named in another case (made on a case-blind disk), by the absolute path of the machine that
    wrote it, or in quotes: the file beside the MTL, as viewers find it."""
    mesh = write_cube(tmp_path)
    mtl = tmp_path / "m.mtl"
    mtl.write_text(mtl.read_text().replace("map_Kd m_tex0.png", line))
    assert load_scan(mesh).materials[0].image is not None


@pytest.mark.parametrize("which", ["obj", "mtl"])
def test_a_byte_order_mark_is_no_text(tmp_path, which):
    """Windows editors start a UTF-8 file with a byte-order mark: the OBJ's first line (``mtllib``) or the
    MTL's (``newmtl``) were read as another word, and the scan lost its texture."""
    mesh = write_cube(tmp_path)
    f = mesh if which == "obj" else tmp_path / "m.mtl"
    # the first line is the one at stake: scantex's own files start with a comment
    f.write_text("".join(ln for ln in f.read_text().splitlines(keepends=True) if not ln.startswith("#")))
    assert f.read_text().split(None, 1)[0] in ("mtllib", "newmtl")
    f.write_bytes(b"\xef\xbb\xbf" + f.read_bytes())
    a = load_scan(mesh)
    assert a.materials[0].image is not None and np.array_equal(a.faces, load_scan(write_cube(tmp_path / "b")).faces)


def test_mtllib_with_several_files(tmp_path):
    mesh = write_cube(tmp_path)
    mtl = (tmp_path / "m.mtl").read_text()
    (tmp_path / "a.mtl").write_text("newmtl other\nKd 1 0 0\n")
    (tmp_path / "b.mtl").write_text(mtl)
    mesh.write_text(mesh.read_text().replace("mtllib m.mtl", "mtllib a.mtl b.mtl"))
    assert load_scan(mesh).materials[0].image is not None


def test_truncated_binary_stl_has_a_real_message(tmp_path, capsys):
    import trimesh

    rng = np.random.default_rng(0)
    tri = trimesh.Trimesh(rng.normal(size=(50, 3)), rng.integers(0, 50, (60, 3)), process=False)
    data = bytearray(tri.export(file_type="stl"))
    data[:80] = b"solid written by an app".ljust(80, b" ")  # binary STLs often start so
    (tmp_path / "cut.stl").write_bytes(bytes(data[:-20]))
    assert_clean_error(*run_cli(capsys, "info", tmp_path / "cut.stl"), "truncated or damaged binary STL")
    assert "charset" not in capsys.readouterr().err


def test_stale_file_temporary_is_removed_by_the_next_success(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    mesh = write_cube(tmp_path / "scan")
    stale = tmp_path / ".view.html.0123abcd.tmp"  # a kill -9 while 'view' wrote its file
    stale.write_text("<html>half")
    other = tmp_path / ".notes.txt.0123abcd.tmp"  # not a temporary of this output: kept
    other.write_text("x")
    rc, err = run_cli(capsys, "view", mesh, "-o", tmp_path / "view.html", "-q")
    assert rc == 0, err
    assert not stale.exists() and other.exists()


def test_binary_ply_check_fast_path_agrees_with_the_row_walk(tmp_path):
    """All-triangle face lists are checked at numpy speed; any other layout row by row: same verdicts."""
    from scantex.io.ply import check_ply

    head = ("ply\nformat binary_little_endian 1.0\nelement vertex 4\nproperty float x\nproperty float y\n"
            "property float z\nelement face {nf}\nproperty list uchar int vertex_indices\nend_header\n")
    verts = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]], np.float32).tobytes()
    tris = [(0, 1, 2), (1, 3, 2)]
    for bad in (None, 4, -1):
        faces = [f if bad is None or k == 0 else (1, 3, bad) for k, f in enumerate(tris)]
        fast = b"".join(struct.pack("<B3i", 3, *f) for f in faces)
        slow = fast + struct.pack("<B4i", 4, 0, 1, 3, 2)  # a quad forces the row walk
        verdicts = []
        for name, body, nf in (("fast.ply", fast, 2), ("slow.ply", slow, 3)):
            (tmp_path / name).write_bytes(head.format(nf=nf).encode() + verts + body)
            try:
                verdicts.append(check_ply(tmp_path / name).triangles - (nf - 2) * 2)
            except ScanError as e:
                verdicts.append(e.problem)
        assert verdicts[0] == verdicts[1], verdicts
        assert (verdicts[0] == 2) == (bad is None)


def test_a_texture_between_pillows_guards_is_the_one_error_line_not_a_warning_too(tmp_path):
    """20000² pixels: over Pillow's warning size, under its error size. Its DecompressionBombWarning went to
    stderr before scantex's own error line; now only the error."""
    import warnings

    mesh = _cube_with_texture(tmp_path, png_claiming(20000, 20000))
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a warning fails the test
        with pytest.raises(ScanError, match="claims 20000x20000 pixels"):
            load_scan(mesh)


def test_sigterm_leaves_no_work_folder(tmp_path, capsys, monkeypatch):
    """SIGTERM (``kill``, a job scheduler stopping the run) unwinds the run as Ctrl-C does: exit status 143, one
    line, and no ``OUT.partial`` left (an empty one was); an earlier output at ``-o`` stays as it was."""
    import signal
    import time

    import scantex.pipeline.enhance
    from scantex.cli import stop_on_sigterm

    monkeypatch.chdir(tmp_path)
    mesh = write_cube(tmp_path / "scan")
    config = write_tiny_config(tmp_path / "tiny.json")
    rc, err = run_cli(capsys, "enhance", mesh, "-o", tmp_path / "out", "--config", config, "-q")
    assert rc == 0, err
    before = fingerprint(tmp_path / "out")

    def killed(*args, **kwargs):
        os.kill(os.getpid(), signal.SIGTERM)
        time.sleep(30)  # the signal's handler raises here
        raise AssertionError("SIGTERM did not stop the run")

    monkeypatch.setattr(scantex.pipeline.enhance, "enhance", killed)
    previous = signal.getsignal(signal.SIGTERM)
    try:
        stop_on_sigterm()
        rc, err = run_cli(capsys, "enhance", mesh, "-o", tmp_path / "out", "--config", config, "--overwrite", "-q")
    finally:
        signal.signal(signal.SIGTERM, previous)
    assert rc == 143 and err.strip() == "scantex: terminated", err
    assert not (tmp_path / "out.partial").exists()
    assert fingerprint(tmp_path / "out") == before
