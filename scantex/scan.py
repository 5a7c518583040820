"""The :class:`Scan`: a textured triangle mesh exactly as its file holds it.

Geometry and texture parameterisation are kept apart, as in an OBJ file: ``faces`` index ``positions``
and ``face_uvs`` index ``uvs``. Nothing here welds, splits or re-orders vertices, so the positions and
triangles a user gave are the ones written back. Every later stage may change the texture (materials,
UVs) but never ``positions`` or ``faces``.

Texture convention: a material's ``image`` is ``(H, W, C) uint8`` with row 0 at the top, and a UV
``(u, v)`` lands at pixel ``(x, y) = (u * W - 0.5, (1 - v) * H - 0.5)`` (texel centres at half
integers), repeating outside ``[0, 1]`` as OBJ and glTF viewers do.
"""

from __future__ import annotations

import dataclasses
import functools
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from scantex.errors import ScanError

if TYPE_CHECKING:
    from scantex.io.images import TextureEncoder


#: largest coordinate magnitude accepted: squares of differences of coordinates stay far inside float32
MAX_COORDINATE = 1e12

#: the cached properties computed from the positions and faces alone, which :meth:`Scan.replace` keeps
_GEOMETRY_CACHE = ("welded", "face_normals", "face_areas", "_normals_and_areas", "bounds")
#: where :meth:`Scan.layout_memo` and :meth:`Scan.texture_memo` keep their results, in the scan's ``__dict__``
_LAYOUT_MEMO, _TEXTURE_MEMO = "_layout_memo", "_texture_memo"


#: the maps of a glTF material besides its colour, as :attr:`Material.maps` names them
GLTF_MAPS = ("normal", "occlusion", "metallic_roughness", "emissive")
#: the parameters of a glTF material besides its colour, as :attr:`Material.gltf` holds them
GLTF_PARAMETERS = ("metallicFactor", "roughnessFactor", "emissiveFactor", "alphaMode", "alphaCutoff", "doubleSided")


@dataclass(frozen=True, eq=False)
class TextureMap:
    """One of a material's maps besides its colour (a glTF normal, occlusion, metallic-roughness or emissive
    texture; an MTL's ``norm`` or ``map_Ke``; a ``UsdPreviewSurface``'s normal, occlusion or emissive input),
    drawn in the same UV layout as the colour. scantex changes the colour only: a map goes to the outputs as
    it came, while the layout stays the input's.

    Attributes:
        image: ``(H, W)`` or ``(H, W, C) uint8`` as decoded, row 0 at the top.
        encoded: the file's own bytes of it (JPEG or PNG), written back as they are; ``None``: encoded anew.
    """

    image: np.ndarray
    encoded: bytes | None = None

    @classmethod
    def of(cls, image, data: bytes | None = None) -> TextureMap:
        """The map of a decoded Pillow ``image`` (its channels as stored; a palette or other mode as RGB),
        keeping ``data``, its file's bytes, when they are a JPEG or a PNG (what glTF, USD and MTL all read)."""
        from scantex.io.images import rgb8

        pixels = np.asarray(image) if image.mode in ("L", "LA", "RGB", "RGBA") else rgb8(image)
        return cls(pixels, data if data is not None and image.format in ("JPEG", "PNG") else None)

    def file_bytes(self, encoder: TextureEncoder | None = None) -> bytes:
        """The bytes a file of it holds: its own, or a PNG of its pixels (``encoder``'s, which encodes each image
        once: :class:`scantex.io.images.TextureEncoder`)."""
        from scantex.io.images import TextureEncoder

        return self.encoded if self.encoded is not None else (encoder or TextureEncoder()).png(self.image)

    @property
    def suffix(self) -> str:
        """The file suffix of :meth:`file_bytes`: ``jpg`` for its own JPEG bytes, else ``png``."""
        return "jpg" if self.encoded is not None and self.encoded[:2] == b"\xff\xd8" else "png"


@dataclass(frozen=True, eq=False)
class Material:
    """One material: a base colour and, usually, a texture atlas.

    Attributes:
        name: the material's name in the file (``newmtl`` in OBJ).
        image: ``(H, W, 3|4) uint8`` texture, row 0 at the top; ``None`` for an untextured material.
        diffuse: ``(4,) float`` RGBA base colour in [0, 1]; multiplies the image when rendering.
        image_name: the texture's file name (``None``: derived from ``name``); an OBJ ``x.obj`` writes it
            as ``x_`` + this name unless it starts with ``x`` (:func:`scantex.io.obj.texture_names`).
        maps: the material's other maps by kind (:data:`GLTF_MAPS`), on the same UV layout as ``image``
            (a Polycam GLB's normal and occlusion maps); a new layout leaves them out.
        gltf: the material's other parameters, as glTF names them (:data:`GLTF_PARAMETERS`): a glTF
            material's (glTF's defaults for what its file leaves out), a ``UsdPreviewSurface``'s; the GLB
            and the USDZ written give them back (a material from another format gets scantex's defaults).
    """

    name: str
    image: np.ndarray | None = None
    diffuse: tuple[float, float, float, float] = (1.0, 1.0, 1.0, 1.0)
    image_name: str | None = None
    maps: dict[str, TextureMap] = field(default_factory=dict)
    gltf: dict[str, object] = field(default_factory=dict)

    def with_image(self, image: np.ndarray) -> Material:
        return dataclasses.replace(self, image=image)


@dataclass(frozen=True, eq=False)
class Scan:
    """A mesh with optional UVs, materials and colours.

    Attributes:
        positions: ``(V, 3) float64`` vertex positions, exactly as read.
        faces: ``(F, 3) int64`` indices into ``positions``; winding as in the file.
        uvs: ``(T, 2) float64`` texture coordinates, or ``None``.
        face_uvs: ``(F, 3) int64`` indices into ``uvs`` per face corner, or ``None``.
        face_materials: ``(F,) int32`` index into ``materials`` per face.
        materials: the materials; at least one (a plain grey one for untextured meshes).
        vertex_colors: ``(V, 4) uint8`` RGBA per vertex, or ``None``.
        face_colors: ``(F, 4) uint8`` RGBA per face, or ``None``.
        normals: ``(N, 3) float64`` shading normals, or ``None``.
        face_normals_idx: ``(F, 3) int64`` indices into ``normals`` per face corner, or ``None``.
        source: the file the scan came from, if any.
        up: the up axis its file declares (``"y"`` for glTF, by the format's rule; a USD stage's ``upAxis``),
            ``None`` where the format says nothing (OBJ, PLY: scanners mostly write z up).
        inputs: every file the scan was read from (the mesh, its material libraries, textures, buffers),
            so that no output ever replaces one of them.
    """

    positions: np.ndarray
    faces: np.ndarray
    uvs: np.ndarray | None = None
    face_uvs: np.ndarray | None = None
    face_materials: np.ndarray | None = None
    materials: tuple[Material, ...] = (Material("default", diffuse=(0.7, 0.7, 0.7, 1.0)),)
    vertex_colors: np.ndarray | None = None
    face_colors: np.ndarray | None = None
    normals: np.ndarray | None = None
    face_normals_idx: np.ndarray | None = None
    source: Path | None = field(default=None)
    inputs: tuple[Path, ...] = ()
    up: str | None = None

    def __post_init__(self) -> None:
        set_ = object.__setattr__
        set_(self, "positions", np.ascontiguousarray(self.positions, dtype=np.float64))
        set_(self, "faces", np.ascontiguousarray(self.faces, dtype=np.int64))
        if self.face_materials is None:
            set_(self, "face_materials", np.zeros(len(self.faces), dtype=np.int32))
        else:
            set_(self, "face_materials", np.ascontiguousarray(self.face_materials, dtype=np.int32))
        if self.uvs is not None:
            set_(self, "uvs", np.ascontiguousarray(self.uvs, dtype=np.float64))
            set_(self, "face_uvs", np.ascontiguousarray(self.face_uvs, dtype=np.int64))
        self.validate()

    # -- checks ---------------------------------------------------------------------------------

    def validate(self) -> None:
        """Raise :class:`ScanError` when the arrays do not describe a usable mesh."""
        where = self.source
        V, F = len(self.positions), len(self.faces)
        if self.positions.ndim != 2 or self.positions.shape[1] != 3:
            raise ScanError(where, f"positions must be (V, 3), got {self.positions.shape}")
        if F == 0:
            raise ScanError(where, "the mesh has no faces")
        if self.faces.ndim != 2 or self.faces.shape[1] != 3:
            raise ScanError(where, f"faces must be (F, 3) triangles, got {self.faces.shape}")
        bad = ~np.isfinite(self.positions).all(axis=1)
        if bad.any():
            raise ScanError(where, f"{int(bad.sum())} vertex positions are NaN or infinite "
                                   f"(first: vertex {int(np.flatnonzero(bad)[0]) + 1})")
        huge = (np.abs(self.positions) > MAX_COORDINATE).any(axis=1)
        if huge.any():
            raise ScanError(where, f"{int(huge.sum())} vertex positions lie beyond +-{MAX_COORDINATE:g} "
                                   f"(first: vertex {int(np.flatnonzero(huge)[0]) + 1}); no scan is that "
                                   "large, and edge lengths, normals and the float32 ray caster overflow")
        _check_index(where, self.faces, V, "face", "vertex", "vertices")
        if (self.uvs is None) != (self.face_uvs is None):
            raise ScanError(where, "uvs and face_uvs must be given together")
        if self.uvs is not None:
            if self.face_uvs.shape != (F, 3):
                raise ScanError(where, f"face_uvs must be ({F}, 3), got {self.face_uvs.shape}")
            if not np.isfinite(self.uvs).all():
                raise ScanError(where, "texture coordinates contain NaN or infinite values")
            _check_index(where, self.face_uvs, len(self.uvs), "face", "texture coordinate",
                         "texture coordinates")
        if self.face_materials.shape != (F,):
            raise ScanError(where, f"face_materials must be ({F},), got {self.face_materials.shape}")
        if len(self.materials) == 0:
            raise ScanError(where, "a scan needs at least one material")
        if F and (self.face_materials.min() < 0 or self.face_materials.max() >= len(self.materials)):
            raise ScanError(where, "a face refers to a material that does not exist")
        if self.vertex_colors is not None and len(self.vertex_colors) != V:
            raise ScanError(where, f"{len(self.vertex_colors)} vertex colours for {V} vertices")
        if self.face_colors is not None and len(self.face_colors) != F:
            raise ScanError(where, f"{len(self.face_colors)} face colours for {F} faces")
        if self.normals is not None:
            _check_index(where, self.face_normals_idx, len(self.normals), "face", "normal", "normals")

    # -- derived quantities -----------------------------------------------------------------------

    @property
    def n_vertices(self) -> int:
        return len(self.positions)

    @property
    def n_faces(self) -> int:
        return len(self.faces)

    @property
    def has_uvs(self) -> bool:
        return self.uvs is not None

    @property
    def is_textured(self) -> bool:
        """True when faces carry UVs and at least one material has an image."""
        return self.has_uvs and any(m.image is not None for m in self.materials)

    @property
    def triangles(self) -> np.ndarray:
        """``(F, 3, 3) float64`` corner positions of every face."""
        return self.positions[self.faces]

    @functools.cached_property
    def triangle_uvs(self) -> np.ndarray:
        """``(F, 3, 2) float64`` corner UVs of every face (requires UVs), read-only, computed once per scan (loops
        over a Matterport export's hundreds of materials had gathered them again for each)."""
        if self.uvs is None:
            raise ValueError("this scan has no texture coordinates")
        out = self.uvs[self.face_uvs]
        out.setflags(write=False)
        return out

    @functools.cached_property
    def bounds(self) -> np.ndarray:
        """``(2, 3)`` min and max corner of the referenced vertices, read-only, computed once per scan."""
        used = np.zeros(len(self.positions), bool)
        used[self.faces.reshape(-1)] = True
        corners = np.stack([self.positions[used].min(axis=0), self.positions[used].max(axis=0)])
        corners.setflags(write=False)
        return corners

    @functools.cached_property
    def welded(self) -> np.ndarray:
        """``(V,) int64``: one index per distinct position (compared by value), read-only, computed once.

        ``welded[faces]`` connects what the file's indices may not: glTF repeats a position at every UV seam,
        and some OBJ writers (OpenMVS) give every face corner a vertex of its own."""
        from scantex.arrays import unique_rows

        _, inverse = unique_rows(self.positions, return_inverse=True)
        inverse = inverse.reshape(-1).astype(np.int64)
        inverse.setflags(write=False)
        return inverse

    def welded_geometry(self) -> tuple[np.ndarray, np.ndarray]:
        """``(positions (U, 3), faces (F, 3))``: the distinct positions (each at its first occurrence) and the
        faces indexing them, the same triangles as ``faces``: what connectivity-based algorithms (charting,
        unwrapping) need where the file repeats positions."""
        weld = self.welded
        first = np.zeros(int(weld.max()) + 1 if weld.size else 0, np.int64)
        first[weld[::-1]] = np.arange(len(weld))[::-1]
        return self.positions[first], weld[self.faces]

    @functools.cached_property
    def face_normals(self) -> np.ndarray:
        """``(F, 3)`` unit geometric normals (zero for degenerate faces), read-only.

        Computed once per scan (a scan's geometry never changes): photo mode asks for them once per photo,
        50 ms each on a 200,000-face room."""
        n, _ = self._normals_and_areas
        return n

    @functools.cached_property
    def face_areas(self) -> np.ndarray:
        """``(F,)`` face areas, read-only, computed once per scan."""
        _, a = self._normals_and_areas
        return a

    @functools.cached_property
    def _normals_and_areas(self) -> tuple[np.ndarray, np.ndarray]:
        t = self.triangles
        n = np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])
        length = np.linalg.norm(n, axis=1, keepdims=True)
        normals = np.divide(n, length, out=np.zeros_like(n), where=length > 0)
        areas = 0.5 * length[:, 0]
        normals.setflags(write=False)
        areas.setflags(write=False)
        return normals, areas

    def replace(self, **changes) -> Scan:
        """A copy with some fields changed; geometry fields may not change. The copy keeps what was computed
        from the geometry (:attr:`welded`, the normals and areas) and, where its UV layout is the same arrays
        (texture coordinates, their indices, the face materials, as many materials), the layout's analyses
        (:meth:`layout_memo`): a texture baked onto a scan's own layout is measured without redoing them."""
        for key in ("positions", "faces"):
            if key in changes and changes[key] is not getattr(self, key):
                raise ValueError(f"scantex never changes a scan's {key}")
        out = dataclasses.replace(self, **changes)
        for name in _GEOMETRY_CACHE:
            if name in self.__dict__:
                out.__dict__[name] = self.__dict__[name]
        same_layout = (all(getattr(out, k) is getattr(self, k) for k in ("uvs", "face_uvs", "face_materials"))
                       and len(out.materials) == len(self.materials))
        if same_layout and _LAYOUT_MEMO in self.__dict__:
            out.__dict__[_LAYOUT_MEMO] = self.__dict__[_LAYOUT_MEMO]  # one dict: either copy's analyses serve both
        return out

    def layout_memo(self, name: str, compute):
        """``compute()``, an analysis of the UV layout alone (charts, seam edges: what depends on the positions,
        faces, texture coordinates, face materials and the number of materials, never on the images), computed
        once for this scan and the copies :meth:`replace` makes of it on the same layout. The result is shared:
        its arrays should be read-only. On an 800,000-face scan the same charts and seams were found ten times
        a run, 20 s in all."""
        return self._memo(_LAYOUT_MEMO, name, compute)

    def texture_memo(self, name: str, compute):
        """``compute()``, an analysis of this scan's texture (its images as well as its layout: the faces it
        leaves black), computed once for this scan; a copy, whatever it changes, computes its own. The result is
        shared: its arrays should be read-only."""
        return self._memo(_TEXTURE_MEMO, name, compute)

    def _memo(self, key: str, name: str, compute):
        memo = self.__dict__.setdefault(key, {})
        if name not in memo:
            memo[name] = compute()
        return memo[name]

    def with_texture(self, uvs: np.ndarray, face_uvs: np.ndarray, materials, face_materials=None) -> Scan:
        """The same geometry with a new UV layout and materials."""
        return self.replace(
            uvs=uvs, face_uvs=face_uvs, materials=tuple(materials),
            face_materials=self.face_materials if face_materials is None else face_materials,
        )

    def to_trimesh(self, process: bool = False):
        """A :class:`trimesh.Trimesh` of the geometry (no texture), for geometric queries."""
        import trimesh

        return trimesh.Trimesh(self.positions, self.faces, process=process, validate=False)

    @property
    def map_kinds(self) -> list[str]:
        """The kinds of the materials' other maps (:attr:`Material.maps`), sorted."""
        return sorted({kind for m in self.materials for kind in m.maps})

    def summary(self) -> str:
        tex = ", ".join(
            (f"{m.name}: {m.image.shape[1]}x{m.image.shape[0]}" if m.image is not None else f"{m.name}: -")
            + "".join(f" + {kind.replace('_', '-')} map" for kind in m.maps)
            for m in self.materials
        )
        return (f"{self.n_vertices:,} vertices, {self.n_faces:,} faces, "
                f"{'UVs' if self.has_uvs else 'no UVs'}, materials [{tex}]"
                + (", vertex colours" if self.vertex_colors is not None else "")
                + (", vertex normals" if self.normals is not None else ""))


def _check_index(where, idx: np.ndarray, n: int, owner: str, target: str, plural: str) -> None:
    if idx.size == 0:
        return
    lo, hi = int(idx.min()), int(idx.max())
    if lo < 0 or hi >= n:
        row = int(np.flatnonzero((idx < 0).any(axis=1) | (idx >= n).any(axis=1))[0])
        value = int(idx[row][(idx[row] < 0) | (idx[row] >= n)][0])
        raise ScanError(where, f"{owner} {row + 1} refers to {target} {value + 1}, "
                               f"the file has {n} {plural}")


def triangle_multiset_key(positions: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Canonical sorted ``(F, 9)`` float64 rows: the triangles as a multiset, winding kept.

    Each triangle is rotated so that its lexicographically smallest corner comes first (a rotation
    keeps the winding), then rows are sorted. Two meshes have bitwise the same triangles, with the same
    orientation, exactly when these arrays are equal.
    """
    tri = np.asarray(positions, dtype=np.float64)[np.asarray(faces)]  # [F, 3, 3]
    F = len(tri)
    # all three rotations of every triangle; keep the lexicographically smallest one, which is
    # well defined even for degenerate faces that repeat a corner
    rotations = np.stack([np.roll(tri, -k, axis=1).reshape(F, 9) for k in range(3)])  # [3, F, 9]
    flat = rotations.reshape(3 * F, 9)
    rank = np.empty(3 * F, dtype=np.int64)
    rank[np.lexsort(flat.T[::-1])] = np.arange(3 * F)
    best = rank.reshape(3, F).argmin(axis=0)
    rows = rotations[best, np.arange(F)]
    return rows[np.lexsort(rows.T[::-1])]


def up_axis(scan: Scan, choice: str = "auto") -> tuple[float, float, float]:
    """The scan's up direction: ``choice``, or with ``auto`` the one its file declares (glTF: y, by the
    format's rule; USD: the stage's), else z (OBJ and PLY scans are mostly z-up)."""
    axes = {"x": (1.0, 0.0, 0.0), "y": (0.0, 1.0, 0.0), "z": (0.0, 0.0, 1.0)}
    if choice == "auto":
        choice = scan.up or "z"
    return axes[choice]
