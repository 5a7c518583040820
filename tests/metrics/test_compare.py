"""``compare`` and ``scantex compare``: geometry and texture of B against A."""

from __future__ import annotations

import dataclasses
import json
import subprocess
import sys

import numpy as np
import pytest

from scantex.errors import ScanError
from scantex.io import save_scan
from scantex.metrics.compare import compare, read_photos, summary_lines
from scantex.synth import make_wall


@pytest.fixture(scope="module")
def demo():
    return make_wall(grid=(12, 10), gt_texture_size=128, scan_texture_size=32, seed=1)


def test_compare_same_geometry(demo):
    r = compare(demo.scan, demo.ground_truth, n_views=2, width=48, height=36, samples=2000)
    assert r["geometry"]["distance"]["hausdorff"] == 0.0
    assert r["geometry"]["volume"][0]["volume"] is None
    assert np.isfinite(r["atlas"]["psnr"]) and r["atlas"]["texels"] > 0
    assert r["renders"]["reference"] == "renders of a" and r["renders"]["b"]["views"] >= 1
    assert "Hausdorff 0" in summary_lines(r)
    json.dumps(r)


def test_compare_moved_vertex_and_other_layout(demo):
    positions = demo.scan.positions.copy()
    positions[20, 1] -= 0.1
    other = dataclasses.replace(demo.scan, positions=positions, uvs=demo.scan.uvs * 0.5)
    r = compare(demo.scan, other, n_views=2, width=48, height=36, samples=2000)
    assert r["geometry"]["distance"]["hausdorff"] == pytest.approx(0.1, rel=0.05)
    assert "skipped" in r["atlas"]


def test_read_photos_errors(tmp_path):
    with pytest.raises(ScanError, match="cameras file not found"):
        read_photos(tmp_path / "nope.json")
    (tmp_path / "bad.json").write_text('{"frames": [{"image": "a.png"}]}')
    with pytest.raises(ScanError, match="not a cameras file"):
        read_photos(tmp_path / "bad.json")


def test_cli_compare_against_photos(tmp_path, demo):
    save_scan(demo.scan, tmp_path / "scan.obj")
    save_scan(demo.ground_truth, tmp_path / "truth.obj")
    run = [sys.executable, "-m", "scantex"]
    # 'photos': unlit renders of the ground truth, as a capture's frames would be
    subprocess.run(run + ["render", str(tmp_path / "truth.obj"), "--views", "3", "--width", "64", "--height", "48",
                          "--unlit", "-o", str(tmp_path / "photos"), "-q"], check=True, timeout=300)
    proc = subprocess.run(run + ["compare", str(tmp_path / "scan.obj"), str(tmp_path / "truth.obj"),
                                 "--cameras", str(tmp_path / "photos" / "cameras.json"), "--samples", "2000",
                                 "--json", str(tmp_path / "m.json")], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    assert "renders of b vs photos" in proc.stdout
    m = json.loads((tmp_path / "m.json").read_text())
    assert m["renders"]["reference"] == "photos"
    # the truth's renders match the photos made from it far better than the degraded scan's
    assert m["renders"]["b"]["psnr"] > m["renders"]["a"]["psnr"] + 10
    assert m["geometry"]["distance"]["hausdorff"] == 0.0

    from PIL import Image

    Image.new("RGB", (10, 10)).save(tmp_path / "photos" / "view_000.png")
    with pytest.raises(ScanError, match="its camera says 64x48"):
        read_photos(tmp_path / "photos" / "cameras.json")
