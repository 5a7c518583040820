"""scantex: better textures for LiDAR-scanned meshes, geometry untouched.

The public API is imported lazily so that ``import scantex`` stays cheap (no torch, no trimesh)::

    import scantex
    scan = scantex.load_scan("room.obj")
    cams = scantex.plan_views(scan, 8)
    views = scantex.render_views(scan, cams, lit=True)
"""

from __future__ import annotations

import importlib

__version__ = "0.1.0"

_API = {
    "Scan": "scantex.scan",
    "Material": "scantex.scan",
    "ScanError": "scantex.errors",
    "load_scan": "scantex.io",
    "save_scan": "scantex.io",
    "Camera": "scantex.views.camera",
    "RayCaster": "scantex.views.raycast",
    "GBuffer": "scantex.views.raycast",
    "cast_gbuffer": "scantex.views.raycast",
    "render": "scantex.views.render",
    "ViewSet": "scantex.views.viewset",
    "render_views": "scantex.views.viewset",
    "write_views": "scantex.views.viewset",
    "plan_views": "scantex.views.planning",
    "face_coverage": "scantex.views.planning",
    "view_html": "scantex.inspect.plotly_view",
    "enhance": "scantex.pipeline.enhance",
    "EnhanceConfig": "scantex.pipeline.config",
    "preset": "scantex.pipeline.config",
    "write_outputs": "scantex.pipeline.outputs",
    "plan_uvs": "scantex.uv",
    "blend_seams": "scantex.uv",
    "compare": "scantex.metrics.compare",
    "geometry_metrics": "scantex.metrics.geometry",
    "load_photos": "scantex.photos",
    "require_alignment": "scantex.photos",
    "check_alignment": "scantex.photos",
    "batch": "scantex.scale.batch",
    "enhance_tiled": "scantex.scale.tiles",
    "TilingConfig": "scantex.pipeline.config",
    "make_wall": "scantex.synth",
    "make_room": "scantex.synth",
    "write_demo": "scantex.synth",
}

__all__ = sorted(_API)


def __getattr__(name: str):
    if name in _API:
        return getattr(importlib.import_module(_API[name]), name)
    raise AttributeError(f"module 'scantex' has no attribute {name!r}")


def __dir__():
    return __all__ + ["__version__"]
