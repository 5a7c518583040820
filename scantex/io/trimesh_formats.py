"""GLB/glTF, PLY and every other format trimesh reads; GLB writing.

These formats store one index space (a vertex carries its position, UV and colour together), which
is what trimesh returns with ``process=False``: vertices exactly as stored, never merged or reordered.
A scene with several meshes (one per material, as Polycam writes) becomes one :class:`Scan` with the
meshes' vertices concatenated in scene order.
"""

from __future__ import annotations

import dataclasses
import logging
from pathlib import Path

import numpy as np

from scantex.arrays import unique_rows
from scantex.errors import ScanError
from scantex.io.images import TextureEncoder, check_image_size, image_from_pil
from scantex.scan import GLTF_PARAMETERS, Material, Scan, TextureMap

log = logging.getLogger(__name__)


def _gltf_resolver(folder: Path):
    """trimesh's resolver of a glTF's files, by their URIs: ``texture%200.png`` is the file ``texture 0.png``
    (Blender writes it so); trimesh looks for the URI as a file name and drops a texture it cannot find
    without a word."""
    from urllib.parse import unquote

    from trimesh.resolvers import FilePathResolver

    class UriResolver(FilePathResolver):
        def get(self, name: str):
            try:
                return super().get(unquote(name))
            except (FileNotFoundError, ValueError):
                return super().get(name)

    return UriResolver(str(folder))


def _load_scene(path: Path):
    import trimesh

    try:
        resolver = _gltf_resolver(path.parent) if path.suffix.lower() == ".gltf" else None
        loaded = trimesh.load(path, process=False, force="scene", resolver=resolver)
    except ScanError:
        raise
    except Exception as e:  # trimesh raises anything from KeyError to struct.error on broken files
        detail = str(e).strip().splitlines()[0][:120] if str(e).strip() else type(e).__name__
        raise ScanError(path, f"cannot read {path.suffix.lstrip('.').upper()} file: {detail}") from None
    return loaded


#: trimesh's ``PBRMaterial`` attribute of each of :data:`scantex.scan.GLTF_MAPS`
_MAP_ATTRIBUTES = {"normal": "normalTexture", "occlusion": "occlusionTexture",
                   "metallic_roughness": "metallicRoughnessTexture", "emissive": "emissiveTexture"}


def _material_of(geometry, index: int, where, encoded: dict | None = None, skip_maps: frozenset = frozenset(),
                 extensions: dict | None = None, colourless: bool = False) -> tuple[Material, np.ndarray | None]:
    """Material and per-vertex UVs of one trimesh geometry. ``encoded``: the file's images' own bytes by
    :func:`_image_key` (a map found there is written back as those bytes); ``skip_maps``: map kinds left out;
    ``extensions``: the glTF material extensions to keep (:func:`_material_extensions`); ``colourless``: the
    format has no material colour (PLY), so the texture is shown as it is, not times the grey (0.4) trimesh
    gives a material without one."""
    from trimesh.visual.material import PBRMaterial

    visual = geometry.visual
    if getattr(visual, "kind", None) == "texture" and visual.uv is not None:
        mat = visual.material
        image = getattr(mat, "baseColorTexture", None) or getattr(mat, "image", None)
        factor = getattr(mat, "baseColorFactor", None)
        if factor is None:
            factor = getattr(mat, "diffuse", None)
        diffuse = (1.0, 1.0, 1.0, 1.0)
        if factor is not None and not colourless:
            f = np.asarray(factor, dtype=np.float64).ravel()
            diffuse = tuple((f / 255.0 if f.max() > 1 else f).tolist() + [1.0] * (4 - len(f)))[:4]
        name = getattr(mat, "name", None) or f"material_{index}"
        img = image_from_pil(image, where) if image is not None else None
        maps = {kind: _texture_map(getattr(mat, attribute), where, encoded or {})
                for kind, attribute in _MAP_ATTRIBUTES.items()
                if kind not in skip_maps and getattr(mat, attribute, None) is not None}
        gltf = {}
        for key in GLTF_PARAMETERS:
            value = getattr(mat, key, None)
            if value is not None:
                gltf[key] = np.asarray(value, np.float64).ravel().tolist() if key == "emissiveFactor" else value
        if isinstance(mat, PBRMaterial):  # a glTF material: what its file leaves out is the format's default
            gltf = {"metallicFactor": 1.0, "roughnessFactor": 1.0, "doubleSided": False, **gltf}
            if extensions:
                gltf["extensions"] = extensions
        return (Material(str(name), img, diffuse, maps=maps, gltf=gltf),
                np.asarray(visual.uv, dtype=np.float64))
    return Material(f"material_{index}", diffuse=(0.7, 0.7, 0.7, 1.0)), None


def _texture_map(image, where, encoded: dict) -> TextureMap:
    """A glTF map trimesh decoded, with the file's own bytes of it when they are JPEG or PNG."""
    check_image_size(image, where, "embedded texture image")
    return TextureMap.of(image, encoded.get(_image_key(image)))


def _image_key(image) -> tuple:
    """What identifies a decoded image's pixels: its mode, size and a digest of its bytes."""
    import hashlib

    return image.mode, image.size, hashlib.blake2b(image.tobytes(), digest_size=16).digest()


def _normals_of(geometry) -> np.ndarray | None:
    """The vertex normals the file gave ``geometry`` (trimesh keeps them in its cache; it would compute
    others on request, which the file did not have)."""
    if "vertex_normals" not in geometry._cache.cache:
        return None
    normals = np.asarray(geometry.vertex_normals, dtype=np.float64)
    return normals if normals.shape == (len(geometry.vertices), 3) else None


def _check_stl(path: Path) -> None:
    """A binary STL is 84 bytes of header and count, then 50 bytes per triangle: refuse one whose size
    does not match its count (trimesh would go on to guess a text encoding and fail obscurely)."""
    import struct

    data = path.read_bytes()
    if len(data) >= 84 and 84 + 50 * struct.unpack("<I", data[80:84])[0] == len(data):
        return
    head = data[:1024].lstrip()
    if head[:5].lower() == b"solid" and all(b < 128 for b in head):
        return  # ASCII STL
    n = struct.unpack("<I", data[80:84])[0] if len(data) >= 84 else 0
    raise ScanError(path, f"truncated or damaged binary STL: its header says {n} triangles "
                          f"({84 + 50 * n} bytes), the file has {len(data)} bytes")


def _gltf_document(path: Path) -> tuple[dict | None, bytes]:
    """A GLB/glTF's JSON document and its binary chunk (``None``, ``b""`` where it cannot be read: trimesh
    then reports what is wrong with the file)."""
    import json
    import struct

    data = path.read_bytes()
    binary = b""
    if path.suffix.lower() == ".glb":
        if len(data) < 20 or data[:4] != b"glTF":
            return None, b""
        length = struct.unpack("<I", data[12:16])[0]
        doc_bytes = data[20:20 + length]
        rest = data[20 + length:]
        if len(rest) >= 8 and rest[4:8] == b"BIN\x00":
            binary = rest[8:8 + struct.unpack("<I", rest[:4])[0]]
    else:
        doc_bytes = data
    try:
        doc = json.loads(doc_bytes)
    except (ValueError, RecursionError):
        return None, b""
    return (doc, binary) if isinstance(doc, dict) else (None, b"")


def _gltf_images(path: Path, doc: dict | None, binary: bytes) -> tuple[list[tuple[str, bytes | Path]], list[Path]]:
    """The images a GLB/glTF holds, as ``(label, bytes or file)``, and the external files it names."""
    import base64
    from urllib.parse import unquote

    if doc is None:
        return [], []
    files, images = [], []
    for key in ("buffers", "images"):
        for item in doc.get(key) or []:
            uri = item.get("uri") if isinstance(item, dict) else None
            if isinstance(uri, str) and not uri.startswith("data:"):
                files.append(path.parent / unquote(uri))
    views = doc.get("bufferViews") or []
    for i, image in enumerate(doc.get("images") or []):
        if not isinstance(image, dict):
            continue
        label = f"embedded texture image {i}"
        uri, view = image.get("uri"), image.get("bufferView")
        try:
            if isinstance(uri, str) and uri.startswith("data:"):
                images.append((label, base64.b64decode(uri.split(",", 1)[1])))
            elif isinstance(uri, str):  # a relative URI: "texture%200.png" is the file "texture 0.png"
                images.append((f"texture image {unquote(uri)}", path.parent / unquote(uri)))
            elif isinstance(view, int) and 0 <= view < len(views) and binary:
                v = views[view]
                start = int(v.get("byteOffset", 0))
                images.append((label, binary[start:start + int(v["byteLength"])]))
        except (KeyError, ValueError, TypeError, IndexError, AttributeError):
            raise ScanError(path, f"{label} is described wrongly in the glTF document") from None
    return images, files


def _check_gltf_images(path: Path, doc: dict | None, binary: bytes) -> tuple[list[Path], dict]:
    """Decode every image of a GLB/glTF (size checked first): trimesh drops one it cannot read without a
    word. Returns the external files the document names, and the JPEG and PNG images' own bytes by
    :func:`_image_key` of their pixels."""
    from scantex.io.images import decoded, open_image

    images, files = _gltf_images(path, doc, binary)
    encoded = {}
    for label, source in images:
        if isinstance(source, Path):
            with open_image(source, "texture") as im:
                im.load()
                if im.format in ("JPEG", "PNG"):
                    encoded[_image_key(im)] = source.read_bytes()
            continue
        with decoded(source, path, label) as im:
            if im.format in ("JPEG", "PNG"):
                # a buffer view may hold the 4-byte alignment's zeros after the image; a JPEG ends in its EOI
                # marker and a PNG in IEND's CRC, so the zeros are not the image's
                encoded[_image_key(im)] = source.rstrip(b"\0")
    return files, encoded


def _material_extensions(path: Path, doc: dict | None) -> dict:
    """The material extensions a GLB/glTF gives every one of its materials alike (``KHR_materials_unlit``:
    a photogrammetry scan's texture holds its light already, and viewers must not light it again), to be
    written back. One that names a texture is left out (the textures are numbered anew), and so are all
    when the materials differ in them (trimesh does not say which of its materials is which of the file's)."""
    import json

    materials = [m for m in (doc or {}).get("materials") or [] if isinstance(m, dict)]
    found = [{name: value for name, value in (m.get("extensions") or {}).items()
              if isinstance(value, dict) and '"index"' not in json.dumps(value)} for m in materials]
    if not found or not found[0]:
        return {}
    if any(f != found[0] for f in found):
        log.info("%s: its materials' extensions differ (%s): left out", path,
                 ", ".join(sorted({name for f in found for name in f})))
        return {}
    return found[0]


def _maps_off_layout(path: Path, doc: dict | None) -> frozenset:
    """The map kinds a glTF material of ``path`` draws in a second UV set that is not its first (the layout
    scantex reads and writes): those maps cannot be written back on the first, and are left out."""
    off = set()
    try:
        for mesh in (doc or {}).get("meshes") or []:
            for primitive in mesh.get("primitives") or []:
                attributes = primitive.get("attributes") or {}
                material = (doc.get("materials") or [])[primitive["material"]] if "material" in primitive else {}
                infos = {"normal": material.get("normalTexture"), "occlusion": material.get("occlusionTexture"),
                         "emissive": material.get("emissiveTexture"),
                         "metallic_roughness": (material.get("pbrMetallicRoughness") or {}).get(
                             "metallicRoughnessTexture")}
                for kind, info in infos.items():
                    uv_set = int((info or {}).get("texCoord", 0))
                    if uv_set and attributes.get(f"TEXCOORD_{uv_set}") != attributes.get("TEXCOORD_0"):
                        off.add(kind)
    except (ValueError, AttributeError, TypeError, KeyError, IndexError):
        return frozenset()  # trimesh reports what is wrong with the document
    if off:
        log.warning("%s: its %s maps are drawn in a second UV layout, which scantex does not keep: left out",
                    path, " and ".join(sorted(k.replace("_", "-") for k in off)))
    return frozenset(off)


def read_with_trimesh(path: str | Path) -> Scan:
    path = Path(path)
    suffix = path.suffix.lower()
    inputs, ply, ply_texture = [path], None, None
    encoded: dict = {}
    skip_maps: frozenset = frozenset()
    extensions: dict = {}
    if suffix == ".stl":
        _check_stl(path)
    elif suffix in (".glb", ".gltf"):
        doc, binary = _gltf_document(path)
        files, encoded = _check_gltf_images(path, doc, binary)
        inputs += files
        skip_maps = _maps_off_layout(path, doc)
        extensions = _material_extensions(path, doc)
    elif suffix == ".ply":
        from scantex.io.images import read_image
        from scantex.io.ply import check_ply

        try:
            ply = check_ply(path)
        except ScanError as e:
            raise ScanError(path, f"cannot read PLY file: {e.problem}") from None
        if ply.texture:
            texture = path.parent / ply.texture.replace("\\", "/")
            ply_texture = read_image(texture)  # refused here, before trimesh prints its own traceback
            inputs.append(texture)
    scene = _load_scene(path)
    # meshes in the file's order (the graph's own node order is not the file's)
    nodes = [n for name in scene.geometry for n in scene.graph.geometry_nodes.get(name, [])]
    if not nodes:
        raise ScanError(path, "the file holds no mesh (no faces)")
    pieces = []
    for node in nodes:
        transform, name = scene.graph[node]
        g = scene.geometry[name]
        if not hasattr(g, "faces") or len(g.faces) == 0:
            continue  # point clouds and paths carry no surface
        positions, vn = np.asarray(g.vertices, dtype=np.float64), _normals_of(g)
        if not np.allclose(transform, np.eye(4)):
            # node transforms are applied (world coordinates); an identity node keeps positions bitwise
            log.info("%s: mesh %s has a node transform; positions are taken in world coordinates", path, name)
            positions = positions @ transform[:3, :3].T + transform[:3, 3]
            if vn is not None:  # normals turn with the node: by the inverse transpose, then of unit length again
                vn = vn @ np.linalg.inv(transform[:3, :3])
                vn /= np.maximum(np.linalg.norm(vn, axis=1, keepdims=True), 1e-300)
        pieces.append((g, positions, vn))
    if not pieces:
        raise ScanError(path, "the mesh has no faces")

    positions, faces, uvs, colors, fcolors, face_mat, materials, normals = [], [], [], [], [], [], [], []
    offset = 0
    any_uv = False
    for i, (g, pos, vn) in enumerate(pieces):
        mat, uv = _material_of(g, i, path, encoded, skip_maps, extensions, colourless=suffix == ".ply")
        materials.append(mat)
        normals.append(vn)
        positions.append(pos)
        faces.append(np.asarray(g.faces, dtype=np.int64) + offset)
        face_mat.append(np.full(len(g.faces), i, dtype=np.int32))
        uvs.append(uv if uv is not None and len(uv) == len(pos) else None)
        any_uv |= uvs[-1] is not None
        kind = getattr(g.visual, "kind", None)
        colors.append(np.asarray(g.visual.vertex_colors, dtype=np.uint8) if kind == "vertex" else None)
        fcolors.append(np.asarray(g.visual.face_colors, dtype=np.uint8) if kind == "face" else None)
        offset += len(pos)

    all_pos = np.concatenate(positions)
    all_faces = np.concatenate(faces)
    scan_uvs = face_uvs = None
    if any_uv:
        scan_uvs = np.concatenate([u if u is not None else np.zeros((len(p), 2)) for u, p in zip(uvs, positions)])
        face_uvs = all_faces.copy()  # one index space: a vertex's UV has the vertex's index
    vertex_colors = face_colors = None
    if any(c is not None for c in colors):
        vertex_colors = np.concatenate([c[:, :4] if c is not None else np.full((len(p), 4), 255, np.uint8)
                                        for c, p in zip(colors, positions)])
    if any(c is not None for c in fcolors):
        face_colors = np.concatenate([c[:, :4] if c is not None else np.full((len(f), 4), 255, np.uint8)
                                      for c, f in zip(fcolors, faces)])
    # the file's shading normals, one a vertex (glTF, PLY), when every mesh has them: as the OBJ reader, a scan
    # with normals on part of it has none (a viewer shades it by its own)
    scan_normals = face_normals = None
    if normals and all(n is not None for n in normals):
        scan_normals, face_normals = np.concatenate(normals), all_faces.copy()
    if ply is not None:
        if (len(all_pos), len(all_faces)) != (ply.vertices, ply.triangles):
            raise ScanError(path, f"read as {len(all_pos)} vertices and {len(all_faces)} triangles, but the "
                                  f"file declares {ply.vertices} and {ply.triangles}: refused rather than "
                                  "changing the geometry")
        # trimesh gives a PLY with UVs and no texture a 2x2 placeholder image: the texture is the file's
        # own TextureFile, read above, or none
        image = ply_texture if scan_uvs is not None else None
        materials = [dataclasses.replace(m, image=image) for m in materials]
    return Scan(all_pos, all_faces, scan_uvs, face_uvs, np.concatenate(face_mat), tuple(materials),
                vertex_colors=vertex_colors, face_colors=face_colors, normals=scan_normals,
                face_normals_idx=face_normals, source=path, inputs=tuple(inputs),
                up="y" if suffix in (".glb", ".gltf") else None)  # glTF is y-up by the format's rule


def _split_for_gltf(scan: Scan, faces_sel: np.ndarray):
    """Vertices for glTF, where a vertex has one position, one UV and one normal.

    Returns positions, faces (into them), uvs (or None), vertex colours (or None), normals (or None). A
    vertex is made for every distinct (position index, UV index, normal index) triple used by the selected
    faces, in the order of those indices, so positions (and the triangles) are the scan's, bit for bit;
    only OBJ-style split indexing is expressed by repeating a position, as the format requires.
    """
    f = scan.faces[faces_sel]
    # the index spaces that are not the positions' own (OBJ's vt and vn): each splits vertices further
    split = [index for index, values in ((scan.face_uvs, scan.uvs), (scan.face_normals_idx, scan.normals))
             if values is not None and not np.array_equal(index, scan.faces)]
    if not split:
        used, inverse = np.unique(f.ravel(), return_inverse=True)
        keys = used[:, None]
    else:
        keys, inverse = unique_rows(np.stack([f.ravel()] + [index[faces_sel].ravel() for index in split], axis=1),
                                    return_inverse=True)
    positions = keys[:, 0]

    def of(index, values):
        """Each glTF vertex's value from ``values`` (indexed by ``index`` per corner)."""
        if values is None:
            return None
        for column, other in enumerate(split, start=1):
            if other is index:
                return values[keys[:, column]]
        return values[positions]  # the same index space as the positions

    colors = scan.vertex_colors[positions] if scan.vertex_colors is not None else None
    return (scan.positions[positions], inverse.reshape(-1, 3), of(scan.face_uvs, scan.uvs), colors,
            of(scan.face_normals_idx, scan.normals))


def _embedded(image: np.ndarray, data: bytes):
    """A PIL image of ``image`` that trimesh's glTF export embeds as the bytes ``data`` (the file's own
    JPEG or PNG, or our PNG of it): trimesh would otherwise encode it again (several times slower on a
    large atlas at zlib's default level, a second encoding when the OBJ's PNG is already made, and a JPEG
    again with a JPEG's loss)."""
    import io

    from PIL import Image

    pil = Image.open(io.BytesIO(data))  # reads the header only; trimesh names a JPEG's type from its format
    pil.save = lambda fp, format=None, **params: fp.write(data)  # noqa: A002 (PIL's own argument name)
    # trimesh hashes a material's image as an array: the pixels it was encoded from, not the file decoded again
    # (0.17 s for a 2048² atlas)
    pixels = np.ascontiguousarray(image)
    pil.__class__ = type("Embedded", (type(pil),),
                         {"__array_interface__": property(lambda _: pixels.__array_interface__)})
    return pil


def _embedded_map(texture_map, encoder):
    return _embedded(texture_map.image, texture_map.file_bytes(encoder))


#: float32 rounds a scan's coordinates by at most this share of its size before a GLB or USDZ holds them about a point
_ROUNDING = 1e-6


def float32_origin(positions: np.ndarray) -> np.ndarray:
    """``(3,)``: the point a GLB or USDZ holds ``positions`` about (as float32, its node or prim translated
    there), zero for a scan near the origin. float32 rounds a coordinate by a share (6e-8) of its magnitude: a
    georeferenced scan (UTM, some 500 km from the origin) by up to 0.125 m, where its size is metres. Where
    that rounding exceeds :data:`_ROUNDING` of the scan's size, the positions are held about the centre of
    their bounds (rounded to whole units, so that the node's translation is exact), and float32 holds them to
    a share of the scan's size."""
    if len(positions) == 0:
        return np.zeros(3)
    lo, hi = positions.min(axis=0), positions.max(axis=0)
    size = float((hi - lo).max())
    error = float(np.abs(positions.astype(np.float32).astype(np.float64) - positions).max())
    if error <= _ROUNDING * max(size, 1e-300):
        return np.zeros(3)
    return np.round(0.5 * (lo + hi))


def write_glb(scan: Scan, path: Path, files, encoder: TextureEncoder | None = None) -> None:
    """Write ``scan`` as a binary glTF, one mesh per material, with the scan's shading normals; colour textures
    embedded as PNG (or as ``encoder`` says), a material's other maps as their file's own bytes
    (:class:`scantex.scan.TextureMap`).

    Args:
        encoder: how the colour textures are written, and the bytes of each once encoded (default: PNG).
    """
    import trimesh

    encoder = encoder or TextureEncoder()

    shift = float32_origin(scan.positions)
    f32 = (scan.positions - shift).astype(np.float32)
    if not np.array_equal(f32.astype(np.float64) + shift, scan.positions):
        log.info("%s: glTF stores float32 positions; this scan's float64 coordinates are rounded "
                    "in the GLB (the OBJ output keeps them exactly)", path)
    if shift.any():
        log.info("%s: the scan lies far from the origin (%s): the GLB holds its positions about that point, "
                 "which its node's translation adds back, as float32 holds them to %.2g of the scan's size",
                 path, ", ".join(f"{c:.0f}" for c in shift), _ROUNDING)
    transform = np.eye(4)
    transform[:3, 3] = shift
    scene = trimesh.Scene()
    for m, material in enumerate(scan.materials):
        sel = np.flatnonzero(scan.face_materials == m)
        if sel.size == 0:
            continue
        pos, faces, uv, colors, normals = _split_for_gltf(scan, sel)
        pos = pos - shift
        if uv is not None and material.image is not None:
            # a glTF material's own parameters and maps come back as they were; other materials are matte,
            # not metallic, and seen from both sides (a scan's open surfaces)
            parameters = {"metallicFactor": 0.0, "roughnessFactor": 1.0, "doubleSided": True,
                          **{k: v for k, v in material.gltf.items() if k in GLTF_PARAMETERS}}
            maps = {_MAP_ATTRIBUTES[kind]: _embedded_map(texture, encoder) for kind, texture in material.maps.items()}
            pbr = trimesh.visual.material.PBRMaterial(
                name=material.name, baseColorTexture=_embedded(material.image, encoder.colour(material.image)),
                baseColorFactor=[float(c) for c in material.diffuse], **parameters, **maps)
            visual = trimesh.visual.TextureVisuals(uv=uv, material=pbr)
        elif colors is not None:
            visual = trimesh.visual.ColorVisuals(vertex_colors=colors)
        else:
            visual = None
        # the scan's shading normals go with it (a glTF viewer shades a mesh without them flat: faceted)
        mesh = trimesh.Trimesh(pos, faces, visual=visual, vertex_normals=normals, process=False, validate=False)
        if scan.face_colors is not None and visual is None:
            mesh.visual.face_colors = scan.face_colors[sel]
        # the index prefix keeps the materials' order through trimesh's name-sorted export
        scene.add_geometry(mesh, geom_name=f"{m:04d}_{material.name}", node_name=f"{m:04d}_{material.name}",
                           transform=transform)
    data = scene.export(file_type="glb")
    extensions = {m.name: m.gltf["extensions"] for m in scan.materials if m.gltf.get("extensions")}
    files.path(path).write_bytes(_with_material_extensions(data, extensions) if extensions else data)


def _with_material_extensions(glb: bytes, by_name: dict[str, dict]) -> bytes:
    """``glb`` with each material named in ``by_name`` given those extensions (trimesh's exporter writes none),
    declared in ``extensionsUsed``; the binary chunk as it was."""
    import json
    import struct

    length = struct.unpack("<I", glb[12:16])[0]
    doc = json.loads(glb[20:20 + length])
    used = set(doc.get("extensionsUsed", []))
    for material in doc.get("materials", []):
        extensions = by_name.get(material.get("name"))
        if extensions:
            material["extensions"] = {**material.get("extensions", {}), **extensions}
            used |= set(extensions)
    doc["extensionsUsed"] = sorted(used)
    text = json.dumps(doc, separators=(",", ":")).encode()
    text += b" " * (-len(text) % 4)  # chunks are 4-byte aligned; JSON pads with spaces
    rest = glb[20 + length:]
    return (b"glTF" + struct.pack("<II", 2, 12 + 8 + len(text) + len(rest))
            + struct.pack("<I", len(text)) + b"JSON" + text + rest)
