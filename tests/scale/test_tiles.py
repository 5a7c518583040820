"""Tiled enhancement: the tiling, the fusion weights and the colour levelling, and a toy run end to end."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from scantex.errors import ScanError
from scantex.scale.executors import LocalPool
from scantex.scale.tiles import (TilingConfig, enhance_tiled, fuse_tiles, grid_shape, plan_tiles, smoothstep,
                                 tile_gains, tile_scan)
from scantex.scan import TextureMap

from tests.pipeline.test_enhance import toy_demo  # noqa: F401  (a fixture)
from tests.pipeline.test_photo_mode import toy_photos  # noqa: F401  (a fixture)
from tests.scale.conftest import TINY, tiny_wall


@pytest.fixture(scope="module")
def wall():
    return tiny_wall(7)


def test_grid_shape_prefers_square_cells():
    assert grid_shape(4, (4.0, 3.0)) == (2, 2)
    assert grid_shape(4, (40.0, 3.0)) == (4, 1)
    assert grid_shape(6, (3.0, 2.0)) == (3, 2)
    assert grid_shape(5, (1.0, 1.0)) in ((5, 1), (1, 5))


def test_smoothstep_is_a_partition_of_unity():
    x = np.linspace(-0.5, 1.5, 101)
    assert np.allclose(smoothstep(x) + smoothstep(1 - x), 1.0)


def test_tiles_cover_every_face_and_weights_sum_to_one(wall):
    scan = wall.scan
    plan = plan_tiles(scan, 4, overlap=0.2)
    assert plan.grid == (2, 2) and len(plan) == 4
    held = np.zeros(scan.n_faces, int)
    for k, faces in enumerate(plan.faces):
        held[faces] += 1
        assert np.isin(np.flatnonzero(plan.home == k), faces).all()  # a tile holds its own cell's faces
    assert (held >= 1).all() and (held > 1).any()  # every face is somewhere; the overlaps are shared
    assert abs(max(len(f) for f in plan.faces) / min(len(f) for f in plan.faces) - 1) < 0.3  # balanced
    rng = np.random.default_rng(0)
    lo, hi = scan.bounds
    points = lo + rng.random((2000, 3)) * (hi - lo)
    st = plan.coords(points)
    total = sum(plan.weights(k, st) for k in range(4))
    assert np.allclose(total, 1.0)
    # a tile's weight is zero outside its grown cell, where it holds no faces
    centroids = plan.coords(scan.triangles.mean(axis=1))
    for k, faces in enumerate(plan.faces):
        outside = np.setdiff1d(np.arange(scan.n_faces), faces)
        assert np.all(plan.weights(k, centroids[outside]) == 0)


def test_tile_scan_keeps_the_uv_layout(wall):
    scan = wall.scan
    faces = plan_tiles(scan, 4).faces[1]
    sub = tile_scan(scan, faces)
    assert np.array_equal(sub.positions[sub.faces], scan.positions[scan.faces[faces]])
    assert np.array_equal(sub.triangle_uvs, scan.triangle_uvs[faces])
    assert sub.materials is scan.materials
    # a material's other maps stay with the whole scan (a tile's job changes colour only); the atlases are shared
    with_maps = scan.replace(materials=tuple(dataclasses.replace(m, maps={"occlusion": TextureMap(m.image[..., 0])})
                                             for m in scan.materials))
    sub = tile_scan(with_maps, faces)
    assert all(m.maps == {} and m.image is w.image for m, w in zip(sub.materials, with_maps.materials))


def test_fusing_identical_tiles_gives_that_image_back(wall):
    scan = wall.scan
    plan = plan_tiles(scan, 4)
    rng = np.random.default_rng(1)
    image = rng.integers(30, 220, (64, 64, 3), dtype=np.uint8)
    fused, report = fuse_tiles(scan, plan, [(image,)] * 4)
    from scantex.atlas.texelmap import texel_map

    covered = texel_map(scan.triangle_uvs, 64, 64).mask
    assert np.abs(fused[0][covered].astype(int) - image[covered]).max() <= 1
    assert np.allclose(report["gains"][0], 1.0, atol=1e-3)


def test_levelling_undoes_a_tile_exposure(wall):
    scan = wall.scan
    plan = plan_tiles(scan, 4)
    image = np.full((64, 64, 3), 120, np.uint8)
    exposures = [1.0, 1.2, 0.9, 1.0]
    tiles = [(np.clip(image * e, 0, 255).astype(np.uint8),) for e in exposures]
    levelled, report = fuse_tiles(scan, plan, tiles, harmonize=True)
    raw, _ = fuse_tiles(scan, plan, tiles, harmonize=False)
    from scantex.atlas.texelmap import texel_map

    covered = texel_map(scan.triangle_uvs, 64, 64).mask
    gains = np.array(report["gains"][0])[:, 0]
    assert np.allclose(gains * np.array(exposures), (gains * np.array(exposures)).mean(), rtol=0.02)
    assert levelled[0][covered].std() < 0.25 * raw[0][covered].std()


def test_tile_gains_with_no_shared_texels_are_one():
    colours = [np.full((10, 3), 0.5), np.full((10, 3), 0.7)]
    weights = [np.r_[np.ones(5), np.zeros(5)], np.r_[np.zeros(5), np.ones(5)]]
    holds = [w > 0 for w in weights]
    assert np.array_equal(tile_gains(None, colours, weights, holds), np.ones((2, 3)))


def test_tiled_enhance_end_to_end(tmp_path, wall):
    from scantex.pipeline.outputs import write_outputs

    result = enhance_tiled(wall.scan, TINY, TilingConfig(tiles=4), ground_truth=wall.ground_truth,
                           runner=LocalPool(workers=2))
    out = result.scan
    assert out.positions is wall.scan.positions and out.faces is wall.scan.faces
    assert np.array_equal(out.uvs, wall.scan.uvs) and np.array_equal(out.face_uvs, wall.scan.face_uvs)
    assert result.metrics["geometry"]["arrays_identical"]
    tiles = result.metrics["tiles"]
    assert tiles["count"] == 4 and len(tiles["per_tile"]) == 4 and tiles["executor"] == "local pool"
    scores = result.metrics["held_out_vs_ground_truth"]
    assert np.isfinite(scores["enhanced"]["psnr"])
    # the input's atlas size, as enhance bakes the input's texels; levelled, so not the input's image
    assert out.materials[0].image.shape == wall.scan.materials[0].image.shape
    assert not np.array_equal(out.materials[0].image, wall.scan.materials[0].image)
    write_outputs(result, tmp_path)
    assert (tmp_path / "report.html").exists() and (tmp_path / "enhanced.obj").exists()


def test_tiles_keep_the_inputs_base_colour_as_an_untiled_run_does(wall):
    """Each tile's texture is made for the input's base colour (``Kd 0.8``, outside the texture): the fused
    texture is written under that colour too, as :func:`enhance` writes its own."""
    from scantex.pipeline.enhance import enhance

    m = wall.scan.materials[0]
    scan = wall.scan.replace(materials=(dataclasses.replace(m, diffuse=(0.8, 0.8, 0.8, 1.0)),))
    tiled = enhance_tiled(scan, TINY, TilingConfig(tiles=2), runner=LocalPool(workers=1)).scan.materials[0]
    whole = enhance(scan, TINY).scan.materials[0]
    assert tiled.diffuse == whole.diffuse == (0.8, 0.8, 0.8, 1.0)
    assert abs(tiled.image.astype(float).mean() - whole.image.astype(float).mean()) < 2


def test_tiles_refuse_what_they_cannot_fuse(wall):
    with pytest.raises(ScanError, match="uv.mode 'unwrap'"):
        enhance_tiled(wall.scan, TINY.override(uv__mode="unwrap"), TilingConfig(tiles=2))
    with pytest.raises(ScanError, match="no texture or vertex colours to enhance in tiles; give the capture's posed "
                                        r"photos \(--photos\)"):
        enhance_tiled(wall.scan.replace(uvs=None, face_uvs=None), TINY, TilingConfig(tiles=2))


def test_cli_refuses_tiles_it_cannot_fuse(tmp_path, wall):
    import subprocess
    import sys

    from scantex.io import save_scan
    from scantex.scan import Scan

    save_scan(wall.scan, tmp_path / "scan.obj")
    proc = subprocess.run([sys.executable, "-m", "scantex", "enhance", str(tmp_path / "scan.obj"), "-o",
                           str(tmp_path / "out"), "--tiles", "2", "--uv", "unwrap"],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2
    assert proc.stderr.strip().endswith("scan.obj: --tiles is not supported with --uv unwrap (tiles share the input's "
                                        "UV layout)")
    assert not (tmp_path / "out").exists() and not (tmp_path / "out.partial").exists()
    # a bare mesh without photos has nothing to enhance, tiled or not: said before any tile is cut
    save_scan(Scan(wall.scan.positions, wall.scan.faces), tmp_path / "bare.obj")
    proc = subprocess.run([sys.executable, "-m", "scantex", "enhance", str(tmp_path / "bare.obj"), "-o",
                           str(tmp_path / "out"), "--tiles", "2"], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2 and "bare.obj: has no colour to enhance" in proc.stderr
    assert not (tmp_path / "out").exists() and not (tmp_path / "out.partial").exists()


def test_each_tile_gets_the_photos_that_see_it(tmp_path):
    import dataclasses

    from scantex.photos.photoset import PhotoSet
    from scantex.scale.tiles import tiles_seen
    from scantex.views.camera import Camera
    from scantex.views.raycast import RayCaster
    from tests.conftest import grid_wall

    square = grid_wall(24)
    scan = dataclasses.replace(square, positions=square.positions * [2.0, 1.0, 1.0])  # 4 m x 2 m, facing -y
    plan = plan_tiles(scan, 2)  # cut across x, at 2 m
    corner = Camera.look_at((0.2, -0.4, 0.2), (0.2, 0.0, 0.2), fov_deg=20, width=64, height=48)
    whole = Camera.look_at((2.0, -6.0, 1.0), (2.0, 0.0, 1.0), fov_deg=45, width=64, height=48)
    behind = Camera.look_at((2.0, -6.0, 1.0), (2.0, -12.0, 1.0), fov_deg=45, width=64, height=48)  # looks away
    photos = PhotoSet(cameras=(corner, whole, behind), images=[tmp_path / f"{i}.png" for i in range(3)],
                      source=tmp_path, format="test")
    seen, hidden, factors, density = tiles_seen(scan, plan, photos, [0, 1, 2], RayCaster(scan.positions, scan.faces),
                                                64)
    assert factors == {}  # no depth maps
    # the photos' pixels per centimetre on the wall, the median of the two that see it (0.4 and 6 m away, square on)
    assert np.isclose(density, np.median([corner.K[0, 0] / 0.4, whole.K[0, 0] / 6.0]) / 100, rtol=0.03)
    home = plan.home[np.argmin(np.linalg.norm(scan.triangles.mean(axis=1) - [0.2, 0.0, 0.2], axis=1))]
    assert [list(s) for s in seen] == [[0, 1] if t == home else [1] for t in range(2)]
    # the whole wall's photo: in each tile, the pixels of the other tile's cell (beyond the overlap) are masked
    for t in range(2):
        assert list(hidden[t]) == [1]
        packed, width = hidden[t][1]
        mask = np.unpackbits(packed, axis=1, count=width).astype(bool)
        assert mask.shape == (48, 64) and 0.15 < mask.mean() < 0.5


def test_a_photo_set_sent_to_another_process_reads_its_photos_there(tmp_path):
    import pickle

    from PIL import Image

    from scantex.photos.photoset import PhotoSet
    from scantex.views.camera import Camera

    Image.fromarray(np.full((4, 6, 3), 7, np.uint8)).save(tmp_path / "a.png")
    photos = PhotoSet(cameras=(Camera.look_at((0, -1, 0), (0, 0, 0), width=6, height=4),), images=[tmp_path / "a.png"],
                      source=tmp_path, format="test")
    photos.load_image(0)  # decoded and cached here
    again = pickle.loads(pickle.dumps(photos))
    assert again.image_cache is not photos.image_cache and again.image_cache.get(tmp_path / "a.png") is None
    assert again.image_cache.budget == photos.image_cache.budget
    assert np.array_equal(again.load_image(0), photos.load_image(0))


def test_tiled_photo_mode_scores_the_fused_result_on_held_out_photos(tmp_path, toy_demo, toy_photos):
    import json
    import subprocess
    import sys

    from scantex.io import save_scan
    from scantex.pipeline.enhance import enhance
    from scantex.pipeline.outputs import write_outputs
    from tests.pipeline.test_enhance import TOY

    config = TOY.override(photos__check_alignment=False)  # a toy wall: see tests/pipeline/test_photo_mode.py
    whole = enhance(toy_demo.scan, config, ground_truth=toy_demo.ground_truth, photos=toy_photos)
    tiled = enhance_tiled(toy_demo.scan, config, TilingConfig(tiles=2), ground_truth=toy_demo.ground_truth,
                          photos=toy_photos, runner=LocalPool(workers=2))
    out, m = tiled.scan, tiled.metrics
    assert out.positions is toy_demo.scan.positions and out.faces is toy_demo.scan.faces
    assert np.array_equal(out.face_uvs, toy_demo.scan.face_uvs) and m["geometry"]["arrays_identical"]
    # the same photos held out as an untiled run; each tile textured from the training photos that see it
    assert m["photos"]["held_out"] == whole.metrics["photos"]["held_out"] and len(m["photos"]["held_out"]) == 1
    assert [t["photos"] for t in m["tiles"]["per_tile"]] == m["photos"]["per_tile"]
    assert all(0 < n <= len(m["photos"]["train"]) for n in m["photos"]["per_tile"])
    # one pose per training photo, refined once for the whole capture (fewer than REFINE_BELOW photos)
    assert m["photos"]["pose_refinement"] == "input"
    assert [c["photo"] for c in m["photos"]["pose_corrections"]] == m["photos"]["train"]
    # the held-out photos score the fused result: better than the input, about as good as the untiled run
    photos = m["held_out_photos"]
    assert photos["enhanced"]["psnr_matched"] > photos["input"]["psnr_matched"]
    truth, untiled = m["held_out_photos_vs_ground_truth"], whole.metrics["held_out_photos_vs_ground_truth"]
    assert truth["enhanced"]["mse"] < 0.7 * truth["input"]["mse"]
    assert abs(truth["enhanced"]["psnr"] - untiled["enhanced"]["psnr"]) < 0.5
    assert list(tiled.comparisons) == [f"held_out_photo_{i:03d}" for i in m["photos"]["held_out"]]
    # the synthetic views planned as the untiled run plans them, only the held-out ones rendered
    assert m["views"]["total"] == whole.metrics["views"]["total"]
    assert m["views"]["test"] == whole.metrics["views"]["test"]
    assert not tiled.views.valid[tiled.views.views.train].any()
    (tmp_path / "api").mkdir()
    write_outputs(tiled, tmp_path / "api")
    assert "Held-out photos" in (tmp_path / "api" / "report.html").read_text()

    # the command line tiles photo mode too
    save_scan(toy_demo.scan, tmp_path / "scan.obj")
    (tmp_path / "config.json").write_text(json.dumps(config.to_dict()))
    run = subprocess.run([sys.executable, "-m", "scantex", "enhance", str(tmp_path / "scan.obj"), "--config",
                          str(tmp_path / "config.json"), "--photos", str(toy_photos.source), "--tiles", "2",
                          "--workers", "2", "-o", str(tmp_path / "cli")], capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr
    assert "enhancing in 2 overlapping tiles" in run.stdout and "1 held-out photo:" in run.stdout
    metrics = json.loads((tmp_path / "cli" / "metrics.json").read_text())
    assert metrics["tiles"]["count"] == 2 and metrics["photos"]["final_texture"]["mode"] == "training"
    # how the tiles coloured their texels, as a whole run says it (the summary's hint on fine detail reads it)
    assert metrics["photos"]["texturing"] == {"mode": "projective"}
    assert "fine detail" in run.stdout


def test_a_tiled_run_names_the_shaken_photos_its_tiles_named_by_their_number_in_the_capture(tmp_path, toy_demo,
                                                                                             toy_photos, capfd):
    """Each tile judges the photos that see it, numbered in its own subset: the warnings and ``photos.blurred`` name
    them by their number in the capture, each photo once (the least detail a tile measured, the tiles that named
    it)."""
    from PIL import Image
    from scipy import ndimage

    from scantex.cli import enhance_summary
    from tests.pipeline.test_enhance import TOY

    path = tmp_path / "smeared_7.png"
    image = np.asarray(Image.open(toy_photos.images[7])).astype(np.float64)
    Image.fromarray(np.round(ndimage.uniform_filter1d(image, 7, axis=1)).astype(np.uint8)).save(path)
    one = dataclasses.replace(toy_photos, images=(*toy_photos.images[:7], path, *toy_photos.images[8:]))
    config = TOY.override(photos__check_alignment=False)
    m = enhance_tiled(toy_demo.scan, config, TilingConfig(tiles=2), photos=one, runner=LocalPool(workers=1)).metrics
    held = m["photos"]["held_out"]
    assert held == [6]  # the smeared photo is the seventh of a tile's training photos, not the eighth
    assert m["photos"]["repeated"] == []  # ten distinct views: none set aside as repeating another
    named = m["photos"]["blurred"]
    assert [d["photo"] for d in named] == [7] and named[0]["image"] == str(path) and named[0]["tiles"]
    assert not named[0]["left_out"]  # one of nine: blended in
    said = [line for line in capfd.readouterr().err.splitlines() if "fine detail" in line]  # from the tiles' workers
    assert said and all(": photo 7 has" in text for text in said)
    assert "blurred photos: 7 (" in enhance_summary(m)


def test_the_tiles_verdicts_on_a_photo_are_merged():
    from scantex.scale.tiles import tiled_blurred

    outputs = [{"index": 0, "blurred": [{"photo": 7, "detail": 0.2, "left_out": False, "softened": False}]},
               {"index": 1, "blurred": [{"photo": 7, "detail": 0.15, "left_out": True, "softened": False},
                                        {"photo": 2, "detail": 0.25, "left_out": False, "softened": True}]},
               {"index": 2, "blurred": []}]
    assert tiled_blurred(outputs) == [
        {"photo": 7, "detail": 0.15, "left_out": True, "softened": False, "tiles": [0, 1]},
        {"photo": 2, "detail": 0.25, "left_out": False, "softened": True, "tiles": [1]}]


def test_an_untextured_scan_is_laid_out_whole_and_tiled_with_its_photos(toy_demo, toy_photos):
    """A bare mesh with photos: one layout made for the whole scan at the atlas size the photos call for, each tile
    textured from its photos into it; as good as the untiled run on the held-out photos."""
    from scantex.pipeline.enhance import enhance
    from scantex.scan import Scan
    from tests.pipeline.test_enhance import TOY

    bare = Scan(toy_demo.scan.positions, toy_demo.scan.faces)
    config = TOY.override(photos__check_alignment=False)
    whole = enhance(bare, config, ground_truth=toy_demo.ground_truth, photos=toy_photos)
    tiled = enhance_tiled(bare, config, TilingConfig(tiles=2), ground_truth=toy_demo.ground_truth, photos=toy_photos,
                          runner=LocalPool(workers=2))
    out, m = tiled.scan, tiled.metrics
    assert out.positions is bare.positions and out.faces is bare.faces and m["geometry"]["arrays_identical"]
    # the layout and the atlas size are the untiled run's (the photos' density from the tiles' own ray casts)
    assert m["uv"]["mode"] == "unwrap" and m["uv"]["texture_size"] == whole.metrics["uv"]["texture_size"]
    assert out.materials[0].image.shape == whole.scan.materials[0].image.shape
    assert m["photos"]["pose_refinement"] == "consensus"  # left to each tile, as an untiled run refines them
    assert "held_out_vs_input" not in m  # no input texture to be faithful to
    # nor one that may have seen the held-out photos: the summary does not warn that it may have
    from scantex.cli import enhance_summary

    assert m["input"]["textured"] is False and "held out from the result only" not in enhance_summary(m)
    truth, untiled = m["held_out_photos_vs_ground_truth"], whole.metrics["held_out_photos_vs_ground_truth"]
    assert truth["enhanced"]["psnr"] > truth["input"]["psnr"] + 3
    assert abs(truth["enhanced"]["psnr"] - untiled["enhanced"]["psnr"]) < 1.0


def test_a_vertex_coloured_scan_is_tiled_as_the_texture_of_its_colours(wall):
    """A fused depth scan's colour per vertex: baked into a texture for the whole scan first, as enhance does, then
    tiled as a textured scan; the result shows the colours."""
    from scantex.scan import Scan
    from scantex.views.render import shade_hits

    scan = wall.scan
    rgb = np.round(255 * shade_hits(wall.ground_truth, *_vertex_samples(scan)))
    coloured = Scan(scan.positions, scan.faces, vertex_colors=rgb.astype(np.uint8))
    result = enhance_tiled(coloured, TINY, TilingConfig(tiles=2), runner=LocalPool(workers=2))
    m = result.metrics
    assert result.scan.positions is coloured.positions and m["geometry"]["arrays_identical"]
    assert m["input"]["texture"].startswith("baked from the vertex colours") and m["tiles"]["count"] == 2
    rng = np.random.default_rng(0)
    f, b = rng.integers(0, scan.n_faces, 2000), rng.dirichlet(np.ones(3), 2000)[:, 1:]
    assert np.abs(shade_hits(result.scan, f, b) - shade_hits(result.input_scan, f, b)).mean() < 3 / 255


def _vertex_samples(scan):
    """A face and the barycentric coordinates of each vertex of ``scan`` (to read a colour there)."""
    face = np.zeros(scan.n_vertices, int)
    corner = np.zeros(scan.n_vertices, int)
    for k in range(3):
        face[scan.faces[:, k]], corner[scan.faces[:, k]] = np.arange(scan.n_faces), k
    return face, np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]])[corner]


def test_a_tiled_run_says_how_its_tiles_coloured_their_texels():
    from scantex.pipeline.config import PhotosConfig
    from scantex.scale.tiles import tiled_texturing

    assert tiled_texturing(PhotosConfig(), 49) == {"mode": "projective"}  # auto: a small capture's blend
    balanced = {"mode": "projective", "detail": {"temperature": 0.1, "sigma_px": 4.0, "gain": 0.5}}
    assert tiled_texturing(PhotosConfig(), 50) == balanced  # auto: a room's
    assert tiled_texturing(PhotosConfig(detail="balanced"), 10) == balanced
    assert tiled_texturing(PhotosConfig(detail="sharp"), 10) == {
        "mode": "projective", "detail": {"temperature": 0.1, "sigma_px": 4.0, "gain": 1.0}}
    assert tiled_texturing(PhotosConfig(detail="blend"), 500) == {"mode": "projective"}
    assert tiled_texturing(PhotosConfig(texturing="field", detail="sharp"), 10) == {"mode": "field"}


def test_a_tiled_run_thins_repeated_views_once_for_the_capture(tmp_path, toy_demo, toy_photos):
    """``photos.keyframes`` on: the capture's repeated views are set aside before the split, once for all the tiles,
    and the run's metrics name them."""
    from tests.pipeline.test_enhance import TOY
    from tests.pipeline.test_photo_mode import given_twice

    twice = given_twice(toy_photos, tmp_path)
    config = TOY.override(photos__check_alignment=False, photos__keyframes="on")
    m = enhance_tiled(toy_demo.scan, config, TilingConfig(tiles=2), photos=twice, runner=LocalPool(workers=1)).metrics
    assert sorted(d["photo"] for d in m["photos"]["repeated"]) == list(range(10, 20))
    assert sorted(m["photos"]["train"] + m["photos"]["held_out"]) == list(range(10))
