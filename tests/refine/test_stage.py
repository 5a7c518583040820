"""The refinement stage inside enhance, at toy size: it runs, reports, and leaves the geometry alone."""

from __future__ import annotations

import numpy as np

from scantex.pipeline.enhance import enhance
from tests.pipeline.test_enhance import TOY, toy_demo  # noqa: F401 (a fixture)


def test_enhance_with_the_refiner_keeps_geometry_and_reports(toy_demo):
    cfg = TOY.override(train__steps=30, refine__enabled=True, refine__steps=6, refine__batch=4,
                       refine__max_views=3)
    result = enhance(toy_demo.scan, cfg, ground_truth=toy_demo.ground_truth)
    m = result.metrics
    assert result.scan.positions is toy_demo.scan.positions and result.scan.faces is toy_demo.scan.faces
    assert m["geometry"]["arrays_identical"]
    r = m["refine"]
    assert r["views_refined"] == 3 and r["view_size"] == [192, 144] and r["steps"] == 6
    assert np.isfinite(r["final_loss"]) and "refine" in m["timings_s"]
    assert np.isfinite(m["held_out_vs_ground_truth"]["enhanced"]["psnr"])
