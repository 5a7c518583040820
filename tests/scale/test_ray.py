"""The same batch and a tiled run as Ray tasks, on a Ray instance started in this process."""

from __future__ import annotations

import os
import sys

import numpy as np
import pytest

from scantex.errors import ScanError
from scantex.scale import batch
from scantex.scale.executors import RAY_HINT, RayCluster

from tests.pipeline.test_enhance import TOY, toy_demo  # noqa: F401  (a fixture)
from tests.pipeline.test_photo_mode import toy_photos  # noqa: F401  (a fixture)
from tests.scale.conftest import TINY, tiny_wall
from tests.scale.test_batch import check_batch


def test_missing_ray_is_one_clear_line(monkeypatch, three_scans, tmp_path):
    monkeypatch.setitem(sys.modules, "ray", None)  # import ray -> ImportError
    with pytest.raises(ScanError) as e:
        batch([three_scans / "wall0"], tmp_path / "out", TINY, ray="auto")
    assert str(e.value) == RAY_HINT and "pip install 'scantex[ray]'" in str(e.value)


@pytest.fixture(scope="module")
def ray_instance():
    ray = pytest.importorskip("ray")
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    yield ray
    ray.shutdown()


def test_ray_batch_then_rerun(ray_instance, tmp_path, three_scans):
    out = tmp_path / "batch"
    result = batch([three_scans], out, TINY, ray="auto")
    assert result.executor == "Ray"
    check_batch(out, three_scans, result)
    stamps = {n: os.stat(out / n / "batch.json").st_mtime_ns for n in ("wall0__scan", "wall1__scan")}
    again = batch([three_scans], out, TINY, ray="auto")
    for name, stamp in stamps.items():
        record = next(r for r in again.records if r["name"] == name)
        assert record["reused"] and os.stat(out / name / "batch.json").st_mtime_ns == stamp


def test_ray_tiles(ray_instance):
    from scantex.scale.tiles import TilingConfig, enhance_tiled

    wall = tiny_wall(8)
    result = enhance_tiled(wall.scan, TINY, TilingConfig(tiles=2), runner=RayCluster())
    assert result.scan.positions is wall.scan.positions
    assert np.array_equal(result.scan.face_uvs, wall.scan.face_uvs)
    assert result.metrics["tiles"]["executor"] == "Ray" and result.metrics["tiles"]["count"] == 2
    assert "held_out_vs_input" in result.metrics


def test_ray_tiles_with_photos(ray_instance, toy_demo, toy_photos):
    """Photo mode's tiles as Ray tasks: each takes its photos (paths, poses, masks) to its worker."""
    from scantex.scale.tiles import TilingConfig, enhance_tiled

    config = TOY.override(photos__check_alignment=False)  # a toy wall: see tests/pipeline/test_photo_mode.py
    result = enhance_tiled(toy_demo.scan, config, TilingConfig(tiles=2), photos=toy_photos, runner=RayCluster())
    m = result.metrics
    assert m["tiles"]["executor"] == "Ray" and [t["photos"] for t in m["tiles"]["per_tile"]] == m["photos"]["per_tile"]
    assert all(n > 0 for n in m["photos"]["per_tile"]) and m["geometry"]["arrays_identical"]
    assert m["held_out_photos"]["enhanced"]["psnr_matched"] > m["held_out_photos"]["input"]["psnr_matched"]
