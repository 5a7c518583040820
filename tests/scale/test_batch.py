"""``scantex batch`` on the local process pool: failures recorded, reruns resumable, summary written."""

from __future__ import annotations

import csv
import json
import os
import subprocess
import sys

import numpy as np
import pytest

from scantex.errors import ScanError
from scantex.io import load_scan
from scantex.scale import batch
from scantex.scale.executors import GiB, Job, LocalPool, WorkerLost
from scantex.scale.inputs import collect_inputs, read_manifest
from scantex.scale.resources import footprint

from tests.conftest import textured_cube
from tests.io.test_discover import exports  # noqa: F401  (a fixture)
from tests.scale.conftest import TINY


def check_batch(out, scans_root, result):
    """Two scans done, the corrupt one failed with its one-line error, the summary lists all three."""
    by_name = {r["name"]: r for r in result.records}
    assert set(by_name) == {"wall0__scan", "wall1__scan", "corrupt__scan"}
    assert by_name["corrupt__scan"]["status"] == "failed"
    assert "corrupt/scan.obj" in by_name["corrupt__scan"]["error"] and "\n" not in by_name["corrupt__scan"]["error"]
    for name in ("wall0__scan", "wall1__scan"):
        r = by_name[name]
        assert r["status"] == "done", r.get("error")
        assert r["scores"]["kind"] == "held-out views vs ground truth"  # ground_truth.obj beside it was used
        assert r["peak_memory_gib"] > 0.1 and r["seconds"] > 0
        before = load_scan(scans_root / name.split("__")[0] / "scan.obj")
        after = load_scan(out / name / "enhanced.obj")
        assert np.array_equal(before.positions, after.positions) and np.array_equal(before.faces, after.faces)
        assert (out / r["report"]).exists()
    summary = json.loads((out / "summary.json").read_text())
    assert (summary["scans"], summary["done"], summary["failed"]) == (3, 2, 1)
    rows = list(csv.DictReader((out / "summary.csv").read_text().splitlines()))
    assert {r["name"]: r["status"] for r in rows} == {n: r["status"] for n, r in by_name.items()}
    index = (out / "index.html").read_text()
    assert 'href="wall0__scan/report.html"' in index and "face 1 refers to vertex 9" in index
    assert not (out / "corrupt__scan").exists()  # nothing half-written for the failed scan


def test_local_pool_batch_then_rerun(tmp_path, three_scans):
    out = tmp_path / "batch"
    result = batch([three_scans], out, TINY, workers=2)
    check_batch(out, three_scans, result)
    stamps = {n: os.stat(out / n / "batch.json").st_mtime_ns for n in ("wall0__scan", "wall1__scan")}

    again = batch([three_scans], out, TINY, workers=2)
    by_name = {r["name"]: r for r in again.records}
    for name, stamp in stamps.items():
        assert by_name[name]["reused"] and by_name[name]["status"] == "done"
        assert os.stat(out / name / "batch.json").st_mtime_ns == stamp  # not redone
    assert by_name["corrupt__scan"]["status"] == "failed"  # retried, fails again
    check_batch(out, three_scans, again)

    with pytest.raises(ScanError, match="another config"):
        batch([three_scans], out, TINY.override(seed=5))
    # a folder made by an earlier scantex, whose config lacks a section added since (written as its defaults):
    # the same config, its finished scans reused
    stored = json.loads((out / "batch_config.json").read_text())
    del stored["output"]
    (out / "batch_config.json").write_text(json.dumps(stored))
    older = batch([three_scans], out, TINY, workers=2)
    assert {r["name"]: bool(r.get("reused")) for r in older.records} == {
        "wall0__scan": True, "wall1__scan": True, "corrupt__scan": False}
    with pytest.raises(ScanError, match="another config"):
        batch([three_scans], out, TINY.override(output__texture_format="jpeg"))


def test_cli_batch_reports_failures(tmp_path, three_scans):
    out = tmp_path / "cli"
    proc = subprocess.run([sys.executable, "-m", "scantex", "batch", str(three_scans / "corrupt"), "-o", str(out),
                           "-q"], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 1
    assert "corrupt__scan" not in proc.stdout and "scan: " in proc.stderr and "refers to vertex 9" in proc.stderr
    assert json.loads((out / "summary.json").read_text())["failed"] == 1
    proc = subprocess.run([sys.executable, "-m", "scantex", "batch", str(tmp_path / "missing"), "-o", str(out)],
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2 and proc.stderr.strip().endswith("missing: no such file or folder")


def test_inputs_folders_manifests_and_names(tmp_path, three_scans):
    scans = collect_inputs([three_scans])
    assert [s.name for s in scans] == ["corrupt__scan", "wall0__scan", "wall1__scan"]
    assert scans[1].ground_truth == three_scans / "wall0" / "ground_truth.obj"
    (tmp_path / "m.json").write_text(json.dumps({"scans": [
        {"mesh": str(three_scans / "wall0" / "scan.obj"), "photos": "caps/a", "name": "room A"},
        str(three_scans / "wall1" / "scan.obj")]}))
    a, b = collect_inputs([tmp_path / "m.json"])
    assert (a.name, a.photos, b.name) == ("room_A", tmp_path / "caps" / "a", "scan")
    (tmp_path / "m.csv").write_text("mesh,ground_truth\nx/scan.obj,x/gt.obj\ny/scan.obj,\n")
    rows = read_manifest(tmp_path / "m.csv")
    assert rows[0].ground_truth == tmp_path / "x" / "gt.obj" and rows[1].ground_truth is None
    (tmp_path / "m.txt").write_text("# rooms\nr1/scan.obj photos1/\nr2/scan.obj\n")
    named = collect_inputs([tmp_path / "m.txt"])
    assert [s.name for s in named] == ["r1__scan", "r2__scan"] and named[0].photos == tmp_path / "photos1"
    (tmp_path / "bad.json").write_text(json.dumps([{"mesh": "a.obj", "colour": 1}]))
    with pytest.raises(ScanError, match="scan 1 of the manifest: unknown key 'colour'"):
        collect_inputs([tmp_path / "bad.json"])
    (tmp_path / "empty").mkdir()
    with pytest.raises(ScanError, match="no mesh files"):
        collect_inputs([tmp_path / "empty"])


def test_footprint_reads_faces_and_atlas_from_headers(three_scans):
    scan = load_scan(three_scans / "wall0" / "scan.obj")
    fp = footprint(three_scans / "wall0" / "scan.obj")
    assert fp.faces == scan.n_faces
    assert fp.atlas_texels == scan.materials[0].image.shape[0] * scan.materials[0].image.shape[1]
    assert fp.output_texels() == 4 * fp.atlas_texels
    assert footprint(three_scans / "nothing.obj").faces >= 1  # never raises


def test_memory_gate_keeps_big_jobs_apart():
    big = [Job(f"big{i}", print, memory=6 * GiB) for i in range(2)]
    small = Job("small", print, memory=1 * GiB)
    running = {object(): big[0]}
    # 8 GiB budget: the second big job must wait, the small one fits beside the first
    assert LocalPool._next([big[1], small], running, workers=4, budget=8 * GiB, alone=set()) is small
    assert LocalPool._next([big[1]], running, workers=4, budget=8 * GiB, alone=set()) is None
    # a job bigger than the whole budget still runs, alone
    assert LocalPool._next([big[1]], {}, workers=4, budget=4 * GiB, alone=set()) is big[1]
    assert LocalPool._next([small], running, workers=1, budget=64 * GiB, alone=set()) is None


def square(x):
    return x * x


def die(code):
    os._exit(code)


def test_pool_blames_only_the_job_whose_worker_died():
    jobs = [Job("dies", die, (3,)), Job("a", square, (3,)), Job("b", square, (4,))]
    results = {job.key: out for job, out in LocalPool(workers=2).run(jobs)}
    assert isinstance(results["dies"], WorkerLost)
    assert results["a"] == 9 and results["b"] == 16


def test_a_script_that_starts_jobs_at_import_is_told_so(tmp_path):
    """Each spawned worker imports the calling script again: a script that starts its jobs at import, not under
    ``if __name__ == "__main__":``, killed every worker in its bootstrap, and the run ended on "the worker process
    died (out of memory?)"."""
    script = tmp_path / "unguarded.py"
    script.write_text("from scantex.scale.executors import Job, LocalPool\n"
                      "from tests.scale.test_batch import square\n"
                      "print(list(LocalPool(workers=1).run([Job('a', square, (3,))]))[0][1])\n")
    proc = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=120,
                          cwd=os.getcwd(), env={**os.environ, "PYTHONPATH": os.getcwd()})
    assert "worker process died" in proc.stdout
    assert 'unguarded.py starts its jobs when imported, which each worker does again' in proc.stdout
    assert "every worker process imports it again" in proc.stderr  # the worker's own log says why it stopped
    guarded = tmp_path / "guarded.py"
    guarded.write_text("from scantex.scale.executors import Job, LocalPool\n"
                       "from tests.scale.test_batch import square\n"
                       "if __name__ == '__main__':\n"
                       "    print(list(LocalPool(workers=1).run([Job('a', square, (3,))]))[0][1])\n")
    proc = subprocess.run([sys.executable, str(guarded)], capture_output=True, text=True, timeout=120,
                          cwd=os.getcwd(), env={**os.environ, "PYTHONPATH": os.getcwd()})
    assert proc.stdout.strip() == "9", proc.stderr


def write_pid_and_wait(path):
    import pathlib
    import time

    pathlib.Path(path).write_text(str(os.getpid()))
    time.sleep(120)


def worker_pid(pid_file, alive=lambda: True) -> int:
    """The pid :func:`write_pid_and_wait` wrote, once it has (``alive``: whether to keep waiting)."""
    import time

    deadline = time.monotonic() + 60
    while not pid_file.exists() or not pid_file.read_text():
        assert time.monotonic() < deadline and alive()
        time.sleep(0.2)
    return int(pid_file.read_text())


def assert_ends(pid: int, after: str, seconds: float = 15) -> None:
    """Process ``pid`` ends within ``seconds`` (else it is killed, no orphan left by the test, and the test fails)."""
    import signal
    import time

    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        try:
            os.kill(pid, 0)
        except ProcessLookupError:
            return
        time.sleep(0.2)
    os.kill(pid, signal.SIGKILL)
    raise AssertionError(f"the worker outlived {after} by {seconds:.0f} s")


def test_workers_end_when_their_parent_is_killed(tmp_path):
    """``kill -9`` of a tiled run (or the out-of-memory killer) left its pool's workers running, adopted by
    init, each computing a tile nobody would fuse and holding its memory. They end within seconds now."""
    import signal

    pid_file = tmp_path / "worker.pid"
    script = ("from scantex.scale.executors import Job, LocalPool\n"
              "from tests.scale.test_batch import write_pid_and_wait\n"
              f"list(LocalPool(workers=1).run([Job('w', write_pid_and_wait, ({str(pid_file)!r},))]))\n")
    parent = subprocess.Popen([sys.executable, "-c", script], cwd=os.getcwd())
    worker = worker_pid(pid_file, alive=lambda: parent.poll() is None)
    os.kill(parent.pid, signal.SIGKILL)
    parent.wait()
    assert_ends(worker, "its parent")


def test_a_stopped_pool_stops_its_workers(tmp_path):
    """Ctrl-C, or SIGTERM (which ``scantex enhance`` turns into an exception), while a job runs: the pool's exit
    had waited for the running jobs to finish (a tiled run's tiles: minutes); its workers are stopped now."""
    import time

    pid_file = tmp_path / "worker.pid"
    runs = LocalPool(workers=2).run([Job("quick", square, (3,)), Job("long", write_pid_and_wait, (str(pid_file),))])
    job, result = next(runs)
    assert job.key == "quick" and result == 9
    worker = worker_pid(pid_file)
    started = time.monotonic()
    with pytest.raises(KeyboardInterrupt):
        runs.throw(KeyboardInterrupt)
    assert time.monotonic() - started < 30  # the long job sleeps 120 s
    assert_ends(worker, "its stopped pool")


def test_a_scan_refused_after_its_work_folder_was_made_leaves_none(tmp_path):
    """A scan that loads but is refused by ``enhance`` (here: no colour and no photos) fails with its one-line
    error, and its empty work folder ``<name>.partial`` is not left beside the other scans' outputs."""
    from scantex.io import save_scan
    from scantex.pipeline.config import preset
    from scantex.scale.batch import enhance_one
    from scantex.scale.inputs import ScanInput
    from scantex.scan import Scan
    from tests.conftest import textured_cube

    cube = textured_cube(materials=1)
    save_scan(Scan(cube.positions, cube.faces), tmp_path / "bare.obj")
    out = tmp_path / "out"
    record = enhance_one(ScanInput(tmp_path / "bare.obj", name="bare"), preset("fast").to_dict(), str(out), 1, False)
    assert record["status"] == "failed" and "has no colour to enhance" in record["error"]
    assert not (out / "bare.partial").exists() and not (out / "bare").exists()


def test_manifests_as_spreadsheets_and_editors_write_them(tmp_path):
    """A CSV saved by a spreadsheet starts with a byte-order mark and ends its lines in CRLF; a .txt line may
    name a path with spaces, whole or in quotes."""
    (tmp_path / "m.csv").write_bytes(b"\xef\xbb\xbfmesh,name\r\nx/scan.obj,first\r\n")
    (row,) = read_manifest(tmp_path / "m.csv")
    assert (row.mesh, row.name) == (tmp_path / "x" / "scan.obj", "first")
    (tmp_path / "My Scan").mkdir()
    (tmp_path / "My Scan" / "scan 2.obj").write_text("v 0 0 0\n")
    (tmp_path / "m.txt").write_text('My Scan/scan 2.obj\n"My Scan/scan 2.obj" "caps/room 1"\n')
    a, b = read_manifest(tmp_path / "m.txt")
    assert a.mesh == b.mesh == tmp_path / "My Scan" / "scan 2.obj"
    assert a.photos is None and b.photos == tmp_path / "caps" / "room 1"


def test_a_rerun_never_takes_another_scans_output_for_its_own(tmp_path, three_scans):
    """Two scans of one name in one batch folder, run one after the other: the second was reported done from
    the first's output, and never enhanced. It is refused in its record; the first's output stays."""
    out = tmp_path / "batch"
    assert batch([three_scans / "wall0" / "scan.obj"], out, TINY, workers=1).records[0]["status"] == "done"
    stamp = os.stat(out / "scan" / "batch.json").st_mtime_ns
    (other,) = batch([three_scans / "wall1" / "scan.obj"], out, TINY, workers=1).records
    assert other["status"] == "failed" and "holds the output of another scan" in other["error"]
    assert os.stat(out / "scan" / "batch.json").st_mtime_ns == stamp
    assert batch([three_scans / "wall0" / "scan.obj"], out, TINY, workers=1).records[0]["reused"]


def test_an_apps_export_is_enhanced_with_its_photos_as_enhance_does(tmp_path, exports):
    """A zipped 3D Scanner App export, and the mesh of an unzipped one with its frames beside it: batch finds
    the mesh and the posed photos as ``scantex enhance`` does (the zip had been refused, the frames ignored)."""
    result = batch([exports["scanner_zip"], exports["scanner"] / "textured_output.obj"], tmp_path / "b", TINY,
                   workers=1)
    for record in result.records:
        assert record["status"] == "done", record.get("error")
        assert record["scores"]["kind"] == "held-out photos"
        assert "scantex-capture" not in record["photos"]  # not the zip's temporary folder, gone by now
    assert result.records[0]["photos"].startswith(str(exports["scanner_zip"]))  # inside the zip, as the user knows it
    metrics = json.loads((tmp_path / "b" / "scanner" / "metrics.json").read_text())
    assert metrics["photos"]["source"].startswith(str(exports["scanner_zip"]))


def test_impossible_pool_and_tiling_settings_are_refused():
    """A negative worker count left a pool that never started a job and waited forever; a tile of at most 0
    faces divided by zero; a NaN overlap wrote a black atlas."""
    from scantex.pipeline.config import TilingConfig

    with pytest.raises(ScanError, match="workers is -1"):
        LocalPool(workers=-1)
    for bad in ({"max_faces": 0}, {"overlap": float("nan")}, {"overlap": -0.5}, {"tiles": -2}):
        with pytest.raises(ScanError, match="tiling needs"):
            TilingConfig(**bad)


def test_tiling_follows_the_config(tmp_path, caplog):
    """A scan over the tiling threshold whose config says uv.mode optimize runs whole (with a warning) rather
    than being refused by the tiles, as it is with --uv optimize; the tiling itself is in the config (written to
    config.json), so that a tiled run's config.json tiles its rerun the same way."""
    import argparse

    from scantex.cli import tile_count
    from scantex.pipeline.config import EnhanceConfig, load_config, save_config

    args = argparse.Namespace(mesh=tmp_path / "m.obj")
    cube = textured_cube()
    config = EnhanceConfig().override(tiling__max_faces=4)
    assert tile_count(args, cube, None, config) == 3
    assert tile_count(args, cube, None, config.override(uv__mode="optimize")) == 1
    assert "cannot be tiled" in caplog.text
    save_config(config.override(tiling__tiles=2, tiling__overlap=0.3), tmp_path / "config.json")
    again = load_config(tmp_path / "config.json")
    assert (again.tiling.tiles, again.tiling.overlap) == (2, 0.3) and tile_count(args, cube, None, again) == 2
    (tmp_path / "bad.json").write_text(json.dumps({"tiling": {"overlap": float("nan")}}))
    with pytest.raises(ScanError, match="bad.json"):
        load_config(tmp_path / "bad.json")


def test_index_says_a_fidelity_is_no_gain(tmp_path):
    """A scan without ground truth or photos has only its fidelity to the input: the index read it as an
    enhanced PSNR in the column captioned "input → enhanced"."""
    from scantex.scale.summary import write_summary

    fidelity = {"kind": "held-out views vs input renders (fidelity)", "psnr_enhanced": 31.5, "ssim_enhanced": 0.93}
    scored = {"kind": "held-out photos", "psnr_input": 20.0, "psnr_enhanced": 22.5, "ssim_input": 0.7,
              "ssim_enhanced": 0.75}
    records = [{"name": n, "status": "done", "report": f"{n}/report.html", "scores": s}
               for n, s in (("room", fidelity), ("wall", scored))]
    write_summary(tmp_path, records, executor="local")
    index = (tmp_path / "index.html").read_text()
    assert "<td>fidelity 31.50</td><td>fidelity 0.930</td>" in index
    assert "<td>20.00 → 22.50</td><td>0.700 → 0.750</td>" in index
