"""Pretext tasks: masks, smooth fill, JPEG-like compression, the downscale to undo."""

from __future__ import annotations

import torch

from scantex.refine.pretext import downscale_blur_compress, gaussian_blur, jpeg_like, random_masks, smooth_fill


def test_masks_cover_about_the_share_asked_for():
    g = torch.Generator().manual_seed(0)
    masks = random_masks(16, 64, 64, 0.3, 16, g)
    assert masks.shape == (16, 1, 64, 64) and masks.dtype == torch.bool
    assert 0.15 < masks.float().mean() < 0.4


def test_smooth_fill_keeps_known_pixels_and_fills_from_around():
    x = torch.zeros(1, 3, 32, 32)
    x[:, 0, :, :16] = 1.0  # red left half, black right half
    known = torch.ones(1, 1, 32, 32, dtype=torch.bool)
    known[..., 10:20, 2:8] = False  # a hole inside the red half
    x_holed = torch.where(known, x, torch.full_like(x, 0.5))
    filled = smooth_fill(x_holed, known)
    assert torch.equal(filled[known.expand_as(x)], x[known.expand_as(x)])
    hole = filled[0, :, 10:20, 2:8]
    assert hole[0].min() > 0.9 and hole[1:].abs().max() < 1e-6


def test_jpeg_like_is_nearly_lossless_at_high_quality_and_lossy_at_low():
    g = torch.Generator().manual_seed(0)
    x = gaussian_blur(torch.rand(2, 3, 37, 45, generator=g), torch.tensor([1.0, 1.0]))
    high = jpeg_like(x, torch.tensor([100.0, 100.0]))
    low = jpeg_like(x, torch.tensor([10.0, 10.0]))
    assert high.shape == x.shape
    assert (high - x).abs().mean() < 0.01
    assert (low - x).abs().mean() > 2 * (high - x).abs().mean()


def test_downscale_blur_compress_loses_detail_but_not_the_mean():
    g = torch.Generator().manual_seed(0)
    x = torch.rand(4, 3, 48, 48, generator=g)
    y = downscale_blur_compress(x, 2.0, g)
    assert y.shape == x.shape
    assert (y.mean() - x.mean()).abs() < 0.02
    assert y.std() < 0.7 * x.std()  # white noise is mostly gone
