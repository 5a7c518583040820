"""Faces the input texture leaves without colour: black untextured faces and out-of-atlas UVs.

Capture apps paint faces no photo saw pure black. Such faces must not teach the field "black"; they
are masked out of the loss and the field fills them from their surroundings.
"""

from __future__ import annotations

import numpy as np

from scantex.scan import Scan
from scantex.views.render import sample_texture

#: colours at or below this (0-255) in every channel count as "no colour" (JPEG leaves a little noise)
BLACK_LEVEL = 6


def untextured_faces(scan: Scan) -> np.ndarray:
    """``(F,) bool``: faces whose texture is black at their centre and near their corners, whose UVs lie
    entirely outside the atlas, or whose UV triangle has no area. All False for untextured scans."""
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
