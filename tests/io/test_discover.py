"""Capture app exports as the apps write them (scantex/io/discover.py): small exports made in code."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import zipfile
from pathlib import Path

import numpy as np
import pytest
import trimesh
from PIL import Image

from scantex.errors import ScanError
from scantex.io import load_scan, save_scan
from scantex.io.discover import extract_zip, find_capture
from scantex.photos import load_photos
from scantex.photos.photoset import PhotoSet
from scantex.photos.polycam import write_polycam
from scantex.photos.scannerapp import write_3dscannerapp
from scantex.views.camera import Camera
from scantex.views.raycast import RayCaster
from scantex.views.render import render, to_uint8
from tests.conftest import textured_cube


def photographs(scan, folder: Path) -> PhotoSet:
    """Four posed renders of ``scan`` as JPEG photos."""
    eyes = [(2.6, -1.8, 1.9), (-1.6, -2.2, 1.4), (2.4, 2.0, 2.2), (-1.5, 2.4, 0.9)]
    cams = [Camera.look_at(e, (0.5, 0.5, 0.5), fov_deg=50, width=96, height=72) for e in eyes]
    caster = RayCaster(scan.positions, scan.faces)
    folder.mkdir(parents=True, exist_ok=True)
    images = []
    for i, cam in enumerate(cams):
        Image.fromarray(to_uint8(render(scan, cam, caster)[0])).save(folder / f"p{i}.jpg", quality=95)
        images.append(folder / f"p{i}.jpg")
    return PhotoSet(cameras=tuple(cams), images=tuple(images), source=folder, format="rendered")


def scanner_app_folder(folder: Path, scan, photos: PhotoSet | None) -> Path:
    """What 3D Scanner App's "All Data" export holds: textured_output.obj/.mtl/.jpg and frame_XXXXX.jpg/.json."""
    folder.mkdir(parents=True, exist_ok=True)
    save_scan(scan, folder / "textured_output.obj")
    mtl = folder / "textured_output.mtl"
    text = mtl.read_text()
    for png in folder.glob("*.png"):  # the app writes a JPEG atlas
        Image.open(png).convert("RGB").save(png.with_name("textured_output.jpg"), quality=95)
        text = text.replace(png.name, "textured_output.jpg")
        png.unlink()
    mtl.write_text(text)
    if photos is not None:
        write_3dscannerapp(photos, folder)
    return folder


def zip_folder(folder: Path, target: Path, prefix: str = "") -> Path:
    with zipfile.ZipFile(target, "w", zipfile.ZIP_DEFLATED) as z:
        for p in sorted(folder.rglob("*")):
            if p.is_file():
                z.write(p, prefix + p.relative_to(folder).as_posix())
    return target


@pytest.fixture(scope="module")
def exports(tmp_path_factory):
    root = tmp_path_factory.mktemp("exports")
    scan = textured_cube(materials=1)
    photos = photographs(scan, root / "renders")
    scanner = scanner_app_folder(root / "scanner", scan, photos)
    scanner_zip = zip_folder(scanner, root / "scanner.zip", prefix="Scan 23 Nov/")
    # Polycam's raw export: the mesh as raw.glb, the photos under keyframes/, zipped
    poly = root / "polycam"
    poly.mkdir()
    save_scan(scan, poly / "raw.glb")
    write_polycam(photos, poly)
    (poly / "mesh_info.json").write_text(json.dumps({"alignmentTransform": list(np.eye(4).ravel())}))
    polycam_zip = zip_folder(poly, root / "polycam.zip")
    return {"scan": scan, "scanner": scanner, "scanner_zip": scanner_zip, "polycam_zip": polycam_zip, "root": root}


def same_geometry(a, b) -> bool:
    """The same triangles in the same order (GLB stores float32 and repeats corners where UVs split)."""
    return np.array_equal(a.triangles.astype(np.float32), b.triangles.astype(np.float32))


def test_scanner_app_folder(exports):
    with find_capture(exports["scanner"]) as capture:
        assert capture.kind == "folder" and capture.mesh.name == "textured_output.obj"
        assert capture.photo_format == "3dscannerapp" and capture.photos == exports["scanner"]
        assert len(load_photos(capture.photos)) == 4
        assert load_scan(capture.mesh).is_textured
        assert "mesh textured_output.obj; photos . (3dscannerapp)" in capture.describe()


def test_scanner_app_mesh_file_finds_the_frames_beside_it(exports):
    capture = find_capture(exports["scanner"] / "textured_output.obj")
    assert capture.kind == "file" and capture.photo_format == "3dscannerapp"
    assert find_capture(exports["scanner"] / "textured_output.obj", photos=False).photos is None


def test_scanner_app_zip_is_unpacked_in_a_temporary_folder(exports):
    before = sorted(exports["root"].iterdir())
    with find_capture(exports["scanner_zip"]) as capture:
        extracted = capture.extracted
        assert capture.kind == "zip" and capture.mesh.name == "textured_output.obj"
        assert capture.mesh.parent.name == "Scan 23 Nov"
        assert Path(tempfile.gettempdir()) in extracted.parents  # never next to the input
        assert exports["root"] not in extracted.parents
        assert same_geometry(load_scan(capture.mesh), exports["scan"])
        assert capture.photo_format == "3dscannerapp" and len(load_photos(capture.photos)) == 4
    assert not extracted.exists()
    assert sorted(exports["root"].iterdir()) == before  # nothing written beside the zip


def test_polycam_zip(exports):
    with find_capture(exports["polycam_zip"]) as capture:
        assert capture.mesh.name == "raw.glb" and capture.photo_format == "polycam"
        assert capture.photos.name == "keyframes"
        assert same_geometry(load_scan(capture.mesh), exports["scan"])
        photos = load_photos(capture.photos)
        assert len(photos) == 4
        # the poses survive the round trip through Polycam's layout
        np.testing.assert_allclose(photos.cameras[0].world_to_camera,
                                   load_photos(exports["scanner"]).cameras[0].world_to_camera, atol=1e-9)


def test_texrecon_scene_folder_below_the_mesh(exports, tmp_path):
    """An RGB-D texturing dataset as G2LTex and texrecon keep it: the mesh, and its photos beside .cam files in a
    folder below it."""
    from scantex.photos.mve import write_mve

    save_scan(exports["scan"], tmp_path / "mesh.obj")
    write_mve(photographs(exports["scan"], tmp_path / "renders"), tmp_path / "textureimages")
    with find_capture(tmp_path) as capture:
        assert capture.mesh.name == "mesh.obj" and capture.photo_format == "texrecon"
        assert capture.photos == tmp_path / "textureimages" and len(load_photos(capture.photos)) == 4


def test_mve_scene_beside_its_mesh(exports, tmp_path):
    """MVE's scene folder: the mesh its reconstruction wrote beside views/."""
    from scantex.photos import write_mve_scene

    save_scan(exports["scan"], tmp_path / "surface-L2-clean.obj")
    write_mve_scene(photographs(exports["scan"], tmp_path / "renders"), tmp_path)
    with find_capture(tmp_path) as capture:
        assert capture.mesh.name == "surface-L2-clean.obj" and capture.photo_format == "mve"
        assert capture.photos == tmp_path / "views" and len(load_photos(capture.photos)) == 4


def test_meshroom_cache(exports, tmp_path):
    """Meshroom's project: its textured mesh in MeshroomCache/Texturing/<id>/ and its cameras in
    StructureFromMotion/<id>/cameras.sfm, found from the project, the cache or the mesh file itself."""
    from scantex.photos import write_meshroom

    cache = tmp_path / "project" / "MeshroomCache"
    for node, name in (("Meshing/11aa", "mesh.obj"), ("MeshFiltering/22bb", "mesh.obj"),
                       ("Texturing/33cc", "texturedMesh.obj")):
        (cache / node).mkdir(parents=True)
        save_scan(exports["scan"], cache / node / name)
    sfm = write_meshroom(photographs(exports["scan"], tmp_path / "renders"), cache / "StructureFromMotion" / "44dd")
    for where in (tmp_path / "project", cache, cache / "Texturing" / "33cc" / "texturedMesh.obj"):
        with find_capture(where) as capture:
            assert capture.mesh == cache / "Texturing" / "33cc" / "texturedMesh.obj", where
            assert capture.photo_format == "meshroom" and capture.photos == sfm, where
    assert len(load_photos(sfm)) == 4


def test_colmap_dense_workspace(exports, tmp_path):
    """COLMAP's dense workspace (``image_undistorter``, ``patch_match_stereo``, ``poisson_mesher``): its
    undistorted images, the PINHOLE model in ``sparse/`` and the meshes beside them."""
    from scantex.photos import write_colmap_binary

    written = write_colmap_binary(photographs(exports["scan"], tmp_path / "renders"), tmp_path / "stage")
    dense = tmp_path / "dense" / "0"
    (dense / "sparse").mkdir(parents=True)
    for name in ("cameras.bin", "images.bin", "points3D.bin"):
        (written / name).rename(dense / "sparse" / name)
    (tmp_path / "stage" / "images").rename(dense / "images")
    scan = exports["scan"]
    trimesh.Trimesh(scan.positions, scan.faces, process=False).export(dense / "meshed-poisson.ply")
    with find_capture(dense) as capture:
        assert capture.mesh.name == "meshed-poisson.ply" and capture.photo_format == "colmap"
        assert len(load_photos(capture.photos)) == 4


def test_openmvs_working_folder(exports, tmp_path):
    """OpenMVS's folder: its scenes (scene.mvs and the later steps' .mvs) and meshes, the textured one preferred to
    the larger untextured ones."""
    import shutil

    from scantex.photos import write_openmvs

    scene = write_openmvs(photographs(exports["scan"], tmp_path / "renders"), tmp_path / "work")
    shutil.copy(scene, tmp_path / "work" / "scene_dense.mvs")
    big = trimesh.creation.icosphere(subdivisions=5)
    big.export(tmp_path / "work" / "scene_dense_mesh.ply")
    save_scan(exports["scan"], tmp_path / "work" / "scene_dense_mesh_refine_texture.obj")
    with find_capture(tmp_path / "work") as capture:
        assert capture.mesh.name == "scene_dense_mesh_refine_texture.obj"
        assert capture.photo_format == "openmvs" and capture.photos == scene and len(load_photos(capture.photos)) == 4


def test_arkitscenes_video_folder(exports, tmp_path):
    """ARKitScenes' video folder: the ARKit mesh <video_id>_3dod_mesh.ply beside <video_id>_frames/."""
    from tests.photos.test_importers import arkitscenes_capture

    scan = exports["scan"]
    (tmp_path / "41069021").mkdir()
    trimesh.Trimesh(scan.positions, scan.faces, process=False).export(tmp_path / "41069021" / "41069021_3dod_mesh.ply")
    frames = arkitscenes_capture(tmp_path / "41069021")
    with find_capture(tmp_path / "41069021") as capture:
        assert capture.mesh.name == "41069021_3dod_mesh.ply" and capture.photo_format == "arkitscenes"
        assert capture.photos == frames and len(load_photos(capture.photos)) == 2
    # the video folder renamed: its frames folder is still found
    (tmp_path / "41069021").rename(tmp_path / "kitchen")
    assert load_photos(tmp_path / "kitchen").source == tmp_path / "kitchen" / "41069021_frames"


def test_info_says_how_a_capture_s_photos_are_read(exports, tmp_path, capsys):
    """``scantex info`` on a capture folder: the mesh found, and its photos as scantex reads them (number and layout,
    size, field of view, depth maps); ``--photos`` names them for a mesh file."""
    from scantex.cli import main
    from scantex.photos.mve import write_mve

    save_scan(exports["scan"], tmp_path / "mesh.obj")
    write_mve(photographs(exports["scan"], tmp_path / "renders"), tmp_path / "textureimages")
    assert main(["info", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert "mesh mesh.obj; photos textureimages (texrecon)" in out
    assert "textureimages: 4 photos (texrecon), 96x72" in out and "depth maps: none" in out
    assert "horizontal field of view 50.0 degrees" in out
    assert main(["info", str(tmp_path / "mesh.obj"), "--photos", str(exports["scanner"])]) == 0
    assert "photos (3dscannerapp)" in capsys.readouterr().out


def test_gltf_with_its_buffers(exports, tmp_path):
    save_scan(exports["scan"], tmp_path / "c.glb")
    files = trimesh.load(tmp_path / "c.glb", process=False).export(file_type="gltf")
    folder = tmp_path / "export"
    folder.mkdir()
    for name, data in files.items():
        (folder / name).write_bytes(data)
    assert len(files) > 2  # the .gltf, its buffers
    for path in (folder, folder / "model.gltf"):
        capture = find_capture(path)
        assert capture.mesh == folder / "model.gltf" and capture.photos is None
        scan = load_scan(capture.mesh)
        assert same_geometry(scan, exports["scan"]) and scan.is_textured


def test_obj_whose_texture_is_missing_loads_untextured(exports, tmp_path, caplog):
    folder = scanner_app_folder(tmp_path / "lost", exports["scan"], None)
    (folder / "textured_output.jpg").unlink()
    capture = find_capture(folder)
    with caplog.at_level("WARNING"):
        scan = load_scan(capture.mesh)
    assert not scan.is_textured and same_geometry(scan, exports["scan"])
    assert any("textured_output.jpg: texture named by material" in r.getMessage() and "untextured" in r.getMessage()
               for r in caplog.records)


def test_the_app_mesh_is_preferred_and_the_others_are_listed(exports, tmp_path):
    folder = scanner_app_folder(tmp_path / "many", exports["scan"], None)
    save_scan(exports["scan"], folder / "a_bigger_copy.glb")
    (folder / "keyframes").mkdir()
    save_scan(exports["scan"], folder / "keyframes" / "ignored.obj")  # photo folders hold no mesh to use
    capture = find_capture(folder)
    assert capture.mesh.name == "textured_output.obj"
    assert [p.name for p in capture.other_meshes] == ["a_bigger_copy.glb"]
    assert "also holds a_bigger_copy.glb (not used)" in capture.describe()


def test_folder_without_a_mesh(tmp_path):
    (tmp_path / "notes.txt").write_text("hello")
    with pytest.raises(ScanError, match="no mesh file found in it"):
        find_capture(tmp_path)


def test_missing_path(tmp_path):
    with pytest.raises(ScanError, match="no such file or folder"):
        find_capture(tmp_path / "nope")


# -- zip guards ------------------------------------------------------------------------------------


def leftovers(before: set[str]) -> set[str]:
    return {p for p in os.listdir(tempfile.gettempdir()) if p.startswith("scantex-capture-")} - before


def scratch() -> set[str]:
    return {p for p in os.listdir(tempfile.gettempdir()) if p.startswith("scantex-capture-")}


@pytest.mark.parametrize("name", ["../escaped.obj", "/abs/escaped.obj", "a/../../escaped.obj", "C:/x.obj",
                                  "..\\escaped.obj"])
def test_zip_slip_is_refused(tmp_path, name):
    archive = tmp_path / "evil.zip"
    with zipfile.ZipFile(archive, "w") as z:
        z.writestr("mesh.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
        z.writestr(name, "v 0 0 0\n")
    before = scratch()
    with pytest.raises(ScanError, match="outside the folder it is unpacked into"):
        find_capture(archive)
    assert not leftovers(before)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["evil.zip"]
    assert not (tmp_path.parent / "escaped.obj").exists()


def test_zip_link_is_refused(tmp_path):
    archive = tmp_path / "link.zip"
    info = zipfile.ZipInfo("mesh.obj")
    info.external_attr = (0o120777 << 16)  # a symbolic link, as `zip -y` stores one
    with zipfile.ZipFile(archive, "w") as z:
        z.writestr(info, "/etc/passwd")
    with pytest.raises(ScanError, match="symbolic link"):
        find_capture(archive)


def test_zip_too_large_is_refused_before_unpacking(tmp_path):
    archive = tmp_path / "big.zip"
    with zipfile.ZipFile(archive, "w", zipfile.ZIP_DEFLATED) as z:
        z.writestr("mesh.obj", b"\0" * (4 << 20))  # 4 MiB of zeros: a few kB packed
    before = scratch()
    with pytest.raises(ScanError, match=r"unpacks to 0\.0 GiB, more than the 0\.0 GiB allowed"):
        find_capture(archive, max_bytes=1 << 20)
    assert not leftovers(before)


def test_zip_whose_header_lies_about_a_size_is_refused_cleanly(tmp_path):
    """zipfile reads no more than the header says and the CRC then fails: one line, nothing left."""
    archive = tmp_path / "liar.zip"
    with zipfile.ZipFile(archive, "w", zipfile.ZIP_STORED) as z:
        z.writestr("mesh.obj", b"v 0 0 0\n" * 1000)
    data = bytearray(archive.read_bytes())
    # the central directory's uncompressed size of the one member (offset 24 in its record): 8000 -> 8
    cd = data.rindex(b"PK\x01\x02")
    data[cd + 24:cd + 28] = (8).to_bytes(4, "little")
    archive.write_bytes(bytes(data))
    before = scratch()
    with pytest.raises(ScanError, match=r"liar\.zip: cannot unpack: Bad CRC-32 for file 'mesh\.obj'"):
        extract_zip(archive)
    assert not leftovers(before)


def test_not_a_zip(tmp_path):
    (tmp_path / "x.zip").write_bytes(b"PK\x03\x04 not really")
    with pytest.raises(ScanError, match="not a readable zip file"):
        find_capture(tmp_path / "x.zip")


# -- the command line ------------------------------------------------------------------------------


def test_enhance_takes_the_zip_as_the_app_wrote_it(exports, tmp_path):
    out = tmp_path / "out"
    before = scratch()
    proc = subprocess.run([sys.executable, "-m", "scantex", "enhance", str(exports["scanner_zip"]), "-o", str(out),
                           "--preset", "fast", "--views", "6", "--steps", "20", "--no-refine",
                           "--texture-size", "64", "--holdout", "1"],
                          capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr
    assert "scanner.zip: zip; mesh Scan 23 Nov/textured_output.obj; photos Scan 23 Nov (3dscannerapp)" in proc.stdout
    assert "4 photos (3dscannerapp)" in proc.stdout
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["geometry"]["arrays_identical"]
    assert metrics["held_out_photos"]["input"]["photos"] == 1
    # the photos named inside the zip, not in the temporary folder it was unpacked into (gone by now)
    inside = str(exports["scanner_zip"] / "Scan 23 Nov")
    assert metrics["photos"]["source"] == inside and f"{inside}: 4 photos (3dscannerapp)" in proc.stdout
    assert "scantex-capture" not in proc.stdout
    assert not leftovers(before)  # the extraction is gone
