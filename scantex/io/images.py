"""Texture images in and out, with errors that name the file.

Every image scantex reads (textures, photos, depth maps) is opened through :func:`open_image`, which
checks the size the file's header claims before anything is decoded: a few hundred bytes of PNG can
claim 100000 x 100000 pixels (a decompression bomb) and would otherwise ask for tens of GB.
"""

from __future__ import annotations

import contextlib
from pathlib import Path

import numpy as np

from scantex.errors import ScanError

#: largest image accepted, in pixels: a 16k x 16k atlas (scan atlases reach 16k; photos are far smaller)
MAX_IMAGE_PIXELS = 16384 * 16384


def check_image_size(image, where, what: str = "image") -> None:
    """Refuse an opened (not yet decoded) Pillow image whose header claims more than
    :data:`MAX_IMAGE_PIXELS` pixels, or no pixels at all."""
    w, h = image.size
    if w <= 0 or h <= 0:
        raise ScanError(where, f"{what} has no pixels ({w}x{h})")
    if w * h > MAX_IMAGE_PIXELS:
        raise ScanError(where, f"{what} claims {w}x{h} pixels, more than scantex reads "
                               f"({MAX_IMAGE_PIXELS:,} pixels: a 16384x16384 atlas)")


@contextlib.contextmanager
def open_image(path: str | Path, what: str = "image"):
    """``with open_image(path, "texture") as im:`` a Pillow image whose size was checked; errors while
    opening or decoding inside the block become one-line :class:`ScanError` naming the file."""
    from PIL import Image, UnidentifiedImageError

    path = Path(path)
    if not path.is_file():
        raise ScanError(path, f"{what} file not found")
    # our own limit is checked below from the header; Pillow's guard would stop at ~89 Mpx
    Image.MAX_IMAGE_PIXELS = max(Image.MAX_IMAGE_PIXELS or 0, MAX_IMAGE_PIXELS + 1)
    try:
        im = _opened(path)
    except UnidentifiedImageError:
        raise ScanError(path, f"{what} is not an image Pillow can read") from None
    except Image.DecompressionBombError:
        raise ScanError(path, f"{what} claims more pixels than scantex reads") from None
    except (OSError, SyntaxError, ValueError) as e:
        raise ScanError(path, f"cannot read the {what} ({_first_line(e)})") from None
    try:
        with im:
            check_image_size(im, path, what)
            yield im
    except Image.DecompressionBombError:
        raise ScanError(path, f"{what} claims more pixels than scantex reads") from None
    except (OSError, SyntaxError, ValueError, EOFError) as e:
        raise ScanError(path, f"{what} is damaged or truncated ({_first_line(e)})") from None


@contextlib.contextmanager
def decoded(data: bytes, where, what: str = "image"):
    """``with decoded(data, path, "embedded texture image 0") as im:`` a Pillow image of the encoded bytes
    ``data`` (an image inside a GLB or a USDZ), its size checked before it is decoded; an image Pillow cannot
    decode is a one-line :class:`ScanError` naming ``where``."""
    import io

    from PIL import Image

    Image.MAX_IMAGE_PIXELS = max(Image.MAX_IMAGE_PIXELS or 0, MAX_IMAGE_PIXELS + 1)  # ours is checked below
    try:
        im = _opened(io.BytesIO(data))
        check_image_size(im, where, what)
        im.load()
    except ScanError:
        raise
    except Image.DecompressionBombError:
        raise ScanError(where, f"{what} claims more pixels than scantex reads") from None
    except Exception as e:  # Pillow raises OSError, SyntaxError, ValueError...
        raise ScanError(where, f"{what} cannot be decoded ({type(e).__name__}: {_first_line(e)[:80]})") from None
    with im:
        yield im


def _opened(source):
    """``Image.open(source)`` without Pillow's warning for an image over its own size guard: scantex's check
    (:func:`check_image_size`) follows at once and says what is wrong in its one line."""
    import warnings

    from PIL import Image

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", Image.DecompressionBombWarning)
        return Image.open(source)


def _first_line(e: BaseException) -> str:
    text = str(e).strip()
    return text.splitlines()[0][:120] if text else type(e).__name__


def rgb8(im) -> np.ndarray:
    """``(H, W, 3) uint8`` RGB of a Pillow image of any mode. Pillow's own conversion clips a 16-bit greyscale
    image (modes ``I;16``, ``I``) at 255, all but its darkest levels white; it is scaled down to 8 bits here,
    and a float image (``F``) read as [0, 1] where it lies there, else as 8-bit levels."""
    if im.mode.startswith("I") or im.mode == "F":
        levels = np.asarray(im, dtype=np.float64)
        if im.mode.startswith("I"):
            levels = levels / 257.0  # 65535 -> 255
        elif levels.size and np.nanmax(levels) <= 1.0:
            levels = levels * 255.0
        grey = np.rint(np.clip(np.nan_to_num(levels), 0, 255)).astype(np.uint8)
        return np.repeat(grey[..., None], 3, axis=2)
    return np.asarray(im.convert("RGB"))


def read_image(path: str | Path) -> np.ndarray:
    """``(H, W, 3) uint8`` RGB of an image file (alpha dropped: scan textures are opaque)."""
    with open_image(path, "texture") as im:
        return rgb8(im)


def image_from_pil(image, where) -> np.ndarray:
    from PIL import Image

    check_image_size(image, where, "embedded texture image")
    try:
        return rgb8(image)
    except Image.DecompressionBombError:
        raise ScanError(where, "embedded texture image claims more pixels than scantex reads") from None
    except (OSError, SyntaxError, ValueError, EOFError) as e:
        raise ScanError(where, f"embedded texture image is damaged ({_first_line(e)})") from None


def box_downscaled(image: np.ndarray, width: int, height: int) -> np.ndarray:
    """``image (H, W, C) uint8`` reduced to ``width x height`` by a box filter (each pixel the mean of the ones it
    covers). Where both sides shrink by one whole factor (a 1920x1080 photo at 640x360), Pillow's ``reduce``:
    3-4x faster than its BOX resize (13 -> 3 ms there), and as close to the blocks' true means (within 0.56 of a
    level on random pixels, the BOX resize 0.67); the two differ by one level at most."""
    from PIL import Image

    picture = Image.fromarray(np.ascontiguousarray(image))
    H, W = image.shape[:2]
    factor = W // width if width else 0
    if factor > 1 and W == factor * width and H == factor * height:
        return np.asarray(picture.reduce(factor))
    return np.asarray(picture.resize((width, height), Image.Resampling.BOX))


#: zlib level of the PNGs written: 1 encodes an 8192^2 atlas several times faster than the default 6 for
#: files about 10 % larger (bench/bench_io.py)
PNG_COMPRESS_LEVEL = 1

#: the formats a colour texture can be written in (:class:`TextureEncoder`)
TEXTURE_FORMATS = ("png", "jpeg")


class TextureEncoder:
    """How a scan's colour textures are written, and each image's bytes once encoded: the OBJ's texture and
    the GLB's embedded one are the same bytes, encoded once.

    ``png`` (the default) is lossless. ``jpeg`` at ``quality`` (1-100, chroma kept at full resolution) makes
    a file several times smaller (the bathroom's 8192² atlas: see bench/RESULTS.md), at the cost of the
    codec's loss, which :meth:`jpeg_psnr` measures; an image with transparency stays PNG (JPEG has no alpha).
    A material's other maps without bytes of their own are always PNG (:meth:`png`): a normal map's
    directions do not survive JPEG well.
    """

    def __init__(self, format: str = "png", quality: int = 90) -> None:  # noqa: A002 (Pillow's word)
        if format not in TEXTURE_FORMATS:
            raise ValueError(f"texture format {format!r} is none of {', '.join(TEXTURE_FORMATS)}")
        if not 1 <= quality <= 100:
            raise ValueError(f"JPEG quality {quality} is not from 1 to 100")
        self.format, self.quality = format, quality
        # (id(image), format) -> (image, bytes), id(image) -> (image, opaque): each image is held so that its
        # id is not reused while it is remembered
        self._encoded: dict[tuple[int, str], tuple[np.ndarray, bytes]] = {}
        self._opaque: dict[int, tuple[np.ndarray, bool]] = {}

    def colour(self, image: np.ndarray) -> bytes:
        """``image (H, W, C) uint8``, a colour texture, as file bytes in this encoder's format."""
        return self._bytes(image, "jpeg" if self.writes_jpeg(image) else "png")

    def png(self, image: np.ndarray) -> bytes:
        """``image`` as PNG file bytes, whatever the format (a material's other maps)."""
        return self._bytes(image, "png")

    def suffix(self, image: np.ndarray) -> str:
        """The file suffix of :meth:`colour` of ``image``: ``jpg`` or ``png``."""
        return "jpg" if self.writes_jpeg(image) else "png"

    def writes_jpeg(self, image: np.ndarray) -> bool:
        """Whether :meth:`colour` writes ``image`` as a JPEG: the format is ``jpeg`` and the image has no
        transparency (grey, RGB, or an alpha channel that is all opaque)."""
        if self.format != "jpeg":
            return False
        if image.ndim == 2 or image.shape[2] in (1, 3):
            return True
        if image.shape[2] != 4:
            return False
        if id(image) not in self._opaque:
            self._opaque[id(image)] = (image, bool((image[..., 3] == 255).all()))
        return self._opaque[id(image)][1]

    def jpeg_psnr(self, image: np.ndarray) -> float | None:
        """PSNR (dB) of :meth:`colour` of ``image`` decoded, against ``image``'s colour channels; ``None`` where
        it is written as PNG (lossless)."""
        if not self.writes_jpeg(image):
            return None
        decoded = _decode(self.colour(image))
        colour = image if image.ndim == 2 else image[..., :min(image.shape[2], 3)]
        decoded = decoded.reshape(colour.shape)
        squares = 0
        for y in range(0, len(colour), 256):  # in blocks of rows: an 8192² atlas as int32 whole would be 0.8 GB
            diff = decoded[y:y + 256].astype(np.int32) - colour[y:y + 256]
            squares += int(np.square(diff).sum(dtype=np.int64))
        mse = squares / colour.size
        return float("inf") if mse == 0 else float(10 * np.log10(255.0 ** 2 / mse))

    def _bytes(self, image: np.ndarray, format: str) -> bytes:  # noqa: A002
        import io

        from PIL import Image

        key = (id(image), format)
        if key in self._encoded:
            return self._encoded[key][1]
        buffer = io.BytesIO()
        pixels = np.ascontiguousarray(image)
        if format == "png":
            Image.fromarray(pixels).save(buffer, format="PNG", compress_level=PNG_COMPRESS_LEVEL)
        else:
            if pixels.ndim == 3 and pixels.shape[2] == 1:
                pixels = pixels[..., 0]
            elif pixels.ndim == 3 and pixels.shape[2] == 4:
                pixels = np.ascontiguousarray(pixels[..., :3])
            Image.fromarray(pixels).save(buffer, format="JPEG", quality=self.quality, subsampling=0)
        data = buffer.getvalue()
        self._encoded[key] = (image, data)
        return data


def _decode(data: bytes) -> np.ndarray:
    import io

    from PIL import Image

    return np.asarray(Image.open(io.BytesIO(data)))


def png_bytes(image: np.ndarray) -> bytes:
    """``image (H, W, C) uint8`` as PNG file bytes (zlib at :data:`PNG_COMPRESS_LEVEL`)."""
    return TextureEncoder().png(image)
