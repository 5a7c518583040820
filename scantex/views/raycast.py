"""G-buffers by ray casting with Embree (through embreex), no OpenGL context needed.

Embree is called directly: trimesh's ray API wraps the same scene but is several times slower
(it returns no barycentrics). Rays are cast in chunks, split over threads (embreex releases the GIL),
so memory stays bounded however large the image.
"""

from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np

from scantex.views.camera import Camera

#: rays per Embree call: 64k rays take ~4 MB of buffers and split well over threads
CHUNK = 1 << 16
#: threads for work that is mostly ray casts and numpy (both release the interpreter lock): a cast's chunks,
#: or whole views side by side; two (one on a single core)
PAIR_THREADS = max(1, min(2, os.cpu_count() or 1))


@dataclass(frozen=True, eq=False)
class Hits:
    """Where rays first hit the mesh.

    Attributes:
        face_id: ``(N,) int32`` face index, -1 for a miss.
        bary: ``(N, 2) float32`` Embree's ``(u, v)``: hit = (1-u-v)·p0 + u·p1 + v·p2.
        t: ``(N,) float32`` distance along the (unnormalised) ray direction; inf for a miss.
    """

    face_id: np.ndarray
    bary: np.ndarray
    t: np.ndarray


class RayCaster:
    """An Embree BVH over a triangle mesh.

    Positions are shifted to the mesh's centre before the float32 conversion Embree needs, so that
    scans in large world coordinates (building scans, geo-referenced tiles) keep their precision.
    """

    def __init__(self, positions: np.ndarray, faces: np.ndarray):
        from embreex import rtcore_scene
        from embreex.mesh_construction import TriangleMesh

        positions = np.asarray(positions, dtype=np.float64)
        self.origin = 0.5 * (positions.min(axis=0) + positions.max(axis=0)) if len(positions) else np.zeros(3)
        self.n_faces = len(faces)
        self._scene = rtcore_scene.EmbreeScene()
        TriangleMesh(scene=self._scene, vertices=(positions - self.origin).astype(np.float32),
                     indices=np.asarray(faces, dtype=np.int32))
        self.threads = PAIR_THREADS

    def intersect(self, origins: np.ndarray, directions: np.ndarray) -> Hits:
        """First hits of rays ``origins + t * directions``, ``t > 0``.

        Args:
            origins: ``(N, 3)``, or ``(3,)`` / ``(1, 3)`` for rays from one point (a camera).
            directions: ``(N, 3)``; need not be unit length.
        """
        origins = np.asarray(origins, dtype=np.float64)
        directions = np.asarray(directions)
        if origins.shape == (1, 3):
            origins = origins[0]
        shared_origin = origins.ndim == 1
        N = len(directions)
        face_id = np.empty(N, dtype=np.int32)
        bary = np.empty((N, 2), dtype=np.float32)
        t = np.empty(N, dtype=np.float32)

        def run(start: int) -> None:
            stop = min(start + CHUNK, N)
            if shared_origin:
                o = np.empty((stop - start, 3), dtype=np.float32)
                o[:] = (origins - self.origin).astype(np.float32)
            else:
                o = (origins[start:stop] - self.origin).astype(np.float32)
            d = np.ascontiguousarray(directions[start:stop], dtype=np.float32)
            out = self._scene.run(o, d, output=1)
            face_id[start:stop] = out["primID"]
            bary[start:stop, 0] = out["u"]
            bary[start:stop, 1] = out["v"]
            t[start:stop] = out["tfar"]

        starts = range(0, N, CHUNK)
        if self.threads > 1 and N > CHUNK:
            with ThreadPoolExecutor(self.threads) as pool:  # Embree releases the GIL
                list(pool.map(run, starts))
        else:
            for s in starts:
                run(s)
        miss = face_id < 0
        t[miss] = np.inf
        bary[miss] = 0
        return Hits(face_id, bary, t)


@dataclass(frozen=True, eq=False)
class GBuffer:
    """Per-pixel surface attributes of one view.

    Attributes:
        face_id: ``(H, W) int32`` visible face, -1 where the ray misses.
        bary: ``(H, W, 2) float32`` Embree barycentrics ``(u, v)`` of the hit in that face.
        depth: ``(H, W) float32`` camera-space z of the hit; inf on a miss.
        normal: ``(H, W, 3) float32`` unit geometric normal of the hit face (world space), zero on a miss;
            ``None`` when the cast was given no face normals.
    """

    face_id: np.ndarray
    bary: np.ndarray
    depth: np.ndarray
    normal: np.ndarray | None

    @property
    def mask(self) -> np.ndarray:
        """``(H, W) bool`` pixels that see the mesh."""
        return self.face_id >= 0

    @property
    def shape(self) -> tuple[int, int]:
        return self.face_id.shape

    def points(self, positions: np.ndarray, faces: np.ndarray) -> np.ndarray:
        """``(H, W, 3)`` world position of each hit (zero on a miss)."""
        return interpolate(self.face_id, self.bary, positions[faces])


def interpolate(face_id: np.ndarray, bary: np.ndarray, corner_values: np.ndarray) -> np.ndarray:
    """Interpolate per-corner values ``(F, 3, C)`` at hits ``face_id (...), bary (..., 2)``.

    Returns ``(..., C)`` float64 (zero where ``face_id`` is -1). Compiled (:mod:`scantex.jit`: one pass, where
    numpy's gathers and rows of a few values took 5-30x as long), or :func:`interpolate_numpy` where numba is
    missing: the same arithmetic, bit for bit.
    """
    from scantex import jit

    corner_values = np.asarray(corner_values)
    if jit.compiled(_interpolate_kernel) is None or corner_values.dtype.kind not in "fiu":
        return interpolate_numpy(face_id, bary, corner_values)
    F = len(corner_values)  # face f's corners are rows 3f, 3f + 1 and 3f + 2 of the values laid flat
    return _interpolated(face_id, bary, _IMPLICIT_CORNERS, corner_values.reshape(F * 3, corner_values.shape[-1]), F)


def interpolate_indexed(face_id: np.ndarray, bary: np.ndarray, corners: np.ndarray, values: np.ndarray) -> np.ndarray:
    """:func:`interpolate` of ``values[corners]`` (``corners (F, 3)`` indices into ``values (T, C)``: a scan's UVs by
    its ``face_uvs``), bit for bit, without gathering the ``(F, 3, C)`` corner values first: only the hits' corners
    are read, in the compiled pass (a room's 1.2 M hits: several times faster than gathering their corners)."""
    from scantex import jit

    values = np.asarray(values)
    if jit.compiled(_interpolate_kernel) is None or values.dtype.kind not in "fiu":
        fid = np.asarray(face_id)
        return interpolate(np.where(fid >= 0, np.arange(fid.size).reshape(fid.shape), -1), bary,
                           values[corners[np.maximum(fid, 0).reshape(-1)]])
    return _interpolated(face_id, bary, np.ascontiguousarray(corners), values, len(corners))


#: ``corners`` of :func:`_interpolate_kernel` saying "face f's corners are rows 3f, 3f + 1 and 3f + 2"
_IMPLICIT_CORNERS = np.zeros((0, 3), np.int64)


def _interpolated(face_id: np.ndarray, bary: np.ndarray, corners: np.ndarray, values: np.ndarray,
                  n_faces: int) -> np.ndarray:
    """The compiled interpolation of :func:`interpolate` and :func:`interpolate_indexed`: ``(..., C)`` float64."""
    from scantex import jit

    shape = np.shape(face_id)
    flat = np.ascontiguousarray(face_id).reshape(-1)
    if flat.size and int(flat.max()) >= n_faces:
        raise IndexError(f"face {int(flat.max())} is out of bounds for {n_faces} faces")
    out = np.empty((flat.size, values.shape[-1]), np.float64)
    jit.compiled(_interpolate_kernel)(flat, np.ascontiguousarray(bary).reshape(-1, 2), corners,
                                      np.ascontiguousarray(values), out)
    return out.reshape(*shape, values.shape[-1])


def _interpolate_kernel(face_id, bary, corners, values, out):
    """The kernel of :func:`_interpolated`, hit by hit: ``out (n, C)`` filled in from the rows of ``values (T, C)``
    that ``corners (F, 3)`` names for each face, or (``corners`` empty) rows 3f, 3f + 1 and 3f + 2."""
    implicit = corners.shape[0] == 0
    for i in range(face_id.shape[0]):
        f = face_id[i]
        if f < 0:
            out[i, :] = 0.0
            continue
        u, v = np.float64(bary[i, 0]), np.float64(bary[i, 1])
        w = 1 - u - v
        if implicit:
            a, b, c = 3 * f, 3 * f + 1, 3 * f + 2
        else:
            a, b, c = corners[f, 0], corners[f, 1], corners[f, 2]
        for k in range(values.shape[1]):
            out[i, k] = values[a, k] * w + values[b, k] * u + values[c, k] * v


def interpolate_numpy(face_id: np.ndarray, bary: np.ndarray, corner_values: np.ndarray) -> np.ndarray:
    """:func:`interpolate` in numpy: its twin, and what runs where numba is missing."""
    shape = face_id.shape
    fid = face_id.reshape(-1)
    b = bary.reshape(-1, 2).astype(np.float64)
    hit = fid >= 0
    every = bool(hit.all())  # the usual case (hits only): no copies of the hits
    c = np.take(corner_values, fid if every else fid[hit], axis=0)  # [n, 3, C]; take: fancy indexing is slower
    if not every:
        b = b[hit]
    # w0 c0 + w1 c1 + w2 c2 in that order, as einsum would sum it, in 2-3x less time
    values = c[:, 0] * (1 - b[:, 0] - b[:, 1])[:, None] + c[:, 1] * b[:, :1] + c[:, 2] * b[:, 1:]
    if every:
        return values.astype(np.float64, copy=False).reshape(*shape, corner_values.shape[-1])
    out = np.zeros((fid.size, corner_values.shape[-1]), dtype=np.float64)
    out[hit] = values
    return out.reshape(*shape, corner_values.shape[-1])


def cast_gbuffer(caster: RayCaster, camera: Camera, face_normals: np.ndarray | None = None) -> GBuffer:
    """Ray-cast one camera's G-buffer.

    Args:
        caster: the BVH of the scan.
        camera: the view; cast at its full resolution (use :meth:`Camera.scaled` to supersample).
        face_normals: ``(F, 3)`` unit normals of the scan's faces, for the G-buffer's normals; ``None``: no
            normals (a quarter of the cast's time at 1-4 M rays goes to gathering them).
    """
    origins, directions = camera.pixel_rays()
    hits = caster.intersect(origins, directions)
    H, W = camera.height, camera.width
    face_id = hits.face_id.reshape(H, W)
    normal = None
    if face_normals is not None:
        normal = np.asarray(face_normals, dtype=np.float32)[hits.face_id]  # -1 picks the last row...
        normal[hits.face_id < 0] = 0  # ...so misses are cleared
        normal = normal.reshape(H, W, 3)
    # directions have unit camera-z, so the ray parameter is the depth
    return GBuffer(face_id, hits.bary.reshape(H, W, 2), hits.t.reshape(H, W), normal)


def pixel_footprints(face_id: np.ndarray, depth: np.ndarray, s: int, usable: np.ndarray | None = None
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """What the ``s x s`` sub-samples of each pixel of a supersampled G-buffer (``face_id``, ``depth``:
    ``(H * s, W * s)``) hit: ``(hits (H, W) int32, all_usable (H, W) bool, mean_depth (H, W) float32, spread
    (H, W) float32)``: how many hit the mesh, whether all hit a face that ``usable (F,) bool`` allows (any
    face when ``None``), the mean and the range (far - near; -inf where none hits) of their depths.
    The sub-samples are combined elementwise, as ``s * s`` strided ``(H, W)`` views: a reduction over the
    strided axes of an ``(H, s, W, s)`` array is several times slower."""
    H, W = face_id.shape[0] // s, face_id.shape[1] // s
    fid = face_id.reshape(H, s, W, s)
    d = depth.reshape(H, s, W, s)
    hits = np.zeros((H, W), np.int32)
    all_usable = np.ones((H, W), bool)
    total = np.zeros((H, W), np.float32)
    near = np.full((H, W), np.inf, np.float32)
    far = np.full((H, W), -np.inf, np.float32)
    for a in range(s):
        for b in range(s):
            f, z = fid[:, a, :, b], d[:, a, :, b]
            hit = f >= 0
            hits += hit
            all_usable &= hit if usable is None else hit & usable[np.where(hit, f, 0)]
            total += np.where(hit, z, 0)
            np.minimum(near, np.where(hit, z, np.inf), out=near)
            np.maximum(far, np.where(hit, z, -np.inf), out=far)
    return hits, all_usable, (total / np.maximum(hits, 1)).astype(np.float32), far - near
