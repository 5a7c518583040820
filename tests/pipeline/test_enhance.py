"""The enhance pipeline at toy size: geometry untouched, the texture measurably closer to the truth."""

from __future__ import annotations

import dataclasses
import json
import subprocess
import sys

import numpy as np
import pytest

from scantex.io import load_scan, save_scan
from scantex.pipeline.config import EnhanceConfig, FieldSettings, TrainConfig, ViewsConfig, load_config, \
    preset, save_config
from scantex.pipeline.enhance import enhance
from scantex.refine.config import RefineConfig
from scantex.scan import Scan, triangle_multiset_key
from scantex.synth import make_wall
from scantex.synth.degrade import Degradation
from tests.conftest import textured_cube

TOY = EnhanceConfig(
    preset="toy",
    views=ViewsConfig(n_views=8, width=96, height=72, adaptive=False),
    field=FieldSettings(hidden=32, n_layers=2, n_levels=8, log2_table_size=14, max_resolution=256),
    train=TrainConfig(steps=150, batch_rays=4096, checkpoint_every=50),
    refine=RefineConfig(enabled=False),  # the refiner has its own toy test (tests/refine/test_stage.py)
)


@pytest.fixture(scope="module")
def toy_demo():
    return make_wall(grid=(24, 18), gt_texture_size=256, scan_texture_size=64, seed=3,
                     degradation=Degradation(hole_share=0.06, hole_clusters=1))


@pytest.fixture(scope="module")
def toy_result(toy_demo):
    return enhance(toy_demo.scan, TOY, ground_truth=toy_demo.ground_truth)


def test_geometry_is_untouched(toy_demo, toy_result):
    out = toy_result.scan
    assert out.positions is toy_demo.scan.positions and out.faces is toy_demo.scan.faces
    assert toy_result.metrics["geometry"]["arrays_identical"]
    assert toy_result.metrics["geometry"]["triangles_identical"]


def test_texture_beats_input_against_ground_truth(toy_result):
    m = toy_result.metrics
    scores = m["held_out_vs_ground_truth"]
    assert scores["enhanced"]["mse"] < 0.85 * scores["input"]["mse"]
    assert m["seam_visibility"]["enhanced"] < m["seam_visibility"]["input"]
    if "hole_psnr" in scores["input"]:
        assert scores["enhanced"]["hole_psnr"] > scores["input"]["hole_psnr"] + 3.0
    assert m["input"]["hole_faces"] > 0


def test_a_new_layout_is_also_measured_at_the_input_seams(toy_demo, toy_result):
    """Optimised, the toy wall merges its charts: the input's seam steps are then inside charts, where the
    layout's own seams do not read them; the summary reads them at the input's seams too."""
    from scantex.atlas.seams import seam_edges, seam_visibility
    from scantex.cli import enhance_summary

    assert "enhanced_at_input_seams" not in toy_result.metrics["seam_visibility"]  # the layout kept
    result = enhance(toy_demo.scan, TOY.override(uv__mode="optimize"))
    seams = result.metrics["seam_visibility"]
    assert seams["enhanced_at_input_seams"] == pytest.approx(
        seam_visibility(result.scan, seam_edges(toy_demo.scan)), abs=1e-3)
    assert result.metrics["uv"]["after"]["shells"] < result.metrics["uv"]["before"]["shells"]
    assert f"at the input's seams {seams['input']:.2f} -> {seams['enhanced_at_input_seams']:.2f}" in \
        enhance_summary(result.metrics)
    # a kept layout with a few faces charted apart reads the same figure at both: said once (the bathroom's
    # summary read "7.29 -> 1.14 along each layout's own seams; at the input's seams 7.29 -> 1.14")
    kept = {**toy_result.metrics, "seam_visibility": {**toy_result.metrics["seam_visibility"],
                                                      "enhanced_at_input_seams":
                                                      toy_result.metrics["seam_visibility"]["enhanced"]}}
    assert "at the input's seams" not in enhance_summary(kept)


def test_output_atlas_keeps_the_input_size_and_layout(toy_demo, toy_result):
    """The default bake keeps the input's texels on its layout, at its size; the field bake doubles it."""
    (img,) = [m.image for m in toy_result.scan.materials]
    assert img.shape[:2] == (64, 64)
    assert np.array_equal(toy_result.scan.uvs, toy_demo.scan.uvs)
    field = enhance(toy_demo.scan, TOY.override(bake__source="field", train__steps=5))
    assert field.scan.materials[0].image.shape[:2] == (128, 128)
    # and the metrics say the size written (they had said the field bake's, 128, for both)
    assert toy_result.metrics["uv"]["texture_size"] == 64 and field.metrics["uv"]["texture_size"] == 128


def test_field_is_trained_only_when_something_uses_it(toy_demo):
    """The default bake uses the field only to denoise, and that is off by default: nothing trains (and the
    metrics say why). With bake.denoise on, a clean atlas still skips it; a noisy one, train.always and
    the field bake train it."""
    from scantex.atlas.colour import NOISE_FLOOR, atlas_noise

    cfg = TOY.override(train__steps=5)
    H, W = toy_demo.scan.materials[0].image.shape[:2]
    smooth = np.stack([*np.meshgrid(np.linspace(40, 200, W), np.linspace(60, 180, H)), np.full((H, W), 120.0)], -1)
    noisy_image = np.clip(smooth + np.random.default_rng(0).normal(0, 8, smooth.shape), 0, 255)

    def with_image(image):
        material = dataclasses.replace(toy_demo.scan.materials[0], image=image.astype(np.uint8))
        return toy_demo.scan.replace(materials=(material,))

    clean, noisy = with_image(smooth), with_image(noisy_image)
    assert atlas_noise(clean) < NOISE_FLOOR < atlas_noise(noisy)

    # denoising is off by default (no measured gain on real app atlases): even the noisy atlas trains nothing
    off = enhance(noisy, cfg).metrics
    assert off["field"]["trained"] is False and "bake.denoise 0" in off["field"]["why"]
    denoise = cfg.override(bake__denoise=1.0)
    skipped = enhance(clean, denoise).metrics
    assert skipped["field"]["trained"] is False and "noise" in skipped["field"]["why"]
    assert skipped["bake"]["denoised"] is False and skipped["timings_s"]["train"] < 5
    # train.always trains a field the default bake does not use: the metrics do not call that denoising
    for scan, c, denoised in ((noisy, denoise, True), (clean, cfg.override(train__always=True), False),
                              (clean, cfg.override(bake__source="field"), None)):
        m = enhance(scan, c).metrics
        assert m["field"]["trained"] is True and m["field"]["steps_run"] == 5 and "why" not in m["field"]
        assert m["bake"].get("denoised") is denoised


def test_resume_continues_from_checkpoint(tmp_path, toy_demo):
    import torch

    cfg = TOY.override(train__steps=60, train__checkpoint_every=20, train__always=True)
    enhance(toy_demo.scan, cfg, work_dir=tmp_path)
    ckpt = tmp_path / "field.pt"
    # the last checkpoint before the end is the state an interrupted run would resume from
    assert torch.load(ckpt, weights_only=True)["step"] == 40
    resumed = enhance(toy_demo.scan, cfg, work_dir=tmp_path, resume=True)
    # 20 steps were left: the loss history holds all 60, the first 40 restored from the checkpoint
    assert resumed.metrics["field"]["steps_run"] == 20 and resumed.metrics["field"]["steps"] == 60
    from scantex.cli import enhance_summary  # and the summary says it resumed

    assert "field: resumed from its checkpoint: 40 of its 60 steps" in enhance_summary(resumed.metrics)
    # how the outputs are written is none of the checkpoint's business: --texture-format jpeg resumes it too
    jpeg = cfg.override(output__texture_format="jpeg", output__jpeg_quality=80)
    again = enhance(toy_demo.scan, jpeg, work_dir=tmp_path, resume=True)
    assert again.metrics["field"]["steps_run"] == 20


def test_config_roundtrip(tmp_path):
    cfg = preset("fast").override(seed=7, train__steps=11)
    save_config(cfg, tmp_path / "config.json")
    back = load_config(tmp_path / "config.json")
    assert back == cfg


def test_a_partial_config_takes_its_presets_other_settings(tmp_path):
    (tmp_path / "c.json").write_text(json.dumps({"preset": "fast", "train": {"steps": 50}}))
    assert load_config(tmp_path / "c.json") == preset("fast").override(train__steps=50)
    (tmp_path / "c.json").write_text(json.dumps({"preset": "mine", "views": {"n_views": 5}}))  # one's own label
    assert load_config(tmp_path / "c.json") == preset("default").override(preset="mine", views__n_views=5)


def test_enhance_takes_a_presets_name():
    from scantex.errors import ScanError

    with pytest.raises(ScanError, match="unknown preset 'quick'"):  # not AttributeError: 'str' has no 'threads'
        enhance(textured_cube(), "quick")


def test_config_rejects_unknown_keys(tmp_path):
    from scantex.errors import ScanError

    (tmp_path / "c.json").write_text(json.dumps({"train": {"stepz": 3}}))
    with pytest.raises(ScanError, match="unknown config key 'train.stepz'"):
        load_config(tmp_path / "c.json")


def test_config_checks_the_output_settings(tmp_path):
    """``output``: the atlases' format and JPEG quality, checked like every other setting; a config written
    before the section existed loads with PNG."""
    from scantex.errors import ScanError

    for bad, needle in (({"texture_format": "gif"}, "one of png, jpeg"), ({"jpeg_quality": 0}, "1 to 100"),
                        ({"jpeg_quality": 90.5}, "a whole number")):
        (tmp_path / "c.json").write_text(json.dumps({"output": bad}))
        with pytest.raises(ScanError, match=needle):
            load_config(tmp_path / "c.json")
    (tmp_path / "c.json").write_text(json.dumps({"preset": "fast"}))
    assert load_config(tmp_path / "c.json").output.texture_format == "png"


def test_enhance_cli_writes_everything(tmp_path, toy_demo):
    save_scan(toy_demo.scan, tmp_path / "scan.obj")
    save_scan(toy_demo.ground_truth, tmp_path / "truth.obj")
    save_config(TOY, tmp_path / "toy.json")
    out = tmp_path / "out"
    proc = subprocess.run([sys.executable, "-m", "scantex", "enhance", str(tmp_path / "scan.obj"), "-o", str(out),
                           "--config", str(tmp_path / "toy.json"), "--ground-truth", str(tmp_path / "truth.obj"),
                           "-q"], capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr
    for name in ("enhanced.obj", "enhanced.mtl", "enhanced_scan.png", "enhanced.glb", "metrics.json", "report.html",
                 "config.json", "renders/cameras.json"):
        assert (out / name).exists(), name
    assert not (tmp_path / "out.partial").exists()
    before, after = load_scan(tmp_path / "scan.obj"), load_scan(out / "enhanced.obj")
    assert np.array_equal(before.positions, after.positions) and np.array_equal(before.faces, after.faces)
    glb = load_scan(out / "enhanced.glb")
    f32 = before.positions.astype(np.float32).astype(np.float64)
    assert np.array_equal(triangle_multiset_key(f32, before.faces), triangle_multiset_key(glb.positions, glb.faces))
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["geometry"]["arrays_identical"] is True
    assert load_config(out / "config.json") == TOY


def test_chart_appearance_inverts():
    import torch

    from scantex.field.appearance import ChartAppearance

    app = ChartAppearance(3, torch.tensor([1.0, 2.0, 3.0]))
    with torch.no_grad():
        app.delta.normal_(0, 0.1)
    rgb = torch.rand(50, 3)
    chart = torch.randint(0, 3, (50,))
    assert torch.allclose(app.canonical(app(rgb, chart), chart), rgb, atol=1e-5)
    # the regulariser is zero at identity and grows with a common gain
    assert float(ChartAppearance(3).regulariser().detach()) == 0.0


def test_detail_transfer_keeps_geometry_and_changes_texture(toy_demo):
    # bake.detail belongs to the field bake (bake.source = field)
    field = TOY.override(bake__source="field", refine__enabled=False)
    plain = enhance(toy_demo.scan, field, ground_truth=toy_demo.ground_truth)
    with_detail = enhance(toy_demo.scan, field.override(bake__detail=1.0), ground_truth=toy_demo.ground_truth)
    assert with_detail.metrics["geometry"]["arrays_identical"]
    assert plain.metrics["bake"]["source"] == "field"
    a, b = plain.scan.materials[0].image, with_detail.scan.materials[0].image
    assert a.shape == b.shape and not np.array_equal(a, b)


def test_default_bake_keeps_the_input_texels_and_reports_patches(toy_demo, toy_result):
    m = toy_result.metrics
    assert m["bake"]["source"] == "input" and m["bake"]["noise_threshold"] >= 0
    assert 0 <= m["patches"]["enhanced_vs_input"] <= 1 and len(m["patches"]["per_view"]) == m["views"]["test"]
    assert m["sampling"]["train_rays"] > 0 and m["sampling"]["used_input_texels"] > 0
    assert m["views"]["rendered"] == m["views"]["total"]  # mesh-only mode renders every view it plans


def test_the_inputs_base_colour_stays_outside_the_texture(toy_demo, toy_result, tmp_path):
    """A scan exported from Blender says ``Kd 0.8`` beside its texture. The formats multiply the texture by it
    and some viewers do; Blender shows the texture alone. The texels baked are the input's times 0.8: written
    under ``Kd 1`` they made the result 20 % darker than the input wherever the base colour is not applied.
    The result keeps ``Kd 0.8`` over the texture the same scan gets under ``Kd 1``, so every viewer shows it as
    it showed the input."""
    m = toy_demo.scan.materials[0]
    scan = toy_demo.scan.replace(materials=(dataclasses.replace(m, diffuse=(0.8, 0.8, 0.8, 1.0)),))
    out = enhance(scan, TOY).scan.materials[0]
    assert out.diffuse == (0.8, 0.8, 0.8, 1.0)
    plain = toy_result.scan.materials[0]  # the same scan under Kd 1
    assert plain.diffuse[:3] == (1.0, 1.0, 1.0)
    step = np.abs(out.image.astype(int) - plain.image.astype(int))
    # a few levels (the rounding of texel * 0.8 / 0.8, and where the fill and levelling round otherwise); the
    # texture times 0.8 under Kd 1, as before, is tens of levels off
    darker = np.abs(np.rint(plain.image * 0.8).astype(int) - plain.image.astype(int)).mean()
    assert step.mean() < 2 and np.quantile(step, 0.99) <= 6 and darker > 10
    from scantex.io.obj import parse_mtl

    result = toy_result.scan.replace(materials=(out,))
    save_scan(result, tmp_path / "out.obj")
    assert parse_mtl(tmp_path / "out.mtl")[out.name]["diffuse"][:3] == [0.8, 0.8, 0.8]


def test_a_result_with_patches_falls_back_to_the_input_texels(toy_demo, monkeypatch):
    """The safety net of the default bake: when levelling and refining draw patches (share of held-out
    pixels above PATCH_LIMIT) without removing SEAM_GAIN of the seam visibility, the texels go back to
    the input's (holes filled, seams blended), and the metrics say why."""
    import scantex.pipeline.enhance as pipeline

    cfg = TOY.override(train__steps=5, refine__enabled=True, refine__over_input=True, refine__steps=2)
    monkeypatch.setattr(pipeline, "PATCH_LIMIT", 2.0)  # no result "has patches"
    kept = enhance(toy_demo.scan, cfg).metrics
    assert "safety" not in kept["bake"] and kept["bake"]["levelling_offset_max"] > 0 and "refine" in kept
    monkeypatch.setattr(pipeline, "PATCH_LIMIT", -1.0)  # every result "has patches" ...
    monkeypatch.setattr(pipeline, "SEAM_GAIN", 1.01)  # ... and no levelling removes enough seams
    result = enhance(toy_demo.scan, cfg)
    m = result.metrics
    assert m["bake"]["safety"]["fallback"] == "no levelling, no refiner" and "seam visibility" in m["bake"]["safety"]["why"]
    assert m["bake"]["levelling_offset_max"] == 0 and "refine" not in m
    assert result.scan.positions is toy_demo.scan.positions and result.scan.faces is toy_demo.scan.faces
    # the field's line no longer says the kept texels are levelled, and the report's summary says why they are kept
    from scantex.report.html import _headline

    assert "the input's texels are kept (holes filled)" in m["field"]["why"]
    assert "Safety fallback" in _headline(m) and "Safety fallback" not in _headline(kept)
    # a new layout is no way around it (the input's seams read where they now lie inside its charts)
    moved = enhance(toy_demo.scan, cfg.override(uv__mode="optimize")).metrics
    assert moved["uv"]["mode"] == "optimize" and moved["bake"]["safety"]["fallback"] == "no levelling, no refiner"


def test_the_safety_net_reads_the_seams_levelling_levels():
    """A room's seams on its creases (wall to floor) join two surfaces whose colours differ for real: levelling
    leaves them, and counted, they made a synthetic room's levelling remove 30 % of the seam steps (under
    SEAM_GAIN: the fallback, 22.4 dB against its truth where the levelled texture scored 25.0) where it removed 58 %
    of those it is for. Here the true texture stands in for a perfect levelling."""
    from scantex.atlas.seams import seam_visibility
    from scantex.pipeline.enhance import SEAM_GAIN, levelled_seams
    from scantex.synth.room import make_room

    room = make_room(0, gt_texture_size=256, scan_texture_size=128)
    before, after = levelled_seams(room.scan, room.ground_truth)
    everywhere = 1 - seam_visibility(room.ground_truth) / seam_visibility(room.scan)
    assert 1 - after / before > 0.5 > everywhere + 0.15 and everywhere < SEAM_GAIN + 0.05


def test_vertex_coloured_mesh_keeps_its_colours_in_a_texture(toy_demo):
    """Mesh-only mode on a fused depth scan's vertex colours: they are baked into a texture and kept as a capture
    app's texels are (no field learning them back from renders), its black vertices filled; no seam levelling
    or blending, as the colours are continuous across the new layout's seams."""
    from scantex.views.render import shade_hits

    scan = toy_demo.scan
    face = np.zeros(scan.n_vertices, int)
    corner = np.zeros(scan.n_vertices, int)
    for k in range(3):
        face[scan.faces[:, k]], corner[scan.faces[:, k]] = np.arange(scan.n_faces), k
    bary = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]])[corner]
    rgb = shade_hits(toy_demo.ground_truth, face, bary)
    coloured = Scan(scan.positions, scan.faces, vertex_colors=np.column_stack(
        [np.round(rgb * 255), np.full(len(rgb), 255)]).astype(np.uint8))
    result = enhance(coloured, TOY)
    m = result.metrics
    assert m["input"]["texture"].startswith("baked from the vertex colours (2048x2048; not levelled nor blended")
    assert m["field"]["trained"] is False and m["timings_s"]["vertex_colours"] > 0
    assert result.scan.positions is coloured.positions and result.scan.faces is coloured.faces
    assert m["geometry"]["arrays_identical"] and m["geometry"]["triangles_identical"]
    assert m["bake"]["levelling_offset_max"] == 0
    assert m["seam_visibility"]["enhanced"] == m["seam_visibility"]["before_blending"]
    # the result shows the vertex colours: at random surface points, within a level or two of them
    rng = np.random.default_rng(0)
    f = rng.integers(0, scan.n_faces, 4000)
    b = rng.dirichlet(np.ones(3), 4000)[:, 1:]
    assert np.abs(shade_hits(result.scan, f, b) - shade_hits(coloured, f, b)).mean() < 2 / 255


def test_black_vertex_colours_are_filled(toy_demo):
    """Vertices a fusion left uncoloured (black) are holes: the texture fills them from around."""
    scan = toy_demo.scan
    x = scan.positions[:, 0]
    rgb = np.column_stack([np.full_like(x, 150), np.full_like(x, 100), np.full_like(x, 60), np.full_like(x, 255)])
    lo, hi = np.quantile(x, [0.45, 0.55])
    rgb[(x > lo) & (x < hi), :3] = 0  # a band of uncoloured vertices
    coloured = Scan(scan.positions, scan.faces, vertex_colors=rgb.astype(np.uint8))
    result = enhance(coloured, TOY)
    image = result.scan.materials[0].image
    used = image.reshape(-1, 3)[image.reshape(-1, 3).any(axis=1)]
    assert np.abs(used.astype(int) - [150, 100, 60]).max() <= 2  # no black left, no other colour invented
