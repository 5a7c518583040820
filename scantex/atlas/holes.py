"""Faces the input texture leaves without colour: black untextured faces and out-of-atlas UVs.

Capture apps paint faces no photo saw pure black. Such faces must not teach the field "black"; they
are masked out of the loss and the field fills them from their surroundings.
"""

from __future__ import annotations

import numpy as np

from scantex import jit
from scantex.arrays import read_only
from scantex.scan import Scan
from scantex.views.render import sample_texture

#: colours at or below this (0-255) in every channel count as "no colour" (JPEG leaves a little noise)
BLACK_LEVEL = 6


def untextured_faces(scan: Scan) -> np.ndarray:
    """``(F,) bool``: faces whose texture is black at their centre and near their corners, whose UVs lie
    entirely outside the atlas, or whose UV triangle has no area. All False for untextured scans. Computed
    once per scan (:meth:`Scan.texture_memo`); read-only."""
    return scan.texture_memo("untextured_faces", lambda: read_only(_untextured_faces(scan)))


def _untextured_faces(scan: Scan) -> np.ndarray:
    F = scan.n_faces
    holes = np.zeros(F, bool)
    if not scan.is_textured:
        return holes
    uv = scan.triangle_uvs  # [F, 3, 2]
    centre = uv.mean(axis=1, keepdims=True)
    probes = np.concatenate([centre, centre + 0.7 * (uv - centre)], axis=1)  # [F, 4, 2]
    e1, e2 = uv[:, 1] - uv[:, 0], uv[:, 2] - uv[:, 0]
    holes |= np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]) < 1e-14
    holes |= ((uv < 0) | (uv > 1)).any(axis=2).all(axis=1)
    for m, material in enumerate(scan.materials):
        sel = np.flatnonzero(scan.face_materials == m)
        if material.image is None or sel.size == 0:
            continue
        rgb = sample_texture(material.image, probes[sel].reshape(-1, 2)).reshape(len(sel), 4, -1)[..., :3]
        holes[sel] |= (rgb.max(axis=(1, 2)) * 255.0 <= BLACK_LEVEL)
    return holes


#: probes per face edge for :func:`partly_untextured_faces` (a triangular grid of (n+1)(n+2)/2 points)
PARTIAL_PROBES = 6


def _black_texels(image, level, out):
    """The compiled twin of :func:`partly_untextured_faces`' mask: ``out (H, W, 1)`` 255 where every channel of
    the 8-bit ``image (H, W, >= 3)`` is at most ``level``, else 0."""
    for y in range(image.shape[0]):
        for x in range(image.shape[1]):
            black = image[y, x, 0] <= level and image[y, x, 1] <= level and image[y, x, 2] <= level
            out[y, x, 0] = 255 if black else 0


def partly_untextured_faces(scan: Scan, holes: np.ndarray | None = None, *, chunk: int = 65536) -> np.ndarray:
    """``(F,) bool``: faces that are not :func:`untextured_faces` (``holes``, when already known) but whose
    texture is black somewhere inside.

    A capture app leaves black where no photo reached: a face on the edge of that region is partly black,
    and its black part is kept as the input's colour where nothing else covers it (black specks on a
    room's walls). Probes a triangular grid of points drawn 10 % towards the face's centre (a UV triangle's
    own border reads the atlas's gutter)."""
    F = scan.n_faces
    partly = np.zeros(F, bool)
    if not scan.is_textured:
        return partly
    n = PARTIAL_PROBES
    grid = np.array([(i / n, j / n) for i in range(n + 1) for j in range(n + 1 - i)])
    weights = np.stack([1 - grid[:, 0] - grid[:, 1], grid[:, 0], grid[:, 1]], axis=1)
    weights = 0.9 * weights + 0.1 / 3
    uv = scan.triangle_uvs  # [F, 3, 2]
    for m, material in enumerate(scan.materials):
        sel = np.flatnonzero(scan.face_materials == m)
        if material.image is None or sel.size == 0:
            continue
        image = material.image
        level = BLACK_LEVEL if image.dtype == np.uint8 else BLACK_LEVEL / 255.0
        # one channel to look up: 1 where a texel is black (a probe is black where all four texels it reads are)
        black = np.empty((*image.shape[:2], 1), np.uint8)
        kernel = jit.compiled(_black_texels) if image.dtype == np.uint8 else None
        if kernel is not None:  # one compiled pass (an 8192^2 atlas: about 0.1 s, where numpy took 0.6 s)
            kernel(image, level, black)
        else:
            brightest = np.maximum(np.maximum(image[..., 0], image[..., 1]), image[..., 2])
            black[..., 0] = (brightest <= level).astype(np.uint8) * np.uint8(255)
        per = max(1, chunk // len(grid))
        for s in range(0, sel.size, per):
            f = sel[s:s + per]
            probes = np.matmul(weights, uv[f])  # [f, P, 2]
            partly[f] = (sample_texture(black, probes.reshape(-1, 2)).reshape(len(f), -1) > 0.999).any(axis=1)
    return partly & ~(untextured_faces(scan) if holes is None else holes)
