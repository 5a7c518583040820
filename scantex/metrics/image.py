"""Image metrics over masked pixels: MSE, PSNR and SSIM (Gaussian 11x11, sigma 1.5).

SSIM is computed with separable Gaussian filtering (scipy.ndimage, no torch: scoring a run that trains
nothing does not import a learning library), in strips of rows so a 4096^2 image needs little memory;
the SSIM map is averaged over covered pixels only, so a render's background does not inflate the score.
"""

from __future__ import annotations

from collections.abc import Sequence

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


def gaussian_kernel(size: int = 11, sigma: float = 1.5) -> np.ndarray:
    """``(size,) float64`` normalised 1-D Gaussian weights."""
    x = np.arange(size, dtype=np.float64) - (size - 1) / 2
    g = np.exp(-(x**2) / (2 * sigma**2))
    return g / g.sum()


def ssim_map(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``(H, W)`` SSIM per pixel (mean over channels) of ``(H, W, C)`` images in [0, 1].

    The Gaussian window reaches past the borders by reflection (``d c b | a b c d``; edge replication when
    the image is smaller than the window).
    """
    return ssim_maps([a], b)[0]


def ssim_maps(images: Sequence[np.ndarray], b: np.ndarray) -> list[np.ndarray]:
    """:func:`ssim_map` of each of ``images`` against one reference ``b``: the reference's filtered moments are made
    once a strip of rows, not once an image (a held-out photo against four renders: 20 filtered planes -> 14), and
    each map is the same, bit for bit, as the image's own :func:`ssim_map`."""
    from scipy.ndimage import correlate1d

    g = gaussian_kernel()
    r = len(g) // 2
    H, W = b.shape[:2]
    tb = np.moveaxis(np.asarray(b, np.float32), 2, 0)  # [C, H, W]
    tas = [np.moveaxis(np.asarray(a, np.float32), 2, 0) for a in images]
    C = tb.shape[0]
    mode = "mirror" if min(H, W) > r else "nearest"
    outs = [np.empty((H, W), np.float32) for _ in images]
    for y0 in range(0, H, STRIP_ROWS):
        y1 = min(y0 + STRIP_ROWS, H)
        lo, hi = max(0, y0 - r), min(H, y1 + r)  # the strip and the rows its window reaches
        xb = tb[:, lo:hi]
        reference = np.empty((2, C, hi - lo, W), np.float32)  # b, b²; filtered in place
        reference[0] = xb
        np.multiply(xb, xb, out=reference[1])
        correlate1d(correlate1d(reference, g, axis=3, mode=mode), g, axis=2, mode=mode, output=reference)
        mu_b, var_b = reference[:, :, y0 - lo:y1 - lo]
        square_b = np.square(mu_b)
        var_b -= square_b  # made central
        for ta, out in zip(tas, outs):
            xa = ta[:, lo:hi]
            stack = np.empty((3, C, hi - lo, W), np.float32)  # a, a², ab; filtered in place
            stack[0] = xa
            np.multiply(xa, xa, out=stack[1])
            np.multiply(xa, xb, out=stack[2])
            correlate1d(correlate1d(stack, g, axis=3, mode=mode), g, axis=2, mode=mode, output=stack)
            mu_a, var_a, cov = stack[:, :, y0 - lo:y1 - lo]  # moments, made central below
            # in place, in float32 (half the time of the textbook expression's temporaries)
            num = mu_a * mu_b
            var_a -= np.square(mu_a, out=mu_a)
            cov -= num
            num *= 2
            num += C1
            num *= 2 * cov + C2  # (2 mu_a mu_b + C1)(2 cov + C2)
            den = mu_a
            den += square_b
            den += C1
            den *= var_a + var_b + C2  # (mu_a² + mu_b² + C1)(var_a + var_b + C2)
            out[y0:y1] = (num / den).mean(0)
    return outs


def ssim(a: np.ndarray, b: np.ndarray, mask: np.ndarray | None = None) -> float:
    """Mean SSIM over ``mask`` (all pixels when ``None``)."""
    m = ssim_map(a, b)
    return float(m[mask].mean() if mask is not None else m.mean())
