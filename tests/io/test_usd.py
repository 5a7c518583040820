"""USD scans (``.usdz``): made here with Pixar's library as iOS capture apps write them, read into the same
geometry, texture coordinates, normals and materials, and enhanced like any other scan."""

from __future__ import annotations

import sys

import numpy as np
import pytest
from PIL import Image

from scantex.deps import MissingDependency
from scantex.errors import ScanError
from scantex.io import load_scan, save_scan
from scantex.io.discover import find_capture
from scantex.pipeline.enhance import enhance
from scantex.scan import up_axis
from tests.conftest import checker
from tests.pipeline.test_enhance import TOY

pxr = pytest.importorskip("pxr")
from pxr import Gf, Sdf, Usd, UsdGeom, UsdShade, UsdUtils, Vt  # noqa: E402


def grid(n: int = 6):
    """An ``n x n`` grid of quads in the x-y plane: points, quad counts and corner indices, per-point UVs."""
    u, v = np.meshgrid(np.linspace(0, 1, n), np.linspace(0, 1, n))
    points = np.stack([u.ravel(), v.ravel(), 0.05 * np.sin(4 * u.ravel())], axis=1)
    idx = np.arange(n * n).reshape(n, n)
    quads = np.stack([idx[:-1, :-1], idx[:-1, 1:], idx[1:, 1:], idx[1:, :-1]], axis=-1).reshape(-1, 4)
    return points, quads, np.stack([u.ravel(), v.ravel()], axis=1)


def textured(stage, where: str, texture: str, *, normal_map: str | None = None, roughness: float | None = None):
    """A UsdPreviewSurface reading ``texture`` through the ``st`` primvar (and a normal map)."""
    material = UsdShade.Material.Define(stage, where)
    surface = UsdShade.Shader.Define(stage, f"{where}/surface")
    surface.CreateIdAttr("UsdPreviewSurface")
    reader = UsdShade.Shader.Define(stage, f"{where}/st")
    reader.CreateIdAttr("UsdPrimvarReader_float2")
    reader.CreateInput("varname", Sdf.ValueTypeNames.Token).Set("st")

    def image(name: str, file: str, output: str, input_name: str, kind):
        shader = UsdShade.Shader.Define(stage, f"{where}/{name}")
        shader.CreateIdAttr("UsdUVTexture")
        shader.CreateInput("file", Sdf.ValueTypeNames.Asset).Set(file)
        shader.CreateInput("st", Sdf.ValueTypeNames.Float2).ConnectToSource(reader.ConnectableAPI(), "result")
        surface.CreateInput(input_name, kind).ConnectToSource(shader.ConnectableAPI(), output)

    image("diffuse", texture, "rgb", "diffuseColor", Sdf.ValueTypeNames.Color3f)
    if normal_map:
        image("normals", normal_map, "rgb", "normal", Sdf.ValueTypeNames.Normal3f)
    if roughness is not None:
        surface.CreateInput("roughness", Sdf.ValueTypeNames.Float).Set(roughness)
    material.CreateSurfaceOutput().ConnectToSource(surface.ConnectableAPI(), "surface")
    return material


def write_usdz(folder, build) -> str:
    """``build(stage)`` into a new stage, packaged as ``folder/scan.usdz`` with the files it names."""
    stage = Usd.Stage.CreateNew(str(folder / "scan.usdc"))
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
    UsdGeom.SetStageMetersPerUnit(stage, 1.0)
    root = UsdGeom.Xform.Define(stage, "/Root")
    stage.SetDefaultPrim(root.GetPrim())
    build(stage)
    stage.GetRootLayer().Save()
    assert UsdUtils.CreateNewUsdzPackage(Sdf.AssetPath(str(folder / "scan.usdc")), str(folder / "scan.usdz"))
    return folder / "scan.usdz"


def scanner_usdz(folder, *, transform=None, left_handed=False):
    """As a capture app writes one: triangles and quads, face-varying indexed UVs, vertex normals, one material
    with a JPEG colour texture and a PNG normal map."""
    points, quads, uv = grid()
    tris = np.concatenate([quads[:5, [0, 1, 2]], quads[:5, [0, 2, 3]]])  # five quads as triangles, the rest quads
    counts = [3] * len(tris) + [4] * (len(quads) - 5)
    corners = np.concatenate([tris.ravel(), quads[5:].ravel()])
    Image.fromarray(checker(64, 4)).save(folder / "albedo.jpg", quality=95)
    normal_map = np.full((16, 16, 3), (128, 128, 255), np.uint8)
    Image.fromarray(normal_map).save(folder / "normal.png")

    def build(stage):
        mesh = UsdGeom.Mesh.Define(stage, "/Root/scan")
        mesh.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(points.astype(np.float32)))
        mesh.CreateFaceVertexCountsAttr(counts)
        mesh.CreateFaceVertexIndicesAttr(corners.tolist())
        if left_handed:
            mesh.CreateOrientationAttr(UsdGeom.Tokens.leftHanded)
        st = UsdGeom.PrimvarsAPI(mesh).CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray,
                                                      UsdGeom.Tokens.faceVarying)
        st.Set(Vt.Vec2fArray.FromNumpy(uv.astype(np.float32)))
        st.SetIndices(Vt.IntArray(corners.tolist()))
        normals = np.tile([[0.0, 0.0, 1.0]], (len(points), 1)) + 0.1 * uv[:, [0]] * [1, 0, 0]
        mesh.CreateNormalsAttr(Vt.Vec3fArray.FromNumpy(normals.astype(np.float32)))
        mesh.SetNormalsInterpolation(UsdGeom.Tokens.vertex)
        if transform is not None:
            UsdGeom.Xformable(mesh).AddTransformOp().Set(Gf.Matrix4d(*transform.ravel().tolist()))
        material = textured(stage, "/Root/material", "albedo.jpg", normal_map="normal.png", roughness=0.7)
        UsdShade.MaterialBindingAPI.Apply(mesh.GetPrim()).Bind(material)

    return write_usdz(folder, build), points, counts, corners, uv


def fan(counts, corners) -> np.ndarray:
    """The triangles the reader makes: each polygon a fan from its first corner."""
    out, at = [], 0
    for c in counts:
        out += [[corners[at], corners[at + k], corners[at + k + 1]] for k in range(1, c - 1)]
        at += c
    return np.array(out)


def test_a_usdz_is_read_exactly(tmp_path):
    path, points, counts, corners, uv = scanner_usdz(tmp_path)
    scan = load_scan(path)
    assert np.array_equal(scan.positions, points.astype(np.float32).astype(np.float64))  # bitwise, as stored
    assert np.array_equal(scan.faces, fan(counts, corners))
    # each corner's texture coordinate is its point's (the UVs were indexed by the same corner list)
    assert np.array_equal(scan.uvs[scan.face_uvs], uv.astype(np.float32)[scan.faces].astype(np.float64))
    assert scan.normals is not None and np.array_equal(scan.face_normals_idx, scan.faces)
    (material,) = scan.materials
    assert np.array_equal(material.image, np.asarray(Image.open(tmp_path / "albedo.jpg")))
    assert set(material.maps) == {"normal"}
    assert material.maps["normal"].encoded == (tmp_path / "normal.png").read_bytes()  # to be written back as it is
    assert material.gltf == {"metallicFactor": 0.0, "roughnessFactor": pytest.approx(0.7), "doubleSided": False}
    assert scan.up == "y" and up_axis(scan) == (0.0, 1.0, 0.0)
    assert scan.inputs == (path,)  # the textures are inside the package


def test_a_placed_or_left_handed_mesh_comes_out_right_handed_in_world_coordinates(tmp_path):
    turn = np.eye(4)
    turn[:3, :3] = [[0, 1, 0], [-1, 0, 0], [0, 0, 1]]  # 90 degrees about z (row vectors: p @ M)
    turn[3, :3] = [2.0, 0.0, 0.5]
    (tmp_path / "a").mkdir()
    path, points, counts, corners, uv = scanner_usdz(tmp_path / "a", transform=turn)
    scan = load_scan(path)
    world = points.astype(np.float32).astype(np.float64) @ turn[:3, :3] + turn[3, :3]
    assert np.allclose(scan.positions, world) and np.array_equal(scan.faces, fan(counts, corners))
    normals = (np.array([0.0, 0.0, 1.0]) + 0.1 * uv[:, [0]] * [1, 0, 0]) @ turn[:3, :3]  # turned with the mesh
    assert np.allclose(scan.normals, normals / np.linalg.norm(normals, axis=1, keepdims=True), atol=1e-6)
    (tmp_path / "b").mkdir()
    path, _, counts, corners, _ = scanner_usdz(tmp_path / "b", left_handed=True)
    assert np.array_equal(load_scan(path).faces, fan(counts, corners)[:, [0, 2, 1]])


def test_material_subsets_vertex_uvs_and_a_display_colour(tmp_path):
    """Two materials bound to subsets of one mesh's faces, UVs one a point, and a mesh with no material but
    a display colour."""
    points, quads, uv = grid(4)
    Image.fromarray(checker(32, 2)).save(tmp_path / "a.png")
    Image.fromarray(checker(32, 4, colors=((10, 200, 10), (200, 200, 10)))).save(tmp_path / "b.png")

    def build(stage):
        mesh = UsdGeom.Mesh.Define(stage, "/Root/scan")
        mesh.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(points.astype(np.float32)))
        mesh.CreateFaceVertexCountsAttr([4] * len(quads))
        mesh.CreateFaceVertexIndicesAttr(quads.ravel().tolist())
        st = UsdGeom.PrimvarsAPI(mesh).CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray, UsdGeom.Tokens.vertex)
        st.Set(Vt.Vec2fArray.FromNumpy(uv.astype(np.float32)))
        binding = UsdShade.MaterialBindingAPI.Apply(mesh.GetPrim())
        for name, faces in (("a", [0, 1, 2, 3]), ("b", list(range(4, len(quads))))):
            subset = binding.CreateMaterialBindSubset(name, Vt.IntArray(faces))
            UsdShade.MaterialBindingAPI.Apply(subset.GetPrim()).Bind(textured(stage, f"/Root/{name}", f"{name}.png"))
        other = UsdGeom.Mesh.Define(stage, "/Root/box")
        other.CreatePointsAttr([(0, 0, 1), (1, 0, 1), (0, 1, 1)])
        other.CreateFaceVertexCountsAttr([3])
        other.CreateFaceVertexIndicesAttr([0, 1, 2])
        other.CreateDisplayColorAttr([(0.2, 0.4, 0.6)])

    scan = load_scan(write_usdz(tmp_path, build))
    assert [m.name for m in scan.materials] == ["a", "b", "box"]
    quads_faces = 2 * len(quads)
    assert np.array_equal(scan.face_materials[:quads_faces], np.repeat([0] * 4 + [1] * (len(quads) - 4), 2))
    assert scan.face_materials[-1] == 2 and scan.materials[2].image is None
    assert scan.materials[2].diffuse == pytest.approx((0.2, 0.4, 0.6, 1.0))
    assert np.array_equal(scan.uvs[scan.face_uvs[:quads_faces]], uv.astype(np.float32)[scan.faces[:quads_faces]])
    assert scan.normals is None  # neither mesh has normals


def test_an_enhanced_usdz_keeps_its_geometry(tmp_path):
    path, *_ = scanner_usdz(tmp_path)
    scan = load_scan(path)
    result = enhance(scan, TOY)
    assert result.scan.positions is scan.positions and result.scan.faces is scan.faces
    save_scan(result.scan, tmp_path / "out.glb")
    back = load_scan(tmp_path / "out.glb")
    assert set(back.materials[0].maps) == {"normal"} and back.normals is not None


def test_a_folder_with_a_usdz_is_found(tmp_path):
    path, *_ = scanner_usdz(tmp_path)
    (tmp_path / "scan.usdc").unlink()
    (tmp_path / "albedo.jpg").unlink()
    (tmp_path / "normal.png").unlink()
    assert find_capture(tmp_path).mesh == path


def test_bad_usd_files_are_one_line_errors(tmp_path):
    (tmp_path / "junk.usdz").write_bytes(b"PK\x03\x04 not really a package")
    with pytest.raises(ScanError, match="junk.usdz"):
        load_scan(tmp_path / "junk.usdz")
    (tmp_path / "typo.usda").write_text("#usda 1.0\n(\n  bad")
    # USD's own words (line 3, in the words of its version), its C++ source location left out
    with pytest.raises(ScanError, match=r"cannot read USD file: (.*typo\.usda:3:3: Expected \)|syntax error .* line 3)"):
        load_scan(tmp_path / "typo.usda")
    (tmp_path / "empty.usda").write_text("#usda 1.0\n")
    with pytest.raises(ScanError, match="no mesh"):
        load_scan(tmp_path / "empty.usda")

    def broken(stage):
        mesh = UsdGeom.Mesh.Define(stage, "/Root/scan")
        mesh.CreatePointsAttr([(0, 0, 0), (1, 0, 0), (0, 1, 0)])
        mesh.CreateFaceVertexCountsAttr([3])
        mesh.CreateFaceVertexIndicesAttr([0, 1, 7])

    with pytest.raises(ScanError, match="refers to point 8"):
        load_scan(write_usdz(tmp_path, broken))


def test_a_missing_texture_is_a_warning_and_an_untextured_material(tmp_path, caplog):
    points, quads, uv = grid(3)

    def build(stage):
        mesh = UsdGeom.Mesh.Define(stage, "/Root/scan")
        mesh.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(points.astype(np.float32)))
        mesh.CreateFaceVertexCountsAttr([4] * len(quads))
        mesh.CreateFaceVertexIndicesAttr(quads.ravel().tolist())
        UsdShade.MaterialBindingAPI.Apply(mesh.GetPrim()).Bind(textured(stage, "/Root/m", "gone.png"))

    stage_path = tmp_path / "scan.usda"
    stage = Usd.Stage.CreateNew(str(stage_path))
    UsdGeom.Xform.Define(stage, "/Root")
    build(stage)
    stage.GetRootLayer().Save()
    scan = load_scan(stage_path)
    assert scan.materials[0].image is None and "gone.png" in caplog.text


def test_without_usd_core_the_error_says_what_to_install(tmp_path, monkeypatch):
    path, *_ = scanner_usdz(tmp_path)
    monkeypatch.setitem(sys.modules, "pxr", None)
    with pytest.raises(MissingDependency, match=r"pip install 'scantex\[usd\]'"):
        load_scan(path)



def test_a_usdz_written_reads_back_the_same(tmp_path, cube):
    """Two materials on face subsets, UVs and normals on their own indices, the up axis: all come back."""
    normals = np.random.default_rng(3).normal(size=(cube.n_faces, 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    scan = cube.replace(normals=normals, face_normals_idx=np.repeat(np.arange(cube.n_faces)[:, None], 3, 1), up="y")
    save_scan(scan, tmp_path / "cube.usdz")
    back = load_scan(tmp_path / "cube.usdz")
    assert np.array_equal(back.positions, scan.positions.astype(np.float32)) and np.array_equal(back.faces, scan.faces)
    assert np.array_equal(back.uvs[back.face_uvs], scan.uvs.astype(np.float32)[scan.face_uvs])
    assert np.allclose(back.normals[back.face_normals_idx], normals[:, None, :], atol=1e-6)
    assert np.array_equal(back.face_materials, scan.face_materials) and back.up == "y"
    assert [m.name for m in back.materials] == [m.name for m in scan.materials]
    assert all(np.array_equal(a.image, b.image) for a, b in zip(back.materials, scan.materials))


def test_a_usdz_written_keeps_a_glbs_maps_and_passes_usds_validators(tmp_path):
    from tests.io.test_gltf_materials import scanner_glb, unpadded

    made = scanner_glb(tmp_path / "raw.glb")
    save_scan(load_scan(tmp_path / "raw.glb"), tmp_path / "raw.usdz")
    back = load_scan(tmp_path / "raw.usdz")
    assert {k: unpadded(m.encoded) for k, m in back.materials[0].maps.items()} == made["files"]
    assert back.materials[0].gltf == {"metallicFactor": 0.0, "roughnessFactor": pytest.approx(0.6),
                                      "doubleSided": False}
    validation = pytest.importorskip("pxr.UsdValidation")
    registry = validation.ValidationRegistry()
    context = validation.ValidationContext(registry.GetOrLoadAllValidators())
    for name in ("raw.usdz",):
        errors = context.Validate(Usd.Stage.Open(str(tmp_path / name)))
        assert [e.GetMessage() for e in errors] == [], name


def test_the_outputs_of_a_usd_input_include_a_usdz(tmp_path):
    from scantex.pipeline.outputs import write_outputs

    path, *_ = scanner_usdz(tmp_path)
    result = enhance(load_scan(path), TOY)
    (tmp_path / "out").mkdir()
    write_outputs(result, tmp_path / "out")
    back = load_scan(tmp_path / "out" / "enhanced.usdz")
    assert np.array_equal(back.positions, result.scan.positions) and np.array_equal(back.faces, result.scan.faces)
    assert np.array_equal(back.materials[0].image, result.scan.materials[0].image)


PLAIN = """#usda 1.0
(
    upAxis = "Z"
)
def Mesh "scan" (prepend apiSchemas = ["MaterialBindingAPI"])
{
    int[] faceVertexCounts = [3, 3]
    int[] faceVertexIndices = [0, 1, 2, 0, 2, 3]
    point3f[] points = [(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0)]
    texCoord2f[] primvars:st = [(0, 0), (1, 0), (1, 1), (0, 1)] (interpolation = "vertex")
    rel material:binding = </m>
}
def Material "m"
{
    token outputs:surface.connect = </m/s.outputs:surface>
    def Shader "s"
    {
        uniform token info:id = "UsdPreviewSurface"
        color3f inputs:diffuseColor.connect = </m/t.outputs:rgb>
        token outputs:surface
    }
    def Shader "t"
    {
        uniform token info:id = "UsdUVTexture"
        asset inputs:file = @texture.png@
        float3 outputs:rgb
    }
}
"""


def test_a_hand_written_usda_with_a_texture_beside_it(tmp_path):
    """The text form, a texture file beside it (never to be overwritten: it is one of the scan's inputs), UVs
    one a point and no primvar reader (the st convention), z up."""
    (tmp_path / "scan.usda").write_text(PLAIN)
    Image.fromarray(checker(16, 2)).save(tmp_path / "texture.png")
    scan = load_scan(tmp_path / "scan.usda")
    assert np.array_equal(scan.materials[0].image, checker(16, 2)) and scan.up == "z"
    assert tmp_path / "texture.png" in scan.inputs
    assert np.array_equal(scan.uvs[scan.face_uvs], np.array([[0, 0], [1, 0], [1, 1], [0, 1]])[scan.faces])


def test_hostile_usd_inputs_are_one_line_errors(tmp_path):
    from tests.io.hostile import png_claiming

    (tmp_path / "nan.usda").write_text(PLAIN.replace("(0, 1, 0)]", "(0, nan, 0)]"))
    with pytest.raises(ScanError, match="NaN"):
        load_scan(tmp_path / "nan.usda")
    (tmp_path / "bomb.usda").write_text(PLAIN)
    (tmp_path / "texture.png").write_bytes(png_claiming(100_000, 100_000))
    with pytest.raises(ScanError, match="texture.png claims more pixels than scantex reads"):
        load_scan(tmp_path / "bomb.usda")
    (tmp_path / "texture.png").write_bytes(png_claiming(20_000, 20_000))  # under Pillow's own guard, over ours
    with pytest.raises(ScanError, match="claims 20000x20000 pixels"):
        load_scan(tmp_path / "bomb.usda")
