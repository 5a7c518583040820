"""Geometry is sacred: every format's triangles come back bit for bit."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import trimesh

from scantex.io import load_scan, save_scan
from scantex.scan import Scan, triangle_multiset_key
from tests.conftest import grid_wall, shared_scan, textured_cube


def same_triangles(a: Scan, b: Scan) -> bool:
    return np.array_equal(triangle_multiset_key(a.positions, a.faces), triangle_multiset_key(b.positions, b.faces))


def distinct_positions(s: Scan) -> np.ndarray:
    return np.unique(s.positions[np.unique(s.faces)], axis=0)


def float32_scan(scan: Scan) -> Scan:
    """The same scan with float32-representable positions (what GLB and most PLY files hold)."""
    return Scan(scan.positions.astype(np.float32).astype(np.float64), scan.faces, scan.uvs, scan.face_uvs,
                scan.face_materials, scan.materials)


def test_obj_multi_material_roundtrip_is_exact(tmp_path, cube):
    written = save_scan(cube, tmp_path / "cube.obj")
    assert {p.name for p in written} == {"cube.obj", "cube.mtl", "cube_tex0.png", "cube_tex1.png"}
    back = load_scan(tmp_path / "cube.obj")
    # OBJ keeps positions and their indexing exactly: same arrays, not only the same triangles
    assert np.array_equal(back.positions, cube.positions)
    assert np.array_equal(back.faces, cube.faces)
    assert np.array_equal(back.uvs, cube.uvs) and np.array_equal(back.face_uvs, cube.face_uvs)
    assert np.array_equal(back.face_materials, cube.face_materials)
    assert [m.name for m in back.materials] == ["mat0", "mat1"]
    for m_in, m_out in zip(cube.materials, back.materials):
        assert np.array_equal(m_in.image, m_out.image)


def test_obj_reader_handles_split_indices_quads_negative_and_duplicates(tmp_path):
    # duplicate positions (scanners write them), a quad, relative indices, faces without vt
    (tmp_path / "m.obj").write_text(
        "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 1 1 0\n"
        "vt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\n"
        "f 1/1 2/2 3/3 4/4\n"
        "f -4/-3 -1/-2 -2/-1\n")
    scan = load_scan(tmp_path / "m.obj")
    assert scan.n_vertices == 5 and scan.n_faces == 3
    assert scan.faces.tolist() == [[0, 1, 2], [0, 2, 3], [1, 4, 3]]
    assert scan.face_uvs.tolist() == [[0, 1, 2], [0, 2, 3], [1, 2, 3]]
    save_scan(scan, tmp_path / "out.obj")
    back = load_scan(tmp_path / "out.obj")
    assert np.array_equal(back.positions, scan.positions) and np.array_equal(back.faces, scan.faces)


@pytest.mark.parametrize("make", [textured_cube, grid_wall])
def test_glb_roundtrip_keeps_float32_geometry_exactly(tmp_path, make):
    scan = float32_scan(make())
    save_scan(scan, tmp_path / "m.glb")
    back = load_scan(tmp_path / "m.glb")
    assert same_triangles(scan, back)
    assert np.array_equal(distinct_positions(scan), distinct_positions(back))
    assert back.n_faces == scan.n_faces
    # and GLB -> OBJ -> GLB keeps it too
    save_scan(back, tmp_path / "m2.obj")
    save_scan(load_scan(tmp_path / "m2.obj"), tmp_path / "m2.glb")
    assert same_triangles(scan, load_scan(tmp_path / "m2.glb"))


@pytest.mark.parametrize("ext", [".glb", ".usdz"])
def test_georeferenced_coordinates_keep_their_precision(tmp_path, ext):
    """float32 rounds UTM-sized coordinates (some 500 km) by up to 6 cm; a GLB or USDZ holds such a scan about
    its centre, which its node's or prim's translation adds back: millimetres stay millimetres."""
    if ext == ".usdz":
        pytest.importorskip("pxr")
    scan = grid_wall(8, 6)
    far = Scan(scan.positions + np.array([512345.678, 4123456.789, 123.456]), scan.faces, scan.uvs,
               scan.face_uvs, scan.face_materials, scan.materials)
    assert np.abs(far.positions.astype(np.float32) - far.positions).max() > 0.01  # what float32 alone gives
    save_scan(far, tmp_path / f"far{ext}")
    back = load_scan(tmp_path / f"far{ext}")
    assert np.array_equal(back.faces, far.faces) or same_triangles(far, back)
    size = np.ptp(far.positions, axis=0).max()
    assert np.abs(distinct_positions(back) - distinct_positions(far)).max() < 1e-6 * size
    # a scan near the origin is written as before: no translation, its float32 positions bit for bit
    near = float32_scan(scan)
    save_scan(near, tmp_path / f"near{ext}")
    assert np.array_equal(distinct_positions(load_scan(tmp_path / f"near{ext}")), distinct_positions(near))


def test_glb_texture_survives(tmp_path, cube):
    save_scan(cube, tmp_path / "c.glb")
    back = load_scan(tmp_path / "c.glb")
    assert back.is_textured and len(back.materials) == 2
    assert np.array_equal(back.materials[0].image, cube.materials[0].image)


def test_copies_saved_in_one_folder_keep_their_own_textures(tmp_path, cube):
    """A copy saved beside its input (the README's `save_scan(scan, "copy.obj")`) is not refused for the
    input's texture name, and two meshes saved in one folder do not share (overwrite) a texture file."""
    save_scan(cube, tmp_path / "cube.obj")
    scan = load_scan(tmp_path / "cube.obj")
    save_scan(scan, tmp_path / "copy.obj")
    darker = scan.replace(materials=tuple(dataclasses.replace(m, image=m.image // 2) for m in scan.materials))
    save_scan(darker, tmp_path / "darker.obj")
    for name, expected in (("cube", cube), ("copy", cube), ("darker", darker)):
        back = load_scan(tmp_path / f"{name}.obj")
        assert all(np.array_equal(b.image, m.image) for b, m in zip(back.materials, expected.materials)), name


def test_obj_and_glb_of_one_output_share_one_png_encoding(tmp_path, cube):
    """write_outputs encodes each atlas once: the GLB embeds the OBJ's PNG files byte for byte."""
    import json
    import struct

    from scantex.io.images import TextureEncoder

    encoder = TextureEncoder()
    save_scan(cube, tmp_path / "c.obj", encoder=encoder)
    save_scan(cube, tmp_path / "c.glb", encoder=encoder)
    assert all(encoder.colour(m.image) is encoder.colour(m.image) for m in cube.materials)  # kept, not made again
    pngs = sorted((tmp_path / name).read_bytes() for name in ("c_tex0.png", "c_tex1.png"))
    blob = (tmp_path / "c.glb").read_bytes()
    json_len = struct.unpack("<I", blob[12:16])[0]
    doc = json.loads(blob[20:20 + json_len])
    binary = blob[20 + json_len + 8:]
    embedded = []
    for image in doc["images"]:
        view = doc["bufferViews"][image["bufferView"]]
        start = view.get("byteOffset", 0)
        embedded.append(binary[start:start + view["byteLength"]])
    embedded = sorted(e.rstrip(b"\0") for e in embedded)  # views are padded to 4 bytes; a PNG ends in IEND's CRC
    assert embedded == [p.rstrip(b"\0") for p in pngs] and all(i["mimeType"] == "image/png" for i in doc["images"])
    back = load_scan(tmp_path / "c.glb")
    assert sorted(m.image.tobytes() for m in back.materials) == sorted(m.image.tobytes() for m in cube.materials)


def test_ply_with_vertex_colours_roundtrip(tmp_path):
    mesh = trimesh.creation.icosphere(subdivisions=2)
    colors = np.random.default_rng(0).integers(0, 255, (len(mesh.vertices), 4), dtype=np.uint8)
    colors[:, 3] = 255
    mesh.visual.vertex_colors = colors
    mesh.export(tmp_path / "s.ply")
    scan = load_scan(tmp_path / "s.ply")
    assert scan.vertex_colors is not None and np.array_equal(scan.vertex_colors, colors)
    assert np.array_equal(scan.positions, np.asarray(mesh.vertices, dtype=np.float32).astype(np.float64)) or \
        np.array_equal(scan.positions, mesh.vertices)
    for ext in (".obj", ".glb"):
        save_scan(scan, tmp_path / f"out{ext}")
        back = load_scan(tmp_path / f"out{ext}")
        assert same_triangles(scan, back), ext
        assert np.array_equal(back.vertex_colors[:, :3], scan.vertex_colors[:, :3]), ext


def test_ply_face_colours_are_read(tmp_path):
    mesh = trimesh.creation.box()
    mesh.visual.face_colors = np.tile([[200, 10, 10, 255]], (len(mesh.faces), 1))
    mesh.export(tmp_path / "b.ply")
    scan = load_scan(tmp_path / "b.ply")
    assert scan.face_colors is not None and (scan.face_colors[:, 0] == 200).all()


def test_ply_texture_file_is_shown_as_it_is(tmp_path):
    """A PLY with texture coordinates and ``comment TextureFile`` (MeshLab's, many scanners'): the format has no
    material colour, so its texture is not darkened by the grey (0.4) trimesh gives such a material."""
    from PIL import Image

    from scantex.views.render import shade_hits

    rgb = np.random.default_rng(1).integers(0, 256, (16, 16, 3), dtype=np.uint8)
    Image.fromarray(rgb).save(tmp_path / "tex.png")
    rows = ["0 0 0 0.09375 0.09375", "1 0 0 0.9 0.1", "0 1 0 0.1 0.9"]  # corner 0 on texel (1, 14)
    (tmp_path / "t.ply").write_text("ply\nformat ascii 1.0\ncomment TextureFile tex.png\nelement vertex 3\n"
                                    "property float x\nproperty float y\nproperty float z\nproperty float s\n"
                                    "property float t\nelement face 1\nproperty list uchar int vertex_indices\n"
                                    "end_header\n" + "\n".join(rows) + "\n3 0 1 2\n")
    scan = load_scan(tmp_path / "t.ply")
    assert scan.materials[0].diffuse == (1.0, 1.0, 1.0, 1.0)
    assert np.array_equal(scan.materials[0].image[..., :3], rgb)
    seen = shade_hits(scan, np.zeros(1, np.int64), np.zeros((1, 2), np.float32))
    assert np.allclose(seen[0], rgb[14, 1] / 255.0, atol=1e-6)


def test_stl_through_trimesh_keeps_triangles(tmp_path):
    mesh = trimesh.creation.cylinder(radius=0.5, height=1.0, sections=16)
    mesh.export(tmp_path / "c.stl")
    scan = load_scan(tmp_path / "c.stl")
    ref = trimesh.load(tmp_path / "c.stl", process=False)
    assert np.array_equal(triangle_multiset_key(scan.positions, scan.faces),
                          triangle_multiset_key(ref.vertices, ref.faces))
    save_scan(scan, tmp_path / "c.obj")
    assert same_triangles(scan, load_scan(tmp_path / "c.obj"))


def test_obj_to_glb_rounds_only_to_float32(tmp_path, cube):
    """GLB holds float32: a float64 OBJ scan's GLB triangles equal its float32-rounded triangles."""
    save_scan(cube, tmp_path / "c.glb")
    assert same_triangles(float32_scan(cube), load_scan(tmp_path / "c.glb"))


@pytest.mark.parametrize("parts", [
    ("bathroom_3dscannerapp", "textured_output.obj"),
    ("polycam_glb", "potted_plant_on_rug_raw.glb"),
    ("polycam_glb", "tyres_on_tiled_floor_raw.glb"),
    ("bolster_rgbd_posed", "bloster.ply"),
])
def test_real_scans_roundtrip(tmp_path, parts):
    path = shared_scan(*parts)
    scan = load_scan(path)
    save_scan(scan, tmp_path / "out.obj")
    back = load_scan(tmp_path / "out.obj")
    assert np.array_equal(back.positions, scan.positions) and np.array_equal(back.faces, scan.faces)
    if path.suffix != ".obj":  # float32 sources survive GLB exactly too
        save_scan(scan, tmp_path / "out.glb")
        assert same_triangles(scan, load_scan(tmp_path / "out.glb"))


def test_never_overwrites_the_input(tmp_path, cube):
    save_scan(cube, tmp_path / "in.obj")
    scan = load_scan(tmp_path / "in.obj")
    before = (tmp_path / "in.obj").read_bytes()
    from scantex.errors import ScanError

    with pytest.raises(ScanError, match="overwrite the input"):
        save_scan(scan, tmp_path / "in.obj")
    assert (tmp_path / "in.obj").read_bytes() == before


MESH_ARRAYS = ("positions", "faces", "uvs", "face_uvs", "face_materials", "normals", "face_normals_idx",
               "vertex_colors")


def read_both_ways(path, monkeypatch) -> tuple:
    """``(scan read as load_scan reads it, the same read line by line, whether the bulk reader read it)``."""
    from scantex.io import obj

    bulk = []
    real = obj._parse_bulk
    with monkeypatch.context() as m:
        m.setattr(obj, "_parse_bulk", lambda data: bulk.append(real(data)) or bulk[-1])
        scan = load_scan(path)
    with monkeypatch.context() as m:
        m.setattr(obj, "_parse_bulk", lambda data: None)
        m.setattr(obj, "_triangles_fast", lambda face_lines: None)
        line_by_line = load_scan(path)
    return scan, line_by_line, bulk[0] is not None


def assert_same_mesh(a, b):
    for name in MESH_ARRAYS:
        x, y = getattr(a, name), getattr(b, name)
        assert (x is None) == (y is None), name
        if x is not None:
            assert x.dtype == y.dtype and np.array_equal(x, y, equal_nan=x.dtype.kind == "f"), name
    assert [m.name for m in a.materials] == [m.name for m in b.materials]


@pytest.mark.parametrize("corner", ["{v}", "{v}/{t}", "{v}//{n}", "{v}/{t}/{n}", "{v}/{t}/{n} mixed", "-{v}"])
def test_obj_bulk_reader_agrees_with_the_line_by_line_one(tmp_path, corner, monkeypatch):
    """Triangles written alike are read in bulk; anything else (here: one face without its vt, relative
    indices) falls back to the line reader. Both must read the same mesh."""
    rng = np.random.default_rng(0)
    n = 12
    lines = [f"v {x} {y} {z}" for x, y, z in rng.random((n, 3))]
    lines += [f"vt {u} {w}" for u, w in rng.random((n, 2))]
    lines += [f"vn {x} {y} {z}" for x, y, z in rng.random((n, 3))]
    pattern = corner.split()[0]
    for f, tri in enumerate(rng.integers(1, n + 1, (20, 3))):
        if f == 5:
            lines.append("usemtl second")
        write = "{v}//{n}" if "mixed" in corner and f == 7 else pattern
        if pattern.startswith("-"):
            tri = tri - n - 1  # relative indices: -1 is the latest vertex
            write = "{v}"
        lines.append("f " + " ".join(write.format(v=i, t=i, n=i) for i in tri))
    path = tmp_path / "m.obj"
    path.write_text("\n".join(lines) + "\n")
    scan, line_by_line, bulk = read_both_ways(path, monkeypatch)
    assert bulk == (corner == pattern and not pattern.startswith("-"))  # in bulk when alike
    assert_same_mesh(scan, line_by_line)


def test_obj_bulk_reader_reads_objects_written_one_after_another(tmp_path, monkeypatch):
    """A file of several objects, each its vertices then its faces: indices past the first object's vertices
    are checked face by face against the vertices read so far, still in bulk; one pointing past them is left
    to the line reader."""
    square = "v 0 0 {z}\nv 1 0 {z}\nv 1 1 {z}\nv 0 1 {z}\nf {a} {b} {c}\nf {a} {c} {d}\n"
    text = square.format(z=0, a=1, b=2, c=3, d=4) + square.format(z=1, a=5, b=6, c=7, d=8)
    (tmp_path / "two.obj").write_text(text)
    scan, line_by_line, bulk = read_both_ways(tmp_path / "two.obj", monkeypatch)
    assert bulk and scan.faces.tolist() == [[0, 1, 2], [0, 2, 3], [4, 5, 6], [4, 6, 7]]
    (tmp_path / "ahead.obj").write_text(text.replace("f 1 3 4", "f 1 3 5"))  # vertex 5 is not read yet there
    scan, line_by_line, bulk = read_both_ways(tmp_path / "ahead.obj", monkeypatch)
    assert not bulk and scan.faces.tolist()[1] == [0, 2, 4]


def scanner_obj(rng, *, colours=False, uvw=False, normals=True, crlf=False, bom=False, materials=2,
                digits=None) -> bytes:
    """An OBJ as scanners and apps write one: comments, groups, vertices (colours), texture coordinates (a third
    component), normals, faces in runs between usemtl lines."""
    n, f = 40, 60
    fmt = (lambda x: repr(float(x))) if digits is None else (lambda x: f"{x:.{digits}f}")
    xyz = rng.standard_normal((n, 3)) * 10.0 ** rng.integers(-6, 6, (n, 1))
    lines = ["# exported", "mtllib m.mtl", "o scan", "g part"]
    lines += ["v " + " ".join(map(fmt, p)) + (" " + " ".join(map(fmt, rng.random(3))) if colours else "")
              for p in xyz]
    lines += ["vt " + " ".join(map(fmt, rng.random(3 if uvw else 2))) for _ in range(n)]
    lines += ["vn " + " ".join(map(fmt, rng.standard_normal(3))) for _ in range(n)] if normals else []
    lines.append("s off")
    for k, tri in enumerate(rng.integers(1, n + 1, (f, 3))):
        if k % (f // materials) == 0:
            lines.append(f"usemtl mat{k // (f // materials) % materials}")
        corner = "{0}/{0}/{0}" if normals else "{0}/{0}"
        lines.append("f " + " ".join(corner.format(i) for i in tri))
    text = ("\r\n" if crlf else "\n").join(lines) + ("\r\n" if crlf else "\n")
    return (b"\xef\xbb\xbf" if bom else b"") + text.encode()


@pytest.mark.parametrize("options", [{}, {"colours": True}, {"uvw": True}, {"normals": False}, {"crlf": True},
                                     {"bom": True}, {"materials": 1}, {"digits": 6}, {"digits": 0}],
                         ids=lambda o: ",".join(f"{k}={v}" for k, v in o.items()) or "plain")
def test_obj_bulk_reader_reads_what_scanners_write_bit_for_bit(tmp_path, options, monkeypatch):
    """A 2,000,000-face OBJ took 10 s and 2.0 GB to read line by line; the bulk reader takes the files scanners
    write (5 s, 0.8 GB): every number as the line reader reads it, bit for bit."""
    path = tmp_path / "m.obj"
    path.write_bytes(scanner_obj(np.random.default_rng(len(options)), **options))
    (tmp_path / "m.mtl").write_text("newmtl mat0\nKd 1 0 0\nnewmtl mat1\nKd 0 1 0\n")
    scan, line_by_line, bulk = read_both_ways(path, monkeypatch)
    assert bulk
    assert_same_mesh(scan, line_by_line)
    assert (scan.vertex_colors is not None) == bool(options.get("colours"))
    assert len(scan.materials) == options.get("materials", 2)


def test_obj_bulk_reader_leaves_the_rest_to_the_line_reader(tmp_path, monkeypatch):
    """Whatever the bulk reader does not take, the line reader reads (or refuses, naming the line); what both
    read, they read alike. The bytes of a scanner's file, mutated at random."""
    from scantex.errors import ScanError

    rng = np.random.default_rng(7)
    base = scanner_obj(rng, normals=False)
    path = tmp_path / "m.obj"
    (tmp_path / "m.mtl").write_text("newmtl mat0\nnewmtl mat1\n")
    taken = 0
    for trial in range(60):
        data = bytearray(base)
        for _ in range(int(rng.integers(1, 4))):
            at = int(rng.integers(0, len(data)))
            data[at:at + 1] = bytes([int(rng.choice(list(b" \t\r\n/-.e0123456789vtfnx")))])
        path.write_bytes(bytes(data))
        try:
            scan, line_by_line, bulk = read_both_ways(path, monkeypatch)
        except ScanError:
            continue
        taken += bulk
        assert_same_mesh(scan, line_by_line)
    assert taken > 5


@pytest.mark.parametrize("data", [b"v 1 2 3\nv 0 1 0\nf 1 1 2\n\x0cv 5 5 5\nf 3 1 2\n",
                                  b"v 1 2 3\nv 0 1 0\nusemtl a\xc2\x85f 1 1 2\nf 1 1 2\n",
                                  b"v 1 2 3\nv 0 1 0\nusemtl \xe2\x80\xa8b\nf 1 1 2\n",
                                  b"v 1 2 3\nv 0 1 0\nf 1 1\xc2\xa02\n", b"v 1 2 3\nv 0 1 0\nf 1 1\x1f2\n"],
                         ids=["form feed", "NEL", "line separator", "no-break space", "unit separator"])
def test_obj_lines_end_and_split_where_the_line_reader_says(tmp_path, data, monkeypatch):
    """Found by fuzzing the bulk reader against the line reader: str.splitlines ends a line at a form feed, NEL or
    line separator, where the bulk reader read on (a vertex, a face or a material name lost or made up); and a
    no-break space between indices made the line reader's own bulk pass raise numpy's ValueError, an internal
    error, instead of reading the face."""
    path = tmp_path / "m.obj"
    path.write_bytes(data)
    scan, line_by_line, bulk = read_both_ways(path, monkeypatch)
    assert not bulk
    assert_same_mesh(scan, line_by_line)


def _glb_images(path) -> tuple[list[dict], list[bytes]]:
    """A GLB's ``images`` entries and each one's embedded bytes."""
    import json
    import struct

    blob = path.read_bytes()
    json_len = struct.unpack("<I", blob[12:16])[0]
    doc = json.loads(blob[20:20 + json_len])
    binary = blob[20 + json_len + 8:]
    views = [doc["bufferViews"][image["bufferView"]] for image in doc["images"]]
    return doc["images"], [binary[v.get("byteOffset", 0):v.get("byteOffset", 0) + v["byteLength"]] for v in views]


def test_jpeg_atlases_written_and_read_back_with_the_geometry_untouched(tmp_path):
    """``TextureEncoder("jpeg")``: the OBJ's atlas is a .jpg its MTL names, the GLB embeds the same bytes as
    image/jpeg, both read back to the atlas within the codec's loss (which ``jpeg_psnr`` measures), and the
    geometry comes back bit for bit."""
    from scantex.io.images import TextureEncoder

    wall = grid_wall(24, 18)
    y, x = np.mgrid[0:256, 0:256]
    atlas = np.stack([x, y, (x + y) // 2], axis=-1).astype(np.uint8)  # smooth: JPEG keeps it closely
    wall = wall.replace(materials=(dataclasses.replace(wall.materials[0], image=atlas),))
    encoder = TextureEncoder("jpeg", 90)
    save_scan(wall, tmp_path / "w.obj", encoder=encoder)
    save_scan(wall, tmp_path / "w.glb", encoder=encoder)
    assert "map_Kd w_" in (tmp_path / "w.mtl").read_text() and (tmp_path / "w.mtl").read_text().strip().endswith(".jpg")
    jpg = next(tmp_path.glob("w_*.jpg"))
    assert not list(tmp_path.glob("w_*.png")) and jpg.read_bytes()[:2] == b"\xff\xd8"
    images, data = _glb_images(tmp_path / "w.glb")
    assert [i["mimeType"] for i in images] == ["image/jpeg"] and data[0].rstrip(b"\0") == jpg.read_bytes()
    measured = encoder.jpeg_psnr(atlas)
    assert 35 < measured < 80
    for name in ("w.obj", "w.glb"):
        back = load_scan(tmp_path / name)
        assert same_triangles(wall if name.endswith(".obj") else float32_scan(wall), back)  # GLB holds float32
        err = back.materials[0].image.astype(float) - atlas
        assert 10 * np.log10(255**2 / np.mean(err**2)) == pytest.approx(measured, abs=1e-6)
    assert np.array_equal(load_scan(tmp_path / "w.obj").positions, wall.positions)


def test_jpeg_keeps_transparent_atlases_and_other_maps_as_png(tmp_path):
    """JPEG has no alpha: an atlas with transparent texels stays PNG (an all-opaque alpha is dropped into a
    JPEG); a material's other maps without bytes of their own are PNG, whatever the colour's format."""
    from scantex.io.images import TextureEncoder
    from scantex.scan import TextureMap

    wall = grid_wall(8, 6)
    rng = np.random.default_rng(0)
    rgba = rng.integers(0, 256, (32, 32, 4), dtype=np.uint8)
    opaque = rgba.copy()
    opaque[..., 3] = 255
    encoder = TextureEncoder("jpeg")
    assert not encoder.writes_jpeg(rgba) and encoder.suffix(rgba) == "png"
    assert encoder.writes_jpeg(opaque) and encoder.suffix(opaque) == "jpg"
    assert encoder.jpeg_psnr(rgba) is None
    normal = TextureMap(rng.integers(0, 256, (32, 32, 3), dtype=np.uint8))
    material = dataclasses.replace(wall.materials[0], image=rgba, maps={"normal": normal})
    save_scan(wall.replace(materials=(material,)), tmp_path / "t.obj", encoder=encoder)
    written = sorted(p.name for p in tmp_path.iterdir())
    assert [n for n in written if n.endswith((".jpg", ".png"))] == sorted(
        n for n in written if n.endswith(".png")), written
    assert (tmp_path / load_scan(tmp_path / "t.obj").materials[0].image_name).read_bytes() == TextureEncoder().png(rgba)
    save_scan(wall.replace(materials=(dataclasses.replace(material, image=opaque),)), tmp_path / "o.obj",
              encoder=encoder)
    assert {p.suffix for p in tmp_path.glob("o_*")} == {".jpg", ".png"}  # the colour as JPEG, the normal map PNG
    with pytest.raises(ValueError, match="gif"):
        TextureEncoder("gif")
    with pytest.raises(ValueError, match="quality"):
        TextureEncoder("jpeg", 0)


def test_a_colour_texture_never_takes_a_maps_file_name(tmp_path):
    """Material ``m_normal``'s colour texture and material ``m``'s normal map would both be ``x_m_normal.jpg``
    (JPEG atlases; every Polycam map is a JPEG): one file, the normal map replaced by an atlas. Each gets a
    file of its own, and the MTL names the right one."""
    import io

    from PIL import Image

    from scantex.io.images import TextureEncoder
    from scantex.scan import TextureMap

    wall = grid_wall(8, 6)
    rng = np.random.default_rng(1)
    buffer = io.BytesIO()
    Image.fromarray(rng.integers(0, 256, (16, 16, 3), dtype=np.uint8)).save(buffer, format="JPEG")
    normal = TextureMap.of(Image.open(io.BytesIO(buffer.getvalue())), buffer.getvalue())
    atlas = rng.integers(0, 256, (16, 16, 3), dtype=np.uint8)
    first = dataclasses.replace(wall.materials[0], name="m", image=atlas, maps={"normal": normal})
    second = dataclasses.replace(wall.materials[0], name="m_normal", image=atlas[::-1].copy())
    half = np.arange(wall.n_faces) >= wall.n_faces // 2
    scan = wall.replace(materials=(first, second), face_materials=half.astype(np.int32))
    written = save_scan(scan, tmp_path / "x.obj", encoder=TextureEncoder("jpeg"))
    assert len(written) == len(set(written)) == 5  # OBJ, MTL, two atlases, the normal map
    mtl = (tmp_path / "x.mtl").read_text().split()
    normal_file = mtl[mtl.index("norm") + 1]
    assert (tmp_path / normal_file).read_bytes() == buffer.getvalue()
    assert normal_file not in [mtl[i + 1] for i, word in enumerate(mtl) if word == "map_Kd"]
