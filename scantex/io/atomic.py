"""Writing outputs so that nothing is ever half-written.

Every file goes to a hidden temporary name in its final folder and is renamed into place only after
all files of the group were written; on any error the temporaries are removed and existing files are
left untouched.
"""

from __future__ import annotations

import contextlib
import os
import re
import shutil
import tempfile
import uuid
from collections.abc import Iterable, Iterator
from pathlib import Path

from scantex.errors import OutputExistsError, ScanError


class AtomicFiles:
    """Hands out temporary paths; :meth:`commit` renames them all to their final names."""

    def __init__(self) -> None:
        self._pending: list[tuple[Path, Path]] = []

    def path(self, final: str | Path) -> Path:
        final = Path(final)
        tmp = final.with_name(f".{final.name}.{uuid.uuid4().hex[:8]}.tmp")
        self._pending.append((tmp, final))
        return tmp

    def commit(self) -> list[Path]:
        for tmp, final in self._pending:
            os.replace(tmp, final)
        # temporaries of the same files that runs killed while writing left behind
        names: dict[Path, set[str]] = {}
        for _, final in self._pending:
            names.setdefault(final.parent, set()).add(final.name)
        stale = re.compile(r"\.(.+)\.[0-9a-f]{8}\.tmp")
        for folder, finals in names.items():
            with contextlib.suppress(OSError):
                for entry in os.scandir(folder):
                    m = stale.fullmatch(entry.name)
                    if m and m.group(1) in finals and entry.is_file(follow_symlinks=False):
                        os.unlink(entry.path)
        return [final for _, final in self._pending]

    def discard(self) -> None:
        for tmp, _ in self._pending:
            with contextlib.suppress(FileNotFoundError):
                tmp.unlink()


@contextlib.contextmanager
def atomic_files() -> Iterator[AtomicFiles]:
    """``with atomic_files() as files: write(files.path(p))`` — all or nothing."""
    files = AtomicFiles()
    try:
        yield files
    except BaseException:
        files.discard()
        raise
    try:
        files.commit()
    except BaseException:
        files.discard()
        raise


def check_output(output: str | Path, inputs: Iterable[str | Path] = (), folders: Iterable[str | Path] = (),
                 *, role: str = "the output") -> None:
    """Refuse an output path whose writing or replacing could touch the user's inputs.

    Args:
        output: the folder (or file) about to be written or replaced.
        inputs: every file the run reads (mesh, material libraries, textures, photos, config, ...):
            ``output`` may be none of them and hold none of them.
        folders: input folders (the photos folder) that ``output`` may not be, hold, or lie inside.
        role: how the error names ``output`` (``"the output"``, ``"the work folder"``).

    Raises:
        ScanError: one line naming the path and the clash. Replacing the current folder or one holding
            it is refused too.
    """
    output = Path(output)
    out = output.resolve()
    for f in inputs:
        r = Path(f).resolve()
        if r == out:
            raise ScanError(output, f"{role} would replace the input file {f}: choose another path")
        if out in r.parents:
            raise ScanError(output, f"{role} holds the input {f}, which writing it would delete: "
                                    "choose another path")
    for d in folders:
        r = Path(d).resolve()
        if r == out or out in r.parents or r in out.parents:
            raise ScanError(output, f"{role} may not be, hold or lie inside the input folder {d}")
    cwd = Path.cwd().resolve()
    if out == cwd or out in cwd.parents:
        raise ScanError(output, f"{role} is the current folder or holds it: choose a new folder")


#: the file every output folder holds: ``--overwrite`` replaces only a folder that has it (or is empty)
MARKER = ".scantex"

#: files that outputs written before the marker existed hold, by command: such a folder is an earlier output
_EARLIER_OUTPUTS = (("metrics.json", "config.json"), ("cameras.json", "view_000.png"),
                    ("scan.obj", "ground_truth.obj"))


def check_replaceable(final: str | Path) -> None:
    """Refuse to replace an existing folder that scantex did not write: ``--overwrite`` replaces an earlier
    output, never a folder of the user's own (``-o ~/Documents --overwrite`` by mistake).

    A folder is replaceable when it is empty, holds :data:`MARKER`, or holds the files an output of an
    earlier scantex (before the marker) always has.

    Raises:
        OutputExistsError: one line naming the folder and what to do.
    """
    final = Path(final)
    if not final.is_dir() or (final / MARKER).is_file():
        return
    with os.scandir(final) as entries:
        if next(entries, None) is None:
            return
    if any(all((final / name).is_file() for name in names) for names in _EARLIER_OUTPUTS):
        return
    raise OutputExistsError(final, f"is not an output of scantex (no {MARKER} file in it), so --overwrite "
                                   "will not replace it: choose a new folder, or empty this one yourself")


def remove_stale_temporaries(final: Path) -> None:
    """Remove ``.NAME.XXXXXXXX.tmp`` folders that :func:`atomic_dir` left beside ``final`` when a run
    writing it was killed (kill -9 leaves no chance to clean up)."""
    pattern = re.compile(rf"\.{re.escape(final.name)}\.[a-z0-9_]{{8}}\.tmp")
    with contextlib.suppress(OSError):
        for entry in os.scandir(final.parent):
            if pattern.fullmatch(entry.name) and entry.is_dir(follow_symlinks=False):
                shutil.rmtree(entry.path, ignore_errors=True)


@contextlib.contextmanager
def atomic_dir(final: str | Path, overwrite: bool = False, inputs: Iterable[str | Path] = (),
               folders: Iterable[str | Path] = ()) -> Iterator[Path]:
    """Build a whole output folder under a temporary name; rename it to ``final`` on success.

    An existing ``final`` folder is replaced only with ``overwrite``, and only when scantex wrote it
    (:func:`check_replaceable`); otherwise :class:`OutputExistsError`. The folder written holds :data:`MARKER`.
    ``final`` is checked with :func:`check_output` against ``inputs`` and ``folders`` first: whatever
    ``overwrite`` says, no input is ever replaced or deleted. A successful run also removes temporaries
    that killed runs left beside ``final``.
    """
    final = Path(final)
    inputs, folders = list(inputs), list(folders)
    check_output(final, inputs, folders)
    if final.exists() and not final.is_dir():
        raise OutputExistsError(final, "is a file, not a folder: choose another path")
    if final.exists() and not overwrite:
        raise OutputExistsError(final, "already exists (pass --overwrite to replace it)")
    check_replaceable(final)
    final.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{final.name}.", suffix=".tmp", dir=final.parent))
    umask = os.umask(0)
    os.umask(umask)
    os.chmod(tmp, 0o777 & ~umask)  # mkdtemp makes it private; the output is the user's ordinary folder
    try:
        yield tmp
        check_output(final, inputs, folders)  # again: the inputs may have moved while the run worked
        check_replaceable(final)  # and a folder may have appeared there
        (tmp / MARKER).write_text("This folder was written by scantex: `--overwrite` may replace it whole.\n")
        if final.exists():
            old = final.with_name(f".{final.name}.{uuid.uuid4().hex[:8]}.old")
            os.replace(final, old)
            os.replace(tmp, final)
            shutil.rmtree(old, ignore_errors=True)
        else:
            os.replace(tmp, final)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    remove_stale_temporaries(final)
