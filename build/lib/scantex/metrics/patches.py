"""The patch measure: low-frequency colour changes with an edge where the reference has none.

A texture pipeline that switches between colour sources face by face (a field here, the input there), or
corrects one region's exposure and not its neighbour's, paints patches: areas a few percent lighter or
darker than their surroundings, with a hard border. PSNR barely moves (the patch is faint), seam
visibility does not see it (the border is not on a UV seam), yet a person sees it at once.

What tells a patch from a legitimate correction is the *edge*: a global exposure change or a smooth
gradient adds no edge, a hard-edged blob does. So both images are reduced to low-pass log-luminance
(``sigma`` px: texture detail and noise vanish, exposure stays; log: a gain is an offset) and their
local gradient energies compared (the squared gradient averaged over ``sigma``: a texture's own gradients
and a step's add up in energy, so a busy texture masks a faint step, as it does for the eye); a pixel
counts as a patch pixel where the root energy of the image exceeds the reference's by more than
``threshold`` (in log units per ``sigma``: 0.01 is about what a 3 % step adds next to its edge). The score
is the share of counted pixels among the usable ones (those more than ``3 sigma`` inside the mask).

Removing an edge the reference has (a levelled exposure seam) never counts. Calibrated in the tests: a
pasted hard-edged +8 % blob scores high, a global +8 % exposure change and a smooth gradient score 0.
"""

from __future__ import annotations

import numpy as np

#: default low-pass scale, as a share of the image's shorter side (at least 2 px)
SIGMA_SHARE = 0.02
#: default threshold: low-frequency log-luminance gradient (per sigma) beyond the reference's
THRESHOLD = 0.01


def _lowpass_log_luminance(image: np.ndarray, mask: np.ndarray, sigma: float) -> np.ndarray:
    """Normalised-convolution Gaussian low-pass of log luminance over ``mask`` (pixels outside do not
    leak in: a silhouette is no edge of the texture)."""
    from scipy import ndimage

    lum = image[..., :3] @ np.array([0.2126, 0.7152, 0.0722])
    log_lum = np.log(np.clip(lum, 0, None) + 0.02)
    m = mask.astype(np.float64)
    num = ndimage.gaussian_filter(np.where(mask, log_lum, 0.0), sigma, mode="constant")
    den = ndimage.gaussian_filter(m, sigma, mode="constant")
    return num / np.maximum(den, 1e-6)


def patch_map(image: np.ndarray, reference: np.ndarray, mask: np.ndarray | None = None, *,
              sigma: float | None = None, threshold: float = THRESHOLD) -> tuple[np.ndarray, np.ndarray]:
    """``(patch, usable)``, both ``(H, W) bool``: the patch pixels and the pixels that were judged.

    Args:
        image, reference: ``(H, W, 3)`` colour images in [0, 1] of the same view.
        mask: ``(H, W) bool`` pixels showing the surface (default: all); pixels within ``3 sigma`` of its
            border are not judged.
        sigma: low-pass scale in pixels (default ``SIGMA_SHARE`` of the shorter side, at least 2).
        threshold: see the module docstring.
    """
    from scipy import ndimage

    if image.shape != reference.shape:
        raise ValueError(f"image {image.shape} and reference {reference.shape} differ in shape")
    H, W = image.shape[:2]
    mask = np.ones((H, W), bool) if mask is None else mask.astype(bool)
    sigma = max(2.0, SIGMA_SHARE * min(H, W)) if sigma is None else float(sigma)
    a = _lowpass_log_luminance(image, mask, sigma)
    b = _lowpass_log_luminance(reference, mask, sigma)
    # local gradient energy (squared gradient averaged over the same scale): a texture's own gradients
    # and a step's add in energy, so an edge taken away never counts and a busy texture masks a faint step
    energy_a = ndimage.gaussian_filter(sum(g**2 for g in np.gradient(a)), sigma) * sigma**2
    energy_b = ndimage.gaussian_filter(sum(g**2 for g in np.gradient(b)), sigma) * sigma**2
    usable = ndimage.binary_erosion(mask, iterations=max(1, round(3 * sigma)))
    return usable & (np.sqrt(energy_a) - np.sqrt(energy_b) > threshold), usable


def patch_score(image: np.ndarray, reference: np.ndarray, mask: np.ndarray | None = None, *,
                sigma: float | None = None, threshold: float = THRESHOLD) -> float:
    """Share of judged pixels (0-1) where ``image`` has a low-frequency edge ``reference`` lacks."""
    patch, usable = patch_map(image, reference, mask, sigma=sigma, threshold=threshold)
    n = int(usable.sum())
    return float(patch.sum() / n) if n else 0.0
