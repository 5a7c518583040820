"""UV optimisation: seams and shells, shell merge/split by a stretch threshold, fresh unwrapping within a
time budget, packing at a uniform texel density, and seam blending after a bake.

``plan_uvs(scan, "keep" | "optimize" | "unwrap")`` plans a layout; ``blend_seams(scan)`` levels the two
sides of every seam of a baked texture.
"""

from scantex.uv.blend import blend_seams, transfer_texture
from scantex.uv.plan import UVPlan, plan_uvs
from scantex.uv.shells import seam_distances, summarise, texel_density

__all__ = ["UVPlan", "blend_seams", "plan_uvs", "seam_distances", "summarise", "texel_density",
           "transfer_texture"]
