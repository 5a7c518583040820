"""The paper's Vision Transformer refiner, in plain ``torch.nn``.

Patch embedding (``p x p x C`` values per patch, linearly projected to the model width), learned
positional embeddings (interpolated for other grid sizes), a pre-norm transformer encoder (multi-head
self-attention through ``scaled_dot_product_attention``, then an MLP), and a head that maps every token
back to pixels as a residual over the input view.

The head departs from a plain "one token -> its own p x p block" un-patchify: each token predicts a
``2p x 2p`` window centred on its patch, and the windows are overlap-added with a Hann weight (a
partition of unity at stride p). Neighbouring tokens then share every pixel near their common border,
so the output has no blocky seams on the patch grid, the "jagged transitions" a ViT for dense
prediction is known for. The head starts at zero: an untrained refiner is the identity.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import nn

#: model sizes: tiny for CPU, small and base for a GPU
PRESETS: dict[str, dict] = {
    "tiny": {"width": 128, "depth": 4, "heads": 4, "mlp_ratio": 2.0},
    "small": {"width": 256, "depth": 6, "heads": 8, "mlp_ratio": 4.0},
    "base": {"width": 384, "depth": 8, "heads": 6, "mlp_ratio": 4.0},
}


class EncoderBlock(nn.Module):
    """Pre-norm transformer block: ``x + MHSA(LN(x))``, then ``x + MLP(LN(x))``."""

    def __init__(self, width: int, heads: int, mlp_ratio: float):
        super().__init__()
        if width % heads:
            raise ValueError(f"width {width} is not divisible by {heads} heads")
        self.heads = heads
        self.norm1 = nn.LayerNorm(width)
        self.qkv = nn.Linear(width, 3 * width)
        self.proj = nn.Linear(width, width)
        self.norm2 = nn.LayerNorm(width)
        hidden = int(width * mlp_ratio)
        self.mlp = nn.Sequential(nn.Linear(width, hidden), nn.GELU(), nn.Linear(hidden, width))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        B, L, D = x.shape
        qkv = self.qkv(self.norm1(x)).reshape(B, L, 3, self.heads, D // self.heads)
        q, k, v = qkv.permute(2, 0, 3, 1, 4)  # each [B, heads, L, D / heads]
        attn = F.scaled_dot_product_attention(q, k, v)
        x = x + self.proj(attn.transpose(1, 2).reshape(B, L, D))
        return x + self.mlp(self.norm2(x))


def hann_window(size: int, device: torch.device | str = "cpu") -> torch.Tensor:
    """``(size, size)`` separable sin² window; shifted by ``size / 2`` its copies sum to 1."""
    w = torch.sin(math.pi * (torch.arange(size, dtype=torch.float32, device=device) + 0.5) / size) ** 2
    return w[:, None] * w[None, :]


class ViTRefiner(nn.Module):
    """Refines an image: ``output = input RGB + residual``.

    Args:
        width: token width after the linear projection of each patch.
        depth: transformer blocks.
        heads: attention heads.
        mlp_ratio: MLP hidden width over ``width``.
        patch: patch side ``p`` in pixels.
        in_channels: input channels: RGB first, then extras (e.g. a mask of pixels to fill).
        grid: ``(rows, cols)`` of patches the positional embedding is learned at (the training crop).

    Input ``x``: ``(B, in_channels, H, W)`` with ``H, W`` multiples of ``p``; output ``(B, 3, H, W)``.
    """

    def __init__(self, width: int = 128, depth: int = 4, heads: int = 4, mlp_ratio: float = 2.0, *,
                 patch: int = 16, in_channels: int = 4, grid: tuple[int, int] = (6, 6)):
        super().__init__()
        if patch % 2:
            raise ValueError(f"the patch side must be even, got {patch}")
        self.patch = patch
        self.in_channels = in_channels
        self.embed = nn.Linear(in_channels * patch * patch, width)
        self.pos = nn.Parameter(torch.zeros(1, width, *grid))
        nn.init.trunc_normal_(self.pos, std=0.02)
        self.blocks = nn.ModuleList(EncoderBlock(width, heads, mlp_ratio) for _ in range(depth))
        self.norm = nn.LayerNorm(width)
        self.head = nn.Linear(width, 3 * (2 * patch) ** 2)
        nn.init.zeros_(self.head.weight)
        nn.init.zeros_(self.head.bias)
        self.register_buffer("window", hann_window(2 * patch), persistent=False)

    @classmethod
    def preset(cls, name: str, **kwargs) -> ViTRefiner:
        if name not in PRESETS:
            raise ValueError(f"unknown refiner size '{name}' (choose from {', '.join(PRESETS)})")
        return cls(**PRESETS[name], **kwargs)

    def positional(self, rows: int, cols: int) -> torch.Tensor:
        """``(1, rows * cols, width)`` positional embedding, interpolated when the grid differs."""
        pos = self.pos
        if pos.shape[-2:] != (rows, cols):
            pos = F.interpolate(pos, size=(rows, cols), mode="bicubic", align_corners=False)
        return pos.flatten(2).transpose(1, 2)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        B, C, H, W = x.shape
        p = self.patch
        if C != self.in_channels:
            raise ValueError(f"expected {self.in_channels} input channels, got {C}")
        if H % p or W % p:
            raise ValueError(f"image size {H}x{W} is not a multiple of the patch ({p})")
        rows, cols = H // p, W // p
        # patchify: a reshape, since patches do not overlap (im2col would cost a third of the forward)
        tokens = x.reshape(B, C, rows, p, cols, p).permute(0, 2, 4, 1, 3, 5).reshape(B, rows * cols, C * p * p)
        t = self.embed(tokens) + self.positional(rows, cols)
        for block in self.blocks:
            t = block(t)
        out = self.head(self.norm(t)).reshape(B, rows, cols, 3, 2 * p, 2 * p) * self.window
        residual = overlap_add(out, p)[:, :, p // 2:p // 2 + H, p // 2:p // 2 + W]
        coverage = overlap_add(self.window.expand(1, rows, cols, 1, 2 * p, 2 * p), p)
        return x[:, :3] + residual / coverage[:, :, p // 2:p // 2 + H, p // 2:p // 2 + W]


def overlap_add(windows: torch.Tensor, p: int) -> torch.Tensor:
    """Sum ``(B, rows, cols, C, 2p, 2p)`` windows placed at stride ``p`` into ``(B, C, (rows+1)p, (cols+1)p)``.

    The window of token ``(r, c)`` lands at ``(r p, c p)``; done as four non-overlapping quadrant
    images (reshapes) added at their offsets, which is several times faster than ``F.fold`` on a CPU.
    """
    B, rows, cols, C = windows.shape[:4]
    canvas = windows.new_zeros(B, C, (rows + 1) * p, (cols + 1) * p)
    for qy in (0, 1):
        for qx in (0, 1):
            part = windows[..., qy * p:(qy + 1) * p, qx * p:(qx + 1) * p]  # [B, rows, cols, C, p, p]
            image = part.permute(0, 3, 1, 4, 2, 5).reshape(B, C, rows * p, cols * p)
            canvas[:, :, qy * p:qy * p + rows * p, qx * p:qx * p + cols * p] += image
    return canvas


def refine_tiled(model: ViTRefiner, x: torch.Tensor, tile: int, batch: int = 64) -> torch.Tensor:
    """Run ``model`` over ``x (B, C, H, W)`` of any size in overlapping ``tile``-square tiles.

    The positional embedding was learned on crops of ``tile`` pixels, so the model sees tiles of that
    size; tiles overlap by half and are blended with a Hann weight, so tile borders leave no line.
    Tiles go through the model ``batch`` at a time. Returns ``(B, 3, H, W)``.
    """
    B, C, H, W = x.shape
    step = tile // 2
    # replicate-pad so every pixel lies where tiles overlap, and to a whole number of steps
    pad_h = step + (-(H + 2 * step - tile) % step)
    pad_w = step + (-(W + 2 * step - tile) % step)
    xp = F.pad(x, (step, pad_w, step, pad_h), mode="replicate")
    Hp, Wp = xp.shape[-2:]
    tiles = F.unfold(xp, tile, stride=step)  # [B, C * tile^2, T]
    T = tiles.shape[-1]
    tiles = tiles.transpose(1, 2).reshape(B * T, C, tile, tile)
    out = torch.cat([model(tiles[s:s + batch]) for s in range(0, B * T, batch)])  # [B * T, 3, tile, tile]
    window = hann_window(tile, device=x.device).to(x.dtype)
    out = (out * window).reshape(B, T, 3 * tile * tile).transpose(1, 2)
    fold = dict(output_size=(Hp, Wp), kernel_size=tile, stride=step)
    weight = F.fold(window.reshape(1, -1, 1).expand(1, -1, T), **fold)
    return (F.fold(out, **fold) / weight.clamp_min(1e-8))[:, :, step:step + H, step:step + W]
