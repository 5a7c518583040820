"""Gutter padding: fill the texels no chart covers from the nearest covered texel.

Bilinear filtering and mip-mapping read texels just outside a chart; left black, they draw dark lines
along every seam. Filling all uncovered texels with their nearest chart colour (a Euclidean distance
transform) removes that for every mip level.
"""

from __future__ import annotations

import numpy as np

#: rows filled at a time (the gathered texels of one strip are the only temporary the size of the image)
ROWS_PER_STRIP = 512


def gutter_sources(covered: np.ndarray) -> np.ndarray | None:
    """Each texel's nearest texel in ``covered (H, W) bool``, as a flat index ``y * W + x`` (``(H, W) int32``:
    0.27 GB at 8192^2, half of the transform's row and column pair), for :func:`fill_gutters`; ``None`` when
    nothing or everything is covered (nothing to fill)."""
    from scipy.ndimage import distance_transform_edt

    if covered.all() or not covered.any():
        return None
    iy, ix = distance_transform_edt(~covered, return_distances=False, return_indices=True)
    if covered.size >= 2**31:
        iy = iy.astype(np.int64)
    iy *= covered.shape[1]
    iy += ix
    return iy


def fill_gutters(image: np.ndarray, covered: np.ndarray, sources: np.ndarray | None = None) -> None:
    """Set, in place, every texel of ``image (H, W, C)`` outside ``covered (H, W) bool`` to its nearest covered texel.

    ``sources``: :func:`gutter_sources` of ``covered``, when a bake of the same atlas has them already.
    Memory: the distance transform's nearest-texel indices (0.5 GB at 8192^2 while it runs, half that kept)
    and one strip; no distances and no second image. In place is safe: only covered texels are read.
    """
    if sources is None:
        sources = gutter_sources(covered)
        if sources is None:
            return
    if not image.flags.c_contiguous:  # a view (an RGBA atlas's colour channels): texel by row and column
        W = covered.shape[1]
        for y0 in range(0, image.shape[0], ROWS_PER_STRIP):
            gap = ~covered[y0:y0 + ROWS_PER_STRIP]
            nearest = sources[y0:y0 + ROWS_PER_STRIP][gap]
            image[y0:y0 + ROWS_PER_STRIP][gap] = image[nearest // W, nearest % W]
        return
    # each texel's channels as one opaque element, the texels by flat index: a gather of whole texels, without
    # dividing indices into rows and columns (an 8192^2 atlas 83 % gutter: 3.2 -> 1.1 s)
    texels = image.reshape(-1).view(np.dtype((np.void, image.itemsize * image.shape[2])))
    inside, nearest = covered.reshape(-1), sources.reshape(-1)
    step = covered.shape[1] * ROWS_PER_STRIP
    for start in range(0, len(inside), step):
        at = np.flatnonzero(~inside[start:start + step]) + start
        texels[at] = texels[np.take(nearest, at)]


def pad_gutters(image: np.ndarray, covered: np.ndarray) -> np.ndarray:
    """``image (H, W, C)`` with every texel outside ``covered (H, W) bool`` set to its nearest covered texel."""
    if covered.all() or not covered.any():
        return image
    out = image.copy()
    fill_gutters(out, covered)
    return out
