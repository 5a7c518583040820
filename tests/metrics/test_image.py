"""SSIM against a direct, pixel-by-pixel reference."""

import numpy as np
import pytest

from scantex.metrics import image
from scantex.metrics.image import C1, C2, gaussian_kernel, ssim, ssim_map


def ssim_reference(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Each pixel's Gaussian-weighted means, variances and covariance over its own 11x11 window, the image
    reflected past its borders (or its edge repeated, when smaller than the window)."""
    g = gaussian_kernel()
    w = np.outer(g, g)[..., None]
    r = len(g) // 2
    H, W = a.shape[:2]
    mode = "reflect" if min(H, W) > r else "edge"
    pa = np.pad(a.astype(np.float64), ((r, r), (r, r), (0, 0)), mode=mode)
    pb = np.pad(b.astype(np.float64), ((r, r), (r, r), (0, 0)), mode=mode)
    out = np.empty((H, W))
    for y in range(H):
        for x in range(W):
            wa, wb = pa[y:y + 2 * r + 1, x:x + 2 * r + 1], pb[y:y + 2 * r + 1, x:x + 2 * r + 1]
            mu_a, mu_b = (w * wa).sum((0, 1)), (w * wb).sum((0, 1))
            var_a = (w * (wa - mu_a) ** 2).sum((0, 1))
            var_b = (w * (wb - mu_b) ** 2).sum((0, 1))
            cov = (w * (wa - mu_a) * (wb - mu_b)).sum((0, 1))
            s = (2 * mu_a * mu_b + C1) * (2 * cov + C2) / ((mu_a**2 + mu_b**2 + C1) * (var_a + var_b + C2))
            out[y, x] = s.mean()
    return out


@pytest.mark.parametrize("shape", [(37, 29, 3), (7, 9, 3), (20, 16, 1)])
def test_ssim_map_matches_the_direct_windows(shape, monkeypatch):
    monkeypatch.setattr(image, "STRIP_ROWS", 8)  # several strips, their window rows borrowed across
    rng = np.random.default_rng(3)
    a = rng.random(shape).astype(np.float32)
    b = np.clip(0.7 * a + 0.3 * rng.random(shape) + 0.05, 0, 1).astype(np.float32)
    np.testing.assert_allclose(ssim_map(a, b), ssim_reference(a, b), atol=2e-5)


def test_ssim_is_one_for_equal_images_and_falls_with_noise():
    rng = np.random.default_rng(0)
    a = rng.random((40, 50, 3)).astype(np.float32)
    noisy = [np.clip(a + s * rng.standard_normal(a.shape), 0, 1).astype(np.float32) for s in (0.02, 0.1, 0.3)]
    assert ssim(a, a) == pytest.approx(1.0, abs=1e-6)
    scores = [ssim(a, n) for n in noisy]
    assert scores[0] > scores[1] > scores[2]
    mask = np.zeros(a.shape[:2], bool)
    mask[:20] = True
    assert ssim(a, noisy[1], mask) == pytest.approx(float(ssim_map(a, noisy[1])[:20].mean()), rel=1e-6)


def test_several_images_against_one_reference_are_each_its_own_ssim_map(monkeypatch):
    """``ssim_maps`` filters the reference once a strip for all the images: each map is the image's own ``ssim_map``,
    bit for bit (a held-out photo against the input's and the result's renders, raw and colour-matched), and all
    near the direct windows."""
    from scantex.metrics.image import ssim_maps

    monkeypatch.setattr(image, "STRIP_ROWS", 8)
    rng = np.random.default_rng(4)
    b = rng.random((37, 29, 3)).astype(np.float32)
    images = [np.clip(b + s * rng.standard_normal(b.shape), 0, 1).astype(np.float32) for s in (0.0, 0.05, 0.2)]
    images.append(rng.random((37, 29, 3)))  # float64 too, as a render may come
    maps = ssim_maps(images, b)
    assert len(maps) == 4 and maps[0].min() > 0.999
    for a, m in zip(images, maps, strict=True):
        assert np.array_equal(m, ssim_map(a, b))
        np.testing.assert_allclose(m, ssim_reference(a, b), atol=2e-5)
