"""The patch measure: hard-edged low-frequency changes count, global and smooth ones do not."""

from __future__ import annotations

import numpy as np
import pytest

from scantex.metrics.patches import patch_map, patch_score


@pytest.fixture
def texture() -> np.ndarray:
    """A detailed 240 x 320 texture: a fine pattern and pixel noise."""
    rng = np.random.default_rng(0)
    yy, xx = np.mgrid[:240, :320]
    t = 0.5 + 0.15 * np.sin(xx / 3.0) * np.cos(yy / 5.0) + 0.05 * rng.standard_normal((240, 320))
    return np.clip(np.repeat(t[..., None], 3, axis=2), 0, 1)


def blob(shape=(240, 320), centre=(120, 160), radius=50) -> np.ndarray:
    yy, xx = np.mgrid[:shape[0], :shape[1]]
    return ((yy - centre[0]) ** 2 + (xx - centre[1]) ** 2 < radius**2)[..., None]


def test_a_pasted_hard_edged_patch_scores_high(texture):
    patched = np.clip(texture * np.where(blob(), 1.08, 1.0), 0, 1)
    assert patch_score(patched, texture) > 0.003  # a busy texture masks a faint step, partly
    assert patch_score(np.clip(texture * np.where(blob(), 1.16, 1.0), 0, 1), texture) > patch_score(patched, texture)
    plain = np.clip(0.6 + np.random.default_rng(2).normal(0, 0.02, texture.shape), 0, 1)
    assert patch_score(np.clip(plain * np.where(blob(), 1.08, 1.0), 0, 1), plain) > 0.02  # on a plain wall: clear


def test_a_global_exposure_change_and_a_smooth_gradient_score_zero(texture):
    assert patch_score(np.clip(texture * 1.08, 0, 1), texture) == 0.0
    ramp = 1 + 0.15 * np.linspace(0, 1, 320)[None, :, None]
    assert patch_score(np.clip(texture * ramp, 0, 1), texture) == 0.0
    assert patch_score(texture, texture) == 0.0


def test_pixel_noise_and_removing_an_edge_do_not_count(texture):
    rng = np.random.default_rng(1)
    assert patch_score(np.clip(texture + rng.normal(0, 0.03, texture.shape), 0, 1), texture) < 0.001
    # the reference has the step; the image has it levelled away: not a patch
    stepped = np.clip(texture * np.where(blob(), 1.1, 1.0), 0, 1)
    assert patch_score(texture, stepped) == 0.0


def test_the_patch_is_found_at_its_border_and_silhouettes_are_ignored(texture):
    patched = np.clip(texture * np.where(blob(), 1.1, 1.0), 0, 1)
    patch, usable = patch_map(patched, texture)
    ys, xs = np.nonzero(patch)
    r = np.hypot(ys - 120, xs - 160)
    assert np.all(np.abs(r - 50) < 15)  # on the blob's border, nowhere else
    # a mask edge (the surface's silhouette) with black outside is no patch
    mask = np.ones((240, 320), bool)
    mask[:, 200:] = False
    assert patch_score(np.where(mask[..., None], texture * 1.05, 0), np.where(mask[..., None], texture, 0), mask) == 0.0


def test_shapes_must_match(texture):
    with pytest.raises(ValueError):
        patch_score(texture[:100], texture)


def test_scores_against_the_input_carry_the_same_patch_measure():
    """measure() takes the patch measure from the held-out scores against the input's renders instead of
    rendering the same cameras again: both must give the same numbers."""
    from scantex.metrics.views import score_views
    from scantex.pipeline.enhance import patch_metrics, patch_summary
    from scantex.synth import make_wall
    from scantex.views.planning import plan_views
    from scantex.views.raycast import RayCaster
    from scantex.views.render import render

    demo = make_wall(grid=(40, 30), gt_texture_size=256, scan_texture_size=128, n_charts=8)
    scan, other = demo.scan, demo.ground_truth
    caster = RayCaster(scan.positions, scan.faces)
    cameras = plan_views(scan, 3, width=96, height=72, caster=caster)
    direct = patch_metrics(scan, other, cameras, caster)
    scores = score_views(lambda cam: render(scan, cam, caster, supersample=2), {"enhanced": other}, cameras,
                         caster, np.zeros(scan.n_faces, bool))
    assert patch_summary(scores["enhanced"]["per_view"]["patches"]) == direct
    assert direct["enhanced_vs_input"] > 0  # the truth has edges the degraded scan lacks: not a vacuous match


def test_a_reference_scan_scores_as_its_renders():
    """score_views renders a reference scan (a ground truth) with the scored scans from one ray cast: the
    scores must be those against its own renders."""
    from scantex.atlas.holes import untextured_faces
    from scantex.metrics.views import score_views
    from scantex.synth import make_wall
    from scantex.views.planning import plan_views
    from scantex.views.raycast import RayCaster
    from scantex.views.render import render

    demo = make_wall(grid=(40, 30), gt_texture_size=256, scan_texture_size=128, n_charts=8)
    truth, scan = demo.ground_truth, demo.scan
    caster = RayCaster(scan.positions, scan.faces)
    cameras = plan_views(scan, 3, width=96, height=72, caster=caster)
    holes = untextured_faces(scan)
    assert holes.any()  # hole PSNR is compared too
    scans = {"input": scan, "truth itself": truth}
    by_renders = score_views(lambda cam: render(truth, cam, caster, supersample=2), scans, cameras, caster, holes)
    assert score_views(truth, scans, cameras, caster, holes) == by_renders
    # identical views score the cap (finite: valid JSON, and a mean that still shows the other views' errors)
    from scantex.metrics.views import PSNR_CAP_DB

    assert by_renders["truth itself"]["psnr"] == PSNR_CAP_DB


def test_a_result_scored_against_its_input_pools_the_views_error():
    """Scored against the input it was made from, a result leaves some views unchanged (the cap, 100 dB each):
    the mean of the views' PSNRs read 74.5 dB for views of 100, 100 and 23.5. Pooled, the PSNR is that of the
    views' mean squared error."""
    from scantex.metrics.views import PSNR_CAP_DB, score_views
    from scantex.synth import make_wall
    from scantex.views.planning import plan_views
    from scantex.views.raycast import RayCaster

    demo = make_wall(grid=(40, 30), gt_texture_size=256, scan_texture_size=128, n_charts=8)
    scan = demo.scan
    caster = RayCaster(scan.positions, scan.faces)
    cameras = plan_views(scan, 3, width=96, height=72, caster=caster)
    holes = np.zeros(scan.n_faces, bool)
    # one view sees the truth, two the scan itself
    scores = score_views(scan, {"same": scan, "truth": demo.ground_truth}, cameras, caster, holes, pooled=True)
    truth = scores["truth"]
    assert truth["psnr"] == pytest.approx(10 * np.log10(1 / truth["mse"]))
    assert truth["psnr_mean_of_views"] == pytest.approx(np.mean(truth["per_view"]["psnr"]))
    assert scores["same"]["psnr"] == PSNR_CAP_DB  # identical everywhere: the cap, pooled or not
    # a reference the scan matches in two views of three
    from scantex.views.render import render

    def reference(cam):
        image, alpha = render(scan, cam, caster, supersample=2)
        return (np.clip(image + 0.05, 0, 1) if cam is cameras[2] else image), alpha

    mixed = score_views(reference, {"scan": scan}, cameras, caster, holes, pooled=True)["scan"]
    assert mixed["per_view"]["psnr"][:2] == [PSNR_CAP_DB, PSNR_CAP_DB] and mixed["per_view"]["psnr"][2] < 30
    assert mixed["psnr_mean_of_views"] > 70  # what the summary said
    assert mixed["psnr"] == pytest.approx(mixed["per_view"]["psnr"][2] + 10 * np.log10(3), abs=0.05)


def test_fidelity_outside_the_holes_the_result_filled():
    """Against its input, a result that fills the input's holes scored low (the demo wall: 16.6 dB) however
    little it changed elsewhere: the PSNR over the pixels of no hole says how much the rest changed."""
    from scantex.atlas.holes import untextured_faces
    from scantex.metrics.views import PSNR_CAP_DB, score_views
    from scantex.synth import make_wall
    from scantex.views.planning import plan_views
    from scantex.views.raycast import RayCaster, cast_gbuffer
    from scantex.views.render import render

    demo = make_wall(grid=(40, 30), gt_texture_size=256, scan_texture_size=128, n_charts=8)
    scan = demo.scan
    caster = RayCaster(scan.positions, scan.faces)
    cameras = plan_views(scan, 3, width=96, height=72, caster=caster)
    holes = untextured_faces(scan)

    def filled(cam):  # the scan's own render, its holes' pixels grey: what a fill changes
        image, alpha = render(scan, cam, caster, supersample=2)
        face = cast_gbuffer(caster, cam).face_id
        image[(face >= 0) & holes[np.maximum(face, 0)]] = 0.5
        return image, alpha

    s = score_views(filled, {"scan": scan}, cameras, caster, holes, pooled=True)["scan"]
    assert s["psnr"] < 40 and s["hole_psnr"] < 20  # the holes differ, and they are all the pooled error
    assert s["psnr_outside_holes"] == PSNR_CAP_DB  # nothing else does
