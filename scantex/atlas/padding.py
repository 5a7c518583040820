"""Gutter padding: fill the texels no chart covers from the nearest covered texel.

Bilinear filtering and mip-mapping read texels just outside a chart; left black, they draw dark lines
along every seam. Filling all uncovered texels with their nearest chart colour (a Euclidean distance
transform) removes that for every mip level.
"""

from __future__ import annotations

import numpy as np


def pad_gutters(image: np.ndarray, covered: np.ndarray) -> np.ndarray:
    """``image (H, W, C)`` with every texel outside ``covered (H, W) bool`` set to its nearest covered texel."""
    from scipy.ndimage import distance_transform_edt

    if covered.all() or not covered.any():
        return image
    _, (iy, ix) = distance_transform_edt(~covered, return_indices=True)
    return image[iy, ix]
