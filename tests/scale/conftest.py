"""Tiny scans on disk for the batch tests, and a config that enhances one in seconds."""

from __future__ import annotations

import pytest

from scantex.io import save_scan
from scantex.pipeline.config import preset
from scantex.synth import make_wall
from scantex.synth.degrade import Degradation

#: the `fast` preset with tiny views and few steps: an enhance run of a tiny scan takes seconds
TINY = preset("fast").override(views__n_views=4, views__width=64, views__height=48, train__steps=20,
                               train__checkpoint_every=10, refine__enabled=False)


def tiny_wall(seed: int):
    return make_wall(grid=(12, 9), gt_texture_size=64, scan_texture_size=32, seed=seed,
                     degradation=Degradation(hole_share=0.0))


@pytest.fixture(scope="module")
def three_scans(tmp_path_factory):
    """``inputs/`` with two tiny walls (each with its ground truth beside it) and one corrupt OBJ."""
    root = tmp_path_factory.mktemp("scans")
    for i in range(2):
        demo = tiny_wall(i)
        folder = root / f"wall{i}"
        folder.mkdir()
        save_scan(demo.scan, folder / "scan.obj")
        save_scan(demo.ground_truth, folder / "ground_truth.obj")
    (root / "corrupt").mkdir()
    (root / "corrupt" / "scan.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 9\n")
    return root
