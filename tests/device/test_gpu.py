"""The whole pipeline on CUDA at toy size (``pytest -m gpu``); skipped where torch sees no GPU.

CI has no GPU: there the CPU suite (with tests/device/test_device_audit.py, which catches tensors made on
the wrong device without one) is the gate. Run this file on any GPU machine at hand.
"""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest
import torch

from scantex.io import save_scan
from scantex.pipeline.config import save_config
from scantex.pipeline.enhance import enhance
from scantex.refine.config import RefineConfig
from scantex.refine.train import corrupt
from scantex.synth.photos import capture_photos
from tests.device.test_device_audit import ALL_STAGES, PHOTO_TOY, assert_every_stage_ran
from tests.pipeline.test_enhance import toy_demo  # noqa: F401  (a fixture)
from tests.pipeline.test_photo_mode import CAPTURE

pytestmark = [pytest.mark.gpu,
              pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA GPU in this torch build")]


def test_refiner_corruption_is_the_same_on_cuda_and_cpu():
    """The pretext draws come from a CPU generator: a seed gives the same masks on any device."""
    config = RefineConfig(patch=8, crop=32)
    target = torch.rand(4, 3, 32, 32, generator=torch.Generator().manual_seed(0))
    known = torch.ones(4, 1, 32, 32, dtype=torch.bool)
    x_cpu, m_cpu = corrupt(target, known, config, torch.Generator().manual_seed(1))
    x_gpu, m_gpu = corrupt(target.cuda(), known.cuda(), config, torch.Generator().manual_seed(1))
    assert x_gpu.is_cuda and torch.equal(m_gpu.cpu(), m_cpu)
    assert torch.allclose(x_gpu.cpu(), x_cpu, atol=1e-4)


def test_mesh_only_with_refiner_and_diffusion_on_cuda(toy_demo):
    result = enhance(toy_demo.scan, ALL_STAGES.override(device="cuda"), ground_truth=toy_demo.ground_truth)
    assert_every_stage_ran(result.metrics)


@pytest.mark.parametrize("texturing", ["projective", "field"])
def test_photo_mode_on_cuda(toy_demo, tmp_path, texturing):
    photos = capture_photos(toy_demo, tmp_path, CAPTURE, seed=1)
    result = enhance(toy_demo.scan, PHOTO_TOY.override(device="cuda", photos__texturing=texturing), photos=photos)
    assert result.metrics["geometry"]["arrays_identical"]
    assert np.isfinite(result.metrics["held_out_photos"]["enhanced"]["psnr"])


def test_cli_device_cuda_writes_outputs(toy_demo, tmp_path):
    save_scan(toy_demo.scan, tmp_path / "scan.obj")
    save_config(ALL_STAGES, tmp_path / "toy.json")
    out = tmp_path / "out"
    proc = subprocess.run([sys.executable, "-m", "scantex", "enhance", str(tmp_path / "scan.obj"), "-o", str(out),
                           "--config", str(tmp_path / "toy.json"), "--device", "cuda", "-q"],
                          capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr
    assert (out / "enhanced.obj").exists() and (out / "enhanced_scan.png").exists()
