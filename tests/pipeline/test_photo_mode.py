"""``enhance`` with photos, at toy size: the texture learns from the photos, geometry stays untouched."""

from __future__ import annotations

import dataclasses
import json
import subprocess
import sys

import numpy as np
import pytest

from scantex.errors import ScanError
from scantex.io import save_scan
from scantex.photos import PhotoSet, load_photos
from scantex.pipeline.enhance import (
    BALANCED_FROM, FINAL_ALL_BELOW, GAPS_FROM, PAIRS_FROM, REFINE_BELOW, depth_gaps_mode, detail_mode, enhance,
    final_texture_mode, pair_weight, pairs_mode, pose_refinement_mode, visibility_settings)
from scantex.scan import Scan
from scantex.synth.photos import PhotoCapture, capture_photos
from scantex.views.render import render
from tests.pipeline.test_enhance import TOY, toy_demo  # noqa: F401  (a fixture)

CAPTURE = PhotoCapture(n_photos=10, width=128, height=96, distance=2.0)


@pytest.fixture(scope="module")
def toy_photos(toy_demo, tmp_path_factory):
    return capture_photos(toy_demo, tmp_path_factory.mktemp("photos"), CAPTURE, seed=1)


@pytest.fixture(scope="module")
def photo_result(toy_demo, toy_photos):
    # the alignment check is off at this toy size: 128 px photos of an open wall with a 64 px atlas show it
    # no contours (the wall's border is the scan's end) and texture edges too fine to fit a pose to (it
    # misjudged it as turned 11 degrees); it is tested on its own in tests/photos/test_alignment.py
    return enhance(toy_demo.scan, TOY.override(photos__check_alignment=False), ground_truth=toy_demo.ground_truth,
                   photos=toy_photos)


def test_synthetic_capture_writes_a_readable_set(toy_photos):
    again = load_photos(toy_photos.source)
    assert len(again) == 10 and again.format == "cameras.json"
    assert again.load_image(0).shape == (96, 128, 3)
    folder = toy_photos.source if toy_photos.source.is_dir() else toy_photos.source.parent
    assert all(p.parent == folder for p in again.images)  # copied beside the file, relative names


def test_photo_mode_keeps_geometry_and_beats_the_input(toy_demo, photo_result):
    m = photo_result.metrics
    assert photo_result.scan.positions is toy_demo.scan.positions
    assert m["geometry"]["arrays_identical"] and m["geometry"]["triangles_identical"]
    assert m["photos"]["total"] == 10 and len(m["photos"]["held_out"]) == 1 and len(m["photos"]["train"]) == 9
    # no field is trained (projective texturing, colour transforms in closed form): the synthetic training
    # views would teach nothing, and are not rendered
    assert m["photos"]["photo_rays"] > 0 and m["photos"]["synthetic_rays"] == 0 and "why" in m["field"]
    # the views rendered are the held-out ones alone, and their coverage counts them
    assert m["views"]["rendered"] == m["views"]["test"] < m["views"]["total"]
    assert m["views"]["coverage"].startswith(f"{m['views']['test']} views: ")
    # rendered once, by the held-out score, their images are the input's renders as the training views would be
    views = photo_result.views.views
    for i in views.test:
        image, alpha = render(toy_demo.scan, views.cameras[i], supersample=TOY.views.supersample)
        assert views.rendered[i] and np.array_equal(views.images[i], image) and np.array_equal(views.alpha[i], alpha)
    truth = m["held_out_photos_vs_ground_truth"]
    assert truth["enhanced"]["mse"] < 0.7 * truth["input"]["mse"]
    photos = m["held_out_photos"]
    assert photos["enhanced"]["psnr_matched"] > photos["input"]["psnr_matched"]
    # the training photos' poses were refined (a small capture): the held-out photo is also scored with its pose
    # aligned to each texture on its own, which no longer counts the recorded pose's error
    assert m["photos"]["pose_refinement"] == "input"
    assert photos["enhanced"]["psnr_aligned"] > photos["input"]["psnr_aligned"]
    assert photos["enhanced"]["psnr_aligned"] >= photos["enhanced"]["psnr_matched"] - 0.5


def test_each_texture_is_aligned_from_the_others_aligned_poses_too(toy_demo, toy_photos, photo_result):
    """A sharp texture's photometric basin is narrow: a held-out photo aligned to it from the recorded pose can stop
    where its alignment to another texture went on. Each texture is also aligned from the other textures' aligned
    poses and scored at the one that agrees best with the photo: scored beside another texture, it never scores
    below itself scored alone; its turn is measured from the recorded pose."""
    from scantex.photos.training import prepare_photos, score_photos
    from scantex.pipeline.enhance import visibility_settings
    from scantex.views.raycast import RayCaster

    pc = TOY.photos
    caster = RayCaster(toy_demo.scan.positions, toy_demo.scan.faces)
    views = prepare_photos(toy_demo.scan, toy_photos, photo_result.metrics["photos"]["held_out"], caster, pc.max_side,
                           visibility_settings(pc, len(toy_photos)))
    both = score_photos({"input": toy_demo.scan, "enhanced": photo_result.scan}, views, caster, align=True)
    alone = score_photos({"enhanced": photo_result.scan}, views, caster, align=True)
    assert both["enhanced"]["psnr_aligned"] >= alone["enhanced"]["psnr_aligned"]
    assert both["enhanced"]["psnr_matched"] == alone["enhanced"]["psnr_matched"]
    assert 0 <= both["enhanced"]["aligned_by_deg"] < 3


def test_rotation_between_two_cameras():
    from scantex.photos.poses import rotation_between
    from scantex.views.camera import Camera

    a = Camera.look_at((0, -2, 0), (0, 0, 0), width=64, height=48)
    b = Camera.look_at((0, -2, 0), (np.tan(np.radians(5)) * 2, 0, 0), width=64, height=48)  # turned 5 degrees
    assert rotation_between(a, a) == 0 and np.isclose(rotation_between(a, b), 5.0, atol=1e-6)
    assert np.isclose(rotation_between(b, a), 5.0, atol=1e-6)


def test_a_small_capture_of_a_textured_scan_refines_its_poses_by_default(toy_demo, photo_result):
    """photos.refine_poses auto: below REFINE_BELOW photos, a textured scan's photos are aligned to its texture
    (each reported in metrics.json) and an untextured scan's to one another (it has no texture); a larger
    capture keeps the recorded poses; a mode asked for is applied as asked."""
    m = photo_result.metrics["photos"]
    assert m["pose_refinement"] == "input" and len(m["pose_corrections"]) == len(m["train"]) == 9
    assert all({"photo", "rotation_deg", "applied"} <= set(c) for c in m["pose_corrections"])
    scan, bare = toy_demo.scan, Scan(toy_demo.scan.positions, toy_demo.scan.faces)
    assert pose_refinement_mode("auto", scan, REFINE_BELOW - 1) == "input"
    assert pose_refinement_mode("auto", scan, REFINE_BELOW) == "off"
    assert pose_refinement_mode("auto", bare, 5) == "consensus" and pose_refinement_mode("input", bare, 5) == "off"
    assert pose_refinement_mode("auto", bare, REFINE_BELOW) == "off"
    assert pose_refinement_mode("consensus", bare, 500) == "consensus"
    assert pose_refinement_mode("off", scan, 5) == "off"



def test_photos_final_all_writes_a_texture_from_every_photo(toy_demo, toy_photos, photo_result):
    """photos.final auto (the default) on a capture of 10 photos writes the texture made from all of them and
    scores the one made without the held-out photo, baked only where it sees the surface: the very scores of
    the texture training writes (baked whole), another texture, the same geometry. A capture of 50 photos or
    more writes the texture scored."""
    m = photo_result.metrics
    final = m["photos"]["final_texture"]
    assert final["mode"] == "all" and final["setting"] == "auto" and final["photos"] == 10
    assert m["geometry"]["arrays_identical"] and m["geometry"]["triangles_identical"]
    scored = enhance(toy_demo.scan, TOY.override(photos__check_alignment=False, photos__final="training"),
                     ground_truth=toy_demo.ground_truth, photos=toy_photos)
    assert scored.metrics["photos"]["final_texture"] == {"photos": 9, "mode": "training", "setting": "training"}
    for name in ("input", "enhanced"):  # the same texture was scored (to an 8-bit level at a few texels)
        for key, value in scored.metrics["held_out_photos"][name].items():
            assert m["held_out_photos"][name][key] == pytest.approx(value, abs=0.01)
    written, kept = photo_result.scan.materials[0].image, scored.scan.materials[0].image
    assert written.shape == kept.shape and not np.array_equal(written, kept)
    assert final_texture_mode("auto", FINAL_ALL_BELOW - 1) == "all"
    assert final_texture_mode("auto", FINAL_ALL_BELOW) == "training"
    assert final_texture_mode("training", 3) == "training" and final_texture_mode("all", 500) == "all"


def test_photos_detail_auto_is_balanced_for_a_room_of_photos(toy_demo, toy_photos, monkeypatch, photo_result):
    """``photos.detail`` auto: a capture of ``BALANCED_FROM`` photos or more (a room's) gets the best views' fine
    detail at half its contrast, a smaller one the blend (the toy's 10 photos: one band)."""
    assert detail_mode("auto", BALANCED_FROM - 1) == "blend" and detail_mode("auto", BALANCED_FROM) == "balanced"
    assert detail_mode("sharp", 3) == "sharp" and detail_mode("blend", 500) == "blend"
    assert "detail" not in photo_result.metrics["photos"]["texturing"]
    monkeypatch.setattr("scantex.pipeline.enhance.BALANCED_FROM", 10)
    room = enhance(toy_demo.scan, TOY.override(photos__check_alignment=False), photos=toy_photos)
    assert room.metrics["photos"]["texturing"]["detail"] == {"temperature": 0.1, "sigma_px": 4.0, "gain": 0.5}
    assert room.metrics["geometry"]["arrays_identical"] and room.metrics["geometry"]["triangles_identical"]
    blended, balanced = photo_result.scan.materials[0].image, room.scan.materials[0].image
    assert blended.shape == balanced.shape and not np.array_equal(blended, balanced)


def test_photo_mode_levels_the_photos_tones_unless_asked_not_to(toy_demo, toy_photos, photo_result):
    """The closed-form colour fit brings every photo it blends to one tone curve first and reports each photo's
    gamma (the toy's 9 training photos: the texture scored); ``photos.tones`` false leaves the photos' values as
    recorded, another texture on the same geometry."""
    texturing = photo_result.metrics["photos"]["texturing"]
    tones = texturing["photo_tones"]
    assert len(tones) == 9 and all(0.5 <= g <= 2.0 for g in tones) and len(set(tones)) > 1
    assert "one tone curve" in photo_result.metrics["field"]["why"]  # the summary says how the photos were brought
    plain = enhance(toy_demo.scan, TOY.override(photos__check_alignment=False, photos__tones=False), photos=toy_photos)
    assert "photo_tones" not in plain.metrics["photos"]["texturing"]
    assert "tone curve" not in plain.metrics["field"]["why"]
    assert plain.metrics["geometry"]["arrays_identical"] and plain.metrics["geometry"]["triangles_identical"]
    assert not np.array_equal(plain.scan.materials[0].image, photo_result.scan.materials[0].image)


def test_photo_pairs_auto_level_a_room_of_photos_only():
    """``photos.pairs`` auto: the closed-form colour fit levels the photos against one another from ``PAIRS_FROM``
    photos (a room's patchwork of exposures), against the input texture alone below."""
    from scantex.pipeline.config import PhotosConfig

    assert pairs_mode("auto", PAIRS_FROM - 1) == "off" and pairs_mode("auto", PAIRS_FROM) == "on"
    assert pair_weight(PhotosConfig(), PAIRS_FROM - 1) == 0.0 and pair_weight(PhotosConfig(), PAIRS_FROM) == 4.0
    assert pair_weight(PhotosConfig(pairs="on", pair_weight=2.0), 3) == 2.0
    assert pair_weight(PhotosConfig(pairs="off"), 500) == 0.0


def test_depth_gaps_auto_are_on_for_a_room_of_photos():
    """``photos.depth_gaps`` auto: lines of missing depth left out from ``GAPS_FROM`` photos (many photos paint a lost
    thin object in many places), not below (each photo's pixels count for more); a tile takes the whole capture's."""
    from scantex.pipeline.config import EnhanceConfig, PhotosConfig
    from scantex.scale.tiles import TilePhotos

    assert depth_gaps_mode("auto", GAPS_FROM - 1) == "off" and depth_gaps_mode("auto", GAPS_FROM) == "on"
    assert depth_gaps_mode("on", 3) == "on" and depth_gaps_mode("off", 500) == "off"
    pc = PhotosConfig()
    assert visibility_settings(pc, GAPS_FROM - 1).depth_gap_px == 0
    assert visibility_settings(pc, GAPS_FROM).depth_gap_px == pc.depth_gap_px == 7
    assert visibility_settings(PhotosConfig(depth_gaps="on", depth_gap_px=5), 3).depth_gap_px == 5
    room = PhotoSet(images=tuple(f"{i}.png" for i in range(GAPS_FROM)), cameras=(None,) * GAPS_FROM, source=".",
                    format="cameras.json")
    tiles = TilePhotos(room, np.arange(GAPS_FROM), np.zeros(0, int), [], [], {}, "off", [], None)
    tile = tiles.tile_config(EnhanceConfig()).photos  # a tile sees some of them: the whole capture's choice
    assert (tile.depth_gaps, tile.detail, tile.pairs) == ("on", "balanced", "on")
    assert visibility_settings(tile, 3).depth_gap_px == 7 and pair_weight(tile, 3) == 4.0


def test_photos_final_all_aligns_the_held_out_photos_to_refined_poses(toy_demo, toy_photos):
    """With the training photos' poses refined, the held-out photos join the texture written in the same
    frame (aligned to the input texture here, as the training photos were) and their corrections are
    reported; the held-out scores are still taken through their recorded poses."""
    result = enhance(toy_demo.scan, TOY.override(photos__check_alignment=False, photos__refine_poses="input"),
                     photos=toy_photos)
    m = result.metrics["photos"]
    final = m["final_texture"]
    assert final["mode"] == "all" and final["photos"] == 10 and len(m["pose_corrections"]) == 9
    moved = final["held_out_pose_corrections"]
    assert [c["photo"] for c in moved] == m["held_out"]
    assert result.metrics["held_out_photos"]["enhanced"]["photos"] == 1
    # the summary says which texture each score is of: the held-out photos' scores, the one made without them;
    # a held-out view's score against a ground truth, the one written
    from scantex.cli import enhance_summary

    said = enhance_summary(result.metrics)
    assert "(the held-out photos' scores above are the texture made without them; photos.final" in said
    truth = {**result.metrics, "held_out_vs_ground_truth": {"input": {"psnr": 20, "ssim": 0.5},
                                                              "enhanced": {"psnr": 25, "ssim": 0.6}}}
    assert "held-out views' score vs ground truth is the texture written" in enhance_summary(truth)


def test_the_photos_sampled_for_the_texture_are_let_go_once_it_is_baked(toy_demo, toy_photos):
    """The photos at their sampling resolution, with their depth and feather maps (0.7 GB of a real apartment's
    197 photos), are not held through the measuring; the training photos' working views (their image, faces,
    depth and usable pixels: 1.5 GB of 400 views of 640x480) are not held through the bake."""
    import contextlib
    import gc

    from scantex.photos.texturing import _Source
    from scantex.photos.training import PhotoView
    from scantex.pipeline.enhance import Reporter

    alive, with_maps = {}, {}

    class Counting(Reporter):
        @contextlib.contextmanager
        def stage(self, name):
            gc.collect()
            objects = gc.get_objects()
            alive[name] = sum(type(o) is _Source for o in objects)  # type(): gc holds dead proxies too
            with_maps[name] = sum(type(o) is PhotoView and o.face_id is not None for o in objects)
            yield lambda done, total: None

    result = enhance(toy_demo.scan, TOY.override(photos__check_alignment=False, photos__final="training"),
                     photos=toy_photos, reporter=Counting())
    held = len(result.metrics["photos"]["held_out"])
    assert alive["baking the texture"] == 9  # sampled from while the atlas is baked
    assert alive["measuring"] == 0
    assert with_maps["UV layout (keep)"] == 9 + held
    assert with_maps["baking the texture"] == held  # the held-out photos', which score the result


def test_photos_sample_memory_bounds_what_the_photos_samples_hold(toy_demo, toy_photos, photo_result):
    def mib(texturing):  # the packed samples, 4 bytes a pixel
        return sum(w * h for w, h in texturing["sampled_at"]) * 4 / 2**20

    wanted = mib(photo_result.metrics["photos"]["texturing"])
    bound = enhance(toy_demo.scan, TOY.override(photos__check_alignment=False, photos__sample_memory_mb=0.75 * wanted),
                    photos=toy_photos).metrics["photos"]["texturing"]
    assert 0.6 * wanted < mib(bound) <= 0.75 * wanted


def test_photos_are_sampled_for_the_atlas_written():
    """On the input's layout the atlas written is bake.texture_size, or twice the input's at most 8192: the photos'
    sampling density follows that atlas, not twice the input's whatever it is."""
    from scantex.pipeline.enhance import atlas_growth
    from tests.conftest import textured_cube

    cube = textured_cube()  # two 64x64 atlases
    assert atlas_growth(cube, 0, 2) == 2.0 and atlas_growth(cube, 0, 1) == 1.0
    assert atlas_growth(cube, 512, 2) == 8.0
    huge = np.zeros((8192, 8192, 3), np.uint8)

    def with_images(*images):
        return dataclasses.replace(cube, materials=tuple(dataclasses.replace(m, image=image)
                                                         for m, image in zip(cube.materials, images)))

    assert atlas_growth(with_images(huge, cube.materials[1].image), 0, 2) == 2.0  # the small atlas still doubles
    assert atlas_growth(with_images(huge, huge), 0, 2) == 1.0  # an 8192 atlas cannot grow
    assert atlas_growth(with_images(None, None), 0, 2) == 2.0


def test_a_larger_texture_size_samples_the_photos_finer(toy_demo, toy_photos, photo_result):
    size = toy_demo.scan.materials[0].image.shape[0]
    default = photo_result.metrics["photos"]["texturing"]["sampled_at"]
    finer = enhance(toy_demo.scan, TOY.override(photos__check_alignment=False, bake__texture_size=4 * size),
                    photos=toy_photos).metrics["photos"]["texturing"]["sampled_at"]
    assert all(w < 128 for w, _ in default) and all(w == 128 for w, _ in finer)  # the photos' own 128 px


def test_photo_mode_beats_mesh_only_mode(toy_demo, photo_result):
    """The photos hold what the degraded atlas lost: with them, the held-out views come out closer to the truth."""
    mesh_only = enhance(toy_demo.scan, TOY, ground_truth=toy_demo.ground_truth)
    assert (photo_result.metrics["held_out_vs_ground_truth"]["enhanced"]["mse"]
            < mesh_only.metrics["held_out_vs_ground_truth"]["enhanced"]["mse"])


def test_untextured_mesh_is_textured_from_photos(toy_demo, toy_photos):
    bare = Scan(toy_demo.scan.positions, toy_demo.scan.faces)
    # an untextured toy mesh shows the check no edges to compare: its own tests cover it
    result = enhance(bare, TOY.override(bake__texture_size=128, photos__check_alignment=False), photos=toy_photos)
    m = result.metrics
    assert m["geometry"]["arrays_identical"] and m["uv"]["mode"] == "unwrap"
    assert m["photos"]["synthetic_rays"] == 0  # an untextured scan's renders teach nothing
    # no field either: the photos' exposures in closed form from their overlaps, their colours carried over
    # what none of them sees
    assert m["field"]["trained"] is False and "from their overlaps" in m["field"]["why"]
    texturing = m["photos"]["texturing"]
    assert texturing["colour_transforms"] == "closed form, from the photos' overlaps"
    assert texturing["fallback_levelling"]["faces_covered"] > 0
    s = m["held_out_photos"]
    assert s["enhanced"]["psnr_matched"] > s["input"]["psnr_matched"] + 3
    image = result.scan.materials[0].image
    assert image is not None and image.std() > 10  # a real texture, not one flat colour
    # no texture to have seen the held-out photos: the summary does not warn that one may have
    from scantex.cli import enhance_summary

    assert m["input"]["textured"] is False and "held out from the result only" not in enhance_summary(m)
    # nor seams to compare: the result's own seam visibility is said, not "0.00 -> x", which reads as worse
    sv = m["seam_visibility"]
    assert sv["input"] == 0
    said = enhance_summary(m)
    assert f"seam visibility: {sv['enhanced']:.2f} across the result's seams" in said, said
    assert "(the input had no texture to compare)" in said and f"{sv['input']:.2f} ->" not in said
    from scantex.report.html import build_report

    assert "the input had no texture to compare; mean RGB step across seams" in build_report(result)
    # a held-out photo that sees none of the mesh is not scored: the summary says so, in good English
    n = s["input"]["photos"]
    blind = {**m, "photos": {**m["photos"], "held_out": list(range(n + 1))}}
    said = f"{n} held-out photo{'' if n == 1 else 's'} (1 more held out sees none of the mesh):"
    assert said in enhance_summary(blind)


def test_vertex_coloured_mesh_takes_its_colours_as_the_input_texture(toy_demo, toy_photos):
    """A fused depth scan's colour is per vertex: photo mode bakes it into a texture first and then treats it as
    a capture app's atlas (no field, closed-form colour transforms against it, its colour where no photo looks)."""
    from scantex.views.render import shade_hits

    scan = toy_demo.scan
    face = np.zeros(scan.n_vertices, int)
    corner = np.zeros(scan.n_vertices, int)
    for k in range(3):
        face[scan.faces[:, k]], corner[scan.faces[:, k]] = np.arange(scan.n_faces), k
    bary = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]])[corner]
    rgb = shade_hits(scan, face, bary)  # the degraded atlas's colour at every vertex
    coloured = Scan(scan.positions, scan.faces, vertex_colors=np.column_stack(
        [np.round(rgb * 255), np.full(len(rgb), 255)]).astype(np.uint8))
    result = enhance(coloured, TOY.override(photos__check_alignment=False), photos=toy_photos)
    m = result.metrics
    assert m["input"]["texture"].startswith("baked from the vertex colours")
    assert m["timings_s"]["vertex_colours"] > 0  # the stage is timed with the others
    assert result.scan.positions is coloured.positions and result.scan.faces is coloured.faces
    assert m["geometry"]["arrays_identical"] and m["geometry"]["triangles_identical"]
    assert m["field"]["trained"] is False and m["photos"]["photo_rays"] > 0
    s = m["held_out_photos"]
    assert s["enhanced"]["psnr_matched"] > s["input"]["psnr_matched"]


def test_photos_of_another_place_are_refused(toy_demo, toy_photos):
    away = dataclasses.replace(toy_demo.scan, positions=toy_demo.scan.positions + np.array([1.5, 0.0, 0.8]))
    with pytest.raises(ScanError, match="not in the cameras' frame"):
        enhance(away, TOY, photos=toy_photos)


def test_a_photo_stored_upside_down_is_left_out(tmp_path, toy_demo, toy_photos, monkeypatch):
    """It passes every check of its file and camera, and was blended into the texture turned; now it is left out
    of the texture and of the score, and metrics.json names it."""
    from PIL import Image

    import scantex.photos.alignment
    import scantex.photos.matching

    turned = tmp_path / "turned.png"
    Image.open(toy_photos.images[3]).rotate(180).save(turned)
    photos = dataclasses.replace(toy_photos, images=(*toy_photos.images[:3], turned, *toy_photos.images[4:]))
    # the alignment check misjudges this toy capture (see photo_result); the photos' own check runs with it, here
    # below its least detail for a verdict (the toy's 64 px atlas holds little: tests/photos/test_matching.py
    # tests the verdicts themselves)
    monkeypatch.setattr(scantex.photos.alignment, "require_alignment", lambda *args, **kwargs: None)
    monkeypatch.setattr(scantex.photos.matching, "MIN_CONTRAST", 0.0)
    monkeypatch.setattr(scantex.photos.matching, "MIN_PHOTO_CONTRAST", 0.0)
    result = enhance(toy_demo.scan, TOY, photos=photos)
    m = result.metrics
    assert [d["photo"] for d in m["photos"]["left_out"]] == [3] and "upside down" in m["photos"]["left_out"][0]["why"]
    assert 3 not in m["photos"]["train"] + m["photos"]["held_out"]
    assert len(m["photos"]["train"]) + len(m["photos"]["held_out"]) == 9
    assert m["photos"]["final_texture"]["photos"] == 9 and m["geometry"]["arrays_identical"]
    from scantex.cli import enhance_summary  # said where a user reads, not only in the warning before it

    assert "photos left out: 1 (3), not showing what its camera sees" in enhance_summary(m)


def test_cli_photos(tmp_path, toy_demo, toy_photos):
    save_scan(toy_demo.scan, tmp_path / "scan.obj")
    (tmp_path / "config.json").write_text(json.dumps(TOY.to_dict()))
    out = tmp_path / "out"
    cmd = [sys.executable, "-m", "scantex", "enhance", str(tmp_path / "scan.obj"), "--config",
           str(tmp_path / "config.json"), "--no-alignment-check", "--blurred", "soften", "--holdout", "2",
           "--refine-poses", "consensus", "--final-texture", "all", "--detail", "sharp",
           "--photos", str(toy_photos.source), "-o", str(out)]
    run = subprocess.run(cmd, capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
    assert json.loads((out / "config.json").read_text())["photos"]["blurred"] == "soften"
    assert "2 held-out photos" in run.stdout and "made from all 10 photos" in run.stdout
    assert "held out from the result only" in run.stdout  # the input's texture may have seen them
    assert "each held-out photo's pose aligned to each texture" in run.stdout  # the poses were refined
    metrics = json.loads((out / "metrics.json").read_text())
    assert len(metrics["photos"]["held_out"]) == 2 and metrics["photos"]["alignment"] is None  # skipped
    assert metrics["photos"]["texturing"]["mode"] == "projective"
    assert metrics["photos"]["texturing"]["detail"] == {"temperature": 0.1, "sigma_px": 4.0, "gain": 1.0}  # sharp
    tally = metrics["photos"]["texturing"]["clipped"]
    assert tally["samples"] > 0 and 0 <= tally["gave_way"] <= tally["clipped"] <= tally["samples"]
    assert metrics["photos"]["final_texture"]["photos"] == 10
    corrections = metrics["photos"]["pose_corrections"]  # one per training photo, against its recorded pose
    assert [c["photo"] for c in corrections] == metrics["photos"]["train"]
    assert all(c["rotation_deg"] < 3 for c in corrections)
    sheets = sorted((out / "comparisons").glob("held_out_photo_*.png"))
    assert len(sheets) == 2
    from PIL import Image

    # photo | input | result, and below (the poses were refined) the same with each render's camera aligned
    assert Image.open(sheets[0]).size == (3 * 128, 2 * 96)
    report = (out / "report.html").read_text()
    assert "Held-out photos" in report and "colour-matched" in report
    bad = subprocess.run(cmd[:-6] + ["--photos", str(tmp_path / "nowhere"), "-o", str(tmp_path / "out2")],
                         capture_output=True, text=True)
    assert bad.returncode == 2 and "nowhere" in bad.stderr and len(bad.stderr.strip().splitlines()) == 1
    assert not (tmp_path / "out2").exists()


def test_photo_mode_without_a_field_never_imports_torch(tmp_path, toy_demo, toy_photos):
    # torch's import is 1.5-2 s of a 14 s run; nothing in projective texturing, its scores or its report
    # needs it
    save_scan(toy_demo.scan, tmp_path / "scan.obj")
    (tmp_path / "config.json").write_text(json.dumps(TOY.to_dict()))
    out = tmp_path / "out"
    argv = ["enhance", str(tmp_path / "scan.obj"), "--config", str(tmp_path / "config.json"), "--no-alignment-check",
            "--photos", str(toy_photos.source), "-o", str(out), "-q"]
    code = f"import sys; from scantex.cli import main; rc = main({argv!r}); print(rc, 'torch' in sys.modules)"
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert run.returncode == 0 and run.stdout.split() == ["0", "False"], run.stdout + run.stderr
    metrics = json.loads((out / "metrics.json").read_text())
    assert not metrics["field"]["trained"] and metrics["held_out_photos"]["enhanced"]["ssim"] > 0
    # only the held-out synthetic views are rendered (for the report's score): renders/ holds those, none black
    from PIL import Image

    frames = json.loads((out / "renders" / "cameras.json").read_text())["frames"]
    assert frames and {f["split"] for f in frames} == {"test"}
    assert len(list((out / "renders").glob("view_*.png"))) == len(frames)
    assert all(np.asarray(Image.open(out / "renders" / f["image"])).max() > 0 for f in frames)


def test_refiner_skips_photo_mode_unless_asked(toy_demo, toy_photos):
    """The refiner learns from renders of the input texture, which the photos outclass (bench_photos)."""
    cfg = TOY.override(photos__check_alignment=False, train__steps=30, refine__enabled=True, refine__steps=4,
                       refine__batch=2, refine__max_views=2)
    skipped = enhance(toy_demo.scan, cfg, photos=toy_photos)
    assert "refine" not in skipped.metrics and "refine" not in skipped.metrics["timings_s"]
    asked = enhance(toy_demo.scan, cfg.override(refine__with_photos=True), photos=toy_photos)
    assert asked.metrics["refine"]["views_refined"] == 2 and asked.metrics["geometry"]["arrays_identical"]


@pytest.mark.parametrize("level_fallback", [False, True])
def test_a_hole_a_photo_sees_only_in_part_is_filled_where_it_does_not(tmp_path, level_fallback):
    """An app's atlas is black where its own photos did not reach. A hole that the edge of the only photo seeing
    it cuts in two: the photo colours the part it sees, and the rest is filled from the input around it, as a
    hole no photo sees is, never left black (a real apartment's photo mode showed such black, 1.3 dB below
    its mesh-only mode); with the fill levelled to the photo's tone (``photos.level_fallback``) too."""
    from PIL import Image

    from scantex.photos import PhotoSet
    from scantex.views.camera import Camera
    from scantex.views.raycast import RayCaster
    from scantex.views.render import render, sample_texture, to_uint8
    from tests.conftest import grid_wall

    wall = grid_wall(n=21, size=2.0)  # x and z in [0, 2], the atlas's u = x / 2, v = z / 2
    u, v = np.meshgrid(np.linspace(0, 1, 160), np.linspace(0, 1, 160))  # 8 texels a grid cell
    truth = np.stack([0.45 + 0.3 * u, 0.5 + 0.2 * v, 0.6 - 0.2 * u], axis=2)  # smooth, nowhere dark
    true_wall = dataclasses.replace(wall, materials=(dataclasses.replace(wall.materials[0], image=to_uint8(truth)),))
    atlas = truth.copy()
    atlas[48:112, 48:112] = 0.0  # the hole: whole faces, u and v in [0.3, 0.7]
    scan = dataclasses.replace(wall, materials=(dataclasses.replace(wall.materials[0], image=to_uint8(atlas)),))
    # one photo, its right edge crossing the hole at about x = 1.05
    cam = Camera.look_at((0.45, -1.6, 1.0), (0.45, 0.0, 1.0), fov_deg=50, width=160, height=120)
    Image.fromarray(to_uint8(render(true_wall, cam, RayCaster(true_wall.positions, true_wall.faces))[0])).save(
        tmp_path / "p0.png")
    photos = PhotoSet(cameras=(cam,), images=(tmp_path / "p0.png",), source=tmp_path, format="rendered")

    result = enhance(scan, TOY.override(photos__check_alignment=False, photos__holdout=0,
                                        photos__level_fallback=level_fallback), photos=photos)
    assert result.metrics["geometry"]["arrays_identical"]
    assert ("fallback_levelling" in result.metrics["photos"]["texturing"]) == level_fallback
    out = result.scan
    hole = (out.positions[out.faces].mean(axis=1)[:, [0, 2]] > 0.66).all(axis=1) & \
           (out.positions[out.faces].mean(axis=1)[:, [0, 2]] < 1.34).all(axis=1)
    w = np.random.default_rng(0).dirichlet(np.ones(3), 64)  # points across each hole face
    uv = np.einsum("kc,fcd->fkd", w, out.triangle_uvs[hole]).reshape(-1, 2)
    colour = sample_texture(out.materials[0].image, uv)[:, :3]
    assert colour.max(axis=1).min() > 0.2  # nowhere black: seen part photographed, the rest filled


def test_an_untextured_scans_atlas_is_as_fine_as_its_photos():
    """The new atlas of an untextured scan: the smallest of 2048² and 4096² whose texels, over the whole
    surface, would be as fine as the photos' pixels there (the photos' px/cm: focal length over depth)."""
    from types import SimpleNamespace

    from scantex.pipeline.enhance import photo_density, untextured_atlas_size
    from scantex.views.camera import Camera

    def capture(px_per_cm: float):
        camera = Camera.look_at((0.0, -2.0, 0.0), (0.0, 0.0, 0.0), fov_deg=60, width=640, height=480)
        depth = np.full((48, 64), camera.K[0, 0] / (100.0 * px_per_cm), np.float32)  # f / depth = px per metre
        view = SimpleNamespace(index=0, depth=depth, valid=np.ones(depth.shape, bool))
        return SimpleNamespace(photos=SimpleNamespace(cameras=[camera]), train=[view])

    def square(side_m: float) -> Scan:  # a square of that side, two triangles
        return Scan(np.array([[0, 0, 0], [side_m, 0, 0], [side_m, 0, side_m], [0, 0, side_m]], float),
                    np.array([[0, 1, 2], [0, 2, 3]]))

    assert photo_density(capture(3.5)) == pytest.approx(3.5)
    assert untextured_atlas_size(square(1.0), photo_density(capture(10.0))) == 2048  # 1,000 texels a side wanted
    assert untextured_atlas_size(square(10.0), photo_density(capture(3.5))) == 4096  # 3,500: a room
    assert untextured_atlas_size(square(40.0), photo_density(capture(3.5))) == 4096  # 14,000: the largest it lays out


def test_photo_mode_without_numba_makes_the_same_texture(toy_demo, toy_photos, photo_result, monkeypatch):
    """Every compiled kernel (:mod:`scantex.jit`) has a numpy twin: with numba missing, photo mode runs in numpy
    and bakes the texture the compiled run baked (a texel on a rounding boundary, or on an edge two faces share,
    may differ)."""
    import sys

    from scantex import jit

    monkeypatch.setitem(sys.modules, "numba", None)  # as if it were not installed
    jit.compiled.cache_clear()
    try:
        result = enhance(toy_demo.scan, TOY.override(photos__check_alignment=False),
                         ground_truth=toy_demo.ground_truth, photos=toy_photos)
    finally:
        jit.compiled.cache_clear()
    assert result.metrics["photos"]["texturing"]["compiled"] is False
    assert photo_result.metrics["photos"]["texturing"]["compiled"] is True
    slow = result.scan.materials[0].image.astype(int)
    fast = photo_result.scan.materials[0].image.astype(int)
    assert slow.shape == fast.shape and (np.abs(slow - fast).max(axis=2) > 2).mean() < 0.01
    assert [c["applied"] for c in result.metrics["photos"]["pose_corrections"]] == \
        [c["applied"] for c in photo_result.metrics["photos"]["pose_corrections"]]


def test_a_shaken_photo_is_named_and_softened_or_left_out_when_asked(tmp_path, toy_demo, toy_photos):
    """One shaken photo of ten is named and blended in (auto: its partners would paint what it saw from further
    off); ``photos.blurred`` soften keeps it for its colour with its detail left to the sharp photos, leave-out
    leaves it out of the texture and the score."""
    from PIL import Image
    from scipy import ndimage

    from scantex.cli import enhance_summary

    def smeared(k):
        path = tmp_path / f"smeared_{k}.png"
        image = np.asarray(Image.open(toy_photos.images[k])).astype(np.float64)
        Image.fromarray(np.round(ndimage.uniform_filter1d(image, 7, axis=1)).astype(np.uint8)).save(path)
        return path

    one = dataclasses.replace(toy_photos, images=(*toy_photos.images[:3], smeared(3), *toy_photos.images[4:]))
    config = TOY.override(photos__check_alignment=False)  # as photo_result: the toy misleads the check
    m = enhance(toy_demo.scan, config, photos=one).metrics
    assert [d["photo"] for d in m["photos"]["blurred"]] == [3] and not m["photos"]["blurred"][0]["left_out"]
    assert 3 in m["photos"]["train"] + m["photos"]["held_out"]
    assert "blurred photos: 3 (" in enhance_summary(m) and "--blurred leave-out leaves them out" in enhance_summary(m)
    assert "soft_photos" not in m["photos"]["texturing"]
    m = enhance(toy_demo.scan, config.override(photos__blurred="soften"), photos=one).metrics
    assert m["photos"]["blurred"][0]["softened"] and not m["photos"]["blurred"][0]["left_out"]
    assert m["photos"]["texturing"]["soft_photos"] == ([3] if 3 in m["photos"]["train"] else [])
    assert m["photos"]["final_texture"]["texturing"]["soft_photos"] == [3]
    assert "their fine detail left to the sharp photos" in enhance_summary(m) and m["geometry"]["arrays_identical"]
    # a field's colour everywhere takes each photo whole: blended in, and said so
    m = enhance(toy_demo.scan, config.override(photos__blurred="soften", photos__texturing="field"), photos=one).metrics
    assert not m["photos"]["blurred"][0]["softened"] and "blended like the others" in enhance_summary(m)
    m = enhance(toy_demo.scan, config.override(photos__blurred="leave-out"), photos=one).metrics
    assert m["photos"]["blurred"][0]["left_out"] and 3 not in m["photos"]["train"] + m["photos"]["held_out"]
    assert m["photos"]["final_texture"]["photos"] == 9 and m["geometry"]["arrays_identical"]
    assert "left out, the texture made sharp" in enhance_summary(m)
    # the sharp photos alone: none named
    assert enhance(toy_demo.scan, config, photos=toy_photos).metrics["photos"]["blurred"] == []


def test_blurred_photos_are_left_out_when_they_are_a_quarter_of_the_training_photos(monkeypatch):
    """auto: one of nine blended in (its partners would paint what it saw from further off), three of nine left out
    (they would smear the texture); leave-out, keep and soften whatever their share; a training photo kept when none
    would be left."""
    import scantex.photos.sharpness as sharpness
    from scantex.pipeline.enhance import judge_detail

    photos = PhotoSet(cameras=(None,) * 10, images=tuple(f"p{i}.png" for i in range(10)), source=".", format="test")
    train, held = np.array([0, 1, 2, 3, 4, 6, 7, 8, 9]), np.array([5])
    views = [_FakeView(int(i)) for i in (*train, *held)]  # the training photos' views, then the held-out ones'

    def judged(named, mode):
        monkeypatch.setattr(sharpness, "blurred_photos", lambda v: [{"photo": i, "detail": 0.2} for i in named])
        kept, t, h, found = judge_detail(photos, views, train, held, mode)
        assert [v.index for v in kept] == [*t, *h]
        return sorted(set(range(10)) - {v.index for v in kept}), [(d["left_out"], d["softened"]) for d in found]

    kept, softened, gone = (False, False), (False, True), (True, False)
    assert judged([3], "auto") == ([], [kept])
    assert judged([3, 5], "auto") == ([], [kept, kept])  # one training photo of nine
    assert judged([1, 3, 7], "auto") == ([1, 3, 7], [gone] * 3)
    assert judged([3], "soften") == ([], [softened])
    assert judged([3], "leave-out") == ([3], [gone])
    assert judged([1, 3, 7], "leave-out") == ([1, 3, 7], [gone] * 3)
    assert judged([1, 3, 7], "keep") == ([], [kept] * 3)
    assert judged([1, 3, 7], "soften") == ([], [softened] * 3)
    assert judged(list(range(10)), "leave-out") == ([], [kept] * 10)  # none would be left to train on


@dataclasses.dataclass
class _FakeView:
    index: int = 0


def given_twice(photos: PhotoSet, folder) -> PhotoSet:
    """``photos`` followed by a copy of each under another name in ``folder`` (a still camera's repeated frames)."""
    import shutil

    copies = []
    for i, image in enumerate(photos.images):
        copies.append(folder / f"copy_{i}{image.suffix}")
        shutil.copyfile(image, copies[-1])
    return PhotoSet(cameras=photos.cameras * 2, images=(*photos.images, *copies), source=folder, format="test")


def test_repeated_views_are_thinned_before_the_split(tmp_path, toy_demo, toy_photos):
    """Each of the ten photos given twice (a copy under another name, as a video's still camera gives): with
    ``photos.keyframes`` on, one of each pair is kept, the split is made of those, and the summary and metrics
    say which repeat which; auto leaves a capture this small as it is."""
    from scantex.cli import enhance_summary

    twice = given_twice(toy_photos, tmp_path)
    config = TOY.override(photos__check_alignment=False, photos__keyframes="on")
    m = enhance(toy_demo.scan, config, photos=twice).metrics
    repeated = m["photos"]["repeated"]
    assert sorted(d["photo"] for d in repeated) == list(range(10, 20))
    assert all(d["repeats"] == d["photo"] - 10 for d in repeated)
    assert sorted(m["photos"]["train"] + m["photos"]["held_out"]) == list(range(10))
    assert len(m["photos"]["held_out"]) == 1 and m["geometry"]["arrays_identical"]
    assert "keyframes: 10 of the 20 photos kept; 10 repeat the view of a sharper one" in enhance_summary(m)
    from scantex.photos.keyframes import KEYFRAMES_FROM
    from scantex.pipeline.enhance import keyframes_mode

    assert keyframes_mode("auto", KEYFRAMES_FROM - 1) == "off" and keyframes_mode("auto", KEYFRAMES_FROM) == "on"
    assert keyframes_mode("off", 10 * KEYFRAMES_FROM) == "off" and keyframes_mode("on", 2) == "on"
    m = enhance(toy_demo.scan, config.override(photos__keyframes="auto"), photos=twice).metrics
    assert m["photos"]["repeated"] == [] and len(m["photos"]["train"]) + len(m["photos"]["held_out"]) == 20
    assert "keyframes" not in enhance_summary(m)
