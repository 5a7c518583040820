"""The benchmark suite: synthetic scans with ground truth, through classical baselines and scantex.

Scenes: the demo wall (paper scale), the room, and wall variants with heavy seams, many holes, a very
low-resolution atlas and strong compression noise. Methods: the input as it is; bicubic upscaling of
the atlas; inpainting of holes plus Gaussian seam blending; multi-view average back-projection of the
input's renders; scantex's presets (``fast`` everywhere, ``default`` too on the demo wall).

Every method's output is scored the same way, with :func:`scantex.metrics.views.score_views`: unlit
renders at held-out cameras that no method saw (planned with their own seed) against renders of the
ground truth; hole PSNR over the pixels whose face the input left black. Seam visibility is measured
on the output atlas along the input's seams. Wall time and peak memory (resident set above the level
before the method started, sampled every 20 ms) are per method.

    python bench/bench_suite.py            # full suite, writes the 'suite' section of bench/RESULTS.md
    python bench/bench_suite.py --quick    # tiny sizes, under a minute, prints the table only
"""

from __future__ import annotations

import argparse
import gc
import json
import os
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

if __package__ in (None, ""):  # run as a script: make 'bench' and 'scantex' importable
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.baselines import backproject, bicubic, inpaint_and_blend  # noqa: E402
from scantex.atlas.holes import untextured_faces  # noqa: E402
from scantex.atlas.seams import seam_edges, seam_visibility  # noqa: E402
from scantex.pipeline.config import EnhanceConfig, FieldSettings, TrainConfig, ViewsConfig, preset  # noqa: E402
from scantex.metrics.views import score_views
from scantex.pipeline.enhance import enhance  # noqa: E402
from scantex.scan import Scan  # noqa: E402
from scantex.synth import make_app_wall, make_room, make_wall  # noqa: E402
from scantex.synth.degrade import Degradation  # noqa: E402
from scantex.views.planning import plan_views  # noqa: E402
from scantex.views.raycast import RayCaster  # noqa: E402
from scantex.views.render import render  # noqa: E402

#: the tiny preset of the quick mode (as the toy enhance test)
QUICK_PRESET = EnhanceConfig(
    preset="quick",
    views=ViewsConfig(n_views=8, width=96, height=72, adaptive=False),
    field=FieldSettings(hidden=32, n_layers=2, n_levels=8, log2_table_size=14, max_resolution=256),
    train=TrainConfig(steps=60, batch_rays=4096, checkpoint_every=1000),
)

HEAVY_SEAMS = Degradation(gain_spread=0.35, white_balance_spread=0.12, offset_spread=0.04)
MANY_HOLES = Degradation(hole_share=0.12, hole_clusters=12)
STRONG_NOISE = Degradation(jpeg_quality=10)


@dataclass(frozen=True)
class Scene:
    """A synthetic scan to benchmark, made on demand."""

    name: str
    make: Callable
    presets: tuple[str, ...]


@dataclass(frozen=True)
class Settings:
    """What differs between the full and the quick suite."""

    scenes: tuple[Scene, ...]
    eval_views: int
    eval_size: tuple[int, int]
    backproject_views: ViewsConfig
    presets: dict[str, EnhanceConfig] = field(default_factory=dict)


def full_settings() -> Settings:
    variant = dict(grid=(100, 76), gt_texture_size=2048, scan_texture_size=512)
    scenes = (
        Scene("wall (demo, 79k faces, 1024² atlas)", lambda: make_wall(seed=0),
              ("fast", "default", "default, bake.source=field")),
        Scene("app-realistic wall (79k faces, sharp 4096² atlas)", lambda: make_app_wall(seed=5),
              ("fast", "default", "default, bake.source=field")),
        Scene("room (4.8k faces, 256² atlas)", lambda: make_room(seed=0), ("fast",)),
        Scene("wall: heavy seams", lambda: make_wall(seed=1, n_charts=120, degradation=HEAVY_SEAMS, **variant),
              ("fast",)),
        Scene("wall: many holes", lambda: make_wall(seed=2, degradation=MANY_HOLES, **variant), ("fast",)),
        Scene("wall: very low resolution (128² atlas)",
              lambda: make_wall(seed=3, grid=(100, 76), gt_texture_size=2048, scan_texture_size=128), ("fast",)),
        Scene("wall: strong noise (JPEG q10)", lambda: make_wall(seed=4, degradation=STRONG_NOISE, **variant),
              ("fast",)),
    )
    return Settings(scenes, eval_views=6, eval_size=(320, 240), backproject_views=preset("fast").views,
                    presets={"fast": preset("fast"), "default": preset("default"),
                             "default, bake.source=field": preset("default").override(bake__source="field")})


def quick_settings() -> Settings:
    tiny = dict(grid=(24, 18), gt_texture_size=256, scan_texture_size=64)
    scenes = (
        Scene("wall", lambda: make_wall(seed=0, **tiny), ("quick",)),
        Scene("room", lambda: make_room(seed=0, cell_m=0.5, gt_texture_size=256, scan_texture_size=64), ("quick",)),
        Scene("wall: heavy seams", lambda: make_wall(seed=1, degradation=HEAVY_SEAMS, **tiny), ("quick",)),
        Scene("wall: many holes", lambda: make_wall(seed=2, degradation=MANY_HOLES, **tiny), ("quick",)),
        Scene("wall: very low resolution",
              lambda: make_wall(seed=3, grid=(24, 18), gt_texture_size=256, scan_texture_size=32), ("quick",)),
        Scene("wall: strong noise", lambda: make_wall(seed=4, degradation=STRONG_NOISE, **tiny), ("quick",)),
    )
    return Settings(scenes, eval_views=2, eval_size=(96, 72), backproject_views=QUICK_PRESET.views,
                    presets={"quick": QUICK_PRESET})


# -- measuring ------------------------------------------------------------------------------------


def _rss_bytes() -> int:
    try:
        with open("/proc/self/statm") as f:
            return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")
    except OSError:  # not Linux: the peak of the whole process so far
        import resource

        return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024


class PeakMemory:
    """Peak resident memory above the level at entry, sampled every ``interval`` seconds."""

    def __init__(self, interval: float = 0.02):
        self.interval = interval
        self.peak = 0

    def __enter__(self) -> PeakMemory:
        gc.collect()
        self.start = _rss_bytes()
        self.peak = self.start
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._sample, daemon=True)
        self._thread.start()
        return self

    def _sample(self) -> None:
        while not self._stop.wait(self.interval):
            self.peak = max(self.peak, _rss_bytes())

    def __exit__(self, *exc) -> None:
        self._stop.set()
        self._thread.join()
        self.peak = max(self.peak, _rss_bytes())

    @property
    def extra_mb(self) -> float:
        return (self.peak - self.start) / 2**20


def run_scene(scene: Scene, settings: Settings, log=print) -> list[dict]:
    """Every method on one scene: rows of the table."""
    t = time.perf_counter()
    demo = scene.make()
    scan, truth = demo.scan, demo.ground_truth
    log(f"{scene.name}: {scan.n_faces:,} faces, made in {time.perf_counter() - t:.1f} s")
    caster = RayCaster(scan.positions, scan.faces)
    holes = untextured_faces(scan)
    edges = seam_edges(scan)
    W, H = settings.eval_size
    # held-out cameras: planned with their own seed, seen by no method
    eval_cameras = plan_views(scan, settings.eval_views, width=W, height=H, fov_deg=60.0, seed=1000, caster=caster)
    bv = settings.backproject_views
    bp_cameras = plan_views(scan, bv.n_views, width=bv.width, height=bv.height, fov_deg=bv.fov_deg, seed=0,
                            caster=caster)

    methods: dict[str, Callable[[], Scan]] = {
        "input": lambda: scan,
        "bicubic ×2": lambda: bicubic(scan),
        "inpaint + seam blend": lambda: inpaint_and_blend(scan),
        "multi-view back-projection": lambda: backproject(scan, bp_cameras),
    }
    for name in scene.presets:
        config = settings.presets[name]
        methods[f"scantex {name}"] = lambda config=config: enhance(scan, config).scan

    rows = []
    for method, run in methods.items():
        gc.collect()
        with PeakMemory() as memory:
            t = time.perf_counter()
            out = run()
            seconds = time.perf_counter() - t
        if not (np.array_equal(out.positions, scan.positions) and np.array_equal(out.faces, scan.faces)):
            raise AssertionError(f"{method} changed the geometry")
        score = score_views(lambda cam: render(truth, cam, caster, supersample=2), {method: out}, eval_cameras,
                            caster, holes)[method]
        row = {"scene": scene.name, "method": method, "psnr": score["psnr"], "ssim": score["ssim"],
               "patches": score["patches"],
               "hole_psnr": score.get("hole_psnr"), "seam_visibility": seam_visibility(out, edges),
               "seconds": 0.0 if method == "input" else seconds,
               "peak_mb": 0.0 if method == "input" else memory.extra_mb,
               "atlas": "×".join(map(str, out.materials[0].image.shape[1::-1]))}
        log(f"  {method}: PSNR {row['psnr']:.2f} dB, SSIM {row['ssim']:.3f}, seams {row['seam_visibility']:.2f}, "
            f"{seconds:.1f} s")
        rows.append(row)
    return rows


def table(rows: list[dict]) -> str:
    lines = ["| scene | method | atlas | PSNR (dB) | SSIM | patches | seam visibility | hole PSNR (dB) | time (s) | "
             "peak memory (MB) |", "|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        hole = f"{r['hole_psnr']:.2f}" if r["hole_psnr"] is not None else "—"
        lines.append(f"| {r['scene']} | {r['method']} | {r['atlas']} | {r['psnr']:.2f} | {r['ssim']:.3f} | "
                     f"{100 * r['patches']:.2f} % | "
                     f"{r['seam_visibility']:.2f} | {hole} | {r['seconds']:.1f} | {r['peak_mb']:.0f} |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true", help="tiny sizes (under a minute); prints the table only")
    parser.add_argument("--json", type=Path, help="also write the rows as JSON")
    parser.add_argument("--only", default="", help="only the scenes whose name contains this (prints, writes nothing)")
    args = parser.parse_args(argv)
    settings = quick_settings() if args.quick else full_settings()
    start = time.perf_counter()
    rows = []
    for scene in settings.scenes:
        if args.only in scene.name:
            rows += run_scene(scene, settings)
    total = time.perf_counter() - start
    markdown = table(rows)
    print(markdown)
    print(f"total {total:.0f} s")
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1))
    if not args.quick and not args.only:
        from bench._results import update_section

        W, H = settings.eval_size
        update_section("suite", "## Benchmark suite: synthetic scans with ground truth, baselines and scantex\n\n"
                       f"Held-out: {settings.eval_views} cameras per scene ({W}x{H}, planned with their own seed, "
                       "seen by no method), unlit renders against the ground truth's, `score_views` as in "
                       "`enhance`; PSNR/SSIM over covered pixels, hole PSNR over pixels of faces the input left "
                       "black. Patches: share of pixels where the output has a low-frequency edge the ground truth "
                       "lacks (`scantex.metrics.patches`). Seam visibility: mean RGB step (0-255) across the "
                       "input's UV seams in the output "
                       "atlas. Time and peak memory (resident set above the level at the method's start) per "
                       "method; scantex's time includes its own view rendering and metrics.\n\n"
                       f"{markdown}\n\nTotal bench time {total:.0f} s. Command: `python bench/bench_suite.py`")
    return 0


if __name__ == "__main__":
    sys.exit(main())
