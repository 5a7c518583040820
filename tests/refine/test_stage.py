"""The refinement stage inside enhance, at toy size: it runs, reports, and leaves the geometry alone."""

from __future__ import annotations

import numpy as np

from scantex.pipeline.enhance import enhance
from tests.pipeline.test_enhance import TOY, toy_demo  # noqa: F401 (a fixture)


def test_enhance_with_the_refiner_keeps_geometry_and_reports(toy_demo):
    # over the denoised input (the toy atlas is noisy): over the input as it is, this toy's refiner draws
    # patches on 1.5 % of the held-out pixels and the safety net sets its work aside
    cfg = TOY.override(train__steps=30, refine__enabled=True, refine__over_input=True, refine__steps=6,
                       refine__batch=4, refine__max_views=3, bake__denoise=1.0)
    result = enhance(toy_demo.scan, cfg, ground_truth=toy_demo.ground_truth)
    m = result.metrics
    assert result.scan.positions is toy_demo.scan.positions and result.scan.faces is toy_demo.scan.faces
    assert m["geometry"]["arrays_identical"]
    r = m["refine"]
    assert r["views_refined"] == 3 and r["view_size"] == [192, 144] and r["steps"] == 6
    assert np.isfinite(r["final_loss"]) and "refine" in m["timings_s"]
    assert np.isfinite(m["held_out_vs_ground_truth"]["enhanced"]["psnr"])


def test_the_refiner_runs_over_the_field_but_not_over_the_input_texels_unless_asked(toy_demo, monkeypatch):
    """Refining the field's colour helped (+0.35 dB on the demo wall); refining the input's own texels, the
    default bake of a textured scan, lost 0.06-0.26 dB: there it runs only when asked (refine.over_input)."""
    from scantex.refine.config import RefineConfig

    assert RefineConfig().enabled and not RefineConfig().over_input  # the defaults of every preset
    cfg = TOY.override(train__steps=30, refine__enabled=True, refine__steps=2, refine__batch=2, refine__max_views=2)
    kept = enhance(toy_demo.scan, cfg).metrics
    assert kept["bake"]["source"] == "input" and "refine" not in kept and "refine" not in kept["timings_s"]
    field = enhance(toy_demo.scan, cfg.override(bake__source="field")).metrics
    assert field["bake"]["source"] == "field" and field["refine"]["views_refined"] == 2
    import scantex.pipeline.enhance as pipeline

    monkeypatch.setattr(pipeline, "PATCH_LIMIT", 2.0)  # the toy's levelled result is not sent to the safety net
    asked = enhance(toy_demo.scan, cfg.override(refine__over_input=True)).metrics
    assert "safety" not in asked["bake"] and asked["refine"]["views_refined"] == 2
