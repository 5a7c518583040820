"""Training the refiner: masked completion learns to fill on a toy; every pretext switch runs."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from scantex.refine.config import RefineConfig
from scantex.refine.correspond import Correspondence
from scantex.refine.train import RefinerData, corrupt, crop_size, fit_refiner


def stripes(n: int = 4, size: int = 64) -> torch.Tensor:
    """Vertical stripes of period 8 with a per-image phase: easy to complete from context."""
    x = torch.arange(size, dtype=torch.float32)
    rows = [0.5 + 0.4 * torch.sin(2 * np.pi * (x + 3 * k) / 8) for k in range(n)]
    return torch.stack([r.expand(size, size) for r in rows])[:, None].expand(n, 3, size, size).contiguous()


def completion_error(model, images, config, seed=1):
    g = torch.Generator().manual_seed(seed)
    known = torch.ones(images.shape[0], 1, *images.shape[2:], dtype=torch.bool)
    x, masked = corrupt(images, known, config, g)
    with torch.no_grad():
        out = model(x) if model is not None else x[:, :3]
    return float(((out - images).abs() * masked).sum() / (3 * masked.sum()))


def test_masked_completion_learns_to_fill():
    images = stripes()
    config = RefineConfig(patch=8, crop=32, steps=120, batch=8, lr=1e-3, cross_view=False,
                          super_resolution=False, mask_share=0.3)
    data = RefinerData(images, torch.ones(4, 1, 64, 64, dtype=torch.bool))
    calls = []
    fitted = fit_refiner(data, config, device=torch.device("cpu"), progress=lambda d, t: calls.append((d, t)))
    assert calls[-1] == (120, 120) and fitted.crop == 32
    assert np.mean(fitted.losses[-20:]) < 0.7 * np.mean(fitted.losses[:10])
    crops = images[:, :, :32, :32]
    assert completion_error(fitted.model, crops, config) < 0.6 * completion_error(None, crops, config)


@pytest.mark.parametrize("switches", [dict(), dict(masked=False, super_resolution=False, cross_view=False)])
def test_all_terms_and_plain_reconstruction_run(switches):
    images = stripes(2, 48)
    known = torch.ones(2, 1, 48, 48, dtype=torch.bool)
    known[1, :, :10] = False
    # view 1 is view 0 shifted 3 pixels to the right
    ys, xs = np.mgrid[0:48, 0:48].astype(np.float32)
    pixels = np.stack([xs + 3, ys], axis=-1)
    pairs = (Correspondence(0, 1, pixels, (xs + 3 <= 47) & (ys >= 10)),)
    config = RefineConfig(patch=8, crop=32, steps=3, batch=4, **switches)
    fitted = fit_refiner(RefinerData(images, known, pairs), config, device=torch.device("cpu"))
    assert len(fitted.losses) == 3 and np.isfinite(fitted.losses).all()


def test_crop_size_fits_the_views():
    assert crop_size(RefineConfig(patch=16, crop=96), 72, 96) == 64
    with pytest.raises(ValueError, match="smaller than one"):
        crop_size(RefineConfig(patch=16), 12, 40)
