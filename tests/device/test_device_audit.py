"""Device discipline without a GPU: every tensor the training code makes lands on the device it was asked for.

CI has no GPU, so a tensor made on the CPU while the run is on CUDA (a factory call without ``device=``)
would only show as "Expected all tensors to be on the same device" on a GPU machine. Here the code runs
on ``device="cpu"`` while torch's *default* device is ``meta``: any factory call that relies on the
default instead of naming a device makes a data-less meta tensor, and the first operation that mixes it
with the real CPU tensors raises -- the same bug, caught on the CPU.
"""

from __future__ import annotations

import contextlib

import numpy as np
import pytest
import torch
from torch.overrides import TorchFunctionMode
from torch.utils._pytree import tree_leaves

from scantex.refine.config import RefineConfig
from scantex.refine.diffusion import DiffusionConfig, fit_denoiser
from scantex.refine.train import RefinerData, fit_refiner

CPU = torch.device("cpu")


class _NoMetaTensors(TorchFunctionMode):
    """Raises as soon as any torch function returns a meta tensor: some operations (``conv2d`` with a
    meta weight, indexing a CPU tensor with a meta index) accept one silently and return garbage, so
    waiting for a device error is not enough."""

    def __torch_function__(self, func, types, args=(), kwargs=None):
        out = func(*args, **(kwargs or {}))
        if any(isinstance(t, torch.Tensor) and t.is_meta for t in tree_leaves(out)):
            raise RuntimeError(f"{getattr(func, '__name__', func)} made a tensor on the default device: "
                               "name the device")
        return out


@contextlib.contextmanager
def default_device_meta():
    """Factory calls that name no device make meta tensors (which hold no data) inside this block, and
    the first one raises."""
    torch.set_default_device("meta")
    try:
        with _NoMetaTensors():
            yield
    finally:
        torch.set_default_device(None)


def test_the_detector_catches_a_factory_call_without_a_device():
    real = torch.ones(4, device=CPU)
    with default_device_meta(), pytest.raises(RuntimeError, match="name the device"):
        real.bool() | (torch.rand(4) < 0.5)  # the kind of bug random_masks had on CUDA
    with default_device_meta():
        assert (real + torch.ones(4, device=CPU)).device == CPU  # naming the device passes
        with torch.device("cpu"):
            assert torch.zeros(2).device == CPU  # and so does an explicit device block


def test_the_detector_catches_what_torch_would_accept_silently():
    image = torch.ones(1, 1, 8, 8, device=CPU)
    with default_device_meta(), pytest.raises(RuntimeError, match="name the device"):
        torch.nn.functional.conv2d(image, torch.ones(1, 1, 3, 3))  # a meta weight: no error from torch


def views(n: int = 3, size: int = 48, seed: int = 0) -> RefinerData:
    g = torch.Generator().manual_seed(seed)
    images = torch.rand(n, 3, size, size, generator=g)
    known = torch.ones(n, 1, size, size, dtype=torch.bool)
    known[0, :, :8] = False
    return RefinerData(images, known)


@pytest.mark.parametrize("switches", [dict(), dict(masked=True, super_resolution=True)])
def test_refiner_training_makes_no_tensor_off_device(switches):
    data = views()
    config = RefineConfig(patch=8, crop=32, steps=2, batch=4, **switches)
    with default_device_meta():
        fitted = fit_refiner(data, config, device=CPU)
    assert np.isfinite(fitted.losses).all()


def test_denoiser_training_and_sampling_make_no_tensor_off_device():
    data = views()
    config = DiffusionConfig(steps=2, patch=32, batch=2, width=8, timesteps=20, sample_steps=2)
    with default_device_meta():
        denoiser = fit_denoiser(data.images, data.known, config, device=CPU)
        out = denoiser.denoise(data.images[:1], strength=0.1)
    assert out.device == CPU and torch.isfinite(out).all()


# -- the whole pipeline ---------------------------------------------------------------------------

from scantex.pipeline.enhance import enhance  # noqa: E402
from scantex.synth.photos import capture_photos  # noqa: E402
from tests.pipeline.test_enhance import TOY, toy_demo  # noqa: E402,F401  (a fixture)
from tests.pipeline.test_photo_mode import CAPTURE  # noqa: E402

#: mesh-only mode with every torch stage on: the field, the ViT refiner and the diffusion denoiser
ALL_STAGES = TOY.override(train__steps=20, refine__enabled=True, refine__over_input=True, refine__steps=3, refine__batch=4,
                          refine__max_views=2, refine__diffusion=True, refine__diffusion_steps=3)


#: photo mode at toy size; toy photos are too small for the alignment check (its own tests cover it)
PHOTO_TOY = TOY.override(train__steps=20, photos__check_alignment=False)


def assert_every_stage_ran(metrics: dict) -> None:
    """ALL_STAGES's field, refiner and denoiser ran, whether the safety net kept the refiner's colour or not
    (tests/device/test_gpu.py checks the same on CUDA: the CPU run here keeps those checks true)."""
    refine = metrics.get("refine") or metrics["bake"].get("safety", {}).get("refine_discarded")
    assert metrics["geometry"]["arrays_identical"] and metrics["field"]["train_rays"] > 0
    assert refine["views_refined"] == 2 and np.isfinite(refine["diffusion_final_loss"])
    assert np.isfinite(metrics["held_out_vs_ground_truth"]["enhanced"]["psnr"])


def test_mesh_only_pipeline_makes_no_tensor_off_device(toy_demo):
    with default_device_meta():
        result = enhance(toy_demo.scan, ALL_STAGES.override(device="cpu"), ground_truth=toy_demo.ground_truth)
    assert_every_stage_ran(result.metrics)


@pytest.mark.parametrize("texturing", ["projective", "field"])
def test_photo_mode_pipeline_makes_no_tensor_off_device(toy_demo, tmp_path, texturing):
    photos = capture_photos(toy_demo, tmp_path, CAPTURE, seed=1)
    with default_device_meta():
        result = enhance(toy_demo.scan, PHOTO_TOY.override(device="cpu", photos__texturing=texturing), photos=photos)
    assert result.metrics["geometry"]["arrays_identical"] and "photos" in result.metrics["timings_s"]
    assert np.isfinite(result.metrics["held_out_photos"]["enhanced"]["psnr"])


@pytest.mark.skipif(torch.cuda.is_available(), reason="a CUDA GPU is present")
def test_asking_for_cuda_without_it_is_a_one_line_error(toy_demo, tmp_path):
    import subprocess
    import sys

    from scantex.io import save_scan

    save_scan(toy_demo.scan, tmp_path / "scan.obj")
    proc = subprocess.run([sys.executable, "-m", "scantex", "enhance", str(tmp_path / "scan.obj"), "-o",
                           str(tmp_path / "out"), "--device", "cuda"], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2 and "no CUDA GPU" in proc.stderr and len(proc.stderr.strip().splitlines()) == 1
    assert not (tmp_path / "out").exists()


@pytest.mark.skipif(torch.cuda.is_available(), reason="CUDA is here")
def test_the_library_refuses_cuda_without_it_even_where_nothing_trains(toy_demo, tmp_path):
    photos = capture_photos(toy_demo, tmp_path, CAPTURE, seed=1)
    # photo mode's projective texturing would not use the device: asking for a missing one is still an error
    with pytest.raises(ValueError, match="no CUDA GPU"):
        enhance(toy_demo.scan, PHOTO_TOY.override(device="cuda"), photos=photos)
