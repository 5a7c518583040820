"""Run xatlas on one mesh in its own process: ``python -m scantex.uv._xatlas_worker IN.npz OUT.npz``.

xatlas can take many minutes on near-planar LiDAR meshes and crashes outright on some (an exact
icosphere(6) segfaults), so the parent runs it here, under a timeout, and survives both.

IN holds ``positions (V, 3) float32``, ``faces (F, 3) uint32`` and optional chart options
(``max_iterations``, ``max_cost``, ``normal_deviation_weight``, ``max_chart_area``). OUT gets xatlas's
``vmapping (W,)``, ``indices (F, 3)`` and ``uvs (W, 2)`` (in [0, 1]) with faces in input order.
"""

from __future__ import annotations

import sys

import numpy as np


def main(argv: list[str]) -> int:
    import xatlas

    source, target = argv
    data = np.load(source)
    atlas = xatlas.Atlas()
    atlas.add_mesh(np.ascontiguousarray(data["positions"], np.float32),
                   np.ascontiguousarray(data["faces"], np.uint32))
    options = xatlas.ChartOptions()
    for name in ("max_iterations", "max_cost", "normal_deviation_weight", "max_chart_area"):
        if name in data:
            setattr(options, name, type(getattr(options, name))(data[name]))
    pack = xatlas.PackOptions()
    pack.padding = 1
    pack.resolution = 1024
    atlas.generate(options, pack)
    vmapping, indices, uvs = atlas[0]
    np.savez(target, vmapping=vmapping, indices=indices, uvs=uvs)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
