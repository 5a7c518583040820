"""The built-in demo wall: a 4 m x 3 m brick wall, partly painted, at the scale of a real LiDAR capture.

The default grid of 200 x 200 vertices gives 40,000 vertices and 79,202 faces; the ground-truth atlas
is 4096² (about 1 mm per texel) and the scan's 1024² (about 4 mm), as a phone capture app delivers.
"""

from __future__ import annotations

from scantex.synth.charts import Unwrap
from scantex.synth.degrade import Degradation
from scantex.synth.demo import DemoScan, make_demo
from scantex.synth.procedural import Finish, Panel

#: red brick, about half of it under an off-white paint
BRICK_WALL = Finish("brick", base_rgb=(0.86, 0.84, 0.78), accent_rgb=(0.62, 0.30, 0.20), paint_cover=0.5,
                    cracks=0.5, relief_mm=4.0, unevenness_mm=2.5)


def wall_panels(*, grid: tuple[int, int] = (200, 200), size_m: tuple[float, float] = (4.0, 3.0),
                finish: Finish = BRICK_WALL) -> tuple[Panel, ...]:
    """The wall as one panel in the x–z plane: x in [-w/2, w/2], z in [0, h] (z up), facing -y.

    Args:
        grid: vertices along x and along z.
        size_m: width and height in metres.
        finish: what the wall is made of.
    """
    if min(grid) < 2:
        raise ValueError(f"a wall grid needs at least 2 x 2 vertices, got {grid}")
    width, height = size_m
    # u along +x and v up: u x v = -y, so the faces look towards the cameras on the -y side
    return (Panel((-0.5 * width, 0.0, 0.0), (1.0, 0.0, 0.0), (0.0, 0.0, 1.0), (width, height),
                  (grid[0] - 1, grid[1] - 1), finish),)


def make_wall(seed: int = 0, *, grid: tuple[int, int] = (200, 200), size_m: tuple[float, float] = (4.0, 3.0),
              gt_texture_size: int = 4096, scan_texture_size: int = 1024, n_charts: int = 80,
              finish: Finish = BRICK_WALL, degradation: Degradation = Degradation(),
              supersample: int = 2) -> DemoScan:
    """The demo wall: a LiDAR-like mesh, its ideal atlas, and the degraded atlas a capture app makes.

    Args:
        seed: seeds geometry, charts, appearance and degradation.
        grid: vertices along x and along z (the default gives 40,000 vertices, 79,202 faces).
        size_m: width and height in metres.
        gt_texture_size: ground-truth atlas size in texels.
        scan_texture_size: degraded atlas size; must divide ``gt_texture_size``.
        n_charts: charts the atlas is cut into (fewer if the atlas is too small for them).
        finish: what the wall is made of.
        degradation: how the scan's texture is degraded.
        supersample: albedo samples per texel along each axis in the ground-truth bake.
    """
    return make_demo(wall_panels(grid=grid, size_m=size_m, finish=finish), seed, "wall",
                     gt_texture_size=gt_texture_size, scan_texture_size=scan_texture_size,
                     unwrap=Unwrap(n_charts=n_charts), degradation=degradation, supersample=supersample)


#: what a good phone capture app delivers: a sharp atlas, subtle exposure steps between charts, mild
#: compression and blur, a few small holes (the demo wall's degradation is far stronger)
APP_LIKE = Degradation(blur_sigma=0.5, gain_spread=0.08, white_balance_spread=0.03, offset_spread=0.005,
                       jpeg_quality=80, hole_share=0.005, hole_clusters=3)


def make_app_wall(seed: int = 0, *, grid: tuple[int, int] = (200, 200), size_m: tuple[float, float] = (4.0, 3.0),
                  texture_size: int = 4096, n_charts: int = 80, supersample: int = 2) -> DemoScan:
    """The app-realistic demo: the demo wall's geometry with a sharp ``texture_size``² atlas degraded as a
    good capture app would (:data:`APP_LIKE`: chart exposure within about ±8 %, JPEG q80, blur 0.5
    texel, 0.5 % of the surface in 3 small holes); the ground truth at the same resolution."""
    return make_demo(wall_panels(grid=grid, size_m=size_m), seed, "app", gt_texture_size=texture_size,
                     scan_texture_size=texture_size, unwrap=Unwrap(n_charts=n_charts), degradation=APP_LIKE,
                     supersample=supersample)
