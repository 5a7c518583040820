"""An optional small diffusion denoiser, trained on the scan's own views and applied SDEdit-style.

A two-level U-Net predicts the noise ``eps`` of a DDPM with a cosine schedule (Nichol & Dhariwal
2021), trained on random clean patches of the images it is given: for a scan, renders of its own
texture, the only clean-ish data a user has. Denoising (Meng et al. 2021, SDEdit) noises an image to
``t0 = strength * T`` and walks back to ``t = 0`` with deterministic DDIM steps (eta = 0): the
injected noise drowns the image's own noise, and the model, which only knows the texture's
statistics, removes both while the low frequencies that survive the noising keep the structure.

Images are in [0, 1] and the model works in [-1, 1]. Training draws ``t`` only up to
``train_strength * T``, where denoising starts; the model never has to learn to draw a texture from
pure noise, which is what makes a few hundred CPU steps enough.

Cost at the defaults (width 24, 300 steps of 16 patches of 32x32, T = 100, strength 0.1, 3 DDIM
steps), torch 2.13 on CPU: one core's CPU time is ~0.09 s a training step (~28 s in all; two idle cores
should need less) and ~0.15 s a U-Net pass over 256x256 (~0.45 s a denoise). On the two cores this was
written on, shared with two other jobs (load ~6), wall times were 211 s and 1.4 s: OpenMP threads
that wait for each other lose most of their time when the cores are oversubscribed.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from scantex.refine.optim import Adam

log = logging.getLogger(__name__)

Progress = Callable[[int, int], None]


@dataclass(frozen=True)
class DiffusionConfig:
    steps: int = 300
    """training steps"""
    patch: int = 32
    """side of the square training patches, pixels"""
    batch: int = 16
    """patches per training step"""
    width: int = 24
    """base channels of the U-Net (the coarse level has twice as many)"""
    timesteps: int = 100
    """T, the number of steps of the cosine noise schedule"""
    strength: float = 0.1
    """SDEdit: denoising starts from t0 = strength x T (higher removes more noise and more detail)"""
    sample_steps: int = 3
    """deterministic DDIM steps from t0 back to 0"""
    lr: float = 2e-3
    """Adam learning rate (cosine decay to 10 % by the last step)"""
    train_strength: float = 0.4
    """training draws t from 1 .. train_strength x T: denoising never starts higher"""
    min_usable: float = 1.0
    """share of a patch's pixels that must be usable (mask True) for it to be drawn"""
    flips: bool = True
    """augment the patches with horizontal and vertical flips"""
    tile: int = 384
    """images larger than this are denoised in tiles of this side (bounded memory)"""
    overlap: int = 32
    """overlap of neighbouring tiles, pixels, blended linearly"""


# -- the noise schedule ---------------------------------------------------------------------------


def cosine_alphas_cumprod(T: int, s: float = 0.008) -> torch.Tensor:
    """``(T + 1,) float64`` signal share abar_t of the cosine schedule, abar_0 = 1, decreasing to ~0.

    Per-step betas are clipped at 0.999 as in Nichol & Dhariwal, so abar_T is tiny but not zero.
    """
    t = torch.arange(T + 1, dtype=torch.float64) / T
    f = torch.cos((t + s) / (1 + s) * math.pi / 2) ** 2
    abar = f / f[0]
    beta = (1 - abar[1:] / abar[:-1]).clamp(max=0.999)
    return torch.cat([abar.new_ones(1), torch.cumprod(1 - beta, 0)])


def noise_to(x0: torch.Tensor, abar: torch.Tensor, eps: torch.Tensor) -> torch.Tensor:
    """x_t = sqrt(abar) x0 + sqrt(1 - abar) eps; ``abar`` broadcast against ``x0``."""
    return abar.sqrt() * x0 + (1 - abar).sqrt() * eps


# -- the model ------------------------------------------------------------------------------------


def timestep_embedding(t: torch.Tensor, dim: int) -> torch.Tensor:
    """Sinusoidal embedding ``(B, dim)`` of timesteps ``t (B,)`` (float: any t in [0, T])."""
    half = dim // 2
    freqs = torch.exp(-math.log(10000.0) * torch.arange(half, dtype=torch.float32, device=t.device) / half)
    angles = t.float()[:, None] * freqs[None]
    return torch.cat([angles.sin(), angles.cos()], dim=1)


def _groups(channels: int) -> int:
    return math.gcd(8, channels)


class ResBlock(nn.Module):
    """GroupNorm-SiLU-conv twice, the timestep embedding added in between, and a skip."""

    def __init__(self, c_in: int, c_out: int, c_emb: int):
        super().__init__()
        self.norm1 = nn.GroupNorm(_groups(c_in), c_in)
        self.conv1 = nn.Conv2d(c_in, c_out, 3, padding=1)
        self.emb = nn.Linear(c_emb, c_out)
        self.norm2 = nn.GroupNorm(_groups(c_out), c_out)
        self.conv2 = nn.Conv2d(c_out, c_out, 3, padding=1)
        nn.init.zeros_(self.conv2.weight)  # each block starts as the identity
        nn.init.zeros_(self.conv2.bias)
        self.skip = nn.Conv2d(c_in, c_out, 1) if c_in != c_out else nn.Identity()

    def forward(self, x: torch.Tensor, emb: torch.Tensor) -> torch.Tensor:
        h = self.conv1(F.silu(self.norm1(x)))
        h = h + self.emb(emb)[:, :, None, None]
        h = self.conv2(F.silu(self.norm2(h)))
        return self.skip(x) + h


class UNet(nn.Module):
    """A two-level U-Net predicting the noise of ``x_t (B, 3, H, W)``; H and W must be even.

    Tensors are channels-last, the layout oneDNN's CPU convolutions run fastest in. (A variant that
    starts with a pixel unshuffle to half resolution ran ~3x faster but trained to a 4x higher loss
    and denoised worse on a brick texture: the noise is per pixel, so the fine level stays.)
    """

    multiple = 2

    def __init__(self, width: int):
        super().__init__()
        w, c_emb = width, 4 * width
        self.width = width
        self.embed = nn.Sequential(nn.Linear(w, c_emb), nn.SiLU(), nn.Linear(c_emb, c_emb))
        self.stem = nn.Conv2d(3, w, 3, padding=1)
        self.fine_down = ResBlock(w, w, c_emb)
        self.down = nn.Conv2d(w, 2 * w, 3, stride=2, padding=1)
        self.coarse = nn.ModuleList([ResBlock(2 * w, 2 * w, c_emb), ResBlock(2 * w, 2 * w, c_emb)])
        self.up = nn.Conv2d(2 * w, w, 3, padding=1)
        self.fine_up = ResBlock(2 * w, w, c_emb)
        self.head = nn.Sequential(nn.GroupNorm(_groups(w), w), nn.SiLU(), nn.Conv2d(w, 3, 3, padding=1))
        self.to(memory_format=torch.channels_last)

    def forward(self, x: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
        emb = self.embed(timestep_embedding(t, self.width))
        x = x.contiguous(memory_format=torch.channels_last)
        skip = self.fine_down(self.stem(x), emb)  # [B, w, H, W]
        h = self.down(skip)  # [B, 2w, H/2, W/2]
        for block in self.coarse:
            h = block(h, emb)
        h = self.up(F.interpolate(h, scale_factor=2.0, mode="nearest"))  # [B, w, H, W]
        h = self.fine_up(torch.cat([h, skip], dim=1), emb)
        return self.head(h).contiguous()  # [B, 3, H, W]


# -- the denoiser ---------------------------------------------------------------------------------


class Denoiser(nn.Module):
    """A trained (or loaded) noise predictor with its schedule; :meth:`denoise` applies it.

    Attributes:
        config: the settings it was built with (``timesteps`` and ``width`` fix the weights' meaning).
        losses: ``(steps,) float32`` training loss per step (empty when loaded from a file).
        seconds: training wall time (0 when loaded).
    """

    def __init__(self, config: DiffusionConfig = DiffusionConfig()):
        super().__init__()
        self.config = config
        self.unet = UNet(config.width)
        self.register_buffer("alphas_cumprod", cosine_alphas_cumprod(config.timesteps).float(), persistent=False)
        self.losses = np.zeros(0, dtype=np.float32)
        self.seconds = 0.0

    @property
    def device(self) -> torch.device:
        return next(self.parameters()).device

    def save(self, path: str | Path) -> None:
        """Write the config and weights to ``path`` (a ``torch.save`` file of plain types)."""
        torch.save({"config": dataclasses.asdict(self.config), "state": self.state_dict()}, path)

    @classmethod
    def load(cls, path: str | Path, device: torch.device | str = "cpu") -> Denoiser:
        """A denoiser saved with :meth:`save` (loaded with ``weights_only``: nothing executable)."""
        saved = torch.load(path, map_location=device, weights_only=True)
        with torch.device("cpu"):
            denoiser = cls(DiffusionConfig(**saved["config"]))
        denoiser = denoiser.to(device)
        denoiser.load_state_dict(saved["state"])
        return denoiser.eval()

    @torch.no_grad()
    def denoise(self, images: torch.Tensor, strength: float | None = None, *, seed: int = 0) -> torch.Tensor:
        """Remove noise from ``images (N, 3, H, W)`` in [0, 1]; returns the same shape, dtype and device.

        Each image is noised to ``t0 = strength * T`` with noise drawn from ``seed`` and brought back
        to ``t = 0`` with ``config.sample_steps`` deterministic DDIM steps. Any H and W: images are
        reflect-padded to the U-Net's multiple and cropped back; images larger than ``config.tile``
        have their noise predicted in overlapping tiles. ``strength = 0`` returns the input unchanged.

        Args:
            strength: share of the schedule to start from, in [0, 1]; ``config.strength`` when ``None``.
            seed: seeds the injected noise (the result is deterministic given it).
        """
        _check_images(images, "images")
        strength = self.config.strength if strength is None else float(strength)
        if not 0.0 <= strength <= 1.0:
            raise ValueError(f"strength must be in [0, 1], got {strength}")
        T = self.config.timesteps
        t0 = round(strength * T)
        if t0 == 0:
            return images.clone()
        if strength > self.config.train_strength + 1e-9:
            log.warning("denoising from strength %.2f, above the %.2f the model was trained up to",
                        strength, self.config.train_strength)
        # t0 -> 0 in sample_steps deterministic jumps (fewer if t0 has fewer integer steps)
        ts = torch.linspace(t0, 0, self.config.sample_steps + 1, device="cpu").round().long().unique_consecutive().tolist()
        gen = torch.Generator(device="cpu").manual_seed(seed)
        out = torch.empty_like(images)
        for i in range(len(images)):  # one image at a time bounds memory
            x0 = images[i:i + 1].to(self.device, torch.float32) * 2 - 1
            eps = torch.randn(x0.shape, generator=gen, device="cpu").to(self.device)
            x = noise_to(x0, self.alphas_cumprod[t0], eps)
            for t, t_next in zip(ts[:-1], ts[1:]):
                x = self._ddim_step(x, t, t_next)
            out[i] = ((x + 1) / 2).clamp(0, 1).to(out.device, out.dtype)[0]
        return out

    def _ddim_step(self, x: torch.Tensor, t: int, t_next: int) -> torch.Tensor:
        """One deterministic DDIM step (eta = 0) of ``x (1, 3, H, W)`` from ``t`` to ``t_next < t``."""
        a, a_next = self.alphas_cumprod[t], self.alphas_cumprod[t_next]
        eps = self.predict_noise(x, t)
        x0 = ((x - (1 - a).sqrt() * eps) / a.sqrt()).clamp(-1, 1)
        return noise_to(x0, a_next, eps)

    def predict_noise(self, x: torch.Tensor, t: int) -> torch.Tensor:
        """The U-Net's noise estimate for ``x (B, 3, H, W)`` at timestep ``t``, any H and W.

        Padded to the U-Net's multiple (reflect) and cropped back; larger than ``config.tile``, the
        estimate is blended from overlapping tiles with weights that fall off linearly at their edges.
        """
        B, _, H, W = x.shape
        m = UNet.multiple
        ph, pw = -H % m, -W % m
        if ph or pw:
            mode = "reflect" if H > ph and W > pw else "replicate"
            x = F.pad(x, (0, pw, 0, ph), mode=mode)
        tt = torch.full((B,), float(t), device=x.device)
        tile = max(self.config.tile // m * m, 2 * m)
        Hp, Wp = x.shape[-2:]
        if Hp <= tile and Wp <= tile:
            return self.unet(x, tt)[..., :H, :W]
        overlap = min(self.config.overlap, tile // 2)
        eps = torch.zeros_like(x)
        weight = x.new_zeros(1, 1, Hp, Wp)
        for y in _tile_starts(Hp, tile, overlap, m):
            for x_ in _tile_starts(Wp, tile, overlap, m):
                h, w = min(tile, Hp - y), min(tile, Wp - x_)
                ramp = _ramp(h, overlap, x.device)[:, None] * _ramp(w, overlap, x.device)[None, :]
                eps[..., y:y + h, x_:x_ + w] += ramp * self.unet(x[..., y:y + h, x_:x_ + w], tt)
                weight[..., y:y + h, x_:x_ + w] += ramp
        return (eps / weight)[..., :H, :W]


def _tile_starts(size: int, tile: int, overlap: int, multiple: int) -> list[int]:
    """Starts of tiles of side ``tile`` covering ``[0, size)``, overlapping by at least ``overlap``."""
    if size <= tile:
        return [0]
    stride = tile - overlap
    starts = list(range(0, size - tile, stride)) + [size - tile]
    return sorted({s // multiple * multiple for s in starts})


def _ramp(n: int, overlap: int, device) -> torch.Tensor:
    """``(n,)`` blending weights: 1 inside, falling linearly towards both ends over ``overlap``."""
    i = torch.arange(n, dtype=torch.float32, device=device)
    return (torch.minimum(i + 0.5, n - 0.5 - i) / max(overlap, 1)).clamp(1e-3, 1.0)


# -- training -------------------------------------------------------------------------------------


def _check_images(images: torch.Tensor, name: str) -> None:
    if not isinstance(images, torch.Tensor) or images.ndim != 4 or images.shape[1] != 3:
        shape = tuple(images.shape) if isinstance(images, torch.Tensor) else type(images).__name__
        raise ValueError(f"{name} must be a (N, 3, H, W) tensor, got {shape}")
    if not images.is_floating_point():
        raise ValueError(f"{name} must be floating point in [0, 1], got {images.dtype}")


def patch_corners(masks: torch.Tensor, patch: int, min_usable: float) -> torch.Tensor:
    """``(K, 3) int64`` rows ``(image, y, x)``: top-left corners of ``patch``-sided patches of ``masks
    (N, 1, H, W) bool`` whose share of usable pixels is at least ``min_usable``."""
    share = F.avg_pool2d(masks.float(), patch, stride=1)  # [N, 1, H - p + 1, W - p + 1]
    n, _, y, x = torch.nonzero(share >= min_usable - 1e-6, as_tuple=True)
    return torch.stack([n, y, x], dim=1)


def fit_denoiser(images: torch.Tensor, masks: torch.Tensor | None, config: DiffusionConfig = DiffusionConfig(), *,
                 device: torch.device | str = "cpu", seed: int = 0, progress: Progress | None = None) -> Denoiser:
    """Train an epsilon-predicting DDPM on random patches of ``images``.

    Args:
        images: ``(N, 3, H, W) float`` in [0, 1], clean examples of the texture.
        masks: ``(N, 1, H, W) bool``, True where a pixel is usable; patches are drawn only where at
            least ``config.min_usable`` of their pixels are, and the loss counts usable pixels only.
            ``None``: every pixel is usable.
        device: where to train; the returned denoiser stays there.
        seed: seeds the weights, the patches, the timesteps and the noise.
        progress: called with ``(done, total)`` steps after every step.
    """
    _check_images(images, "images")
    N, _, H, W = images.shape
    p = config.patch
    if p % UNet.multiple:
        raise ValueError(f"patch must be a multiple of {UNet.multiple}, got {p}")
    if H < p or W < p:
        raise ValueError(f"images of {H}x{W} pixels are smaller than the {p}-pixel training patch")
    if masks is None:
        masks = torch.ones(N, 1, H, W, dtype=torch.bool, device=images.device)
    elif masks.shape != (N, 1, H, W):
        raise ValueError(f"masks must be (N, 1, H, W) = {(N, 1, H, W)}, got {tuple(masks.shape)}")
    corners = patch_corners(masks.bool().cpu(), p, config.min_usable)
    if len(corners) == 0:
        raise ValueError(f"no {p}x{p} patch has {config.min_usable:.0%} usable pixels; "
                         "lower min_usable or patch")
    log.info("training the diffusion denoiser on %d images, %d patch positions", N, len(corners))

    device = torch.device(device)
    torch.manual_seed(seed)
    gen = torch.Generator(device="cpu").manual_seed(seed)
    with torch.device("cpu"):  # initialised on the CPU: the same starting weights whatever the device
        denoiser = Denoiser(config)
    denoiser = denoiser.to(device)
    unet = denoiser.unet.train()
    optim = Adam(unet.parameters())  # fused where it can be: fewer tiny kernels a step
    warmup = max(1, config.steps // 20)

    def lr(s: int) -> float:  # warm-up, then cosine decay to 10 %
        return config.lr * min(1.0, (s + 1) / warmup) * (
            0.1 + 0.45 * (1 + math.cos(math.pi * min(s, config.steps) / max(1, config.steps))))

    data = images.detach().to(device, torch.float32) * 2 - 1
    usable = masks.detach().to(device, torch.float32)
    t_max = max(1, round(config.train_strength * config.timesteps))
    offsets = torch.arange(p, device=device)
    losses = []
    start = time.perf_counter()
    for step in range(config.steps):
        # the draws are made on the CPU generator (the same on any device) and moved
        pick = corners[torch.randint(0, len(corners), (config.batch,), generator=gen, device="cpu")].to(device)
        rows = (pick[:, 1:2] + offsets)[:, :, None]  # [B, p, 1]
        cols = (pick[:, 2:3] + offsets)[:, None, :]  # [B, 1, p]
        x0 = data[pick[:, 0, None, None], :, rows, cols].permute(0, 3, 1, 2)  # [B, 3, p, p]
        weight = usable[pick[:, 0, None, None], :, rows, cols].permute(0, 3, 1, 2)  # [B, 1, p, p]
        if config.flips:
            flip = torch.rand(2, config.batch, generator=gen, device="cpu").to(device) < 0.5
            x0 = torch.where(flip[0, :, None, None, None], x0.flip(-1), x0)
            weight = torch.where(flip[0, :, None, None, None], weight.flip(-1), weight)
            x0 = torch.where(flip[1, :, None, None, None], x0.flip(-2), x0)
            weight = torch.where(flip[1, :, None, None, None], weight.flip(-2), weight)
        t = torch.randint(1, t_max + 1, (config.batch,), generator=gen, device="cpu").to(device)
        eps = torch.randn(x0.shape, generator=gen, device="cpu").to(device)
        x_t = noise_to(x0, denoiser.alphas_cumprod[t][:, None, None, None], eps)
        loss = ((unet(x_t, t.float()) - eps) ** 2 * weight).sum() / (3 * weight.sum()).clamp(min=1)
        optim.zero_grad()
        loss.backward()
        optim.step(lr(step))
        losses.append(loss.item())
        if progress:
            progress(step + 1, config.steps)
    denoiser.seconds = time.perf_counter() - start
    denoiser.losses = np.array(losses, dtype=np.float32)
    log.info("diffusion denoiser trained in %.1f s, loss %.4f -> %.4f", denoiser.seconds,
             float(np.mean(losses[:20])), float(np.mean(losses[-20:])))
    return denoiser.eval()
