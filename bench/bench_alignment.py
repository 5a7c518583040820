"""The alignment check on the real captures in ../shared/data: aligned passes, moved or turned is refused.

    python bench/bench_alignment.py
    python bench/bench_alignment.py --hints     # a mesh in other units, poses in another convention

For the bolster (app-style input and the bare Kinect mesh) and the façade (app-style input): the mesh as
captured, then moved by 5 cm along each axis (the façade, nine times larger, by a proportionate 43 cm:
4.2 % of its size, as 5 cm is of the bolster's), and turned 5 degrees about each axis through its
centroid. Prints the verdict and the estimated correction; writes the 'alignment' section of
bench/RESULTS.md. With ``--hints``: the meshes exported in millimetres or centimetres, and the cameras given as
camera-to-world poses (OpenCV's or OpenGL's axes), what the refusal says (``require_alignment``); writes the
'alignment hints' section. Skips without ../shared/data.
"""

from __future__ import annotations

import dataclasses
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
from bench._results import update_section  # noqa: E402

DATA = ROOT.parent / "shared" / "data"
SETS = {"bolster (app-style OBJ)": ("bolster_rgbd_posed/app_style_input/bolster_app_style.obj", "bolster_rgbd_posed/cameras.json"),
        "bolster (bare PLY)": ("bolster_rgbd_posed/bloster.ply", "bolster_rgbd_posed/cameras.json"),
        "façade (app-style OBJ)": ("facade_openmvs/app_style_input/scene_mesh_baked.obj", "facade_openmvs/cameras.json")}


def moved(scan, offset=(0.0, 0.0, 0.0), turn=0.0, axis=2):
    c = scan.positions.mean(axis=0)
    a = np.radians(turn)
    i, j = [k for k in range(3) if k != axis]
    R = np.eye(3)
    R[i, i], R[i, j], R[j, i], R[j, j] = np.cos(a), -np.sin(a), np.sin(a), np.cos(a)
    return dataclasses.replace(scan, positions=(scan.positions - c) @ R.T + c + np.asarray(offset))


def main() -> None:
    from scantex.io import load_scan
    from scantex.photos import load_photos
    from scantex.photos.alignment import check_alignment

    if not DATA.exists():
        print(f"{DATA} not present: nothing to do")
        return
    lines = ["## Alignment check on real captures", "",
             "| mesh | change | verdict | estimated move | estimated turn | image motion (% of side) | "
             "edge ratio (as is -> corrected) | time s |", "|---|---|---|---|---|---|---|---|"]
    for name, (mesh, cams) in SETS.items():
        scan, photos = load_scan(DATA / mesh), load_photos(DATA / cams)
        shift = 0.05 * float(np.linalg.norm(np.ptp(scan.positions, axis=0))) / 1.18  # 5 cm on the 1.18 m bolster
        changes = [("none", scan)]
        changes += [(f"moved {100 * shift:.0f} cm along {'xyz'[k]}", moved(scan, np.eye(3)[k] * shift)) for k in range(3)]
        changes += [(f"turned 5 deg about {'xyz'[k]}", moved(scan, turn=5.0, axis=k)) for k in range(3)]
        for label, s in changes:
            t = time.perf_counter()
            r = check_alignment(s, photos)
            verdict = "pass" if r.ok else ("refused: by how much" if "away from" in (r.problem or "")
                                           else "refused: edges miss")
            lines.append(f"| {name} | {label} | {verdict} | {100 * r.offset_m:.1f} cm | {r.turn_deg:.1f} deg | "
                         f"{100 * r.displacement:.2f} | {r.ratio:.2f} -> {r.corrected_ratio:.2f} | "
                         f"{time.perf_counter() - t:.0f} |")
            print(lines[-1], flush=True)
    lines += ["", "Refused when the best rigid correction moves the mesh's image by more than 0.6 % of the photo "
              "side (and turns it more than 2 degrees or shifts it more than 2 % of its size), or when even after "
              "it the edges of the best third of the photos match no better than half as well as unrelated edges. "
              "4 photos are checked, up to 12 when fewer than 3 show edges or their edges miss. Times: one check, "
              "seconds. Command: `python bench/bench_alignment.py`"]
    update_section("alignment", "\n".join(lines))


def hints() -> None:
    from scantex.errors import ScanError
    from scantex.io import load_scan
    from scantex.photos import load_photos
    from scantex.photos.alignment import require_alignment

    if not DATA.exists():
        print(f"{DATA} not present: nothing to do")
        return
    gl = np.diag([1.0, -1.0, -1.0, 1.0])
    lines = ["## Alignment check: a mesh in other units, poses in another convention (`bench_alignment.py --hints`)",
             "", "| mesh | change | what the refusal says after its problem | time s |", "|---|---|---|---|"]
    for name in ("bolster (app-style OBJ)", "façade (app-style OBJ)"):
        mesh, cams = SETS[name]
        scan, photos = load_scan(DATA / mesh), load_photos(DATA / cams)

        def posed(change):
            return dataclasses.replace(photos, cameras=tuple(dataclasses.replace(c, world_to_camera=change(
                c.world_to_camera)) for c in photos.cameras))

        shift = 0.05 * float(np.linalg.norm(np.ptp(scan.positions, axis=0))) / 1.18
        changes = [("in millimetres", dataclasses.replace(scan, positions=scan.positions * 1000.0), photos),
                   ("in centimetres", dataclasses.replace(scan, positions=scan.positions * 100.0), photos),
                   ("camera-to-world poses", scan, posed(np.linalg.inv)),
                   ("OpenGL camera-to-world poses", scan, posed(lambda w2c: np.linalg.inv(gl @ w2c))),
                   (f"moved {100 * shift:.0f} cm along x (no hint)", moved(scan, (shift, 0.0, 0.0)), photos)]
        for label, s, p in changes:
            t = time.perf_counter()
            try:
                require_alignment(s, p)
                said = "(passed)"
            except ScanError as e:
                text = str(e)
                said = text.split(", but ", 1)[1] if ", but " in text else "(no hint: " + text.split(": ")[2][:60] + ")"
            lines.append(f"| {name} | {label} | {said} | {time.perf_counter() - t:.1f} |")
            print(lines[-1], flush=True)
    lines += ["", "A refused mesh is checked again on 4 photos with the cameras in other units (those that make the "
              "mesh's size plausible against the cameras' spread) and with the poses read in another convention; "
              "the time is the whole refusal; a hint is given where a reading fits as it is (image motion under 0.6 %), "
              "and the pose conventions only for a `cameras.json`. The façade exported in *centimetres* passes the "
              "check (its image moves 19 % of the photo's side to fit, by a 19 m shift, under the 2 % of its 1 km "
              "size a shift must exceed): a pass needing over 5 % is tried in other units too, and refused where one "
              "fits as it is with its edges at half the distance or closer (the façade: 8.4 px in centimetres, 1.0 px "
              "in metres). Refusing any image motion over 5 % whatever the shift had refused aligned close-ups with "
              "realistic pose errors (the demo room's walls from 0.3-0.4 m, 0.35-0.5 degrees and 10-15 mm: 5-24 %); "
              "they pass (a close-up of exact poses fits in feet at 3.3 px, against 0.8 px as it is). Command: "
              "`python bench/bench_alignment.py --hints`"]
    update_section("alignment hints", "\n".join(lines))


if __name__ == "__main__":
    hints() if "--hints" in sys.argv[1:] else main()
