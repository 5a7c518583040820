"""Photos through a distorting lens, in each photogrammetry tool's format, on the real façade (skips without it).

    python bench/bench_lens.py     # a barrel lens, a fisheye (COLMAP, Metashape, Meshroom, OpenMVG, RealityCapture,
                                   # OpenSfM, OpenMVS), centred
    python bench/bench_lens.py --lens fisheye --no-write

The façade's 8 training photos (``../shared/data/facade_openmvs``, held-out photos 2 and 7) are drawn again through a
lens, computed here on its own (each pixel of the drawn photo takes the original's colour at the undistorted point,
found by fixed-point iteration on the lens's forward model, as OpenCV's ``undistortPoints``), with a focal length a
little longer than the original's so that the drawn photo stays inside it, and saved as JPEGs (quality 95). They are
written as a COLMAP text model (``OPENCV`` or ``OPENCV_FISHEYE``), and from it by :func:`write_metashape`,
:func:`write_meshroom`, :func:`write_openmvg`, :func:`write_realitycapture` (a fisheye's photos undistorted),
:func:`write_opensfm` and :func:`write_openmvs` (whose format holds no lens: the photos written undistorted, as PNGs);
``scantex enhance`` is given the app-style input and each (``--holdout 0``), and the written texture is scored through
the held-out photos' cameras at 640 px, colour-matched, against the same run on the original photos (``cameras.json``).
The originals are also resampled so that their principal point is the image's centre (``centred``: Bundler's and
VisualSfM's formats have no principal point, and the tools exporting them resample their photos so) and written by
:func:`write_bundler` and :func:`write_nvm`. Each run is its own process. Writes the 'lens formats' section of
bench/RESULTS.md.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
from bench._results import run_worker, update_section  # noqa: E402

DATA = ROOT.parent / "shared" / "data" / "facade_openmvs"
TRAIN, HELD = [0, 1, 3, 4, 5, 6, 8, 9], [2, 7]
#: lens: (COLMAP model, its parameters after fx fy cx cy, projection, focal length over the original's)
LENSES = {"barrel": ("OPENCV", (-0.12, 0.03, 0.0005, -0.0003), "perspective", 1.08),
          "fisheye": ("OPENCV_FISHEYE", (0.02, -0.01, 0.0, 0.0), "equidistant", 1.15)}

SCORE = r"""
import json, sys
spec = json.loads(sys.argv[1])
sys.path.insert(0, spec["root"])
from scantex.io import load_scan
from scantex.photos import load_photos
from scantex.photos.training import VisibilitySettings, prepare_photos, score_photos
from scantex.views.raycast import RayCaster
inp = load_scan(spec["input"])
scans = {"input": inp, **{k: load_scan(v) for k, v in spec["outputs"].items()}}
caster = RayCaster(inp.positions, inp.faces)
held = load_photos(spec["held"])
views = prepare_photos(inp, held, range(len(held)), caster, 640, VisibilitySettings(supersample=2))
s = score_photos(scans, views, caster)
print(json.dumps({k: [v["psnr_matched"], v["ssim_matched"]] for k, v in s.items()}))
"""


def distort(model: str, params, projection: str, x, y):
    """The lens's forward model on normalised coordinates (OpenCV's and COLMAP's)."""
    if projection == "equidistant":
        r = np.sqrt(x * x + y * y)
        scale = np.divide(np.arctan(r), r, out=np.ones_like(r), where=r > 0)
        x, y = x * scale, y * scale
        k, (p1, p2) = params, (0.0, 0.0)
    else:
        k, (p1, p2) = params[:2], params[2:]
    r2 = x * x + y * y
    radial = 1 + sum(c * r2 ** (i + 1) for i, c in enumerate(k))
    return x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x), y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y


def draw_through_lens(lens: str, out: Path) -> Path:
    """The training photos drawn through ``lens``, a COLMAP text model of them in ``out``; returns ``out``."""
    from PIL import Image
    from scipy.ndimage import map_coordinates
    from scipy.spatial.transform import Rotation

    model, params, projection, zoom = LENSES[lens]
    doc = json.loads((DATA / "cameras.json").read_text())
    (out / "images").mkdir(parents=True)
    cameras, images = [], []
    for n, i in enumerate(TRAIN):
        frame = doc["frames"][i]
        K, (W, H) = np.array(frame["K"]), (frame["width"], frame["height"])
        Kd = K.copy()
        Kd[:2, :2] *= zoom
        photo = np.asarray(Image.open(DATA / frame["image"]).convert("RGB"), np.float32)
        u, v = np.meshgrid(np.arange(W, dtype=np.float64), np.arange(H, dtype=np.float64))
        xd, yd = (u - Kd[0, 2]) / Kd[0, 0], (v - Kd[1, 2]) / Kd[1, 1]
        x, y = xd.copy(), yd.copy()
        for _ in range(30):  # fixed-point iteration: the undistorted point of each drawn pixel
            fx, fy = distort(model, params, projection, x, y)
            x, y = x + (xd - fx), y + (yd - fy)
        us, vs = K[0, 0] * x + K[0, 2], K[1, 1] * y + K[1, 2]
        if not ((us >= 0) & (us <= W - 1) & (vs >= 0) & (vs <= H - 1)).all():
            raise SystemExit(f"{lens}: the drawn photo {i} reaches outside the original: a longer focal length")
        drawn = np.stack([map_coordinates(photo[..., c], [vs, us], order=1) for c in range(3)], -1)
        name = f"{i:05d}.jpg"
        Image.fromarray(np.clip(np.round(drawn), 0, 255).astype(np.uint8)).save(out / "images" / name, quality=95)
        w2c = np.array(frame["world_to_camera"])
        qx, qy, qz, qw = Rotation.from_matrix(w2c[:3, :3]).as_quat()
        values = [Kd[0, 0], Kd[1, 1], Kd[0, 2] + 0.5, Kd[1, 2] + 0.5, *params]
        cameras.append(f"{n + 1} {model} {W} {H} " + " ".join(repr(float(p)) for p in values))
        images.append(f"{n + 1} " + " ".join(repr(float(p)) for p in (qw, qx, qy, qz, *w2c[:3, 3]))
                      + f" {n + 1} {name}\n")
    (out / "cameras.txt").write_text("\n".join(cameras) + "\n")
    (out / "images.txt").write_text("\n".join(images) + "\n")
    return out


def centre_photos(out: Path) -> Path:
    """The training photos resampled so that their principal point is the image's centre, cropped to the largest such
    window (bilinear), as RealityCapture's and Metashape's Bundler exports write undistorted photos; their
    ``cameras.json`` in ``out``; returns its path."""
    from PIL import Image
    from scipy.ndimage import map_coordinates

    doc = json.loads((DATA / "cameras.json").read_text())
    out.mkdir(parents=True)
    frames = []
    for i in TRAIN:
        frame = doc["frames"][i]
        K, (W, H) = np.array(frame["K"]), (frame["width"], frame["height"])
        half_w = int(np.floor(min(K[0, 2] + 0.5, W - 0.5 - K[0, 2]))) - 1
        half_h = int(np.floor(min(K[1, 2] + 0.5, H - 0.5 - K[1, 2]))) - 1
        w, h = 2 * half_w, 2 * half_h
        photo = np.asarray(Image.open(DATA / frame["image"]).convert("RGB"), np.float32)
        v, u = np.mgrid[0:h, 0:w].astype(np.float64)
        # the centred photo's pixel (u, v) shows the original's (cx - (w - 1) / 2 + u, cy - (h - 1) / 2 + v)
        at = [v + K[1, 2] - (h - 1) / 2, u + K[0, 2] - (w - 1) / 2]
        centred = np.stack([map_coordinates(photo[..., c], at, order=1) for c in range(3)], -1)
        name = out / f"{i:05d}.png"
        Image.fromarray(np.clip(np.round(centred), 0, 255).astype(np.uint8)).save(name)
        Kc = K.copy()
        Kc[0, 2], Kc[1, 2] = (w - 1) / 2, (h - 1) / 2
        frames.append(dict(frame, image=str(name), width=w, height=h, K=Kc.tolist()))
    (out / "cameras.json").write_text(json.dumps(dict(doc, frames=frames)))
    return out / "cameras.json"


def frames_file(indices, out: Path) -> Path:
    doc = json.loads((DATA / "cameras.json").read_text())
    doc["frames"] = [dict(doc["frames"][i], image=str(DATA / doc["frames"][i]["image"])) for i in indices]
    out.write_text(json.dumps(doc))
    return out


def enhance(photos: Path, out: Path) -> tuple[float, Path]:
    start = time.perf_counter()
    subprocess.run([sys.executable, "-m", "scantex", "enhance", str(DATA / "app_style_input" / "scene_mesh_baked.obj"),
                    "--photos", str(photos), "--holdout", "0", "-o", str(out), "-q"], check=True, cwd=ROOT)
    return time.perf_counter() - start, out / "enhanced.obj"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--lens", choices=sorted(LENSES) + ["centred"], action="append",
                        help="a lens to draw the photos through, or centred: the originals resampled to a centred "
                             "principal point, as Bundler's and VisualSfM's formats need (default: all)")
    parser.add_argument("--no-write", action="store_true", help="print only, leave RESULTS.md alone")
    args = parser.parse_args()
    if not DATA.exists():
        print(f"{DATA} not present: nothing to do")
        return
    from scantex.photos import (load_photos, write_bundler, write_meshroom, write_metashape, write_nvm, write_openmvg,
                                write_openmvs, write_opensfm, write_realitycapture)

    lines = ["## Photos through a lens, in each tool's format (`bench/bench_lens.py`)", "",
             "| photos given | held-out colour-matched PSNR dB (SSIM) | enhance s |", "|---|---|---|"]
    with tempfile.TemporaryDirectory(prefix="scantex-lens-") as tmp:
        tmp = Path(tmp)
        runs = {"originals (`cameras.json`, pinhole)": frames_file(TRAIN, tmp / "train.json")}
        for lens in args.lens or sorted(LENSES) + ["centred"]:
            if lens == "centred":  # no lens: the photos resampled as Bundler and VisualSfM exports write them
                photos = load_photos(centre_photos(tmp / lens / "photos"))
                runs["centred: Bundler `bundle.out`"] = write_bundler(photos, tmp / lens / "bundler")
                runs["centred: VisualSfM `.nvm`"] = write_nvm(photos, tmp / lens / "nvm")
                continue
            colmap = draw_through_lens(lens, tmp / lens / "colmap")
            photos = load_photos(colmap)
            runs[f"{lens}: COLMAP `{LENSES[lens][0]}`"] = colmap
            runs[f"{lens}: Metashape XML"] = write_metashape(photos, tmp / lens / "metashape")
            runs[f"{lens}: Meshroom `cameras.sfm`"] = write_meshroom(photos, tmp / lens / "meshroom")
            runs[f"{lens}: OpenMVG `sfm_data.json`"] = write_openmvg(photos, tmp / lens / "openmvg")
            # Brown's lens holds the barrel; a fisheye's photos are written undistorted
            undistorted = " (written undistorted)" if LENSES[lens][2] != "perspective" else ""
            runs[f"{lens}: RealityCapture XMP{undistorted}"] = write_realitycapture(photos, tmp / lens / "rc")
            runs[f"{lens}: OpenSfM `reconstruction.json`"] = write_opensfm(photos, tmp / lens / "opensfm")
            # a format without a lens model: the photos written undistorted (PNG), read as pinhole photos
            runs[f"{lens}: OpenMVS `scene.mvs` (written undistorted)"] = write_openmvs(photos, tmp / lens / "openmvs")
        outputs, seconds = {}, {}
        for k, (label, photos) in enumerate(runs.items()):
            seconds[label], outputs[label] = enhance(photos, tmp / f"out{k}")
            print(f"{label}: {seconds[label]:.1f} s", flush=True)
        scores = run_worker(SCORE, {"root": str(ROOT), "input": str(DATA / "app_style_input" / "scene_mesh_baked.obj"),
                                    "held": str(frames_file(HELD, tmp / "held.json")),
                                    "outputs": {label: str(path) for label, path in outputs.items()}})
    psnr, ssim = scores["input"]
    lines.append(f"| the app-style input | {psnr:.2f} ({ssim:.3f}) | - |")
    for label in runs:
        psnr, ssim = scores[label]
        lines.append(f"| {label} | **{psnr:.2f}** ({ssim:.3f}) | {seconds[label]:.1f} |")
    described = ", ".join(f"{name}: {model} {params}, focal length {zoom} times the original"
                          for name, (model, params, _, zoom) in LENSES.items())
    lines += ["", f"The façade's training photos {TRAIN} drawn through each lens ({described}), or resampled so that "
              "their principal point is the image's centre and cropped (2756x2002, as a Bundler export writes them: "
              f"centred), held-out photos {HELD}; one run each. Command: `python bench/bench_lens.py`"]
    print("\n".join(lines))
    if not args.no_write:
        update_section("lens formats", "\n".join(lines))


if __name__ == "__main__":
    main()
