"""Image metrics over masked pixels: MSE, PSNR and SSIM (Gaussian 11x11, sigma 1.5).

SSIM is computed with separable Gaussian filtering in torch (grouped conv2d: measured faster here than
shift-and-add or batched single-channel conv), in strips of rows so a 4096^2 image needs little
memory; the SSIM map is averaged over covered
pixels only, so a render's background does not inflate the score.
"""

from __future__ import annotations

import numpy as np

C1 = 0.01**2
C2 = 0.03**2
STRIP_ROWS = 256


def mse(a: np.ndarray, b: np.ndarray, mask: np.ndarray | None = None) -> float:
    """Mean squared error of ``(H, W, C)`` images in [0, 1] over ``mask (H, W)``."""
    d = (np.asarray(a, np.float64) - np.asarray(b, np.float64)) ** 2
    if mask is not None:
        d = d[mask]
    return float(d.mean()) if d.size else float("nan")


def psnr(a: np.ndarray, b: np.ndarray, mask: np.ndarray | None = None) -> float:
    """Peak signal-to-noise ratio in dB (peak 1.0) over ``mask``."""
    e = mse(a, b, mask)
    return float("inf") if e == 0 else float(10 * np.log10(1.0 / e))


def _gaussian(size: int = 11, sigma: float = 1.5):
    import torch

    x = torch.arange(size, dtype=torch.float64, device="cpu") - (size - 1) / 2
    g = torch.exp(-(x**2) / (2 * sigma**2))
    return (g / g.sum()).to(torch.float32)


def ssim_map(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``(H, W)`` SSIM per pixel (mean over channels) of ``(H, W, C)`` images in [0, 1].

    Valid-convolution borders (5 px) are filled by edge replication of the input (reflect padding).
    """
    import torch
    import torch.nn.functional as F

    g = _gaussian()
    k = g.numel()
    r = k // 2
    H, W = a.shape[:2]
    out = np.empty((H, W), np.float32)
    ta = torch.from_numpy(np.ascontiguousarray(a, dtype=np.float32)).permute(2, 0, 1)  # [C, H, W]
    tb = torch.from_numpy(np.ascontiguousarray(b, dtype=np.float32)).permute(2, 0, 1)
    C = ta.shape[0]
    mode = "reflect" if min(H, W) > r else "replicate"

    gh = g.view(1, 1, 1, k).repeat(5 * C, 1, 1, 1)
    gv = g.view(1, 1, k, 1).repeat(5 * C, 1, 1, 1)

    def blur(x):  # [5C, h + 2r, W + 2r] -> [5C, h, W]
        return F.conv2d(F.conv2d(x[None], gh, groups=5 * C), gv, groups=5 * C)[0]

    with torch.no_grad():
        for y0 in range(0, H, STRIP_ROWS):
            y1 = min(y0 + STRIP_ROWS, H)
            lo, hi = max(0, y0 - r), min(H, y1 + r)
            xa, xb = ta[:, lo:hi], tb[:, lo:hi]
            stack = torch.cat([xa, xb, xa * xa, xb * xb, xa * xb])[None]  # [1, 5C, h, W]
            pad_top, pad_bottom = r - (y0 - lo), r - (hi - y1)
            stack = F.pad(stack, (r, r, pad_top, pad_bottom), mode=mode)[0]
            mu_a, mu_b, s_aa, s_bb, s_ab = blur(stack).split(C)
            var_a, var_b, cov = s_aa - mu_a**2, s_bb - mu_b**2, s_ab - mu_a * mu_b
            num = (2 * mu_a * mu_b + C1) * (2 * cov + C2)
            den = (mu_a**2 + mu_b**2 + C1) * (var_a + var_b + C2)
            out[y0:y1] = (num / den).mean(0).numpy()
    return out


def ssim(a: np.ndarray, b: np.ndarray, mask: np.ndarray | None = None) -> float:
    """Mean SSIM over ``mask`` (all pixels when ``None``)."""
    m = ssim_map(a, b)
    return float(m[mask].mean() if mask is not None else m.mean())
