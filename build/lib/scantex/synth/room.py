"""The built-in test room: a floor, four walls facing inwards, and two boxes, a few thousand faces.

Small enough for tests to make and render in about a second, with the same kinds of appearance,
charts and degradation as the demo wall. Walls and floor share their edges; the boxes stand on the
floor as separate pieces, as capture apps often mesh furniture.
"""

from __future__ import annotations

import numpy as np

from scantex.synth.charts import Unwrap
from scantex.synth.degrade import Degradation
from scantex.synth.demo import DemoScan, make_demo
from scantex.synth.procedural import Finish, Panel

PLASTER = Finish("plaster", base_rgb=(0.85, 0.83, 0.76), cracks=0.6, unevenness_mm=3.0)
FEATURE_BRICK = Finish("brick", base_rgb=(0.80, 0.84, 0.86), accent_rgb=(0.60, 0.32, 0.22), paint_cover=0.3,
                       cracks=0.3)
WOOD_FLOOR = Finish("wood", base_rgb=(0.60, 0.43, 0.28), cracks=0.1, relief_mm=1.0, unevenness_mm=1.0)
CARDBOARD = Finish("plaster", base_rgb=(0.66, 0.50, 0.33), cracks=0.0, unevenness_mm=1.5)

#: footprint corner (x, y) and size (x, y, z) in metres of each box, as shares of the room's size
BOXES = (((0.15, 0.55), (0.12, 0.16, 0.18)), ((0.62, 0.18), (0.18, 0.13, 0.28)))


def _cells(length: float, cell_m: float) -> int:
    return max(1, round(length / cell_m))


def _panel(origin, u_axis, v_axis, size, cells, finish: Finish) -> Panel:
    return Panel(tuple(map(float, origin)), tuple(map(float, u_axis)), tuple(map(float, v_axis)), size, cells,
                 finish)


def room_panels(*, size_m: tuple[float, float, float] = (4.0, 3.0, 2.5), cell_m: float = 0.15) -> tuple[Panel, ...]:
    """Floor, four walls and the sides and tops of two boxes; all visible sides face into the room.

    The room spans x in [0, X], y in [0, Y], z in [0, Z] (z up). Panels sharing an edge use the same
    number of cells along it, so their vertices weld there.
    """
    X, Y, Z = size_m
    nx, ny, nz = _cells(X, cell_m), _cells(Y, cell_m), _cells(Z, cell_m)
    x, y, z = np.eye(3)
    panels = [
        _panel((0, 0, 0), x, y, (X, Y), (nx, ny), WOOD_FLOOR),  # x cross y = +z: up
        _panel((X, 0, 0), -x, z, (X, Z), (nx, nz), PLASTER),  # wall at y = 0, facing +y
        _panel((0, Y, 0), x, z, (X, Z), (nx, nz), FEATURE_BRICK),  # wall at y = Y, facing -y
        _panel((0, 0, 0), y, z, (Y, Z), (ny, nz), PLASTER),  # wall at x = 0, facing +x
        _panel((X, Y, 0), -y, z, (Y, Z), (ny, nz), PLASTER),  # wall at x = X, facing -x
    ]
    for (fx, fy), (sx, sy, sz) in BOXES:
        x0, y0 = fx * X, fy * Y
        bx, by, bz = sx * X, sy * Y, sz * Z
        cx, cy, cz = _cells(bx, cell_m), _cells(by, cell_m), _cells(bz, cell_m)
        panels += [
            _panel((x0, y0, bz), x, y, (bx, by), (cx, cy), CARDBOARD),  # top, facing +z
            _panel((x0, y0, 0), x, z, (bx, bz), (cx, cz), CARDBOARD),  # facing -y
            _panel((x0 + bx, y0 + by, 0), -x, z, (bx, bz), (cx, cz), CARDBOARD),  # facing +y
            _panel((x0, y0 + by, 0), -y, z, (by, bz), (cy, cz), CARDBOARD),  # facing -x
            _panel((x0 + bx, y0, 0), y, z, (by, bz), (cy, cz), CARDBOARD),  # facing +x
        ]
    return tuple(panels)


def make_room(seed: int = 0, *, size_m: tuple[float, float, float] = (4.0, 3.0, 2.5), cell_m: float = 0.15,
              gt_texture_size: int = 1024, scan_texture_size: int = 256, n_charts: int = 40,
              degradation: Degradation = Degradation(), supersample: int = 2) -> DemoScan:
    """The test room, with its ideal and degraded atlases.

    Args:
        seed: seeds geometry, charts, appearance and degradation.
        size_m: room extent along x, y and z (height) in metres.
        cell_m: grid spacing of the mesh (the default gives about 4,800 faces).
        gt_texture_size: ground-truth atlas size in texels.
        scan_texture_size: degraded atlas size; must divide ``gt_texture_size``.
        n_charts: charts the atlas is cut into (each panel gets at least one).
        degradation: how the scan's texture is degraded.
        supersample: albedo samples per texel along each axis in the ground-truth bake.
    """
    return make_demo(room_panels(size_m=size_m, cell_m=cell_m), seed, "room", gt_texture_size=gt_texture_size,
                     scan_texture_size=scan_texture_size, unwrap=Unwrap(n_charts=n_charts),
                     degradation=degradation, supersample=supersample)
