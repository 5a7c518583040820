"""Compiling scantex's loops before the first run (``scantex precompile``).

numba compiles each loop of :mod:`scantex.jit` the first time a run calls it, and keeps it in its cache for the
runs after. On a new machine (or after an update, which changes the sources) the first run pays for it: about
12 s of photo mode's first run on 2 cores (the bolster's 12 photos: 19-25 s, against 8-9 s once compiled).
:func:`precompile` pays it ahead: it enhances a small synthetic wall mesh-only and with photos, which calls the
same loops with the same types a real scan's run does, and leaves the outputs nowhere.
"""

from __future__ import annotations

import importlib.util
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path


@dataclass(frozen=True)
class Precompiled:
    """What :func:`precompile` did.

    Attributes:
        compiled: kernel versions (a loop and the types it is called with) compiled now.
        loaded: kernel versions already in numba's cache, loaded.
        seconds: wall time.
        cached: whether numba can keep a cache here (else every run compiles again, and precompiling is moot).
    """

    compiled: int
    loaded: int
    seconds: float
    cached: bool


def precompile(work: str | Path | None = None) -> Precompiled | None:
    """Run the loops mesh-only and photo mode call, on a small synthetic wall, so that numba compiles and caches
    them; ``None`` where numba is not installed (the loops then run in numpy: nothing to compile). ``work``: a
    folder for the synthetic photos (default: a temporary one, removed)."""
    from scantex import jit

    if importlib.util.find_spec("numba") is None:
        return None
    start = time.perf_counter()
    loaded0, compiled0 = jit.cache_counts()
    with tempfile.TemporaryDirectory(prefix="scantex-precompile-") as tmp:
        _run(Path(work) if work is not None else Path(tmp))
    loaded, compiled = jit.cache_counts()
    return Precompiled(compiled=compiled - compiled0, loaded=loaded - loaded0,
                       seconds=time.perf_counter() - start, cached=jit.keeps_cache())


def _run(folder: Path) -> None:
    """Mesh-only, then photo mode (4 photos with depth maps, the poses aligned to the input texture as for a
    small capture), then a fresh UV layout, on a 2,400-face wall; the defaults otherwise; and a photo undistorted."""
    from scantex.io import load_scan
    from scantex.photos.alignment import check_alignment
    from scantex.pipeline.config import preset
    from scantex.pipeline.enhance import enhance
    from scantex.synth import make_wall, write_demo
    from scantex.synth.photos import PhotoCapture, capture_photos
    from scantex.uv import plan_uvs

    demo = make_wall(seed=0, grid=(41, 31), size_m=(1.6, 1.2), gt_texture_size=512, scan_texture_size=256,
                     n_charts=6)
    photos = capture_photos(demo, folder / "photos", PhotoCapture(n_photos=4, width=320, height=240, distance=1.0,
                                                                jitter_deg=0.0, jitter_m=0.0),
                            seed=0, up=(0.0, 0.0, 1.0))
    scan = load_scan(write_demo(demo, folder)["scan"])  # read from a file, as a user's scan is (read-only arrays)
    config = preset("default").override(bake__texture_size=256, views__n_views=8)
    enhance(scan, config)
    # the alignment check's loops run whatever its verdict on this capture; its verdict does not stop the run
    check_alignment(scan, photos)
    enhance(scan, config.override(photos__holdout=0, photos__refine_poses="input", photos__check_alignment=False),
            photos=photos)
    plan_uvs(scan, "unwrap", texture_size=256, use_xatlas=False)  # its packing loop; xatlas is an optional extra
    # a photo through a distorting lens (a capture straight from structure from motion) is undistorted when read
    from scantex.photos.lens import pinhole_lens, undistort_image
    from scantex.photos.photoset import Distortion

    undistort_image(photos.load_image(0), pinhole_lens(photos.cameras[0], Distortion("OPENCV", (-0.05,)), folder,
                                                       "precompile"))
