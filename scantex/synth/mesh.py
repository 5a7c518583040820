"""LiDAR-like triangle meshes of panel scenes: grids with relief, jitter and scanner noise.

Panels that share an edge (a wall and the floor, two walls at a corner) share the vertices along it, so
a room is one connected surface as a capture app would mesh it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from scantex.arrays import unique_rows
from scantex.synth.noise import NoiseField
from scantex.synth.procedural import Panel, finish_relief


@dataclass(frozen=True)
class MeshNoise:
    """How far a synthetic scan's vertices stray from the ideal surface.

    Attributes:
        jitter: in-plane displacement of interior grid vertices, as a share of the grid spacing.
        noise_mm: standard deviation of the isotropic Gaussian scanner noise on every vertex.
    """

    jitter: float = 0.2
    noise_mm: float = 1.0


@dataclass(frozen=True, eq=False)
class PanelMesh:
    """The geometry of a panel scene.

    Attributes:
        positions: ``(V, 3) float64`` vertex positions in metres.
        faces: ``(F, 3) int64`` triangles, wound so their normals face the panel's visible side.
        panel_of_face: ``(F,) int64`` panel each face belongs to.
        cell_of_face: ``(F, 2) int64`` grid cell ``(i, j)`` of each face within its panel.
    """

    positions: np.ndarray
    faces: np.ndarray
    panel_of_face: np.ndarray
    cell_of_face: np.ndarray


def build_mesh(panels: tuple[Panel, ...], rng: np.random.Generator, noise: MeshNoise = MeshNoise()) -> PanelMesh:
    """Mesh every panel as a grid, weld shared edges, then add relief, jitter and scanner noise."""
    base, owner, plane_uv, on_border, faces, panel_of_face, cells = [], [], [], [], [], [], []
    offset = 0
    for k, panel in enumerate(panels):
        nu, nv = panel.cells
        if nu < 1 or nv < 1:
            raise ValueError(f"panel {k} needs at least one cell each way, got {panel.cells}")
        a, b = np.meshgrid(np.linspace(0.0, panel.size[0], nu + 1), np.linspace(0.0, panel.size[1], nv + 1),
                           indexing="ij")  # [nu+1, nv+1]
        uv = np.stack([a.ravel(), b.ravel()], axis=1)
        base.append(np.asarray(panel.origin) + uv[:, :1] * np.asarray(panel.u_axis)
                    + uv[:, 1:] * np.asarray(panel.v_axis))
        owner.append(np.full(len(uv), k))
        plane_uv.append(uv)
        ii, jj = np.meshgrid(np.arange(nu + 1), np.arange(nv + 1), indexing="ij")
        on_border.append(((ii == 0) | (ii == nu) | (jj == 0) | (jj == nv)).ravel())
        ci, cj = np.meshgrid(np.arange(nu), np.arange(nv), indexing="ij")
        ci, cj = ci.ravel(), cj.ravel()
        v00 = offset + ci * (nv + 1) + cj
        v10, v01 = v00 + (nv + 1), v00 + 1
        v11 = v10 + 1
        # (p00, p10, p11) and (p00, p11, p01) turn from u_axis to v_axis: normal u x v
        faces.append(np.concatenate([np.stack([v00, v10, v11], 1), np.stack([v00, v11, v01], 1)]))
        panel_of_face.append(np.full(2 * len(ci), k))
        cells.append(np.tile(np.stack([ci, cj], 1), (2, 1)))
        offset += len(uv)
    base = np.concatenate(base)
    owner = np.concatenate(owner)
    plane_uv = np.concatenate(plane_uv)
    on_border = np.concatenate(on_border)

    # weld vertices that panels share, on a micrometre grid (two panels may reach the same corner by
    # different floating-point sums)
    _, weld = unique_rows(np.rint(base * 1e6).astype(np.int64), return_inverse=True)
    weld = weld.ravel()
    V = int(weld.max()) + 1
    shared = np.bincount(weld, minlength=V) > 1

    # in-plane jitter only inside a panel, so panel outlines and shared edges stay put
    spacing = np.array([[p.size[0] / p.cells[0], p.size[1] / p.cells[1]] for p in panels])[owner]
    movable = ~on_border & ~shared[weld]
    jitter = rng.uniform(-noise.jitter, noise.jitter, plane_uv.shape) * spacing * movable[:, None]
    plane_uv = plane_uv + jitter

    relief_field = NoiseField.random(rng, 0.25, 64, smooth=2.0)
    displaced = np.empty_like(base)
    for k, panel in enumerate(panels):
        sel = owner == k
        uv = plane_uv[sel]
        height = finish_relief(panel.finish, uv[:, 0], uv[:, 1], relief_field).astype(np.float64)
        displaced[sel] = (np.asarray(panel.origin) + uv[:, :1] * np.asarray(panel.u_axis)
                          + uv[:, 1:] * np.asarray(panel.v_axis) + height[:, None] * panel.normal)
    # a welded vertex sits where the panels meeting there put it, on average
    positions = np.zeros((V, 3))
    np.add.at(positions, weld, displaced)
    positions /= np.bincount(weld, minlength=V)[:, None]
    positions += rng.normal(0.0, noise.noise_mm * 1e-3, positions.shape)

    return PanelMesh(positions, weld[np.concatenate(faces)], np.concatenate(panel_of_face), np.concatenate(cells))
