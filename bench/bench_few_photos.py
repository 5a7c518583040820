"""Photo mode on a small RGB-D capture by the protocol of the hidden relief wall: 12 photos, 9 given, 3 held out.

    python bench/bench_few_photos.py                          # five draws of the 3 held-out photos
    python bench/bench_few_photos.py --held 1,5,9 --held 2,6,10
    python bench/bench_few_photos.py --override photos__detail=sharp
    python bench/bench_few_photos.py --motion-blur 21      # every third given photo smeared sideways by 21 px

The project is also scored on a real relief wall kept outside the repository (12 RGB-D photos, 9 given and
3 held out, an app-style input). ``../shared/data/bolster_rgbd_posed`` (14 Kinect photos) stands in for it:
for each draw, 12 of its photos make the capture, 3 of them are held out, and the app-style input is baked
again from the other 9 alone (:func:`bench.baselines.app_style_bake`: per texel the photo that sees it best,
on the bolster's own UV layout at 2048², as ``../shared/data``'s inputs were made). scantex gets those 9
(``photos.holdout`` 0) and that input; input and result are scored through the 3 held-out photos' recorded
cameras at 640 px, colour-matched (``scantex.photos.training.score_photos``). Prints a Markdown row a draw;
the numbers go into bench/RESULTS.md by hand. Skips without ``../shared/data``.

``--motion-blur L``: a handheld capture's shaken frames. Every third given photo (3 of 9) is smeared by a
horizontal box of L pixels at its full resolution (written to a temporary folder as JPEG), for the app-style
input and for scantex alike; the held-out photos stay sharp.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
CAPTURE = ROOT.parent / "shared" / "data" / "bolster_rgbd_posed"
#: (held out, the capture's 12 photos): four draws from the 12 photos the bolster's protocol gives
#: (all but 4 and 11), one from 12 that hold those two
DRAWS = [((1, 5, 9), (0, 1, 2, 3, 5, 6, 7, 8, 9, 10, 12, 13)), ((2, 6, 10), (0, 1, 2, 3, 5, 6, 7, 8, 9, 10, 12, 13)),
         ((3, 8, 12), (0, 1, 2, 3, 5, 6, 7, 8, 9, 10, 12, 13)), ((0, 7, 13), (0, 1, 2, 3, 5, 6, 7, 8, 9, 10, 12, 13)),
         ((4, 8, 11), (0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 11, 12))]


def run_draw(held: tuple[int, ...], pool: tuple[int, ...], override: dict | None = None,
             motion_blur: int = 0) -> dict:
    import dataclasses
    import tempfile

    from bench.baselines import app_style_bake
    from scantex.io import load_scan
    from scantex.photos import load_photos
    from scantex.photos.training import VisibilitySettings, prepare_photos, score_photos
    from scantex.pipeline.config import preset
    from scantex.pipeline.enhance import enhance
    from scantex.views.raycast import RayCaster

    everything = load_photos(CAPTURE / "cameras.json")
    photos = everything.subset([i for i in pool if i not in held])
    temporary = tempfile.TemporaryDirectory(prefix="few_photos_")
    if motion_blur > 1:
        photos = dataclasses.replace(photos, images=tuple(
            _smeared(path, motion_blur, Path(temporary.name)) if k % 3 == 1 else path
            for k, path in enumerate(photos.images)))
    scan = load_scan(CAPTURE / "app_style_input" / "bolster_app_style.obj")  # its geometry and UV layout
    caster = RayCaster(scan.positions, scan.faces)
    app = app_style_bake(scan, photos, prepare_photos(scan, photos, range(len(photos)), caster, 640), size=2048)
    t = time.perf_counter()
    result = enhance(app, preset("default").override(photos__holdout=0, **(override or {})), photos=photos)
    seconds = time.perf_counter() - t
    held_views = prepare_photos(app, everything, list(held), caster, 640, VisibilitySettings(supersample=2))
    scores = score_photos({"input": app, "output": result.scan}, held_views, caster)
    temporary.cleanup()
    return {"scores": scores, "seconds": seconds}


def _smeared(path: Path, length: int, folder: Path) -> Path:
    """A copy of the photo at ``path`` in ``folder``, smeared by a horizontal box of ``length`` pixels (JPEG)."""
    import numpy as np
    from PIL import Image
    from scipy import ndimage

    image = np.asarray(Image.open(path).convert("RGB"), np.float32)
    image = ndimage.uniform_filter1d(image, length, axis=1, mode="nearest")
    out = folder / f"{Path(path).stem}_smeared.jpg"
    Image.fromarray(np.clip(np.rint(image), 0, 255).astype(np.uint8)).save(out, quality=95)
    return out


def main() -> None:
    from bench._results import parse_override

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--held", action="append", default=None, metavar="I,J,K",
                        help="three photos to hold out (repeat for more draws; the capture is the bolster's "
                             "protocol photos, all but 4 and 11, unless a held-out photo is one of them)")
    parser.add_argument("--override", action="append", default=[], metavar="SECTION__NAME=VALUE",
                        help="a config override for the scantex runs (JSON value or a string)")
    parser.add_argument("--motion-blur", type=int, default=0, metavar="L",
                        help="smear every third given photo by a horizontal box of L pixels (a shaken frame)")
    args = parser.parse_args()
    override = {k: v for item in args.override for k, v in parse_override(item).items()}
    if not CAPTURE.exists():
        print(f"{CAPTURE}: not found; skipped")
        return
    draws = DRAWS
    if args.held:
        draws = []
        for text in args.held:
            held = tuple(int(x) for x in text.split(","))
            pool = next((p for h, p in DRAWS if set(held) <= set(p)), DRAWS[-1][1])
            draws.append((held, pool))
    print("| held out | given | colour-matched PSNR (input -> output) | SSIM | enhance s |\n|---|---|---|---|---|")
    for held, pool in draws:
        r = run_draw(held, pool, override, args.motion_blur)
        i, o = r["scores"]["input"], r["scores"]["output"]
        given = ", ".join(str(p) for p in pool if p not in held)
        print(f"| {', '.join(map(str, held))} | {given} | {i['psnr_matched']:.2f} -> **{o['psnr_matched']:.2f}** "
              f"({o['psnr_matched'] - i['psnr_matched']:+.2f}) | {i['ssim_matched']:.3f} -> {o['ssim_matched']:.3f} | "
              f"{r['seconds']:.0f} |", flush=True)


if __name__ == "__main__":
    main()
