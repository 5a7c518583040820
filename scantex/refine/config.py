"""Settings of the refinement stage (the ViT refiner and the optional diffusion denoiser)."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class RefineConfig:
    enabled: bool = True
    """refine views of the field's colour with a self-supervised ViT and fuse them back into the atlas, where
    the bake is the field's colour (bake.source field, an untextured mesh): +0.35 dB on the demo wall for
    about 20 s (fast; bench/bench_refine.py)"""
    over_input: bool = False
    """also refine where the bake keeps the input's own texels (mesh-only mode's default): off, since there
    it measured -0.26 dB (fast) and -0.06 dB (default) on the demo wall and 0.00 dB on the real facade, for
    10-23 s (bench/RESULTS.md, "enhance"); the CLI's --refine turns it on"""
    with_photos: bool = False
    """also refine in photo mode (off: there it trains on renders of the input texture, which the photos
    outclass; measured -0.12 dB on the demo wall with photos, bench/bench_photos.py)"""
    model: str = "tiny"
    """ViT size: tiny (CPU), small or base (GPU)"""
    patch: int = 16
    """ViT patch side in pixels (the paper's 16: 16x16x3 = 768 values per patch)"""
    crop: int = 96
    """side of the square training crops and inference tiles, pixels (a multiple of the patch)"""
    steps: int = 100
    """training steps"""
    batch: int = 8
    """crops per training step (pairs of overlapping crops when cross-view consistency is on)"""
    lr: float = 1e-3
    """AdamW learning rate (warm-up over the first 10 % of the steps, cosine decay to 10 % by the last)"""
    masked: bool = True
    """self-supervision: random patches and irregular regions are masked out and must be filled"""
    mask_share: float = 0.25
    """share of a crop masked out for completion"""
    mask_weight: float = 1.0
    """weight of the loss on masked pixels against the rest"""
    cross_view: bool = False
    """self-supervision: two views that see the same surface point must agree after refinement (off: leaving it
    out measured +0.08 dB on the demo wall and +0.02 dB on the room; bench_refine.py --per-term)"""
    cross_view_weight: float = 0.5
    """weight of the cross-view consistency loss"""
    super_resolution: bool = True
    """self-supervision: learn to undo a downscale + blur + compression of the scan's own views"""
    view_scale: float = 2.0
    """refined views have this many times the pixels per axis of the training views (the super-resolution
    factor: about one pixel per output texel for an atlas twice the input's)"""
    max_views: int = 8
    """most views refined and fused back (picked greedily by the faces they add)"""
    diffusion: bool = False
    """denoise the refined views with a small diffusion model trained on the scan's own views (SDEdit)"""
    diffusion_strength: float = 0.1
    """diffusion: share of the noise schedule denoising starts from (more removes more noise and detail)"""
    diffusion_steps: int = 300
    """diffusion: training steps of the denoiser"""
