"""Real captures, mesh-only: does ``enhance`` beat the app-style input on photos it never saw?

``../shared/data`` holds two real captures whose app-style input texture was baked without some of their
photos (see its README): the bolster (held-out photos 4 and 11) and the facade (2 and 7). Each is
enhanced in mesh-only mode (the photos are not given to scantex); then the input and the output are
rendered through the held-out photos' cameras and scored against the photos on the pixels the mesh
covers cleanly, colour-matched (a per-channel gain and offset fitted per photo, the same way for both:
a held-out photo's exposure is unknowable). The patch measure (:mod:`scantex.metrics.patches`) of
the output against the input is reported beside it: a texture that only levels exposure smoothly
scores about 0.

    python bench/bench_real.py                  # default preset, writes the 'real' section of RESULTS.md
    python bench/bench_real.py --preset fast --no-write
    python bench/bench_real.py --images /tmp/real   # also writes photo | input | output sheets there

Skips (exit 0, a message) when ``../shared/data`` is absent.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

if __package__ in (None, ""):  # run as a script: make 'bench' and 'scantex' importable
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench._results import run_worker, update_section  # noqa: E402

DATA = Path(__file__).resolve().parents[2] / "shared" / "data"

#: (name, app-style input, cameras, held-out photo indices)
CAPTURES = (
    ("bolster", "bolster_rgbd_posed/app_style_input/bolster_app_style.obj", "bolster_rgbd_posed/cameras.json",
     (4, 11)),
    ("facade", "facade_openmvs/app_style_input/scene_mesh_baked.obj", "facade_openmvs/cameras.json", (2, 7)),
)

#: longer side of the held-out photos when scored (the issue's protocol: about half resolution)
SCORE_SIDE = 960

WORKER = r"""
import json, resource, sys, time
from pathlib import Path
import numpy as np
spec = json.loads(sys.argv[1])
from scantex import load_scan
from scantex.metrics.patches import patch_score
from scantex.photos import load_photos
from scantex.photos.training import VisibilitySettings, prepare_photos, score_photos
from scantex.pipeline.config import EnhanceConfig, preset
from scantex.pipeline.enhance import enhance
from scantex.views.raycast import RayCaster
from scantex.views.render import render

scan = load_scan(spec["mesh"])
config = preset(spec["preset"])
if spec.get("config"):
    d = config.to_dict()
    for section, values in spec["config"].items():
        d[section].update(values) if isinstance(values, dict) else d.__setitem__(section, values)
    config = EnhanceConfig.from_dict(d)
t = time.perf_counter()
result = enhance(scan, config)
seconds = time.perf_counter() - t
photos = load_photos(spec["cameras"])
caster = RayCaster(scan.positions, scan.faces)
views = prepare_photos(scan, photos, spec["held_out"], caster, spec["score_side"], VisibilitySettings())
sheets = {}
scores = score_photos({"input": scan, "enhanced": result.scan}, views, caster, images=sheets)
patches = []
for v in views:
    a, mask = render(scan, v.camera, caster, supersample=2)
    b, _ = render(result.scan, v.camera, caster, supersample=2)
    patches.append(patch_score(b, a, v.valid))
if spec.get("images"):
    from PIL import Image
    out = Path(spec["images"]); out.mkdir(parents=True, exist_ok=True)
    for i, im in sheets.items():
        Image.fromarray((np.clip(im, 0, 1) * 255).astype(np.uint8)).save(out / f"{spec['name']}_{i:03d}.png")
peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20
print(json.dumps({"scores": scores, "patch": float(np.mean(patches)), "seconds": seconds, "peak_gib": peak,
                  "metrics": {k: result.metrics.get(k) for k in ("field", "sampling", "patches", "timings_s")}}))
"""


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--preset", default="default")
    ap.add_argument("--config", default="", help="JSON of config overrides by section, e.g. '{\"bake\": {\"source\": \"field\"}}'")
    ap.add_argument("--only", default="", help="one capture by name")
    ap.add_argument("--images", default="", help="folder for photo | input | output sheets")
    ap.add_argument("--no-write", action="store_true", help="print only; leave RESULTS.md alone")
    args = ap.parse_args(argv)
    if not DATA.is_dir():
        print(f"skipped: {DATA} is absent")
        return 0
    rows = []
    for name, mesh, cameras, held_out in CAPTURES:
        if args.only and name != args.only:
            continue
        spec = {"name": name, "mesh": str(DATA / mesh), "cameras": str(DATA / cameras), "held_out": list(held_out),
                "preset": args.preset, "score_side": SCORE_SIDE, "images": args.images,
                "config": json.loads(args.config) if args.config else None}
        r = run_worker(WORKER, spec)
        s = r["scores"]
        row = (f"| {name} | {s['input']['psnr_matched']:.2f} | {s['enhanced']['psnr_matched']:.2f} | "
               f"{s['enhanced']['psnr_matched'] - s['input']['psnr_matched']:+.2f} | "
               f"{s['input']['ssim_matched']:.3f} | {s['enhanced']['ssim_matched']:.3f} | {r['patch'] * 100:.2f} % | "
               f"{r['seconds']:.0f} s | {r['peak_gib']:.1f} GiB |")
        print(row, flush=True)
        print(json.dumps(r["metrics"]), flush=True)
        rows.append(row)
    table = ("| capture | input dB (matched) | output dB | gain | input SSIM | output SSIM | patches vs input | "
             "time | peak |\n|---|---|---|---|---|---|---|---|---|\n" + "\n".join(rows))
    print(table)
    if not args.no_write and not args.only:
        update_section("real", f"### Real captures, mesh-only, held-out photos (`--preset {args.preset}`)\n\n"
                       f"`python bench/bench_real.py --preset {args.preset}`\n\n{table}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
