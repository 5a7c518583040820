"""Self-supervised pretext tasks made from the scan's own views: masks to complete, and the downscale +
blur + compression to undo (internal super-resolution), plus the smooth fill that stands in for
missing pixels.

All functions take and return ``(B, C, H, W)`` float tensors in [0, 1] and draw from an explicit
``torch.Generator``; random draws are made on the generator's device (the CPU in training, so a
seed gives the same corruption on any device) and moved to the images'.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F


def random_masks(batch: int, height: int, width: int, share: float, patch: int,
                 generator: torch.Generator) -> torch.Tensor:
    """``(B, 1, H, W) bool`` regions to mask: half of ``share`` as whole patches, half as irregular blobs.

    Whole patches are the paper's masked-patch experiment; blobs (a thresholded smooth random field)
    look like the holes and occlusions the refiner has to fill in a real scan.
    """
    rows, cols = max(1, height // patch), max(1, width // patch)
    patches = torch.rand(batch, 1, rows, cols, generator=generator, device=generator.device) < share / 2
    patches = F.interpolate(patches.float(), size=(height, width), mode="nearest") > 0.5
    coarse = torch.rand(batch, 1, max(2, height // (2 * patch)) + 1, max(2, width // (2 * patch)) + 1,
                        generator=generator, device=generator.device)
    field = F.interpolate(coarse, size=(height, width), mode="bicubic", align_corners=True)
    level = torch.quantile(field.flatten(1), 1 - share / 2, dim=1).reshape(batch, 1, 1, 1)
    return patches | (field > level)


def smooth_fill(x: torch.Tensor, known: torch.Tensor, levels: int = 6) -> torch.Tensor:
    """``x`` with pixels where ``known (B, 1, H, W)`` is False replaced by a smooth colour from around them.

    Pull-push over a pyramid (Gortler et al., "The Lumigraph", 1996): known pixels are averaged down by
    halves ``levels`` times; then, coarsest first, each level's empty cells take the bilinear upsample of
    the level below, so a missing pixel gets the mean of the known pixels in the finest cell (2, 4, 8, ...
    pixels wide) that has any, blended smoothly, as a harmonic fill looks from a distance. Cells that no
    level reaches take the image's mean known colour. Work: about 4/3 of one pass over the image.
    """
    B, C, H, W = x.shape
    w = known.to(x.dtype)
    pyramid = [torch.cat([x * w, w], dim=1)]  # (sum of colour, weight) per cell: a pull step is a 2x2 mean
    for _ in range(levels):
        if max(pyramid[-1].shape[-2:]) <= 1:
            break
        pyramid.append(F.avg_pool2d(pyramid[-1], 2, stride=2, ceil_mode=True))
    global_mean = pyramid[0][:, :C].sum(dim=(2, 3), keepdim=True) / w.sum(dim=(2, 3), keepdim=True).clamp_min(1)
    top = pyramid[-1]
    value = torch.where(top[:, C:] > 0, top[:, :C] / top[:, C:].clamp_min(1e-12), global_mean)
    for level in reversed(pyramid[:-1]):
        h, w_ = level.shape[-2:]
        up = F.interpolate(value, scale_factor=2, mode="bilinear", align_corners=False)[..., :h, :w_]
        value = torch.where(level[:, C:] > 0, level[:, :C] / level[:, C:].clamp_min(1e-12), up)
    return torch.where(known, x, value)


def _dct_matrix(n: int = 8, device: torch.device | str = "cpu") -> torch.Tensor:
    k = torch.arange(n, dtype=torch.float32, device=device)
    m = torch.cos(math.pi * (2 * k[None, :] + 1) * k[:, None] / (2 * n)) * math.sqrt(2 / n)
    m[0] /= math.sqrt(2)
    return m


#: the JPEG standard's luminance and chrominance quantisation tables (quality 50)
_LUMA = torch.tensor([
    [16, 11, 10, 16, 24, 40, 51, 61], [12, 12, 14, 19, 26, 58, 60, 55], [14, 13, 16, 24, 40, 57, 69, 56],
    [14, 17, 22, 29, 51, 87, 80, 62], [18, 22, 37, 56, 68, 109, 103, 77], [24, 35, 55, 64, 81, 104, 113, 92],
    [49, 64, 78, 87, 103, 121, 120, 101], [72, 92, 95, 98, 112, 100, 103, 99]], dtype=torch.float32)
_CHROMA = torch.full((8, 8), 99.0)
_CHROMA[:4, :4] = torch.tensor([[17, 18, 24, 47], [18, 21, 26, 66], [24, 26, 56, 99], [47, 66, 99, 99]],
                               dtype=torch.float32)


def jpeg_like(x: torch.Tensor, quality: torch.Tensor) -> torch.Tensor:
    """An approximation of JPEG: YCbCr, 8x8 block DCT quantised with the standard tables at ``quality (B,)``.

    No chroma subsampling or entropy coding (they do not change what a decoder shows beyond this).
    ``H`` and ``W`` are padded to multiples of 8 internally.
    """
    B, C, H, W = x.shape
    ph, pw = -H % 8, -W % 8
    xp = F.pad(x, (0, pw, 0, ph), mode="replicate") * 255
    r, g, b = xp[:, 0], xp[:, 1], xp[:, 2]
    ycc = torch.stack([0.299 * r + 0.587 * g + 0.114 * b - 128,
                       -0.168736 * r - 0.331264 * g + 0.5 * b,
                       0.5 * r - 0.418688 * g - 0.081312 * b], dim=1)
    Hp, Wp = H + ph, W + pw
    blocks = ycc.reshape(B, 3, Hp // 8, 8, Wp // 8, 8).permute(0, 1, 2, 4, 3, 5)  # [B, 3, h, w, 8, 8]
    D = _dct_matrix(device=x.device).to(x.dtype)
    q = quality.to(x.dtype).clamp(1, 100).reshape(B, 1, 1, 1, 1, 1)
    scale = torch.where(q < 50, 5000 / q, 200 - 2 * q) / 100
    tables = torch.stack([_LUMA, _CHROMA, _CHROMA]).to(x.device, x.dtype).reshape(1, 3, 1, 1, 8, 8)
    step = (tables * scale).clamp_min(1)
    coeff = D @ blocks @ D.T
    blocks = D.T @ (torch.round(coeff / step) * step) @ D
    ycc = blocks.permute(0, 1, 2, 4, 3, 5).reshape(B, 3, Hp, Wp)
    y, cb, cr = ycc[:, 0] + 128, ycc[:, 1], ycc[:, 2]
    rgb = torch.stack([y + 1.402 * cr, y - 0.344136 * cb - 0.714136 * cr, y + 1.772 * cb], dim=1)
    return (rgb / 255).clamp(0, 1)[..., :H, :W]


def gaussian_blur(x: torch.Tensor, sigma: torch.Tensor) -> torch.Tensor:
    """Separable Gaussian blur with a per-image ``sigma (B,)`` in pixels."""
    B, C, H, W = x.shape
    radius = max(1, int(math.ceil(3 * float(sigma.max()))))
    t = torch.arange(-radius, radius + 1, dtype=x.dtype, device=x.device)
    k = torch.exp(-0.5 * (t[None, :] / sigma.to(x.dtype).clamp_min(1e-3)[:, None]) ** 2)
    k = k / k.sum(dim=1, keepdim=True)  # [B, 2r + 1]
    xp = F.pad(x, (radius, radius, radius, radius), mode="replicate").reshape(1, B * C, H + 2 * radius, -1)
    kh = k.repeat_interleave(C, 0)[:, None, None, :]  # [B * C, 1, 1, 2r + 1]
    xp = F.conv2d(xp, kh, groups=B * C)
    xp = F.conv2d(xp, kh.transpose(2, 3), groups=B * C)
    return xp.reshape(B, C, H, W)


def downscale_blur_compress(x: torch.Tensor, factor: float, generator: torch.Generator) -> torch.Tensor:
    """What a lower-resolution capture of ``x`` looks like at ``x``'s pixel grid.

    Blur (sigma 0.3-1.2 low-resolution pixels), area downscale by ``factor``, JPEG-like compression at a
    quality of 30-90, bilinear upscale back: the refiner learns to undo this and is then applied to
    views rendered ``factor`` times finer than the ones it learned on (internal super-resolution).
    """
    B, C, H, W = x.shape
    sigma = (0.3 + 0.9 * torch.rand(B, generator=generator, device=generator.device)) * factor
    small = F.interpolate(gaussian_blur(x, sigma.to(x.device)), size=(max(1, round(H / factor)), max(1, round(W / factor))),
                          mode="area")
    quality = 30 + 60 * torch.rand(B, generator=generator, device=generator.device)
    small = jpeg_like(small, quality.to(x.device))
    return F.interpolate(small, size=(H, W), mode="bilinear", align_corners=False)
