"""USD scans (``.usdz``, ``.usda``, ``.usdc``, ``.usd``): what iOS capture apps share (3D Scanner App, Polycam,
Scaniverse, Apple's Object Capture), read through Pixar's own USD library (the optional ``usd`` extra,
``usd-core``).

Every visible mesh of the stage, in the stage's order, becomes part of one :class:`Scan`: its points as
stored (in world coordinates where a transform places them; an identity keeps them bitwise), its polygons
as triangles (triangles as they are, a polygon as a fan from its first corner), the texture coordinates
and normals of any interpolation with their own indices, as an OBJ keeps them. Its material, where it is a
``UsdPreviewSurface``, gives the base colour texture (or colour) and the normal, occlusion and emissive maps
that go back out in the GLB; the stage's up axis is kept for planning views.
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from scantex.errors import ScanError
from scantex.io.images import TextureEncoder, decoded
from scantex.scan import Material, Scan, TextureMap

log = logging.getLogger(__name__)

#: ``UsdPreviewSurface`` inputs whose texture becomes one of :data:`scantex.scan.GLTF_MAPS`
_MAP_INPUTS = {"normal": "normal", "occlusion": "occlusion", "emissive": "emissiveColor"}


def read_usd(path: str | Path) -> Scan:
    from scantex.deps import require

    require("pxr", "reading USD files")
    from pxr import Tf, Usd, UsdGeom

    path = Path(path)
    try:
        stage = Usd.Stage.Open(str(path))
    except Tf.ErrorException as e:
        raise ScanError(path, f"cannot read USD file: {_usd_problem(e)}") from None
    if stage is None:
        raise ScanError(path, "cannot read USD file")
    time = Usd.TimeCode.Default()
    xforms = UsdGeom.XformCache(time)
    reader = _Materials(path)
    pieces = []
    for prim in stage.Traverse():
        if not prim.IsA(UsdGeom.Mesh):
            continue
        imageable = UsdGeom.Imageable(prim)
        if imageable.ComputeVisibility(time) == UsdGeom.Tokens.invisible or \
                imageable.ComputePurpose() in (UsdGeom.Tokens.guide, UsdGeom.Tokens.proxy):
            continue
        piece = _mesh(path, UsdGeom.Mesh(prim), xforms, reader)
        if piece is not None:
            pieces.append(piece)
    if not pieces:
        raise ScanError(path, "the file holds no mesh with faces")
    up = "y" if UsdGeom.GetStageUpAxis(stage) == UsdGeom.Tokens.y else "z"
    if UsdGeom.GetStageMetersPerUnit(stage) != 1.0:
        log.info("%s: its unit is %g m; positions are kept as stored", path, UsdGeom.GetStageMetersPerUnit(stage))
    return _assemble(path, pieces, reader, up)


def _usd_problem(e) -> str:
    """The first (most specific) of the errors USD raised, without its C++ source location: a parse error's
    line and column, or that the layer cannot be opened."""
    for error in e.args:
        text = (getattr(error, "commentary", "") or "").strip()
        if text:
            return text.splitlines()[0][:160]
    return (str(e).strip().splitlines() or [type(e).__name__])[-1][:160]


def _values(attribute, dtype, width: int | None = None) -> np.ndarray | None:
    """An attribute's value (its default, else its earliest time sample) as an array, ``None`` if unset."""
    from pxr import Usd

    value = attribute.Get(Usd.TimeCode.Default()) if attribute else None
    if value is None and attribute and attribute.GetNumTimeSamples():
        value = attribute.Get(Usd.TimeCode.EarliestTime())
    if value is None:
        return None
    array = np.asarray(value, dtype=dtype)
    return array.reshape(-1, width) if width else array.reshape(-1)


def _mesh(path: Path, mesh, xforms, reader: _Materials) -> dict | None:
    """One mesh prim as arrays: world positions, triangles, and the UVs, normals and materials of its
    corners and faces."""
    from pxr import UsdGeom, UsdShade

    prim = mesh.GetPrim()
    where = f"{path} (mesh {prim.GetPath()})"
    points = _values(mesh.GetPointsAttr(), np.float64, 3)
    counts = _values(mesh.GetFaceVertexCountsAttr(), np.int64)
    indices = _values(mesh.GetFaceVertexIndicesAttr(), np.int64)
    if points is None or counts is None or indices is None or counts.size == 0:
        return None
    if int(counts.sum()) != indices.size:
        raise ScanError(where, f"its faces count {int(counts.sum())} corners, but it lists {indices.size}")
    if (counts < 3).any():
        raise ScanError(where, f"face {int(np.flatnonzero(counts < 3)[0]) + 1} has fewer than 3 corners")
    outside = (indices < 0) | (indices >= len(points))
    if outside.any():
        raise ScanError(where, f"a face refers to point {int(indices[outside][0]) + 1}, but it has {len(points)}")
    # each polygon as a fan of triangles over its corners (a triangle is one fan of one)
    fans = counts - 2
    polygon = np.repeat(np.arange(len(counts)), fans)
    first = np.repeat(np.cumsum(counts) - counts, fans)
    step = np.arange(len(polygon)) - np.repeat(np.cumsum(fans) - fans, fans) + 1
    corners = np.stack([first, first + step, first + step + 1], axis=1)

    matrix = np.asarray(xforms.GetLocalToWorldTransform(prim), np.float64)  # row vectors: p @ M
    moved = not np.array_equal(matrix, np.eye(4))
    linear = matrix[:3, :3]
    if moved:
        points = points @ linear + matrix[3, :3]
    mirrored = moved and np.linalg.det(linear) < 0
    if (mesh.GetOrientationAttr().Get() == UsdGeom.Tokens.leftHanded) != mirrored:
        corners = corners[:, [0, 2, 1]]  # written right-handed, as OBJ and glTF read triangles

    # the materials bound to subsets of the faces, then the mesh's own (or its display colour) for the rest
    binding = UsdShade.MaterialBindingAPI(prim)
    face_material = np.full(len(counts), -1, np.int64)
    for subset in binding.GetMaterialBindSubsets():
        faces_of = _values(subset.GetIndicesAttr(), np.int64)
        if faces_of is not None:
            faces_of = faces_of[(faces_of >= 0) & (faces_of < len(counts))]
            face_material[faces_of] = reader.index(
                UsdShade.MaterialBindingAPI(subset.GetPrim()).ComputeBoundMaterial()[0], mesh)
    if (face_material < 0).any():
        face_material[face_material < 0] = reader.index(binding.ComputeBoundMaterial()[0], mesh)
    uv_name = reader.uv_set(face_material)
    uvs, uv_index = _corner_values(mesh, uv_name, corners, indices, polygon, points=len(points))
    normals, normal_index = _corner_values(mesh, "normals", corners, indices, polygon, points=len(points))
    if normals is not None and moved:
        normals = normals @ np.linalg.inv(linear).T
        normals /= np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-300)
    return {"positions": points, "faces": indices[corners], "uvs": uvs, "face_uvs": uv_index, "normals": normals,
            "face_normals": normal_index, "materials": face_material[polygon]}


def _corner_values(mesh, name: str, corners: np.ndarray, indices: np.ndarray, polygon: np.ndarray, points: int
                   ) -> tuple[np.ndarray | None, np.ndarray | None]:
    """A primvar's values and each triangle corner's index into them (``None``, ``None``: the mesh has none,
    or not one per point, corner or face). ``normals`` is also the mesh's own normals attribute."""
    from pxr import UsdGeom

    primvar = UsdGeom.PrimvarsAPI(mesh).GetPrimvar(name)
    if primvar and primvar.HasValue():
        values, interpolation = primvar.Get(), primvar.GetInterpolation()
        element = np.asarray(primvar.GetIndices(), np.int64) if primvar.IsIndexed() else None
    elif name == "normals" and mesh.GetNormalsAttr().HasValue():
        values, interpolation, element = mesh.GetNormalsAttr().Get(), mesh.GetNormalsInterpolation(), None
    else:
        return None, None
    if values is None:
        return None, None
    values = np.asarray(values, np.float64)
    if values.ndim != 2 or len(values) == 0:
        return None, None
    # what each triangle corner takes: its corner's element, its point's, or its face's
    of = {UsdGeom.Tokens.faceVarying: corners, UsdGeom.Tokens.vertex: indices[corners],
          UsdGeom.Tokens.varying: indices[corners], UsdGeom.Tokens.uniform: np.repeat(polygon[:, None], 3, 1)}
    if interpolation not in of:
        return None, None
    index = of[interpolation]
    if element is not None:
        if index.size and index.max() >= len(element):
            return None, None
        index = element[index]
    if index.size and (index.min() < 0 or index.max() >= len(values)):
        return None, None
    return values, index


class _Materials:
    """The stage's materials as :class:`Material` s, each read once, in the order the meshes bind them."""

    def __init__(self, path: Path):
        self.path = path
        self.materials: list[Material] = []
        self.uv_sets: list[str] = []
        self.inputs: list[Path] = []
        self._index: dict = {}

    def index(self, material, mesh) -> int:
        """The index of ``material`` (a ``UsdShade.Material``, maybe invalid: the mesh's display colour)."""
        key = str(material.GetPath()) if material else f"display colour of {mesh.GetPath()}"
        if key not in self._index:
            self._index[key] = len(self.materials)
            made, uv_set = self._read(material, mesh)
            self.materials.append(made)
            self.uv_sets.append(uv_set)
        return self._index[key]

    def uv_set(self, face_material: np.ndarray) -> str:
        """The texture coordinates the mesh's materials read (``st``, the convention, by default)."""
        names = [self.uv_sets[i] for i in np.unique(face_material)]
        return names[0] if names else "st"

    def _read(self, material, mesh) -> tuple[Material, str]:
        name = material.GetPrim().GetName() if material else mesh.GetPrim().GetName()
        shader = material.ComputeSurfaceSource()[0] if material else None
        if not shader or shader.GetIdAttr().Get() != "UsdPreviewSurface":
            colour = _values(mesh.GetDisplayColorAttr(), np.float64, 3)
            rgb = tuple(colour[0]) if colour is not None and len(colour) else (0.7, 0.7, 0.7)
            if shader:
                log.warning("%s: material %s is not a UsdPreviewSurface: read untextured", self.path, name)
            return Material(name, diffuse=(*map(float, rgb), 1.0)), "st"
        image, rgb, uv_set = None, (0.18, 0.18, 0.18), "st"  # UsdPreviewSurface's defaults
        texture = self._texture(shader.GetInput("diffuseColor"))
        if texture is not None:
            data, source, uv_set = texture
            image = self._decode(data, source, "texture")
            rgb = (1.0, 1.0, 1.0)
        elif shader.GetInput("diffuseColor") and shader.GetInput("diffuseColor").Get() is not None:
            rgb = tuple(float(c) for c in shader.GetInput("diffuseColor").Get())
        opacity = shader.GetInput("opacity").Get() if shader.GetInput("opacity") else None
        diffuse = (*rgb, float(opacity) if opacity is not None else 1.0)
        maps = {}
        for kind, input_name in _MAP_INPUTS.items():
            found = self._texture(shader.GetInput(input_name))
            if found is not None:
                data, source, _ = found
                with decoded(data, self.path, f"{kind} map {source}") as opened:
                    maps[kind] = TextureMap.of(opened, data)
        # the glTF written gives the surface as USD defines it: UsdPreviewSurface's own defaults (not metallic,
        # roughness 0.5) where it sets no constant, one side unless the mesh says both
        gltf: dict = {"metallicFactor": 0.0, "roughnessFactor": 0.5,
                      "doubleSided": bool(mesh.GetDoubleSidedAttr().Get())}
        for key, input_name in (("metallicFactor", "metallic"), ("roughnessFactor", "roughness")):
            given = shader.GetInput(input_name)
            if given and not given.HasConnectedSource() and given.Get() is not None:
                gltf[key] = float(given.Get())
        if diffuse[3] < 1:
            gltf["alphaMode"] = "BLEND"
        return Material(name, image, diffuse, maps=maps, gltf=gltf), uv_set

    def _texture(self, shader_input) -> tuple[bytes, str, str] | None:
        """The bytes, name and UV set of the ``UsdUVTexture`` an input reads, ``None`` if it reads none (or
        its file is missing: a warning names it)."""
        from pxr import UsdShade

        if not shader_input or not shader_input.HasConnectedSource():
            return None
        source = UsdShade.Shader(shader_input.GetConnectedSources()[0][0].source.GetPrim())
        if not source or source.GetIdAttr().Get() != "UsdUVTexture" or not source.GetInput("file"):
            return None
        asset = source.GetInput("file").Get()
        if asset is None or not asset.path:
            return None
        uv_set = "st"
        reader_input = source.GetInput("st")
        if reader_input and reader_input.HasConnectedSource():
            reader = UsdShade.Shader(reader_input.GetConnectedSources()[0][0].source.GetPrim())
            varname = reader.GetInput("varname").Get() if reader and reader.GetInput("varname") else None
            uv_set = str(varname) if varname else "st"
        if not asset.resolvedPath:
            log.warning("%s: texture %s not found: that material is read untextured", self.path, asset.path)
            return None
        data = _asset_bytes(asset.resolvedPath)
        if data is None:
            log.warning("%s: texture %s cannot be read: that material is read untextured", self.path, asset.path)
            return None
        if "[" not in asset.resolvedPath:  # a file beside the stage, not inside a package: never overwritten
            self.inputs.append(Path(asset.resolvedPath))
        return data, asset.path, uv_set

    def _decode(self, data: bytes, name: str, what: str) -> np.ndarray:
        """``(H, W, 3) uint8`` RGB of a colour texture's bytes."""
        from scantex.io.images import image_from_pil

        with decoded(data, self.path, f"{what} {name}") as image:
            return image_from_pil(image, self.path)


def _asset_bytes(resolved: str) -> bytes | None:
    """The bytes of a resolved asset path: a file, or a file inside a package (``scan.usdz[0/texture.png]``,
    packages nested as ``a.usdz[b.usdz[c.png]]``). A USDZ is a plain zip archive (stored, not compressed);
    Python's own reader serves every usd-core version (Ar's asset reading is not bound in all of them)."""
    import io
    import zipfile

    outer, _, inner = resolved.partition("[")
    try:
        if not inner:
            return Path(outer).read_bytes()
        source = outer  # the package on disk, then each nested one in memory
        while inner:
            member, _, inner = inner[:-1].partition("[")  # the closing bracket of this level goes
            with zipfile.ZipFile(source) as package:
                data = package.read(member)
            source = io.BytesIO(data)
    except (OSError, KeyError, zipfile.BadZipFile):
        return None
    return data


def _assemble(path: Path, pieces: list[dict], reader: _Materials, up: str) -> Scan:
    """One :class:`Scan` of the meshes' arrays, their indices offset."""
    offsets = np.cumsum([0] + [len(p["positions"]) for p in pieces])
    faces = np.concatenate([p["faces"] + o for p, o in zip(pieces, offsets)])
    uvs = face_uvs = None
    if any(p["uvs"] is not None for p in pieces):
        # a mesh without texture coordinates gets one at (0, 0), as trimesh's reader gives one
        parts, corner_parts, base = [], [], 0
        for p in pieces:
            values = p["uvs"] if p["uvs"] is not None else np.zeros((1, 2))
            index = p["face_uvs"] if p["uvs"] is not None else np.zeros_like(p["faces"])
            parts.append(values[:, :2])
            corner_parts.append(index + base)
            base += len(values)
        uvs, face_uvs = np.concatenate(parts), np.concatenate(corner_parts)
    normals = face_normals = None
    if all(p["normals"] is not None for p in pieces):  # as the other readers: normals on part of a scan are none
        normals = np.concatenate([p["normals"][:, :3] for p in pieces])
        normal_offsets = np.cumsum([0] + [len(p["normals"]) for p in pieces])
        face_normals = np.concatenate([p["face_normals"] + o for p, o in zip(pieces, normal_offsets)])
    return Scan(np.concatenate([p["positions"] for p in pieces]), faces, uvs, face_uvs,
                np.concatenate([p["materials"] for p in pieces]), tuple(reader.materials), normals=normals,
                face_normals_idx=face_normals, source=path, inputs=(path, *reader.inputs), up=up)


def write_usdz(scan: Scan, path: Path, files, encoder: TextureEncoder | None = None) -> None:
    """Write ``scan`` as a USDZ package (what iOS shows in AR Quick Look): one mesh with the scan's triangles,
    texture coordinates and normals on their own indices, a ``UsdPreviewSurface`` material per material
    (bound to its faces), its colour texture as PNG and its other maps as their own bytes.

    Args:
        files: an :class:`~scantex.io.atomic.AtomicFiles` that hands out the temporary path.
        encoder: how the colour textures are written, and the bytes of each once encoded (default: PNG).
    """
    import re
    import shutil
    import tempfile

    from scantex.deps import require

    require("pxr", "writing USD files")
    from pxr import Gf, Sdf, Usd, UsdGeom, UsdShade, Vt

    from scantex.io.trimesh_formats import float32_origin

    shift = float32_origin(scan.positions)  # a georeferenced scan's points about its centre: see there
    points = (scan.positions - shift).astype(np.float32)
    if not np.array_equal(points.astype(np.float64) + shift, scan.positions):
        log.info("%s: USD stores float32 points; this scan's float64 coordinates are rounded in the USDZ "
                 "(the OBJ output keeps them exactly)", path)
    with tempfile.TemporaryDirectory(prefix="scantex-usdz-") as work:
        work = Path(work)
        stage = Usd.Stage.CreateNew(str(work / "scan.usdc"))
        UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y if scan.up == "y" else UsdGeom.Tokens.z)
        UsdGeom.SetStageMetersPerUnit(stage, 1.0)
        root = UsdGeom.Xform.Define(stage, "/Scan")
        stage.SetDefaultPrim(root.GetPrim())
        if shift.any():  # the points' centre, exact in double precision
            root.AddTranslateOp(UsdGeom.XformOp.PrecisionDouble).Set(Gf.Vec3d(*(float(c) for c in shift)))
        mesh = UsdGeom.Mesh.Define(stage, "/Scan/mesh")
        mesh.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(points))
        mesh.CreateFaceVertexCountsAttr(Vt.IntArray.FromNumpy(np.full(scan.n_faces, 3, np.int32)))
        mesh.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(scan.faces.astype(np.int32).ravel()))
        mesh.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)  # a scan's triangles as they are, not a limit surface
        primvars = UsdGeom.PrimvarsAPI(mesh)
        if scan.uvs is not None:
            st = primvars.CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray, UsdGeom.Tokens.faceVarying)
            st.Set(Vt.Vec2fArray.FromNumpy(scan.uvs.astype(np.float32)))
            st.SetIndices(Vt.IntArray.FromNumpy(scan.face_uvs.astype(np.int32).ravel()))
        if scan.normals is not None:
            normals = primvars.CreatePrimvar("normals", Sdf.ValueTypeNames.Normal3fArray, UsdGeom.Tokens.faceVarying)
            normals.Set(Vt.Vec3fArray.FromNumpy(scan.normals.astype(np.float32)))
            normals.SetIndices(Vt.IntArray.FromNumpy(scan.face_normals_idx.astype(np.int32).ravel()))
        sided = [m.gltf.get("doubleSided") for m in scan.materials if "doubleSided" in m.gltf]
        mesh.CreateDoubleSidedAttr(bool(sided[0]) if sided else True)  # scantex's own materials: both sides

        binding = UsdShade.MaterialBindingAPI.Apply(mesh.GetPrim())
        used = [m for m in range(len(scan.materials)) if (scan.face_materials == m).any()]
        names = [re.sub(r"\W", "_", scan.materials[m].name) for m in used]  # prim names are identifiers
        if len(set(names)) < len(names) or not all(n and not n[0].isdigit() for n in names):
            names = [f"m{m}_{n}" for m, n in zip(used, names)]
        for m, name in zip(used, names):
            material = scan.materials[m]
            shading = _preview_surface(stage, f"/Scan/materials/{name}", material, m, work, encoder or TextureEncoder())
            if len(used) == 1:
                binding.Bind(shading)
            else:
                subset = binding.CreateMaterialBindSubset(name, Vt.IntArray.FromNumpy(
                    np.flatnonzero(scan.face_materials == m).astype(np.int32)))
                UsdShade.MaterialBindingAPI.Apply(subset.GetPrim()).Bind(shading)
        stage.GetRootLayer().Save()
        del stage
        # the package: the stage first, then the files it names at the paths it names them by (USD's own
        # packaging would look for them again, and warn about every one)
        zip_writer = getattr(Sdf, "ZipFileWriter", None) or Usd.ZipFileWriter  # Usd's before usd-core 25.x
        writer = zip_writer.CreateNew(str(work / "scan.usdz"))
        writer.AddFile(str(work / "scan.usdc"), "scan.usdc")
        for texture in sorted((work / "textures").glob("*")) if (work / "textures").is_dir() else ():
            writer.AddFile(str(texture), f"textures/{texture.name}")
        writer.Save()
        shutil.move(work / "scan.usdz", files.path(path))


def _preview_surface(stage, where: str, material: Material, index: int, work: Path, encoder: TextureEncoder):
    """A ``UsdPreviewSurface`` material of ``material``: its texture (written into ``work`` for the package)
    times its base colour, its other maps, its metallic, roughness and opacity."""
    from pxr import Gf, Sdf, UsdShade

    made = UsdShade.Material.Define(stage, where)
    surface = UsdShade.Shader.Define(stage, f"{where}/surface")
    surface.CreateIdAttr("UsdPreviewSurface")
    made.CreateSurfaceOutput().ConnectToSource(surface.ConnectableAPI(), "surface")
    reader = UsdShade.Shader.Define(stage, f"{where}/uv")
    reader.CreateIdAttr("UsdPrimvarReader_float2")
    reader.CreateInput("varname", Sdf.ValueTypeNames.String).Set("st")
    r, g, b, a = (float(c) for c in material.diffuse)

    def texture(name: str, data: bytes, suffix: str, output: str, kind, input_name: str, *, raw: bool = False,
                scale=None, bias=None):
        file = f"textures/{index}_{name}.{suffix}"
        (work / "textures").mkdir(exist_ok=True)
        (work / file).write_bytes(data)
        shader = UsdShade.Shader.Define(stage, f"{where}/{name}")
        shader.CreateIdAttr("UsdUVTexture")
        shader.CreateInput("file", Sdf.ValueTypeNames.Asset).Set(file)
        shader.CreateInput("st", Sdf.ValueTypeNames.Float2).ConnectToSource(reader.ConnectableAPI(), "result")
        shader.CreateInput("sourceColorSpace", Sdf.ValueTypeNames.Token).Set("raw" if raw else "sRGB")
        if scale is not None:
            shader.CreateInput("scale", Sdf.ValueTypeNames.Float4).Set(Gf.Vec4f(*scale))
        if bias is not None:
            shader.CreateInput("bias", Sdf.ValueTypeNames.Float4).Set(Gf.Vec4f(*bias))
        surface.CreateInput(input_name, kind).ConnectToSource(shader.ConnectableAPI(), output)

    if material.image is not None:
        tint = None if (r, g, b) == (1.0, 1.0, 1.0) else (r, g, b, 1.0)
        texture("colour", encoder.colour(material.image), encoder.suffix(material.image), "rgb",
                Sdf.ValueTypeNames.Color3f, "diffuseColor", scale=tint)
    else:
        surface.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).Set(Gf.Vec3f(r, g, b))
    for kind, input_name in _MAP_INPUTS.items():
        found = material.maps.get(kind)
        if found is None:
            continue
        data, suffix = found.file_bytes(encoder), found.suffix
        if kind == "normal":  # a tangent-space normal map's bytes hold (n + 1) / 2
            texture(kind, data, suffix, "rgb", Sdf.ValueTypeNames.Normal3f, input_name, raw=True,
                    scale=(2.0, 2.0, 2.0, 1.0), bias=(-1.0, -1.0, -1.0, 0.0))
        elif kind == "occlusion":  # glTF reads occlusion from the red channel
            texture(kind, data, suffix, "r", Sdf.ValueTypeNames.Float, input_name, raw=True)
        else:
            texture(kind, data, suffix, "rgb", Sdf.ValueTypeNames.Color3f, input_name)
    gltf = material.gltf
    surface.CreateInput("metallic", Sdf.ValueTypeNames.Float).Set(float(gltf.get("metallicFactor", 0.0)))
    surface.CreateInput("roughness", Sdf.ValueTypeNames.Float).Set(float(gltf.get("roughnessFactor", 1.0)))
    if a < 1:
        surface.CreateInput("opacity", Sdf.ValueTypeNames.Float).Set(a)
    return made
