"""Does the optional diffusion denoiser help on a scan? Renders of the input, denoised, against the truth.

For each scene, views of the degraded input texture are rendered at cameras planned on the scan; the
denoiser is trained on the input renders of the training views (the only images a user has, with
hole and background pixels masked out) and applied to the held-out views' input renders at several
strengths. PSNR / SSIM are against ground-truth renders at the same cameras, over covered pixels
that are not holes. Scenes: the demo wall (blur, exposure jumps, JPEG q50), the wall with strong JPEG
(q10), and the demo wall's renders with added Gaussian noise (sigma 0.05), the noise it is built for.
Also times training and a 256x256 denoise at the defaults.

    python bench/bench_diffusion.py            # prints a table
    python bench/bench_diffusion.py --quick    # smaller scenes and fewer steps
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import time
from pathlib import Path

import numpy as np
import torch

if __package__ in (None, ""):  # run as a script: make 'scantex' importable
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from scantex.atlas.holes import untextured_faces  # noqa: E402
from scantex.metrics.image import psnr, ssim  # noqa: E402
from scantex.refine.diffusion import DiffusionConfig, fit_denoiser  # noqa: E402
from scantex.synth import make_wall  # noqa: E402
from scantex.synth.degrade import Degradation  # noqa: E402
from scantex.views.planning import plan_views  # noqa: E402
from scantex.views.raycast import RayCaster, cast_gbuffer  # noqa: E402
from scantex.views.render import render  # noqa: E402

STRENGTHS = (0.0, 0.05, 0.1, 0.15, 0.2, 0.3)


def views(demo, n: int, size: tuple[int, int], noise: float, seed: int = 0):
    """Input renders ``(n, 3, H, W)``, ground-truth renders ``(n, H, W, 3)`` and usable masks ``(n, H, W)``."""
    scan = demo.scan
    caster = RayCaster(scan.positions, scan.faces)
    holes = untextured_faces(scan)
    W, H = size
    cameras = plan_views(scan, n, width=W, height=H, fov_deg=60.0, seed=seed, caster=caster)
    rng = np.random.default_rng(seed)
    inputs, truths, masks = [], [], []
    for cam in cameras:
        img, alpha = render(scan, cam, caster, supersample=2)
        ref, _ = render(demo.ground_truth, cam, caster, supersample=2)
        g = cast_gbuffer(caster, cam, scan.face_normals)
        hole = (g.face_id >= 0) & holes[np.where(g.face_id >= 0, g.face_id, 0)]
        if noise:
            img = np.clip(img + rng.normal(0, noise, img.shape), 0, 1).astype(np.float32)
        inputs.append(img)
        truths.append(ref)
        masks.append((alpha >= 0.999) & ~hole)
    return torch.as_tensor(np.stack(inputs)).permute(0, 3, 1, 2), np.stack(truths), np.stack(masks)


def score(images: torch.Tensor, truths: np.ndarray, masks: np.ndarray) -> tuple[float, float]:
    out = images.permute(0, 2, 3, 1).numpy()
    return (float(np.mean([psnr(o, t, m) for o, t, m in zip(out, truths, masks)])),
            float(np.mean([ssim(o, t, m) for o, t, m in zip(out, truths, masks)])))


def run_scene(name: str, demo, config: DiffusionConfig, n_views: int, n_test: int, size, noise: float = 0.0):
    images, truths, masks = views(demo, n_views, size, noise)
    train, test = slice(0, n_views - n_test), slice(n_views - n_test, n_views)
    denoiser = fit_denoiser(images[train], torch.as_tensor(masks[train])[:, None], config)
    print(f"{name}: trained on {n_views - n_test} views of {size[0]}x{size[1]} in {denoiser.seconds:.1f} s, "
          f"loss {denoiser.losses[:20].mean():.3f} -> {denoiser.losses[-20:].mean():.3f}")
    rows = []
    for strength in STRENGTHS:
        t = time.perf_counter()
        out = denoiser.denoise(images[test], strength)
        seconds = (time.perf_counter() - t) / n_test
        p, s = score(out, truths[test], masks[test])
        rows.append((strength, p, s, seconds))
        print(f"  strength {strength:.2f}: PSNR {p:.2f} dB, SSIM {s:.4f}  ({seconds:.2f} s a view)")
    return rows


def timing(config: DiffusionConfig) -> None:
    """Training at the defaults on 32x32 patches, and one 256x256 denoise at the default strength."""
    images = torch.rand(4, 3, 128, 128)
    denoiser = fit_denoiser(images, None, config)
    x = torch.rand(1, 3, 256, 256)
    denoiser.denoise(x)  # first call builds the convolution primitives
    best = min(_seconds(lambda: denoiser.denoise(x)) for _ in range(3))
    print(f"defaults ({torch.get_num_threads()} threads): training {config.steps} steps {denoiser.seconds:.1f} s, "
          f"256x256 denoise {best:.2f} s")


def _seconds(f) -> float:
    t = time.perf_counter()
    f()
    return time.perf_counter() - t


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="smaller scenes and fewer steps")
    args = parser.parse_args()
    config = DiffusionConfig()
    if args.quick:
        config = dataclasses.replace(config, steps=100)
        wall = dict(grid=(60, 46), gt_texture_size=1024, scan_texture_size=256)
        size, n_views, n_test = (160, 120), 6, 2
    else:
        wall = dict(grid=(100, 76), gt_texture_size=2048, scan_texture_size=512)
        size, n_views, n_test = (256, 192), 10, 3
    timing(config)
    demo = make_wall(seed=0, **wall)
    run_scene("wall", demo, config, n_views, n_test, size)
    run_scene("wall + Gaussian noise 0.05", demo, config, n_views, n_test, size, noise=0.05)
    run_scene("wall: strong noise (JPEG q10)", make_wall(seed=4, degradation=Degradation(jpeg_quality=10), **wall),
              config, n_views, n_test, size)


if __name__ == "__main__":
    main()
