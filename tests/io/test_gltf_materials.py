"""A GLB's shading goes out as it came in: its vertex normals, its material's other maps (a Polycam GLB's
normal and occlusion maps) as their own bytes, and its material parameters; scantex changes the colour."""

from __future__ import annotations

import io
import json
import logging
import struct

import numpy as np
import pytest
import trimesh
from PIL import Image

from scantex.io import load_scan, save_scan
from scantex.pipeline.enhance import enhance
from scantex.scan import Material, Scan, TextureMap
from scantex.uv import plan_uvs
from tests.conftest import checker, grid_wall, shared_scan, textured_cube
from tests.pipeline.test_enhance import TOY


def glb_document(path) -> tuple[dict, bytes]:
    blob = path.read_bytes()
    length = struct.unpack("<I", blob[12:16])[0]
    return json.loads(blob[20:20 + length]), blob[20 + length + 8:]


def embedded(path, image: int) -> bytes:
    doc, binary = glb_document(path)
    view = doc["bufferViews"][doc["images"][image]["bufferView"]]
    start = view.get("byteOffset", 0)
    return binary[start:start + view["byteLength"]]


def jpeg(image: np.ndarray) -> bytes:
    buffer = io.BytesIO()
    Image.fromarray(image).save(buffer, format="JPEG", quality=90)
    return buffer.getvalue()


def as_stored(data: bytes):
    """A PIL image that trimesh's export embeds as ``data`` itself (it would encode a JPEG again)."""
    image = Image.open(io.BytesIO(data))
    image.save = lambda fp, format=None, **params: fp.write(data)  # noqa: A002
    return image


def unpadded(data: bytes) -> bytes:
    return data.rstrip(b"\0")  # a buffer view is padded to 4 bytes; a JPEG ends in FFD9, a PNG in IEND's CRC


def scanner_glb(path, n: int = 10) -> dict:
    """A GLB as Polycam writes one: a curved surface with smooth vertex normals, a colour texture, and a
    material with JPEG normal and occlusion maps, not metallic, a roughness and one side. Returns what
    it holds."""
    rng = np.random.default_rng(1)
    u, v = np.meshgrid(np.linspace(0, 1, n), np.linspace(0, 1, n))
    positions = np.stack([u.ravel(), 0.2 * np.sin(3 * u.ravel()), v.ravel()], axis=1)
    idx = np.arange(n * n).reshape(n, n)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, 1:].ravel(), idx[1:, :-1].ravel()
    faces = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])
    normals = trimesh.Trimesh(positions, faces, process=False).vertex_normals.copy()
    normal_map = np.clip(rng.normal([128, 128, 255], 20, (64, 64, 3)), 0, 255).astype(np.uint8)
    occlusion = np.clip(rng.normal(200, 30, (64, 64)), 0, 255).astype(np.uint8)
    files = {"normal": jpeg(normal_map), "occlusion": jpeg(occlusion)}
    pbr = trimesh.visual.material.PBRMaterial(
        baseColorTexture=Image.fromarray(checker(64, 4)), metallicFactor=0.0, roughnessFactor=0.6,
        doubleSided=False, normalTexture=as_stored(files["normal"]), occlusionTexture=as_stored(files["occlusion"]))
    mesh = trimesh.Trimesh(positions, faces, vertex_normals=normals, process=False,
                           visual=trimesh.visual.TextureVisuals(uv=np.stack([u.ravel(), v.ravel()], 1), material=pbr))
    path.write_bytes(trimesh.Scene(mesh).export(file_type="glb"))
    return {"normals": normals, "files": files}


def material_of(path) -> tuple[dict, dict]:
    """The written GLB's one material and its maps' embedded bytes by kind."""
    doc, _ = glb_document(path)
    (material,) = doc["materials"]
    maps = {kind: unpadded(embedded(path, doc["textures"][material[key]["index"]]["source"]))
            for kind, key in (("normal", "normalTexture"), ("occlusion", "occlusionTexture")) if key in material}
    return material, maps


def test_a_glb_is_read_with_its_normals_maps_and_parameters(tmp_path):
    made = scanner_glb(tmp_path / "raw.glb")
    scan = load_scan(tmp_path / "raw.glb")
    (material,) = scan.materials
    assert set(material.maps) == {"normal", "occlusion"}
    for kind, data in made["files"].items():
        assert unpadded(material.maps[kind].encoded) == data  # the file's own JPEG, to be written back as it is
        assert np.array_equal(material.maps[kind].image, np.asarray(Image.open(io.BytesIO(data))))
    assert material.gltf == {"metallicFactor": 0.0, "roughnessFactor": 0.6, "doubleSided": False}
    assert np.allclose(scan.normals, made["normals"], atol=1e-6)
    assert np.array_equal(scan.face_normals_idx, scan.faces)
    assert "normal map + occlusion map" in scan.summary() and scan.summary().endswith(", vertex normals")
    assert scan.up == "y"  # glTF is y-up by the format's rule: views are planned so


def test_the_glb_written_keeps_them(tmp_path):
    """Before: the GLB written had no NORMAL (a glTF viewer shades it flat, every triangle visible), no normal
    or occlusion map, and was double-sided, roughness 1."""
    made = scanner_glb(tmp_path / "raw.glb")
    scan = load_scan(tmp_path / "raw.glb")
    save_scan(scan, tmp_path / "out.glb")
    material, maps = material_of(tmp_path / "out.glb")
    assert maps == made["files"]  # byte for byte
    assert material["doubleSided"] is False
    assert material["pbrMetallicRoughness"]["roughnessFactor"] == 0.6
    assert material["pbrMetallicRoughness"]["metallicFactor"] == 0.0
    doc, _ = glb_document(tmp_path / "out.glb")
    assert all("NORMAL" in p["attributes"] for m in doc["meshes"] for p in m["primitives"])
    back = load_scan(tmp_path / "out.glb")
    assert np.allclose(back.normals, made["normals"], atol=1e-6)
    assert np.array_equal(back.positions, scan.positions) and np.array_equal(back.faces, scan.faces)
    # the OBJ written keeps the normals (vn) too
    save_scan(scan, tmp_path / "out.obj")
    obj = load_scan(tmp_path / "out.obj")
    assert np.array_equal(obj.normals[obj.face_normals_idx], scan.normals[scan.face_normals_idx])


def test_an_enhanced_glb_keeps_its_maps(tmp_path):
    """The enhance run changes the colour only: the same UV layout, so the maps still fit it."""
    made = scanner_glb(tmp_path / "raw.glb", n=16)
    scan = load_scan(tmp_path / "raw.glb")
    result = enhance(scan, TOY)
    assert result.scan.materials[0].maps == scan.materials[0].maps
    save_scan(result.scan, tmp_path / "enhanced.glb")
    material, maps = material_of(tmp_path / "enhanced.glb")
    assert maps == made["files"] and material["doubleSided"] is False
    assert np.array_equal(load_scan(tmp_path / "enhanced.glb").materials[0].image, result.scan.materials[0].image)


def test_a_new_layout_leaves_the_maps_out_and_says_so(tmp_path, caplog):
    scanner_glb(tmp_path / "raw.glb")
    scan = load_scan(tmp_path / "raw.glb")
    with caplog.at_level(logging.WARNING):
        plan = plan_uvs(scan, "unwrap", texture_size=64, use_xatlas=False)
    assert plan.scan.materials[0].maps == {} and plan.report["maps_left_out"] == ["normal", "occlusion"]
    assert "normal and occlusion maps are left out" in caplog.text
    assert plan_uvs(scan, "keep").scan.materials[0].maps == scan.materials[0].maps


def rewritten_glb(source, target, edit) -> None:
    """``source``'s GLB with its JSON document changed by ``edit(doc)``."""
    doc, binary = glb_document(source)
    edit(doc)
    text = json.dumps(doc).encode()
    text += b" " * (-len(text) % 4)
    chunks = struct.pack("<I", len(text)) + b"JSON" + text + struct.pack("<I", len(binary)) + b"BIN\0" + binary
    target.write_bytes(b"glTF" + struct.pack("<II", 2, 12 + len(chunks)) + chunks)


def test_a_map_on_a_second_uv_layout_is_left_out(tmp_path, caplog):
    scanner_glb(tmp_path / "raw.glb")

    def second_layout(doc):
        (primitive,) = doc["meshes"][0]["primitives"]
        doc["accessors"].append(dict(doc["accessors"][primitive["attributes"]["TEXCOORD_0"]]))
        primitive["attributes"]["TEXCOORD_1"] = len(doc["accessors"]) - 1
        doc["materials"][0]["occlusionTexture"]["texCoord"] = 1

    rewritten_glb(tmp_path / "raw.glb", tmp_path / "two.glb", second_layout)
    with caplog.at_level(logging.WARNING):
        scan = load_scan(tmp_path / "two.glb")
    assert set(scan.materials[0].maps) == {"normal"} and "occlusion maps are drawn in a second UV layout" in caplog.text

    def same_layout(doc):  # as the Polycam plant writes it: TEXCOORD_1 the very accessor of TEXCOORD_0
        (primitive,) = doc["meshes"][0]["primitives"]
        primitive["attributes"]["TEXCOORD_1"] = primitive["attributes"]["TEXCOORD_0"]
        doc["materials"][0]["occlusionTexture"]["texCoord"] = 1

    rewritten_glb(tmp_path / "raw.glb", tmp_path / "same.glb", same_layout)
    assert set(load_scan(tmp_path / "same.glb").materials[0].maps) == {"normal", "occlusion"}


def test_obj_normals_on_their_own_indices_reach_the_glb(tmp_path):
    """An OBJ's ``vn`` index differs from its ``v`` index (a flat-shaded export: one normal a face): the GLB
    splits its vertices by (position, UV, normal) and each corner keeps its own normal."""
    wall = grid_wall(n=6)
    tilt = np.random.default_rng(2).normal(0, 0.2, (wall.n_faces, 3)) + [0, -1, 0]
    normals = tilt / np.linalg.norm(tilt, axis=1, keepdims=True)
    scan = Scan(wall.positions, wall.faces, wall.uvs, wall.face_uvs, None, wall.materials, normals=normals,
                face_normals_idx=np.repeat(np.arange(wall.n_faces)[:, None], 3, axis=1))
    save_scan(scan, tmp_path / "flat.glb")
    back = load_scan(tmp_path / "flat.glb")
    corners = back.normals[back.face_normals_idx]  # (F, 3 corners, 3)
    assert np.allclose(corners, normals[:, None, :], atol=1e-6)
    assert np.array_equal(back.positions[back.faces], scan.positions.astype(np.float32)[scan.faces].astype(np.float64))


def test_a_scan_without_normals_or_maps_is_written_as_before(tmp_path, wall):
    """No NORMAL invented, scantex's own material: matte, not metallic, seen from both sides."""
    save_scan(wall, tmp_path / "w.glb")
    doc, _ = glb_document(tmp_path / "w.glb")
    assert all("NORMAL" not in p["attributes"] for m in doc["meshes"] for p in m["primitives"])
    (material,) = doc["materials"]
    assert material["doubleSided"] is True and "normalTexture" not in material
    assert material["pbrMetallicRoughness"]["roughnessFactor"] == 1.0
    assert load_scan(tmp_path / "w.glb").materials[0].maps == {}


def test_a_map_without_its_files_bytes_is_written_as_png(tmp_path, wall):
    occlusion = np.full((32, 32), 180, np.uint8)
    material = Material("wall", wall.materials[0].image, maps={"occlusion": TextureMap(occlusion)})
    save_scan(wall.replace(materials=(material,)), tmp_path / "w.glb")
    back = load_scan(tmp_path / "w.glb")
    assert np.array_equal(back.materials[0].maps["occlusion"].image, occlusion)
    assert back.materials[0].maps["occlusion"].encoded.startswith(b"\x89PNG")


@pytest.mark.parametrize("name", ["tyres_on_tiled_floor_raw.glb", "potted_plant_on_rug_raw.glb"])
def test_polycam_glbs_keep_their_maps_and_normals(tmp_path, name):
    scan = load_scan(shared_scan("polycam_glb", name))
    assert set(scan.materials[0].maps) == {"normal", "occlusion"} and scan.normals is not None
    save_scan(scan, tmp_path / "out.glb")
    back = load_scan(tmp_path / "out.glb")
    for before, after in zip(scan.materials, back.materials):
        assert {k: m.encoded for k, m in before.maps.items()} == {k: m.encoded for k, m in after.maps.items()}
    assert np.allclose(back.normals, scan.normals, atol=1e-6)


def test_ply_normals_reach_both_outputs(tmp_path):
    corners = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0.3]], float)
    normals = np.array([[0, 0, 1], [0, 0.6, 0.8], [0.6, 0, 0.8], [0.48, 0.6, 0.64]])
    header = ["ply", "format ascii 1.0", "element vertex 4"] + [f"property float {a}" for a in
                                                            ("x", "y", "z", "nx", "ny", "nz")]
    header += ["element face 2", "property list uchar int vertex_indices", "end_header"]
    rows = [" ".join(map(str, [*p, *n])) for p, n in zip(corners, normals)] + ["3 0 1 2", "3 1 3 2"]
    (tmp_path / "n.ply").write_text("\n".join(header + rows) + "\n")
    scan = load_scan(tmp_path / "n.ply")
    assert np.allclose(scan.normals, normals, atol=1e-6)
    for name in ("out.glb", "out.obj"):
        save_scan(scan, tmp_path / name)
        back = load_scan(tmp_path / name)
        assert np.allclose(back.normals[back.face_normals_idx], normals[scan.faces], atol=1e-6), name


def test_the_run_says_what_shading_it_kept(tmp_path):
    from scantex.cli import shading_summary

    scanner_glb(tmp_path / "raw.glb")
    scan = load_scan(tmp_path / "raw.glb")
    assert shading_summary(scan, scan) == "shading kept as it came: the vertex normals, the normal and occlusion maps"
    relaid = plan_uvs(scan, "unwrap", texture_size=64, use_xatlas=False).scan
    assert shading_summary(scan, relaid) == ("shading kept as it came: the vertex normals\n"
                                             "shading: the input's normal and occlusion maps are left out (they are "
                                             "drawn in its UV layout, not the new one)")
    wall = grid_wall()
    assert shading_summary(wall, wall) is None
    assert texture_summary_of(scan) == (True, ["normal", "occlusion"])


def texture_summary_of(scan) -> tuple:
    from scantex.metrics.texture import texture_summary

    summary = texture_summary(scan)
    return summary["vertex_normals"], summary["other_maps"]


def test_an_obj_carries_the_normal_and_emissive_maps_under_the_pbr_statements(tmp_path):
    """MTL's PBR extension names a normal map ``norm`` and an emissive one ``map_Ke``: read into the material's
    maps (so the GLB written has them) and written back, as their own bytes. A GLB's occlusion map has no MTL
    statement: the OBJ leaves it out, the GLB keeps it."""
    made = scanner_glb(tmp_path / "raw.glb")
    scan = load_scan(tmp_path / "raw.glb")
    save_scan(scan, tmp_path / "out.obj")
    mtl = (tmp_path / "out.mtl").read_text()
    assert "norm out_material_0_normal.jpg" in mtl and "occlusion" not in mtl
    assert (tmp_path / "out_material_0_normal.jpg").read_bytes() == unpadded(scan.materials[0].maps["normal"].encoded)
    back = load_scan(tmp_path / "out.obj")
    assert set(back.materials[0].maps) == {"normal"}
    assert unpadded(back.materials[0].maps["normal"].encoded) == made["files"]["normal"]
    save_scan(back, tmp_path / "again.glb")
    assert material_of(tmp_path / "again.glb")[1] == {"normal": made["files"]["normal"]}

    # a capture's own OBJ: options before the file names, an emissive map, and a normal map the export lost
    glow = np.zeros((8, 8, 3), np.uint8)
    Image.fromarray(glow).save(tmp_path / "glow.png")
    lines = mtl.replace("norm out_material_0_normal.jpg", "norm -bm 1.0 out_material_0_normal.jpg\nmap_Ke glow.png")
    (tmp_path / "out.mtl").write_text(lines)
    back = load_scan(tmp_path / "out.obj")
    assert set(back.materials[0].maps) == {"normal", "emissive"}
    assert np.array_equal(back.materials[0].maps["emissive"].image, glow)
    assert tmp_path / "glow.png" in back.inputs  # never overwritten
    (tmp_path / "out.mtl").write_text(lines.replace("glow.png", "lost.png"))
    assert set(load_scan(tmp_path / "out.obj").materials[0].maps) == {"normal"}  # a warning says so


def test_an_unlit_scan_stays_unlit(tmp_path):
    """A photogrammetry GLB's materials say KHR_materials_unlit (the texture holds the light already): the GLB
    written says it too. An extension naming a texture, or extensions the materials differ in, are left out."""
    scanner_glb(tmp_path / "raw.glb")

    def unlit(doc):
        doc["materials"][0]["extensions"] = {"KHR_materials_unlit": {},
                                             "KHR_materials_clearcoat": {"clearcoatTexture": {"index": 0}}}
        doc["extensionsUsed"] = ["KHR_materials_unlit", "KHR_materials_clearcoat"]

    rewritten_glb(tmp_path / "raw.glb", tmp_path / "unlit.glb", unlit)
    scan = load_scan(tmp_path / "unlit.glb")
    assert scan.materials[0].gltf["extensions"] == {"KHR_materials_unlit": {}}
    save_scan(scan, tmp_path / "out.glb")
    doc, _ = glb_document(tmp_path / "out.glb")
    assert doc["materials"][0]["extensions"] == {"KHR_materials_unlit": {}}
    assert doc["extensionsUsed"] == ["KHR_materials_unlit"]
    back = load_scan(tmp_path / "out.glb")  # the file stays readable, its geometry and maps as they were
    assert np.array_equal(back.positions, scan.positions) and set(back.materials[0].maps) == {"normal", "occlusion"}
    assert back.materials[0].gltf["extensions"] == {"KHR_materials_unlit": {}}

    def two_materials_differ(doc):
        doc["materials"].append(dict(doc["materials"][0], extensions={}))

    rewritten_glb(tmp_path / "unlit.glb", tmp_path / "mixed.glb", two_materials_differ)
    assert "extensions" not in load_scan(tmp_path / "mixed.glb").materials[0].gltf


def test_gltf_file_uris_are_percent_decoded(tmp_path):
    """A glTF names its files by URI: ``texture%200.png`` is the file ``texture 0.png`` (Blender writes a space
    so). The texture had been refused as missing, and trimesh alone drops it without a word."""
    scan = textured_cube(materials=1)
    save_scan(scan, tmp_path / "c.glb")
    files = trimesh.load(tmp_path / "c.glb", process=False).export(file_type="gltf")
    doc = json.loads(files.pop("model.gltf"))
    assert len(doc["images"]) == 1
    Image.fromarray(scan.materials[0].image[..., :3]).save(tmp_path / "texture 0.png")
    doc["images"][0] = {"uri": "texture%200.png", "mimeType": "image/png"}  # a file, not the buffer's copy
    for name, data in files.items():
        (tmp_path / name).write_bytes(data)
    (tmp_path / "m.gltf").write_text(json.dumps(doc))
    back = load_scan(tmp_path / "m.gltf")
    assert back.materials[0].image is not None
    assert np.array_equal(back.materials[0].image[..., :3], scan.materials[0].image[..., :3])
