"""Texture images in and out, with errors that name the file."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from scantex.errors import ScanError


def read_image(path: str | Path) -> np.ndarray:
    """``(H, W, 3) uint8`` RGB of an image file (alpha dropped: scan textures are opaque)."""
    from PIL import Image, UnidentifiedImageError

    path = Path(path)
    if not path.is_file():
        raise ScanError(path, "texture file not found")
    # scan atlases reach 16k x 16k; Pillow's decompression-bomb guard stops at ~89 Mpx
    Image.MAX_IMAGE_PIXELS = max(Image.MAX_IMAGE_PIXELS or 0, 16384 * 16384 + 1)
    try:
        with Image.open(path) as im:
            return np.asarray(im.convert("RGB"))
    except UnidentifiedImageError:
        raise ScanError(path, "texture is not an image Pillow can read") from None
    except (OSError, SyntaxError, ValueError) as e:
        raise ScanError(path, f"texture image is damaged or truncated ({e})") from None


def image_from_pil(image, where) -> np.ndarray:
    try:
        return np.asarray(image.convert("RGB"))
    except (OSError, SyntaxError, ValueError) as e:
        raise ScanError(where, f"embedded texture image is damaged ({e})") from None


#: zlib level of the PNGs written: 1 encodes an 8192^2 atlas several times faster than the default 6 for
#: files about 10 % larger (bench/bench_io.py)
PNG_COMPRESS_LEVEL = 1

#: ``id(image) -> (image, PNG bytes)``: lets the OBJ and the GLB of one output share one encoding (the
#: image is held so that its id is not reused while the cache lives)
PngCache = dict


def png_bytes(image: np.ndarray, cache: PngCache | None = None) -> bytes:
    """``image (H, W, C) uint8`` as PNG file bytes; with ``cache``, each image is encoded once."""
    import io

    from PIL import Image

    if cache is not None and id(image) in cache:
        return cache[id(image)][1]
    buffer = io.BytesIO()
    Image.fromarray(np.ascontiguousarray(image)).save(buffer, format="PNG", compress_level=PNG_COMPRESS_LEVEL)
    data = buffer.getvalue()
    if cache is not None:
        cache[id(image)] = (image, data)
    return data


def write_png(path: str | Path, image: np.ndarray, cache: PngCache | None = None) -> None:
    Path(path).write_bytes(png_bytes(image, cache))
