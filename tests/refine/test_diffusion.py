"""The diffusion denoiser: schedule, patch sampling, shapes, determinism, and denoising a brick texture."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch

from scantex.refine.diffusion import (
    Denoiser,
    DiffusionConfig,
    cosine_alphas_cumprod,
    fit_denoiser,
    noise_to,
    patch_corners,
)

TINY = DiffusionConfig(steps=240, patch=32, batch=8, width=16, timesteps=100, strength=0.1, sample_steps=3)
SIGMA = 0.08


def bricks(n: int, H: int, W: int, seed: int) -> torch.Tensor:
    """``(n, 3, H, W)`` images of a running-bond brick wall (8 px courses, 16 px bricks, 1 px mortar)
    with a random offset each and a per-brick shade."""
    g = torch.Generator().manual_seed(seed)
    images = []
    for _ in range(n):
        oy, ox = torch.randint(0, 16, (2,), generator=g).tolist()
        y = torch.arange(H)[:, None] + oy
        x = torch.arange(W)[None, :] + ox + (y // 8 % 2) * 8
        mortar = (y % 8 == 0) | (x % 16 == 0)
        shade = 0.9 + 0.2 * ((y // 8 * 7 + x // 16 * 13) % 5 / 4)  # [H, W] per-brick shade
        brick = torch.tensor([0.7, 0.35, 0.25])[:, None, None] * shade
        images.append(torch.where(mortar, torch.tensor([0.85, 0.85, 0.8])[:, None, None], brick))
    return torch.stack(images).float()


@pytest.fixture(scope="module")
def trained() -> Denoiser:
    return fit_denoiser(bricks(6, 48, 48, seed=0), None, TINY, seed=0)


def mse(a: torch.Tensor, b: torch.Tensor) -> float:
    return float(((a - b) ** 2).mean())


# -- pieces ---------------------------------------------------------------------------------------


def test_cosine_schedule():
    abar = cosine_alphas_cumprod(100)
    assert abar.shape == (101,)
    assert abar[0] == 1 and abar[-1] < 1e-4
    assert torch.all(abar[1:] < abar[:-1])
    # the continuous cosine schedule at t = T/2 (no clipping happens that early)
    s = 0.008
    expected = np.cos((0.5 + s) / (1 + s) * np.pi / 2) ** 2 / np.cos(s / (1 + s) * np.pi / 2) ** 2
    assert float(abar[50]) == pytest.approx(expected, rel=1e-9)


def test_noise_to_keeps_unit_variance():
    g = torch.Generator().manual_seed(0)
    x0, eps = torch.randn(2, 100_000, generator=g)
    x = noise_to(x0, torch.tensor(0.3), eps)
    assert float(x.var()) == pytest.approx(1.0, abs=0.02)
    assert float((x * x0).mean()) == pytest.approx(0.3**0.5, abs=0.02)


def test_patch_corners_against_loop():
    g = torch.Generator().manual_seed(1)
    masks = torch.rand(2, 1, 20, 17, generator=g) > 0.03
    masks[1, :, 5:9] = False
    for p, min_usable in ((4, 1.0), (6, 0.95)):
        got = {tuple(r) for r in patch_corners(masks, p, min_usable).tolist()}
        expected = {(n, y, x) for n in range(2) for y in range(20 - p + 1) for x in range(17 - p + 1)
                    if masks[n, 0, y:y + p, x:x + p].float().mean() >= min_usable - 1e-6}
        assert got == expected and got


# -- bad input ------------------------------------------------------------------------------------


def test_bad_input_raises():
    images = torch.rand(2, 3, 40, 40)
    with pytest.raises(ValueError, match=r"\(N, 3, H, W\)"):
        fit_denoiser(torch.rand(2, 4, 40, 40), None, TINY)
    with pytest.raises(ValueError, match="floating point"):
        fit_denoiser((images * 255).to(torch.uint8), None, TINY)
    with pytest.raises(ValueError, match="smaller than"):
        fit_denoiser(torch.rand(1, 3, 20, 40), None, TINY)
    with pytest.raises(ValueError, match="masks must be"):
        fit_denoiser(images, torch.ones(2, 40, 40, dtype=torch.bool), TINY)
    sparse = torch.ones(2, 1, 40, 40, dtype=torch.bool)
    sparse[:, :, ::20] = False
    with pytest.raises(ValueError, match="no 32x32 patch"):
        fit_denoiser(images, sparse, TINY)
    with pytest.raises(ValueError, match="strength"):
        Denoiser(TINY).denoise(images, 1.5)


# -- shapes, identity, determinism ----------------------------------------------------------------


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_denoise_shapes_and_dtype_odd_size(dtype):
    images = torch.rand(2, 3, 37, 23, dtype=dtype)
    out = Denoiser(TINY).denoise(images, 0.2)
    assert out.shape == images.shape and out.dtype == dtype
    assert torch.isfinite(out).all() and out.min() >= 0 and out.max() <= 1


def test_denoise_single_pixel_image():
    out = Denoiser(TINY).denoise(torch.rand(1, 3, 1, 3), 0.2)
    assert out.shape == (1, 3, 1, 3)


def test_strength_zero_is_identity(trained):
    images = torch.rand(2, 3, 21, 30)
    assert torch.equal(trained.denoise(images, 0.0), images)


def test_deterministic_given_seed(trained):
    images = bricks(1, 40, 40, seed=3)
    a, b = trained.denoise(images, seed=7), trained.denoise(images, seed=7)
    assert torch.equal(a, b)
    assert not torch.equal(a, trained.denoise(images, seed=8))


def test_training_is_deterministic_given_seed():
    config = dataclasses.replace(TINY, steps=5)
    images = bricks(2, 40, 40, seed=0)
    a, b = fit_denoiser(images, None, config, seed=3), fit_denoiser(images, None, config, seed=3)
    assert np.array_equal(a.losses, b.losses)
    for (name, pa), pb in zip(a.state_dict().items(), b.state_dict().values()):
        assert torch.equal(pa, pb), name


def test_progress_reports_every_step():
    calls = []
    fit_denoiser(bricks(1, 32, 32, seed=0), None, dataclasses.replace(TINY, steps=3),
                 progress=lambda done, total: calls.append((done, total)))
    assert calls == [(1, 3), (2, 3), (3, 3)]


def test_masked_pixels_never_reach_the_loss():
    """Garbage where the mask is False changes nothing when no drawn patch may contain it."""
    images = bricks(2, 48, 48, seed=0)
    masks = torch.ones(2, 1, 48, 48, dtype=torch.bool)
    masks[:, :, :, 40:] = False
    spoiled = images.clone()
    spoiled[:, :, :, 40:] = torch.rand(2, 3, 48, 8)
    config = dataclasses.replace(TINY, steps=4)
    a, b = fit_denoiser(images, masks, config), fit_denoiser(spoiled, masks, config)
    assert np.array_equal(a.losses, b.losses)


# -- the trained model ----------------------------------------------------------------------------


def test_training_loss_decreases(trained):
    losses = trained.losses
    assert losses.shape == (TINY.steps,)
    assert losses[-40:].mean() < 0.4 * losses[:20].mean()


def test_denoising_removes_noise_and_keeps_a_clean_texture(trained):
    """Held-out brick images with Gaussian noise come out much closer to the clean images."""
    clean = bricks(4, 53, 61, seed=1)  # unseen offsets, an odd size
    g = torch.Generator().manual_seed(5)
    noisy = (clean + SIGMA * torch.randn(clean.shape, generator=g)).clamp(0, 1)
    before = mse(noisy, clean)
    after = mse(trained.denoise(noisy), clean)
    assert after < 0.4 * before, (before, after)
    # a clean input stays close to itself: well under the noise the model removes
    assert mse(trained.denoise(clean), clean) < 0.25 * before


def test_tiles_agree_with_whole_image(trained):
    images = bricks(1, 70, 90, seed=2)
    tiled = Denoiser(dataclasses.replace(TINY, tile=40, overlap=12))
    tiled.load_state_dict(trained.state_dict())
    a, b = trained.denoise(images, seed=1), tiled.denoise(images, seed=1)
    assert not torch.equal(a, b)  # the tiled path did run
    assert float((a - b).abs().mean()) < 0.01


def test_save_and_load(trained, tmp_path):
    trained.save(tmp_path / "denoiser.pt")
    loaded = Denoiser.load(tmp_path / "denoiser.pt")
    assert loaded.config == trained.config
    images = bricks(1, 36, 36, seed=4)
    assert torch.equal(loaded.denoise(images, seed=2), trained.denoise(images, seed=2))
