"""``batch``: enhance many scans with one config, on a local process pool or a Ray cluster.

Every scan runs in its own worker process and writes its own output folder ``OUTDIR/<name>/`` (the
files of ``scantex enhance``, plus ``batch.json``: its status, time and peak memory) through a temporary
folder renamed at the end, so a folder that exists is a finished scan. One scan's failure is recorded
(its one-line error) and never stops the others; a rerun skips the finished scans and retries the rest
(an interrupted field fit resumes from its checkpoint). ``index.html``, ``summary.json`` and
``summary.csv`` list every scan and are rewritten as each one finishes.

With Ray, workers on other machines read the inputs and write the outputs at the same paths: the output
folder must be on a filesystem every node sees (NFS, a cluster volume); results are not shipped back
through Ray's object store.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import shutil
import socket
import time
import traceback
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

from scantex.errors import ScanError
from scantex.pipeline.config import EnhanceConfig, load_config
from scantex.scale.executors import Job, LocalPool, WorkerLost, check_not_bootstrapping, executor as make_executor
from scantex.scale.inputs import ScanInput, collect_inputs
from scantex.scale.resources import GiB, footprint, machine, peak_memory

log = logging.getLogger(__name__)

#: the record each finished scan leaves in its output folder
RECORD = "batch.json"
#: the config a batch folder was started with (a rerun must use the same one)
BATCH_CONFIG = "batch_config.json"


@dataclass(frozen=True)
class BatchResult:
    """What a batch did: one record per scan (see :func:`enhance_one`), and where the summary is."""

    records: list[dict]
    out_dir: Path
    seconds: float
    executor: str

    @property
    def done(self) -> list[dict]:
        return [r for r in self.records if r["status"] == "done"]

    @property
    def failed(self) -> list[dict]:
        return [r for r in self.records if r["status"] == "failed"]

    @property
    def index(self) -> Path:
        return self.out_dir / "index.html"


def batch(inputs: Sequence[str | Path], out_dir: str | Path, config: EnhanceConfig | None = None, *,
          ray: str | None = None, workers: int | None = None, cpus_per_scan: int | None = None,
          gpus_per_scan: float | None = None, overwrite: bool = False,
          progress: Callable[[int, int], None] | None = None) -> BatchResult:
    """Enhance every scan of ``inputs`` into ``out_dir/<name>/`` with one ``config``.

    Args:
        inputs: mesh files, folders of them, and manifests (see :mod:`scantex.scale.inputs`).
        out_dir: the batch folder: one folder per scan, ``index.html``, ``summary.json``, ``summary.csv``.
        config: the enhance settings for every scan (default: the ``default`` preset).
        ray: run each scan as a Ray task: ``"auto"`` (this machine's cluster, or a new local one) or a
            cluster address; ``None``: a local process pool.
        workers: local pool: scans at once (default: the cores; fewer where memory is short).
        cpus_per_scan: torch threads per scan, and the CPUs a Ray task declares (default: local, the
            cores shared among the scans running at once; Ray, 1).
        gpus_per_scan: GPUs a Ray task declares (default: 1 when ``config.device`` is ``cuda``, else 0).
        overwrite: redo finished scans (and accept a config other than the folder's first one).
        progress: called with ``(finished scans, all scans)``.

    The local pool spawns its workers, which import the calling script's main module again: call this from
    a script under ``if __name__ == "__main__":`` (as with any :mod:`multiprocessing` code).

    Raises:
        ScanError: an input that does not exist, an unreadable manifest, an output folder made with
            another config (without ``overwrite``), Ray asked for but not installed. A scan that fails
            does not raise: its record says why.
    """
    check_not_bootstrapping()  # a worker re-running the caller's script writes no summary of its own
    t0 = time.perf_counter()
    config = config or EnhanceConfig()
    out_dir = Path(out_dir)
    scans = collect_inputs(inputs, exclude=out_dir)
    _check_folder_config(out_dir, config, overwrite)
    run = make_executor(ray, workers)

    records: dict[str, dict] = {}
    todo: list[ScanInput] = []
    for s in scans:
        previous = finished_record(out_dir / s.name)
        if previous is not None and not overwrite and not _same_input(previous, s):
            # another scan's output under this name: neither taken for this one's nor replaced by it
            records[s.name] = {**pending_record(s), "status": "failed",
                               "error": f"{out_dir / s.name} holds the output of another scan ({previous['mesh']}): "
                                        "give this one another name (a manifest's name column) or another "
                                        "batch folder, or pass --overwrite to replace it"}
        elif previous is not None and not overwrite:
            records[s.name] = {**previous, "reused": True}
        else:
            records[s.name] = pending_record(s)
            todo.append(s)
    log.info("%d scans: %d finished earlier, %d to enhance (%s)", len(scans), len(scans) - len(todo),
             len(todo), run.name)
    if isinstance(run, LocalPool):
        cores = machine().cores
        n_at_once = min(run.workers or cores, max(1, len(todo)))
        cpus = cpus_per_scan or max(1, cores // n_at_once)
    else:
        cpus = cpus_per_scan or 1
    gpus = gpus_per_scan if gpus_per_scan is not None else (1.0 if config.device == "cuda" else 0.0)
    config_dict = config.to_dict()
    jobs = [Job(s.name, enhance_one, (s, config_dict, str(out_dir), cpus, overwrite),
                memory=footprint(s.mesh).memory(config.bake.texture_size), cpus=cpus, gpus=gpus)
            for s in todo]

    finished = len(scans) - len(todo)
    ordered = [s.name for s in scans]
    write_summary(out_dir, [records[n] for n in ordered], executor=run.name)
    if progress:
        progress(finished, len(scans))
    for job, outcome in (run.run(jobs) if jobs else ()):
        if isinstance(outcome, WorkerLost):
            outcome = {**records[job.key], "status": "failed", "error": outcome.message}
        records[job.key] = outcome
        finished += 1
        if outcome["status"] == "done":
            log.info("%s: done in %.0f s", job.key, outcome["seconds"])
        else:
            log.warning("%s: failed: %s", job.key, outcome["error"])
        write_summary(out_dir, [records[n] for n in ordered], executor=run.name)
        if progress:
            progress(finished, len(scans))
    result = [records[n] for n in ordered]
    seconds = time.perf_counter() - t0
    write_summary(out_dir, result, executor=run.name, seconds=seconds)
    return BatchResult(result, out_dir, seconds, run.name)


def pending_record(s: ScanInput) -> dict:
    return {"name": s.name, **{k: v for k, v in s.to_dict().items() if k != "name"},
            "status": "pending", "error": None}


def _same_input(record: dict, scan: ScanInput) -> bool:
    """Whether a finished scan's ``record`` is ``scan``'s: the same mesh file."""
    try:
        return Path(record["mesh"]).resolve() == Path(scan.mesh).resolve()
    except (KeyError, TypeError, OSError):
        return False


def finished_record(folder: Path) -> dict | None:
    """The record of a scan whose output folder was completed (it holds ``batch.json``), else ``None``."""
    try:
        record = json.loads((folder / RECORD).read_text())
    except (OSError, json.JSONDecodeError):
        return None
    return record if record.get("status") == "done" else None


def _check_folder_config(out_dir: Path, config: EnhanceConfig, overwrite: bool) -> None:
    from scantex.io.atomic import atomic_files

    path = out_dir / BATCH_CONFIG
    if path.exists() and not overwrite:
        # read as a config, not compared as text: a folder made by an earlier scantex lacks the settings added
        # since (the output section), which are their defaults
        try:
            before = load_config(path)
        except ScanError:
            before = None
        if before != config:
            raise ScanError(out_dir, "was made with another config (see its batch_config.json): pass "
                                     "--overwrite to redo its scans with this one, or choose another folder")
        return
    out_dir.mkdir(parents=True, exist_ok=True)
    with atomic_files() as files:
        files.path(path).write_text(json.dumps(config.to_dict(), indent=2))


def enhance_one(scan: ScanInput, config: dict, out_root: str, threads: int, overwrite: bool) -> dict:
    """Enhance one scan into ``out_root/<scan.name>/`` (a worker process's job; never raises).

    Returns its record: ``name``, ``mesh``, ``photos``, ``ground_truth``, ``status`` (``done`` or
    ``failed``), ``error`` (one line) and ``traceback`` (internal errors only), ``seconds``,
    ``peak_memory_gib`` (this worker process's peak resident memory), ``host``, ``faces``, ``scores``
    (see :func:`scores`) and ``report`` (the report's path relative to the batch folder).
    """
    t0 = time.perf_counter()
    record = {**pending_record(scan), "host": socket.gethostname(), "threads": threads}
    out = Path(out_root) / scan.name
    work = None
    try:
        import torch

        from scantex.io import load_scan
        from scantex.io.atomic import atomic_dir
        from scantex.io.discover import find_capture
        from scantex.photos import load_photos
        from scantex.pipeline.enhance import enhance
        from scantex.pipeline.outputs import work_dir_for, write_outputs
        from scantex.report.html import strict_json

        torch.set_num_threads(threads)
        cfg = EnhanceConfig.from_dict(config).override(threads=threads)
        # an app's export as enhance takes it: a zip or folder's mesh, the posed photos beside a mesh
        with find_capture(scan.mesh, photos=scan.photos is None) as capture:
            mesh = load_scan(capture.mesh)
            truth = load_scan(scan.ground_truth) if scan.ground_truth else None
            photos_path = scan.photos or capture.photos
            photos = load_photos(photos_path) if photos_path else None
            if photos is not None and capture.extracted is not None:
                # named inside the zip, not by the temporary folder it was unpacked into
                photos = dataclasses.replace(photos, source=capture.shown(photos.source))
            if photos_path and not scan.photos:
                record["photos"] = str(capture.shown(photos_path))
            work = work_dir_for(out)
            work.mkdir(parents=True, exist_ok=True)
            result = enhance(mesh, cfg, ground_truth=truth, photos=photos, work_dir=work, resume=True)
            with atomic_dir(out, overwrite=overwrite) as tmp:
                write_outputs(result, tmp)
                metrics = json.loads((tmp / "metrics.json").read_text())
                record.update(status="done", faces=mesh.n_faces, scores=scores(metrics),
                              geometry_identical=bool(metrics["geometry"]["arrays_identical"]),
                              report=f"{scan.name}/report.html", seconds=round(time.perf_counter() - t0, 2),
                              peak_memory_gib=round(peak_memory() / GiB, 3))
                (tmp / RECORD).write_text(strict_json(record, indent=2))
        shutil.rmtree(work, ignore_errors=True)
    except ScanError as e:
        record.update(status="failed", error=str(e))
    except Exception as e:  # a bug: keep the batch going, keep the traceback for the report
        record.update(status="failed", error=f"internal error: {type(e).__name__}: {e}".splitlines()[0],
                      traceback=traceback.format_exc())
    if record["status"] == "failed":
        record.update(seconds=round(time.perf_counter() - t0, 2), peak_memory_gib=round(peak_memory() / GiB, 3))
        if work is not None:  # no empty work folder left beside the outputs; a field checkpoint stays for a rerun
            from scantex.pipeline.outputs import remove_work_dir

            remove_work_dir(work, keep_checkpoint=True)
    return record


def scores(metrics: dict) -> dict:
    """The headline held-out scores of a run's ``metrics.json``: against the ground truth when it was
    known, else on held-out photos, else the fidelity of the result to the input's renders."""
    for key, kind in (("held_out_vs_ground_truth", "held-out views vs ground truth"),
                      ("held_out_photos", "held-out photos")):
        if key in metrics:
            s = metrics[key]
            return {"kind": kind, "psnr_input": s["input"]["psnr"], "psnr_enhanced": s["enhanced"]["psnr"],
                    "ssim_input": s["input"]["ssim"], "ssim_enhanced": s["enhanced"]["ssim"]}
    if "held_out_vs_input" in metrics:
        s = metrics["held_out_vs_input"]["enhanced"]
        return {"kind": "held-out views vs input renders (fidelity)", "psnr_enhanced": s["psnr"],
                "ssim_enhanced": s["ssim"]}
    return {}


def write_summary(out_dir: Path, records: list[dict], *, executor: str, seconds: float | None = None) -> None:
    from scantex.scale.summary import write_summary as write

    write(out_dir, records, executor=executor, seconds=seconds)
