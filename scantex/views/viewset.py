"""A set of rendered views: cameras, images, coverage masks and the train/test split."""

from __future__ import annotations

import json
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from scantex.io.atomic import atomic_files
from scantex.scan import Scan
from scantex.views.camera import Camera
from scantex.views.raycast import RayCaster
from scantex.views.render import Light, render, to_uint8

Progress = Callable[[int, int], None]


@dataclass(frozen=True, eq=False)
class ViewSet:
    """Views of one scan.

    Attributes:
        cameras: the cameras.
        images: ``(N, H, W, 3) float32`` colours in [0, 1].
        alpha: ``(N, H, W) float32`` share of each pixel covered by the mesh.
        train: indices of the training views.
        test: indices of the held-out views.
        rendered: ``(N,) bool``, the views whose images were rendered; None when all were (a run that
            trains nothing on its views renders only the held-out ones and leaves the others black).
    """

    cameras: tuple[Camera, ...]
    images: np.ndarray
    alpha: np.ndarray
    train: np.ndarray
    test: np.ndarray
    rendered: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.cameras)


def split_train_test(n: int, test_fraction: float = 0.2, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Split ``n`` views into training and held-out indices (the paper's 80/20), at least one of each
    when ``n >= 2``."""
    rng = np.random.default_rng(seed)
    order = rng.permutation(n)
    n_test = int(round(n * test_fraction))
    if n >= 2:
        n_test = min(max(n_test, 1), n - 1)
    return np.sort(order[n_test:]), np.sort(order[:n_test])


def render_views(scan: Scan, cameras: Sequence[Camera], *, lit: bool = False, supersample: int = 1,
                 light: Light = Light(), test_fraction: float = 0.2, seed: int = 0,
                 caster: RayCaster | None = None, progress: Progress | None = None) -> ViewSet:
    """Render every camera's view of ``scan`` and split them into training and held-out views."""
    caster = caster or RayCaster(scan.positions, scan.faces)
    images, alpha = [], []
    for i, cam in enumerate(cameras):
        rgb, a = render(scan, cam, caster, lit=lit, supersample=supersample, light=light)
        images.append(rgb)
        alpha.append(a)
        if progress:
            progress(i + 1, len(cameras))
    train, test = split_train_test(len(cameras), test_fraction, seed)
    return ViewSet(tuple(cameras), np.stack(images), np.stack(alpha), train, test)


def write_views(views: ViewSet, out_dir: str | Path) -> Path:
    """Write ``view_000.png ...`` and ``cameras.json`` (OpenCV convention) into ``out_dir``: the views
    that were rendered, under their index in the set (views never rendered are left out, not written black).

    ``cameras.json``: ``{"convention": ..., "frames": [{image, width, height, K, world_to_camera,
    split}]}`` with image paths relative to the file.
    """
    from PIL import Image

    from scantex.io.images import PNG_COMPRESS_LEVEL

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    test = set(views.test.tolist())
    frames = []
    with atomic_files() as files:
        for i, (cam, img) in enumerate(zip(views.cameras, views.images)):
            if views.rendered is not None and not views.rendered[i]:
                continue
            name = f"view_{i:03d}.png"
            Image.fromarray(to_uint8(img)).save(files.path(out_dir / name), format="PNG",
                                                    compress_level=PNG_COMPRESS_LEVEL)
            frames.append({"image": name, **cam.to_dict(), "split": "test" if i in test else "train"})
        doc = {"convention": "OpenCV: x_cam = R X + t, +z forward, +y down; pixel = K x_cam / z",
               "frames": frames}
        files.path(out_dir / "cameras.json").write_text(json.dumps(doc, indent=1))
    return out_dir / "cameras.json"


def read_cameras(path: str | Path) -> list[Camera]:
    """Cameras of a ``cameras.json`` written by :func:`write_views` (or any file of that shape)."""
    doc = json.loads(Path(path).read_text())
    return [Camera.from_dict(f) for f in doc["frames"]]
