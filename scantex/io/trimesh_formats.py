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
from scantex.io.images import image_from_pil
from scantex.scan import Material, Scan

log = logging.getLogger(__name__)


def _load_scene(path: Path):
    import trimesh

    try:
        loaded = trimesh.load(path, process=False, force="scene")
    except ScanError:
        raise
    except Exception as e:  # trimesh raises anything from KeyError to struct.error on broken files
        detail = str(e).strip().splitlines()[0][:120] if str(e).strip() else type(e).__name__
        raise ScanError(path, f"cannot read {path.suffix.lstrip('.').upper()} file: {detail}") from None
    return loaded


def _material_of(geometry, index: int, where) -> tuple[Material, np.ndarray | None]:
    """Material and per-vertex UVs of one trimesh geometry."""
    visual = geometry.visual
    if getattr(visual, "kind", None) == "texture" and visual.uv is not None:
        mat = visual.material
        image = getattr(mat, "baseColorTexture", None) or getattr(mat, "image", None)
        factor = getattr(mat, "baseColorFactor", None)
        if factor is None:
            factor = getattr(mat, "diffuse", None)
        diffuse = (1.0, 1.0, 1.0, 1.0)
        if factor is not None:
            f = np.asarray(factor, dtype=np.float64).ravel()
            diffuse = tuple((f / 255.0 if f.max() > 1 else f).tolist() + [1.0] * (4 - len(f)))[:4]
        name = getattr(mat, "name", None) or f"material_{index}"
        img = image_from_pil(image, where) if image is not None else None
        return Material(str(name), img, diffuse), np.asarray(visual.uv, dtype=np.float64)
    return Material(f"material_{index}", diffuse=(0.7, 0.7, 0.7, 1.0)), None


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


def _gltf_images(path: Path) -> tuple[list[tuple[str, bytes | Path]], list[Path]]:
    """The images a GLB/glTF holds, as ``(label, bytes or file)``, and the external files it names."""
    import base64
    import json
    import struct

    data = path.read_bytes()
    binary = b""
    if path.suffix.lower() == ".glb":
        if len(data) < 20 or data[:4] != b"glTF":
            return [], []  # trimesh reports what is wrong with it
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
        return [], []
    if not isinstance(doc, dict):
        return [], []
    files, images = [], []
    for key in ("buffers", "images"):
        for item in doc.get(key) or []:
            uri = item.get("uri") if isinstance(item, dict) else None
            if isinstance(uri, str) and not uri.startswith("data:"):
                files.append(path.parent / uri)
    views = doc.get("bufferViews") or []
    for i, image in enumerate(doc.get("images") or []):
        if not isinstance(image, dict):
            continue
        label = f"embedded texture image {i}"
        uri, view = image.get("uri"), image.get("bufferView")
        try:
            if isinstance(uri, str) and uri.startswith("data:"):
                images.append((label, base64.b64decode(uri.split(",", 1)[1])))
            elif isinstance(uri, str):
                images.append((f"texture image {uri}", path.parent / uri))
            elif isinstance(view, int) and 0 <= view < len(views) and binary:
                v = views[view]
                start = int(v.get("byteOffset", 0))
                images.append((label, binary[start:start + int(v["byteLength"])]))
        except (KeyError, ValueError, TypeError, IndexError, AttributeError):
            raise ScanError(path, f"{label} is described wrongly in the glTF document") from None
    return images, files


def _check_gltf_images(path: Path) -> list[Path]:
    """Decode every image of a GLB/glTF (size checked first): trimesh drops one it cannot read without a
    word. Returns the external files the document names."""
    import io

    from PIL import Image

    from scantex.io.images import check_image_size, open_image

    images, files = _gltf_images(path)
    for label, source in images:
        if isinstance(source, Path):
            with open_image(source, "texture") as im:
                im.load()
            continue
        try:
            with Image.open(io.BytesIO(source)) as im:
                check_image_size(im, path, label)
                im.load()
        except ScanError:
            raise
        except Exception as e:  # Pillow raises OSError, SyntaxError, ValueError, DecompressionBombError...
            raise ScanError(path, f"{label} cannot be decoded ({type(e).__name__}: "
                                  f"{(str(e).strip().splitlines() or [''])[0][:80]})") from None
    return files


def read_with_trimesh(path: str | Path) -> Scan:
    path = Path(path)
    suffix = path.suffix.lower()
    inputs, ply, ply_texture = [path], None, None
    if suffix == ".stl":
        _check_stl(path)
    elif suffix in (".glb", ".gltf"):
        inputs += _check_gltf_images(path)
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
        positions = np.asarray(g.vertices, dtype=np.float64)
        if not np.allclose(transform, np.eye(4)):
            # node transforms are applied (world coordinates); an identity node keeps positions bitwise
            log.info("%s: mesh %s has a node transform; positions are taken in world coordinates", path, name)
            positions = positions @ transform[:3, :3].T + transform[:3, 3]
        pieces.append((g, positions))
    if not pieces:
        raise ScanError(path, "the mesh has no faces")

    positions, faces, uvs, colors, fcolors, face_mat, materials = [], [], [], [], [], [], []
    offset = 0
    any_uv = False
    for i, (g, pos) in enumerate(pieces):
        mat, uv = _material_of(g, i, path)
        materials.append(mat)
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
                vertex_colors=vertex_colors, face_colors=face_colors, source=path, inputs=tuple(inputs))


def _split_for_gltf(scan: Scan, faces_sel: np.ndarray):
    """Vertices for glTF, where a vertex has one position and one UV.

    Returns positions, faces (into them), uvs (or None), vertex colours (or None). A vertex is made for
    every distinct (position index, UV index) pair used by the selected faces, in order of first use,
    so positions (and the triangles) are the scan's, bit for bit; only OBJ-style split UV indexing is
    expressed by repeating a position, as the format requires.
    """
    f = scan.faces[faces_sel]
    if scan.uvs is None:
        used, inverse = np.unique(f.ravel(), return_inverse=True)
        keys_pos, uv = used, None
    elif np.array_equal(scan.face_uvs, scan.faces):
        used, inverse = np.unique(f.ravel(), return_inverse=True)
        keys_pos, uv = used, scan.uvs[used]
    else:
        pairs = np.stack([f.ravel(), scan.face_uvs[faces_sel].ravel()], axis=1)
        uniq, inverse = unique_rows(pairs, return_inverse=True)
        keys_pos, uv = uniq[:, 0], scan.uvs[uniq[:, 1]]
    colors = scan.vertex_colors[keys_pos] if scan.vertex_colors is not None else None
    return scan.positions[keys_pos], inverse.reshape(-1, 3), uv, colors


def _encoded_png(image: np.ndarray, cache: dict | None):
    """A PIL image of ``image`` that trimesh's glTF export embeds as our PNG bytes: trimesh would encode
    it again at zlib's default level (several times slower on a large atlas, and a second encoding when
    the OBJ's PNG is already made)."""
    import io

    from PIL import Image

    from scantex.io.images import png_bytes

    data = png_bytes(image, cache)
    pil = Image.open(io.BytesIO(data))  # reads the header only
    pil.save = lambda fp, format=None, **params: fp.write(data)  # noqa: A002 (PIL's own argument name)
    # trimesh hashes a material's image as an array: the pixels it was encoded from, not the PNG decoded again
    # (0.17 s for a 2048² atlas)
    pixels = np.ascontiguousarray(image)
    pil.__class__ = type("EncodedPng", (type(pil),),
                         {"__array_interface__": property(lambda _: pixels.__array_interface__)})
    return pil


def write_glb(scan: Scan, path: Path, files, png_cache: dict | None = None) -> None:
    """Write ``scan`` as a binary glTF, one mesh per material, textures embedded as PNG.

    Args:
        png_cache: see :func:`scantex.io.images.png_bytes`.
    """
    import trimesh

    f32 = scan.positions.astype(np.float32)
    if not np.array_equal(f32.astype(np.float64), scan.positions):
        log.info("%s: glTF stores float32 positions; this scan's float64 coordinates are rounded "
                    "in the GLB (the OBJ output keeps them exactly)", path)
    scene = trimesh.Scene()
    for m, material in enumerate(scan.materials):
        sel = np.flatnonzero(scan.face_materials == m)
        if sel.size == 0:
            continue
        pos, faces, uv, colors = _split_for_gltf(scan, sel)
        if uv is not None and material.image is not None:
            pbr = trimesh.visual.material.PBRMaterial(
                name=material.name, baseColorTexture=_encoded_png(material.image, png_cache),
                baseColorFactor=[float(c) for c in material.diffuse], metallicFactor=0.0,
                roughnessFactor=1.0, doubleSided=True)
            visual = trimesh.visual.TextureVisuals(uv=uv, material=pbr)
        elif colors is not None:
            visual = trimesh.visual.ColorVisuals(vertex_colors=colors)
        else:
            visual = None
        mesh = trimesh.Trimesh(pos, faces, visual=visual, process=False, validate=False)
        if scan.face_colors is not None and visual is None:
            mesh.visual.face_colors = scan.face_colors[sel]
        # the index prefix keeps the materials' order through trimesh's name-sorted export
        scene.add_geometry(mesh, geom_name=f"{m:04d}_{material.name}", node_name=f"{m:04d}_{material.name}")
    data = scene.export(file_type="glb")
    files.path(path).write_bytes(data)
