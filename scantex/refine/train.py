"""Training the ViT refiner on the scan's own views, self-supervised.

Every step draws crops of training views (centred on pixels that carry a target, in pairs that see the
same surface when cross-view consistency is on), corrupts them by the pretext tasks that are switched on
and learns to restore them:

- **masked completion**: random whole patches and irregular blobs are replaced by a smooth fill and
  flagged in the mask channel; the refiner must put the texture back (what fills holes and occlusions);
- **internal super-resolution**: the crop is downscaled, blurred and compressed, then upscaled back; the
  refiner learns to undo it, and is then applied to views rendered finer than the ones it learned on;
- **cross-view consistency**: two crops that see the same surface points, corrupted independently, must
  agree after refinement at every corresponding pixel (the paper's comparison of overlapping patches).

With all three off the refiner is trained on plain reconstruction of the uncorrupted crops (the
"no self-supervision" ablation).
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import torch
import torch.nn.functional as F

from scantex.refine.config import RefineConfig
from scantex.refine.correspond import Correspondence
from scantex.refine.optim import Adam
from scantex.refine.pretext import downscale_blur_compress, random_masks, smooth_fill
from scantex.refine.vit import ViTRefiner

log = logging.getLogger(__name__)

Progress = Callable[[int, int], None]


@dataclass(frozen=True, eq=False)
class RefinerData:
    """The scan's own views, as training targets.

    Attributes:
        images: ``(N, 3, H, W) float32`` colours in [0, 1] (canonical appearance).
        known: ``(N, 1, H, W) bool`` pixels that carry a target (holes and silhouettes do not).
        pairs: correspondences between views, for cross-view consistency (may be empty).
    """

    images: torch.Tensor
    known: torch.Tensor
    pairs: tuple[Correspondence, ...] = ()


@dataclass(frozen=True, eq=False)
class FittedRefiner:
    model: ViTRefiner
    crop: int
    losses: np.ndarray
    seconds: float


def crop_size(config: RefineConfig, height: int, width: int) -> int:
    """The training crop: ``config.crop``, shrunk to fit the views, a multiple of the patch."""
    p = config.patch
    side = min(config.crop, height, width) // p * p
    if side < p:
        raise ValueError(f"views of {height}x{width} are smaller than one {p}-pixel patch")
    return side


def corrupt(target: torch.Tensor, known: torch.Tensor, config: RefineConfig, generator: torch.Generator
            ) -> tuple[torch.Tensor, torch.Tensor]:
    """The refiner's input for ``target (B, 3, h, w)``: ``(B, 4, h, w)`` (RGB + fill mask) and the mask.

    Pixels without a target always get the smooth fill, as holes do at inference.
    """
    B, _, h, w = target.shape
    x = target
    if config.super_resolution:
        x = downscale_blur_compress(smooth_fill(x, known), config.view_scale, generator)
    fill = ~known
    if config.masked:
        fill = fill | random_masks(B, h, w, config.mask_share, config.patch, generator).to(fill.device)
    x = smooth_fill(x, ~fill)
    return torch.cat([x, fill.to(x.dtype)], dim=1), fill


def fit_refiner(data: RefinerData, config: RefineConfig, *, device: torch.device, seed: int = 0,
                progress: Progress | None = None) -> FittedRefiner:
    """Train a :class:`ViTRefiner` on ``data`` with the pretext tasks ``config`` switches on."""
    N, _, H, W = data.images.shape
    if N == 0:
        raise ValueError("no views to train the refiner on")
    torch.manual_seed(seed)
    gen = torch.Generator(device="cpu").manual_seed(seed)  # draws on the CPU, moved: the same on any device
    rng = np.random.default_rng(seed)
    c = crop_size(config, H, W)
    with torch.device("cpu"):  # initialised on the CPU: the same starting weights whatever the device
        model = ViTRefiner.preset(config.model, patch=config.patch, in_channels=4,
                                  grid=(c // config.patch, c // config.patch))
    model = model.to(device)
    optim = Adam(model.parameters(), weight_decay=1e-4, decoupled=True)  # AdamW, fused where it can be
    warmup = max(1, config.steps // 10)

    def lr(s: int) -> float:
        # linear warm-up (the zero head's first moves would otherwise throw the output far off), then
        # cosine decay to 10 %
        return config.lr * min(1.0, (s + 1) / warmup) * (
            0.1 + 0.45 * (1 + np.cos(np.pi * min(1.0, s / max(1, config.steps)))))

    images = data.images.to(device)
    known = data.known.to(device)
    known_pixels = [np.flatnonzero(k.reshape(-1).cpu().numpy()) for k in data.known]
    pairs = [p for p in data.pairs if p.mask.any()] if config.cross_view else []
    pair_pixels = [np.flatnonzero(p.mask.reshape(-1)) for p in pairs]
    views_with_target = [i for i in range(N) if known_pixels[i].size]

    def origin(centre: int) -> tuple[int, int]:
        y, x = divmod(int(centre), W)
        return int(np.clip(y - c // 2, 0, H - c)), int(np.clip(x - c // 2, 0, W - c))

    losses = []
    t0 = time.perf_counter()
    model.train()
    for step in range(config.steps):
        crops, pair_terms = [], []
        n_pairs = config.batch // 2 if pairs else 0
        for _ in range(n_pairs):
            k = int(rng.integers(len(pairs)))
            pair = pairs[k]
            centre = pair_pixels[k][rng.integers(pair_pixels[k].size)]
            ya, xa = origin(centre)
            bx, by = pair.pixels.reshape(-1, 2)[centre]
            yb, xb = origin(int(np.clip(round(by), 0, H - 1)) * W + int(np.clip(round(bx), 0, W - 1)))
            # A pixels of the crop seen inside B's crop, and where (crop-relative)
            m = pair.mask[ya:ya + c, xa:xa + c]
            pb = pair.pixels[ya:ya + c, xa:xa + c] - np.array([xb, yb], np.float32)
            m = m & (pb[..., 0] >= 0) & (pb[..., 0] <= c - 1) & (pb[..., 1] >= 0) & (pb[..., 1] <= c - 1)
            pair_terms.append((len(crops), len(crops) + 1, torch.as_tensor(m, device=device),
                               torch.as_tensor(pb, device=device)))
            crops += [(pair.a, ya, xa), (pair.b, yb, xb)]
        while len(crops) < config.batch:
            i = views_with_target[int(rng.integers(len(views_with_target)))]
            crops.append((i, *origin(known_pixels[i][rng.integers(known_pixels[i].size)])))
        target = torch.stack([images[i, :, y:y + c, x:x + c] for i, y, x in crops])
        have = torch.stack([known[i, :, y:y + c, x:x + c] for i, y, x in crops])
        x_in, masked = corrupt(target, have, config, gen)
        out = model(x_in)
        weight = have.to(out.dtype) * torch.where(masked, config.mask_weight, 1.0)
        loss = (weight * (out - target).abs()).sum() / (3 * weight.sum().clamp_min(1))
        if pair_terms:
            loss = loss + config.cross_view_weight * cross_view_loss(out, pair_terms, c)
        optim.zero_grad()
        loss.backward()
        optim.step(lr(step))
        losses.append(loss.item())
        if progress:
            progress(step + 1, config.steps)
    model.eval()
    return FittedRefiner(model, c, np.array(losses), time.perf_counter() - t0)


def cross_view_loss(out: torch.Tensor, pair_terms: list, crop: int) -> torch.Tensor:
    """Mean L1 difference of refined crops at corresponding pixels (B's crop sampled bilinearly)."""
    total, count = out.new_zeros(()), 0
    for ia, ib, mask, pixels in pair_terms:
        if not mask.any():
            continue
        pb = pixels[mask]  # [n, 2] (x, y) in B's crop
        grid = (2 * (pb + 0.5) / crop - 1).reshape(1, 1, -1, 2)
        yb = F.grid_sample(out[ib:ib + 1], grid, mode="bilinear", align_corners=False)[0, :, 0]  # [3, n]
        ya = out[ia][:, mask]  # [3, n]
        total = total + (ya - yb).abs().sum()
        count += 3 * ya.shape[1]
    return total / max(count, 1)
