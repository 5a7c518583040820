"""scantex's photo mode against texrecon (mvs-texturing) on the real captures, on one machine, in one run.

    python bench/bench_texrecon.py --texrecon /path/to/texrecon              # bolster and façade, 3 pairs each
    python bench/bench_texrecon.py --texrecon "$(which texrecon)" --only bolster -n 5

texrecon is not a dependency and is not built by this project: build mvs-texturing yourself (its sources and
their ``elibs`` dependencies, offline from source snapshots) and pass its binary. Skips without
``../shared/data`` or without the binary.

For each capture of ``../shared/data`` (its held-out protocol): both programs get ONLY the training photos,
texrecon as its scene folder (the photos copied, one ``.cam`` beside each: :func:`scantex.photos.write_mve`) and the
input mesh's geometry as a PLY (texrecon makes its own UV layout; ``--keep_unseen_faces`` so that it
returns every face), scantex as a filtered ``cameras.json`` and the input mesh (``photos.holdout`` 0): the
app-style input, or for ``bolster_bare`` the untextured Kinect mesh (texrecon's own case; its input scores a
flat grey),
from the command line as a user runs it. The two commands run in turn, pair by pair, each a whole process
to its outputs written (wall seconds and peak memory of the process from the operating system). Then input,
scantex and texrecon are rendered through the held-out photos' recorded cameras at 640 px and scored on the
pixels the visibility test keeps, colour-matched (:func:`scantex.photos.training.score_photos`). Prints
Markdown; the numbers go into bench/RESULTS.md by hand.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
from bench.bench_real_photos import CAPTURES, DATA, training_frames  # noqa: E402


def timed(command: list[str]) -> tuple[float, float]:
    """Wall seconds and peak resident MiB of ``command`` run to its end (its output thrown away)."""
    with tempfile.TemporaryFile() as errors:
        t = time.perf_counter()
        process = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=errors)
        _, status, usage = os.wait4(process.pid, 0)
        seconds = time.perf_counter() - t
        process.returncode = os.waitstatus_to_exitcode(status)
        if process.returncode:
            errors.seek(0)
            last = (errors.read().decode(errors="replace").strip().splitlines() or [""])[-1]
            raise RuntimeError(f"{Path(command[0]).name} failed ({process.returncode}): {last}")
    return seconds, usage.ru_maxrss / 1024


def fresh(folder: Path) -> None:
    shutil.rmtree(folder, ignore_errors=True)
    folder.mkdir()


def run_capture(name: str, texrecon: str, pairs: int, work: Path) -> str:
    import trimesh

    from scantex.io import load_scan
    from scantex.photos import load_photos, write_mve
    from scantex.photos.training import VisibilitySettings, prepare_photos, score_photos
    from scantex.views.raycast import RayCaster

    cams, mesh, held = CAPTURES[name]
    cameras = DATA / cams
    train = training_frames(cameras, held)
    (work / "cameras.json").write_text(json.dumps({"frames": train}))
    write_mve(load_photos(work / "cameras.json"), work / "scene")  # texrecon's scene folder: photos beside .cam files
    scan = load_scan(DATA / mesh)
    trimesh.Trimesh(scan.positions, scan.faces, process=False).export(work / "mesh.ply")

    scantex = [sys.executable, "-m", "scantex", "enhance", str(DATA / mesh), "--photos", str(work / "cameras.json"),
               "--holdout", "0", "-o", str(work / "scantex"), "--overwrite", "--quiet"]
    classical = [texrecon, "--keep_unseen_faces", str(work / "scene"), str(work / "mesh.ply"),
                 str(work / "texrecon" / "textured")]
    runs: dict[str, list[tuple[float, float]]] = {"scantex": [], "texrecon": []}
    label = "texrecon"
    for _ in range(pairs):
        runs["scantex"].append(timed(scantex))
        fresh(work / "texrecon")
        try:
            runs["texrecon"].append(timed(classical))
        except RuntimeError as e:
            if "--skip_local_seam_leveling" in classical:
                raise
            # its Poisson blending of the seams crashes on some inputs (mvs-texturing issue 125, open): without it
            print(f"{name}: {e}; again with --skip_local_seam_leveling", file=sys.stderr)
            classical.insert(1, "--skip_local_seam_leveling")
            label = "texrecon (`--skip_local_seam_leveling`: it crashed with it)"
            fresh(work / "texrecon")  # a crashed run leaves its temporary folder, which the next refuses
            runs["texrecon"].append(timed(classical))

    everything = load_photos(cameras)
    caster = RayCaster(scan.positions, scan.faces)
    views = prepare_photos(scan, everything, held, caster, 640, VisibilitySettings(supersample=2))
    scans = {"input": scan, "scantex": load_scan(work / "scantex" / "enhanced.obj"),
             "texrecon": load_scan(work / "texrecon" / "textured.obj")}
    scores = {}
    for key, textured in scans.items():  # each its own ray caster: texrecon's file orders the faces its own way
        scores.update(score_photos({key: textured}, views, RayCaster(textured.positions, textured.faces)))
    ratios = [a[0] / b[0] for a, b in zip(runs["scantex"], runs["texrecon"])]
    rows = []
    for key in ("input", "scantex", "texrecon"):
        s = scores[key]
        seconds = (f"{statistics.median(t for t, _ in runs[key]):.2f} | {max(m for _, m in runs[key]):.0f}"
                   if key in runs else "- | -")
        shown = label if key == "texrecon" else key
        rows.append(f"| {name} | {shown} | {s['psnr_matched']:.2f} | {s['ssim_matched']:.3f} | {seconds} |")
    rows.append(f"| {name} | scantex / texrecon, pair by pair | | | **{statistics.median(ratios):.2f}x** "
                f"({min(ratios):.2f}-{max(ratios):.2f}) | |")
    return "\n".join(rows)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--texrecon", default=shutil.which("texrecon"), help="the texrecon binary (default: on PATH)")
    parser.add_argument("--only", choices=sorted(CAPTURES), action="append")
    parser.add_argument("-n", "--pairs", type=int, default=3, help="timed runs of each program, in turn")
    args = parser.parse_args()
    if not DATA.exists():
        print(f"{DATA} not present: nothing to do")
        return
    if not args.texrecon or not Path(args.texrecon).exists():
        print("no texrecon binary (pass --texrecon PATH): nothing to do")
        return
    print("| capture | texture | colour-matched PSNR dB (held out) | SSIM | wall s (median) | peak MiB |")
    print("|---|---|---|---|---|---|")
    for name in args.only or sorted(CAPTURES):
        with tempfile.TemporaryDirectory(prefix=f"scantex_texrecon_{name}_") as tmp:
            print(run_capture(name, args.texrecon, args.pairs, Path(tmp)), flush=True)


if __name__ == "__main__":
    main()
