"""Image helpers: box downscaling."""

from __future__ import annotations

import numpy as np
from PIL import Image

from scantex.io.images import box_downscaled


def test_box_downscaling_takes_each_blocks_mean_by_a_whole_factor_or_not():
    image = np.random.default_rng(0).integers(0, 256, (60, 90, 3), dtype=np.uint8)
    # a whole factor (Pillow's reduce): every pixel its 3x3 block's mean, to within one level of rounding
    small = box_downscaled(image, 30, 20)
    means = image.reshape(20, 3, 30, 3, 3).astype(np.float64).mean(axis=(1, 3))
    assert small.shape == (20, 30, 3) and small.dtype == np.uint8
    assert np.abs(small - means).max() < 1
    # within one level of Pillow's BOX resize, which the other sizes take
    boxed = np.asarray(Image.fromarray(image).resize((30, 20), Image.Resampling.BOX))
    assert np.abs(small.astype(int) - boxed).max() <= 1
    odd = box_downscaled(image, 40, 27)
    assert np.array_equal(odd, np.asarray(Image.fromarray(image).resize((40, 27), Image.Resampling.BOX)))
