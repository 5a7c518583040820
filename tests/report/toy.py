"""A small enhance result made in code, without training a field: enough to build a report in a second."""

from __future__ import annotations

import numpy as np

from scantex.atlas.holes import untextured_faces
from scantex.atlas.seams import seam_visibility
from scantex.metrics.geometry import geometry_metrics
from scantex.pipeline.config import EnhanceConfig, ViewsConfig
from scantex.metrics.views import score_views
from scantex.pipeline.enhance import EnhanceResult, TrainingViews
from scantex.synth import make_wall
from scantex.synth.degrade import Degradation
from scantex.views.planning import plan_views
from scantex.views.raycast import RayCaster
from scantex.views.render import render
from scantex.views.viewset import render_views


def toy_result() -> EnhanceResult:
    """The toy wall's scan as input, its ground truth standing in for the enhanced scan."""
    demo = make_wall(grid=(24, 18), gt_texture_size=256, scan_texture_size=64, seed=3,
                     degradation=Degradation(hole_share=0.06, hole_clusters=1))
    scan, truth = demo.scan, demo.ground_truth
    cameras = plan_views(scan, 10, width=384, height=288, seed=0)
    views = render_views(scan, cameras)
    N, H, W = views.alpha.shape
    tv = TrainingViews(views, np.full((N, H, W), -1, np.int32), np.zeros((N, H, W), np.float32),
                       np.zeros((N, H, W), bool))
    caster = RayCaster(scan.positions, scan.faces)
    test = [cameras[i] for i in views.test]
    metrics = {
        "geometry": geometry_metrics(scan, truth),
        "held_out_vs_ground_truth": score_views(lambda cam: render(truth, cam, caster, supersample=2),
                                                {"input": scan, "enhanced": truth}, test, caster,
                                                untextured_faces(scan)),
        "seam_visibility": {"input": seam_visibility(scan), "enhanced": seam_visibility(truth)},
        "timings_s": {"plan": 0.1, "render": 0.2, "total": 0.3},
    }
    config = EnhanceConfig(preset="toy", views=ViewsConfig(n_views=10, width=384, height=288))
    return EnhanceResult(truth, metrics, config, tv, input_scan=scan, ground_truth=truth)
