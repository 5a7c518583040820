"""``report.html``: self-contained, one plotly.js for both 3D views, the run's renders and numbers."""

from __future__ import annotations

import dataclasses
import json
import re

import numpy as np
import pytest

from scantex.report import build_report, write_report
from tests.report.toy import toy_result


@pytest.fixture(scope="module")
def result():
    return toy_result()


@pytest.fixture(scope="module")
def page(result):
    return build_report(result)


def figures(page: str) -> list[dict]:
    """The 3D views' figures as the page's script assembles them: the geometry they share is written once."""
    shared = dict(re.findall(r'<script type="application/json" class="geometry" id="([^"]+)">(.*?)</script>', page,
                             re.S))
    out = []
    for attrs, block in re.findall(r'<script type="application/json" class="figure"([^>]*)>(.*?)</script>', page,
                                   re.S):
        figure = json.loads(block)
        if (key := re.search(r"data-geometry=(\S+)", attrs)) is not None:
            figure["data"][0].update(json.loads(shared[key.group(1)]))
        out.append(figure)
    return out


def test_self_contained(page):
    assert page.count("plotly.js v") == 1  # embedded once for both views
    # nothing is fetched: no script, style or image refers to another file or a server
    assert not re.search(r'<(script|link|img|iframe)\b[^>]*\b(src|href)="(?!data:)', page)


def test_two_3d_views_of_every_face(page, result):
    before, after = figures(page)
    for fig, scan in ((before, result.input_scan), (after, result.scan)):
        (trace,) = fig["data"]
        assert trace["type"] == "mesh3d"
        assert len(trace["facecolor"]) == scan.n_faces
    # the views differ where the textures do
    assert before["data"][0]["facecolor"] != after["data"][0]["facecolor"]
    # one geometry for both: a page of a 79,202-face mesh held its positions and triangles twice (2.5 MB)
    assert page.count('class="geometry"') == 1 and page.count("data-geometry=geometry-3d") == 2
    for k in ("x", "i"):
        assert before["data"][0][k] == after["data"][0][k] and "bdata" in before["data"][0][k]


def compares(page: str) -> list[tuple[str, list[str]]]:
    """``(id, names of the images it holds)`` of every wipe viewer."""
    out = []
    for m in re.finditer(r'<div class="compare" id="compare-([^"]+)"', page):
        sources = page[m.end():].split('<div class="cmp-sources" hidden>', 1)[1].split("</div>", 1)[0]
        out.append((m.group(1), re.findall(r'data-name="([^"]+)"', sources)))
    return out


def test_renders_atlases_metrics_timings_config(page, result):
    n_test = len(result.views.views.test)
    # one wipe viewer per held-out view (input, enhanced, ground truth), one over the atlas crop
    assert compares(page) == [(f"view-{k + 1}", ["input", "enhanced", "ground truth"]) for k in range(n_test)] + [
        ("atlas-0", ["before", "after"])]
    assert page.count('class="thumb"') == 2
    body = page.split("<body>", 1)[1]
    # every image once: the viewers' images are copied into place by the script, not repeated
    assert body.count('src="data:image/png;base64,') == 3 * n_test + 2 + 2
    assert "Hausdorff" in page and "mean point-to-mesh" in page
    assert "identical: 432 vertices, 782 faces" in page
    assert "&quot;preset&quot;: &quot;toy&quot;" in page  # the config
    assert "<th>plan</th><td>0.10 s</td>" in page  # the timings
    assert "open surface" in page  # the volume note


def test_held_out_views_show_their_own_scores(page, result):
    """Each viewer shows its view's PSNR and SSIM from the metrics (not the mean)."""
    scores = result.metrics["held_out_vs_ground_truth"]
    per_view = scores["input"]["per_view"]
    assert len(per_view["psnr"]) == len(result.views.views.test)
    assert np.mean(per_view["psnr"]) == pytest.approx(scores["input"]["psnr"])
    assert len(set(np.round(per_view["psnr"], 2))) > 1  # the views differ, so a mean would show here
    tables = re.findall(r"<table class='cmp-scores'><caption>view (\d+):.*?</table>", page, re.S)
    assert len(tables) == len(per_view["psnr"])
    for k, (psnr, ssim) in enumerate(zip(per_view["psnr"], per_view["ssim"])):
        table = page.split(f"<caption>view {k + 1}:", 1)[1].split("</table>", 1)[0]
        assert f"<th>input</th><td>{psnr:.4g} dB</td><td>{ssim:.4g}</td>" in table
    assert "per_view" not in page.split('id="metrics"', 1)[1].split("</section>", 1)[0]


def test_atlas_viewer_holds_the_same_uv_region_at_each_atlas_resolution(page, result):
    from PIL import Image
    import base64
    import io

    sources = page.split('id="compare-atlas-0"', 1)[1].split('<div class="cmp-sources" hidden>', 1)[1]
    crops = {name: np.asarray(Image.open(io.BytesIO(base64.b64decode(data))))
             for name, data in re.findall(r'data-name="(\w+)"[^>]*src="data:image/png;base64,([^"]+)"', sources)}
    before, after = result.input_scan.materials[0].image, result.scan.materials[0].image
    scale = after.shape[1] / before.shape[1]
    assert crops["after"].shape[0] == round(crops["before"].shape[0] * scale)  # the same UV square
    assert 'data-open="1"' in page.split('id="compare-atlas-0"', 1)[1][:200]  # opens at 1:1


def test_decimates_large_meshes_for_display(tmp_path, result):
    path = write_report(result, tmp_path / "r" / "report.html", max_faces=100)
    before, after = figures(path.read_text(encoding="utf-8"))
    assert len(before["data"][0]["i"]["bdata"]) > 0
    assert "100 of 782 faces" in before["layout"]["title"]["text"]
    assert sorted(p.name for p in path.parent.iterdir()) == ["report.html"]


def test_a_phone_screen_holds_every_viewer(page):
    """On a 390-px phone the 720-px wipe viewers, and the atlas viewer's table, widened the page: it scrolled
    sideways. A viewer now keeps its aspect in at most the page's width, and no viewer sits in a table."""
    boxes = re.findall(r'<div class="cmp-view" style="([^"]*)"', page)
    assert boxes and all(re.fullmatch(r"width:\d+px;aspect-ratio:\d+/\d+", b) for b in boxes)
    for rule in ("cmp-view", "cmp-split"):
        assert re.search(rf"\.{rule} \{{[^}}]*max-width: 100%", page)
    for table in re.findall(r"<table.*?</table>", page, flags=re.S):
        assert 'class="compare"' not in table
    assert "window.addEventListener('resize'" in page  # a fitted image fits the new width again


def test_report_without_input_scan(result):
    from dataclasses import replace

    page = build_report(replace(result, input_scan=None, ground_truth=None))
    assert len(figures(page)) == 1 and 'class="thumb"' not in page


def test_the_title_names_the_scan_with_its_folder(result):
    """Capture apps name every export's mesh alike: a batch's reports were all "scantex report: textured_output.obj"."""
    from pathlib import Path

    scan = result.input_scan.replace(source=Path("/scans/kitchen/textured_output.obj"))
    page = build_report(dataclasses.replace(result, input_scan=scan))
    assert "<title>scantex report: kitchen/textured_output.obj</title>" in page


def test_enhance_outputs_include_report_and_zero_distances(tmp_path):
    """A real (tiny) enhance run: every output folder holds metrics.json and report.html, and the
    geometry distances between input and output are exactly zero."""
    from scantex.pipeline.config import EnhanceConfig, FieldSettings, TrainConfig, ViewsConfig
    from scantex.pipeline.enhance import enhance
    from scantex.pipeline.outputs import write_outputs
    from scantex.synth import make_wall

    demo = make_wall(grid=(12, 10), gt_texture_size=128, scan_texture_size=32, seed=2)
    config = EnhanceConfig(views=ViewsConfig(n_views=5, width=48, height=36, adaptive=False),
                           field=FieldSettings(hidden=16, n_layers=2, n_levels=4, log2_table_size=12,
                                               max_resolution=64),
                           train=TrainConfig(steps=10, batch_rays=512))
    result = enhance(demo.scan, config, ground_truth=demo.ground_truth)
    write_outputs(result, tmp_path)
    metrics = json.loads((tmp_path / "metrics.json").read_text())
    d = metrics["geometry"]["distance"]
    assert d["hausdorff"] == 0.0 and d["mean_a_to_b"] == 0.0 and d["mean_b_to_a"] == 0.0
    assert metrics["texture"]["enhanced"]["atlas_sizes"] == [[32, 32]]  # the input's texels, kept at its size
    page = (tmp_path / "report.html").read_text(encoding="utf-8")
    assert len(figures(page)) == 2 and "Held-out views vs ground truth" in page
    assert np.isfinite(metrics["held_out_vs_ground_truth"]["enhanced"]["psnr"])


def test_scores_are_measured_when_the_metrics_lack_per_view_scores(page, result):
    """Metrics from before per-view scores existed: the report measures each view itself, the same way."""
    import copy

    old = copy.deepcopy(result.metrics)
    for scores in old["held_out_vs_ground_truth"].values():
        del scores["per_view"]
    measured = build_report(result, metrics=old)
    tables = lambda p: re.findall(r"<table class='cmp-scores'><caption>view .*?</table>", p, re.S)  # noqa: E731
    assert tables(measured) == tables(page)


def test_held_out_views_show_the_renders_the_metrics_scored(page, result, monkeypatch):
    """Given the renders its metrics were scored from (as ``enhance`` gives them), the report shows them and
    casts no ray; made without them it renders the same images itself."""
    import dataclasses

    import scantex.report.html as report_html
    from scantex.atlas.holes import untextured_faces
    from scantex.metrics.views import score_views
    from scantex.views.raycast import RayCaster

    cameras = [result.views.views.cameras[i] for i in result.views.views.test]
    shown: list = []
    scan, truth = result.input_scan, result.ground_truth
    score_views(truth, {"input": scan, "enhanced": result.scan}, cameras, RayCaster(scan.positions, scan.faces),
                untextured_faces(scan), renders=shown, reference_name="ground truth")
    assert [sorted(r) for r in shown] == [["enhanced", "ground truth", "input"]] * len(cameras)
    assert shown[0]["input"].shape == (2 * cameras[0].height, 2 * cameras[0].width, 3)

    def no_casting(*args, **kwargs):
        raise AssertionError("the report rendered a view it was given")

    monkeypatch.setattr(report_html, "render_scans", no_casting)
    monkeypatch.setattr(report_html, "RayCaster", no_casting)
    given = build_report(dataclasses.replace(result, renders=shown))
    views = lambda p: re.findall(r'<div class="compare" id="compare-view-.*?</table>', p, re.S)  # noqa: E731
    assert views(given) and views(given) == views(page)


def test_metrics_are_json_every_parser_reads():
    """A photo that sees nothing has no pose error (NaN): ``json.dumps`` wrote ``NaN``, which a browser's
    ``JSON.parse`` refuses. Non-finite floats are ``null``; numpy values are Python's."""
    import json

    import numpy as np

    from scantex.report.html import strict_json

    metrics = {"poses": [{"error_before": float("nan"), "error_after": np.float32("inf")}],
               "psnr": np.float64(21.5), "counts": np.arange(3), "ok": np.bool_(True)}
    text = strict_json(metrics, indent=2)
    assert "NaN" not in text and "Infinity" not in text
    # Python's parser made strict: it refuses the constants a browser's refuses
    back = json.loads(text, parse_constant=lambda c: (_ for _ in ()).throw(ValueError(c)))
    assert back == {"poses": [{"error_before": None, "error_after": None}], "psnr": 21.5, "counts": [0, 1, 2],
                    "ok": True}


def test_only_the_atlases_on_most_surface_are_shown(monkeypatch):
    """A Matterport export's hundreds of materials made an 830 MB report (each atlas's thumbnails and crops): the
    report shows the MAX_ATLASES on the most surface and says where the others are."""
    import scantex.report.html as report
    from tests.conftest import textured_cube

    cube = textured_cube(materials=6)  # two faces each
    area = np.bincount(cube.face_materials, cube.face_areas)
    monkeypatch.setattr(report, "MAX_ATLASES", 3)
    shown = report._atlases(cube, cube)
    assert "The 3 of 6 materials on the most surface" in shown
    crop = report._crop_centre(cube)
    expected = {int(m) for m in np.argsort(-area)[:3]} if crop is None else None
    names = set(re.findall(r"<h3>material (mat\d)</h3>", shown))
    assert len(names) == 3 and (expected is None or names == {f"mat{m}" for m in expected})


def test_the_summary_of_a_tiled_run_and_of_photos_scored_against_a_truth():
    """A tiled run's metrics hold the patch measure only in the held-out views' scores; photo mode with a ground
    truth scores the held-out photos' cameras against it: both are in the summary. Booleans read yes / no."""
    import scantex.report.html as report

    tiled = {"held_out_vs_input": {"enhanced": {"psnr": 40.0, "ssim": 0.99, "patches": 0.0206}}}
    assert "Patches vs input" in report._headline(tiled) and "2.06 %" in report._headline(tiled)
    scores = {"input": {"psnr": 15.95, "ssim": 0.5, "psnr_matched": 16.0, "photos": 2},
              "enhanced": {"psnr": 24.71, "ssim": 0.7, "psnr_matched": 25.0, "photos": 2}}
    photos = {"held_out_photos": scores, "held_out_photos_vs_ground_truth": scores}
    assert "Held-out photos&#x27; cameras vs ground truth" in report._headline(photos)
    assert report._fmt(True) == "yes" and report._fmt(False) == "no"


def test_the_summary_names_the_photos_left_out_repeated_and_blurred_as_the_command_line_does():
    import scantex.report.html as report

    m = {"photos": {"left_out": [{"photo": 2, "why": "upside down"}], "total": 12,
                    "repeated": [{"photo": 4, "repeats": 3}, {"photo": 9, "repeats": 8}],
                    "blurred": [{"photo": 7, "detail": 0.12, "left_out": False, "softened": True}]}}
    headline = report._headline(m)
    assert "Keyframes" in headline and "10 of the 12 photos kept; 2 repeat the view of a sharper one" in headline
    assert "Photos left out" in headline and "1 (2), not showing what its camera sees" in headline
    assert "Blurred photos" in headline and "7 (12 %) of the fine detail" in headline
    assert "their fine detail left to the sharp photos" in headline
    assert "Blurred photos" not in report._headline({"photos": {"blurred": []}})


def test_a_views_wipe_opens_where_its_surface_is():
    import scantex.report.html as report

    image = np.zeros((40, 100, 3), np.uint8)
    image[:, 10:40] = 200  # the surface fills the left third
    assert report._split_at(image) == pytest.approx(25.0)
    assert report._split_at(np.zeros((4, 4, 3), np.uint8)) == 50.0


def test_the_atlas_crop_is_centred_where_surface_fills_it():
    """Of the holes, the crop shows the one with the most surface around it in the atlas: a hole at a chart's
    edge showed a crop of gutter (unused texels) more than of surface."""
    import scantex.report.html as report
    from scantex.scan import Scan
    from tests.conftest import grid_wall

    wall = grid_wall(n=40)
    image = np.kron(wall.materials[0].image, np.ones((8, 8, 1), np.uint8))  # 1024²: a crop is an eighth of it
    H, W = image.shape[:2]
    image[H - 120:, :120] = 0  # a large hole at the atlas's corner (the most hole faces)
    image[H // 2 - 24:H // 2 + 24, W // 2 - 24:W // 2 + 24] = 0  # a small one in its middle
    scan = Scan(wall.positions, wall.faces, wall.uvs, wall.face_uvs, None,
                (dataclasses.replace(wall.materials[0], image=image),))
    u, v, _ = report._crop_centre(scan)
    assert abs(u - 0.5) < 0.1 and abs(v - 0.5) < 0.1
