"""Image helpers: box downscaling, images of any depth read as 8-bit RGB."""

from __future__ import annotations

import numpy as np
import pytest
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


@pytest.mark.parametrize("mode", ["I;16", "I", "F"])
def test_deep_greyscale_images_are_scaled_to_8_bits(tmp_path, mode):
    """A 16-bit greyscale PNG texture (or photo) was read white all over: Pillow's RGB conversion clips its
    levels at 255. Its levels are scaled down instead (65535 -> 255), a float image's [0, 1] up."""
    from PIL import Image

    from scantex.io.images import read_image, rgb8

    ramp = np.linspace(0, 1, 64 * 32).reshape(32, 64)
    if mode == "F":
        image = Image.fromarray(ramp.astype(np.float32), mode="F")
    else:
        image = Image.fromarray(np.rint(ramp * 65535).astype(np.uint16))  # I;16
        if mode == "I":
            image = image.convert("I")
    want = np.rint(ramp * 255).astype(np.uint8)
    got = rgb8(image)
    assert got.shape == (32, 64, 3) and np.abs(got.astype(int) - want[..., None]).max() <= 1
    if mode == "I;16":
        image.save(tmp_path / "t.png")  # a 16-bit greyscale PNG
        assert np.abs(read_image(tmp_path / "t.png").astype(int) - want[..., None]).max() <= 1
