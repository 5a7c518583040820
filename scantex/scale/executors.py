"""Where independent jobs (scans of a batch, tiles of a huge scan) run: a local process pool or Ray.

Both run each job in a fresh worker process (a crash or a leak cannot touch the next job, and the
process's peak memory is the job's) and hand results back as jobs finish. Neither is a scheduler of
our own: the local pool is :class:`concurrent.futures.ProcessPoolExecutor` with a gate that starts a
job only when its estimated memory fits beside the running ones; Ray schedules its tasks by the
resources they declare (CPUs, GPUs, memory), over every machine of a cluster.

A job's function must be importable by name (a module-level function) and should catch its own
errors and return them as data; the executors only report jobs whose worker process died.
"""

from __future__ import annotations

import concurrent.futures as cf
import logging
import multiprocessing
import os
import sys
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from scantex.errors import ScanError
from scantex.scale.resources import GiB, machine

log = logging.getLogger(__name__)

RAY_HINT = "Ray is not installed: pip install 'scantex[ray]' (or run without --ray: a local process pool)"


@dataclass(frozen=True)
class Job:
    """One unit of work and the resources it declares."""

    key: str
    """a name for logs and results (a scan's output name, a tile's index)"""
    fn: Callable
    """a module-level function (pickled by name)"""
    args: tuple = ()
    memory: int = 1 * GiB
    """estimated peak memory in bytes"""
    cpus: int = 1
    """CPU cores (torch threads) the job uses"""
    gpus: float = 0.0
    """GPUs the job uses (Ray only; the local pool runs on this machine's device)"""


@dataclass(frozen=True)
class WorkerLost:
    """The job's worker process died (killed for memory, a crash in native code) or Ray gave up on it."""

    message: str


@dataclass
class LocalPool:
    """A process pool sized to this machine: at most ``workers`` jobs at once, and only as many as
    fit in ``memory_budget`` bytes by their estimates (a job bigger than the budget runs alone).

    ``workers=1`` runs the jobs one after another (still each in its own process).
    """

    workers: int | None = None
    """jobs at once (default: the cores this process may use)"""
    memory_budget: int | None = None
    """bytes the running jobs may need together (default: 85 % of the memory available now)"""
    context: str = "spawn"
    """multiprocessing start method: spawn (a clean interpreter per job; torch is not fork-safe)"""
    name: str = field(default="local pool", init=False)

    def __post_init__(self):
        if self.workers is not None and self.workers < 0:  # none could ever start: the pool would wait forever
            raise ScanError(None, f"workers is {self.workers}: give a count of 1 or more (0 or none: the cores)")

    def resolved(self) -> tuple[int, int]:
        m = machine()
        return (self.workers or m.cores), (self.memory_budget or int(0.85 * m.memory))

    def run(self, jobs: Sequence[Job]) -> Iterator[tuple[Job, object]]:
        """Yield ``(job, result)`` as jobs finish; ``result`` is the function's return value or a
        :class:`WorkerLost`. A job whose worker died beside others is run again alone once, so that only
        the job that died is blamed."""
        check_not_bootstrapping()
        workers, budget = self.resolved()
        pending = list(jobs)
        alone = set()  # keys of jobs that must run with nothing beside them
        while pending:
            ctx = multiprocessing.get_context(self.context)
            running: dict[cf.Future, Job] = {}
            broken = False
            with cf.ProcessPoolExecutor(max_workers=max(1, min(workers, len(pending))), mp_context=ctx,
                                        max_tasks_per_child=1, initializer=exit_with_parent,
                                        initargs=(os.getpid(),)) as pool:
                try:
                    while (pending or running) and not broken:
                        while pending and not broken:
                            job = self._next(pending, running, workers, budget, alone)
                            if job is None:
                                break
                            pending.remove(job)
                            running[pool.submit(job.fn, *job.args)] = job
                        done, _ = cf.wait(running, return_when=cf.FIRST_COMPLETED)
                        lost = []
                        for future in done:
                            job = running.pop(future)
                            try:
                                result = future.result()
                            except cf.process.BrokenProcessPool:
                                lost.append(job)
                                continue
                            except Exception as e:  # the job's own errors are its data; this is a bug or pickling
                                result = WorkerLost(f"{type(e).__name__}: {first_line(str(e))}")
                            yield job, result
                        if lost:
                            # the pool is broken: every job in flight died with it; which one killed it is known
                            # only when it ran alone, so each of the others runs again, alone
                            broken = True
                            lost += list(running.values())
                            running.clear()
                            for job in lost:
                                if job.key in alone or len(lost) == 1:
                                    yield job, WorkerLost(f"the worker process died (out of memory? see the system "
                                                          f"log{_unguarded_hint()})")
                                else:
                                    alone.add(job.key)
                                    pending.insert(0, job)
                except BaseException:
                    # stopped (Ctrl-C; SIGTERM, which the command turns into an exception) or failing: the
                    # workers' jobs stop too, rather than the pool's exit waiting for each to finish
                    for process in list((getattr(pool, "_processes", None) or {}).values()):
                        process.terminate()
                    raise

    @staticmethod
    def _next(pending: list[Job], running: dict, workers: int, budget: int, alone: set) -> Job | None:
        if len(running) >= workers or any(j.key in alone for j in running.values()):
            return None
        used = sum(j.memory for j in running.values())
        cores = sum(j.cpus for j in running.values())
        for job in pending:
            if job.key in alone:
                if not running:
                    return job
                continue
            if not running or (used + job.memory <= budget and cores + job.cpus <= max(workers, 1)):
                return job
        return None


def _unguarded_hint() -> str:
    """What else kills every spawned worker at once when a script, not scantex's command, started the pool: each
    worker imports the script again, and one that starts its jobs at import dies in its bootstrap."""
    main = sys.modules.get("__main__")
    script = getattr(main, "__file__", None)
    ours = (getattr(getattr(main, "__spec__", None), "name", "").startswith("scantex")  # python -m scantex
            or getattr(getattr(main, "run", None), "__module__", None) == "scantex.cli")  # the scantex command
    if not script or ours:
        return ""
    return (f"; or {Path(script).name} starts its jobs when imported, which each worker does again: call them "
            f"under `if __name__ == \"__main__\":`")


def check_not_bootstrapping() -> None:
    """A spawned worker importing its parent's script again must not start a pool of its own (the script
    starts its jobs at import): say so in the worker's log, where multiprocessing's own error would be."""
    if getattr(multiprocessing.current_process(), "_inheriting", False):
        raise ScanError(None, "this script starts scantex's jobs when it is imported, and every worker process "
                              "imports it again: call them under `if __name__ == \"__main__\":`")


def exit_with_parent(parent: int, every_s: float = 1.0) -> None:
    """A pool worker's initializer: a thread that ends the worker when ``parent`` (the process that made the
    pool) is gone. A parent killed outright (``kill -9``, the out-of-memory killer) runs no clean-up, and its
    workers, adopted by init, went on computing a tile nobody would fuse, each holding its memory."""
    def watch() -> None:
        while True:
            time.sleep(every_s)
            if os.getppid() != parent:
                os._exit(1)

    threading.Thread(target=watch, name="exit-with-parent", daemon=True).start()


@dataclass
class RayCluster:
    """Runs each job as a Ray task declaring its CPUs, GPUs and memory.

    ``address``: ``"auto"`` connects to the cluster this machine belongs to (``ray start``), or starts a
    local one when there is none; otherwise a cluster address (``ray://host:10001`` or ``host:6379``).
    When Ray is already initialised in this process (``ray.init(...)`` by the caller), that is used as is.
    Workers read the inputs and write the outputs at the same paths as here: a shared filesystem.
    """

    address: str = "auto"
    name: str = field(default="Ray", init=False)

    def _connect(self):
        try:
            import ray
        except ImportError:
            raise ScanError(None, RAY_HINT) from None
        if not ray.is_initialized():
            # "auto": Ray's own rule, an existing cluster of this machine or else a new local one
            kwargs = {} if self.address == "auto" else {"address": self.address}
            try:
                ray.init(**kwargs, include_dashboard=False, log_to_driver=False, logging_level=logging.WARNING)
            except ConnectionError as e:
                raise ScanError(None, f"cannot reach the Ray cluster at {self.address}: {e}") from None
        return ray

    def run(self, jobs: Sequence[Job]) -> Iterator[tuple[Job, object]]:
        ray = self._connect()
        # a task asking for more than any node has would wait forever: ask for at most the largest node's
        nodes = [n.get("Resources", {}) for n in ray.nodes() if n.get("Alive")]
        most_memory = max((n.get("memory", 0) for n in nodes), default=0)
        most_cpus = max((n.get("CPU", 0) for n in nodes), default=0)
        refs = {}
        for job in jobs:
            memory = min(job.memory, int(most_memory)) if most_memory else job.memory
            cpus = min(job.cpus, most_cpus) if most_cpus else job.cpus
            if memory < job.memory:
                log.warning("%s: estimated to need %.1f GiB, more than any Ray node has (%.1f GiB); asking for that",
                            job.key, job.memory / GiB, memory / GiB)
            # max_calls=1: a fresh worker process per job, so its peak memory is the job's and nothing leaks
            task = ray.remote(max_calls=1, max_retries=0)(job.fn).options(
                num_cpus=cpus, num_gpus=job.gpus, memory=memory, name=f"scantex:{job.key}")
            refs[task.remote(*job.args)] = job
        remaining = list(refs)
        while remaining:
            done, remaining = ray.wait(remaining, num_returns=1)
            for ref in done:
                job = refs.pop(ref)
                try:
                    yield job, ray.get(ref)
                except ray.exceptions.RayError as e:
                    yield job, WorkerLost(f"Ray task failed: {type(e).__name__}: {first_line(str(e))}")


def first_line(text: str) -> str:
    lines = [line.strip() for line in text.strip().splitlines() if line.strip()]
    return lines[0] if lines else ""


def executor(ray: str | None = None, workers: int | None = None):
    """The executor the options ask for: Ray at ``ray`` (``"auto"`` or an address), else a local pool."""
    if ray:
        return RayCluster(ray)
    return LocalPool(workers=workers)
