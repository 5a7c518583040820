"""Synthetic scans with a known ground truth: a LiDAR-like wall (as a poor and as a good app delivers it) and a small room.

Each demo is a mesh with a fragmented atlas as capture apps make it, the ideal atlas, the degraded one
(lower resolution, blur, per-chart exposure, JPEG, holes), and the procedural albedo itself, so that
any view can be rendered exactly.
"""

from scantex.synth.charts import Unwrap
from scantex.synth.degrade import Degradation
from scantex.synth.demo import DemoScan, make_demo, make_geometry, render_ground_truth, write_demo
from scantex.synth.mesh import MeshNoise, PanelMesh
from scantex.synth.procedural import Finish, Panel, ProceduralAlbedo
from scantex.synth.room import make_room, room_panels
from scantex.synth.wall import make_app_wall, make_wall, wall_panels

__all__ = [
    "Degradation", "DemoScan", "Finish", "MeshNoise", "Panel", "PanelMesh", "ProceduralAlbedo", "Unwrap",
    "make_app_wall", "make_demo", "make_geometry", "make_room", "make_wall", "render_ground_truth", "room_panels",
    "wall_panels", "write_demo",
]
