"""The first run on a machine: numba's loops compiled in the run, or ahead by ``scantex precompile``.

    python bench/bench_first_run.py            # the bolster's photo mode, 1 round
    python bench/bench_first_run.py -n 3

numba compiles scantex's loops the first time a run calls them and caches them (``scantex.jit``). Each round
gives each of these a fresh, empty cache (``NUMBA_CACHE_DIR`` in a temporary folder), in turn, each a whole
process to its outputs written:

- the first run, which compiles;
- a second run on that cache;
- ``scantex precompile``, then a run after it.

The run is ``scantex enhance`` on ``../shared/data``'s bolster app-style input with its 12 training photos
(``--holdout 0``), as a user runs it. Wall seconds and peak resident memory come from the operating system.
The atlases of the first run and of the run after precompile are compared byte for byte.

Prints Markdown; the numbers go into bench/RESULTS.md by hand. Skips without ``../shared/data``.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
from bench.bench_real_photos import capture_files, training_frames  # noqa: E402
from bench.bench_texrecon import timed  # noqa: E402


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("-n", "--rounds", type=int, default=1, help="rounds, each with fresh caches")
    args = parser.parse_args()
    files = capture_files("bolster")
    if files is None:
        return
    cameras, mesh, held = files
    runs: dict[str, list[tuple[float, float]]] = {"first run": [], "second run": [], "scantex precompile": [],
                                                  "first run after precompile": []}
    same = []
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        (work / "cameras.json").write_text(json.dumps({"frames": training_frames(cameras, held)}))
        scantex = [sys.executable, "-m", "scantex"]

        def enhance(out: str) -> list[str]:
            return [*scantex, "enhance", str(mesh), "--photos", str(work / "cameras.json"), "--holdout", "0",
                    "-o", str(work / out), "--overwrite", "--quiet"]

        for r in range(args.rounds):
            os.environ["NUMBA_CACHE_DIR"] = str(work / f"cold_{r}")
            runs["first run"].append(timed(enhance("cold")))
            runs["second run"].append(timed(enhance("warm")))
            os.environ["NUMBA_CACHE_DIR"] = str(work / f"precompiled_{r}")
            runs["scantex precompile"].append(timed([*scantex, "precompile", "--quiet"]))
            runs["first run after precompile"].append(timed(enhance("precompiled")))
            atlases = [sorted((work / out).glob("*.png")) for out in ("cold", "precompiled")]
            same.append(all(a.read_bytes() == b.read_bytes() for a, b in zip(*atlases)) and len(atlases[0]) > 0)
    print("| run (a fresh numba cache each round) | wall s (median) | peak MiB |")
    print("|---|---|---|")
    for name, timings in runs.items():
        print(f"| {name} | {statistics.median(t for t, _ in timings):.1f} | {max(m for _, m in timings):.0f} |")
    print(f"\nThe first run's atlas and the one after precompile the same bytes: {sum(same)} of {len(same)} rounds. "
          f"Command: `python bench/bench_first_run.py -n {args.rounds}`")


if __name__ == "__main__":
    main()
