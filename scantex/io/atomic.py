"""Writing outputs so that nothing is ever half-written.

Every file goes to a hidden temporary name in its final folder and is renamed into place only after
all files of the group were written; on any error the temporaries are removed and existing files are
left untouched.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import tempfile
import uuid
from collections.abc import Iterator
from pathlib import Path

from scantex.errors import OutputExistsError


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


@contextlib.contextmanager
def atomic_dir(final: str | Path, overwrite: bool = False) -> Iterator[Path]:
    """Build a whole output folder under a temporary name; rename it to ``final`` on success.

    An existing ``final`` is replaced only with ``overwrite``; otherwise :class:`OutputExistsError`.
    """
    final = Path(final)
    if final.exists() and not overwrite:
        raise OutputExistsError(final, "already exists (pass --overwrite to replace it)")
    final.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{final.name}.", suffix=".tmp", dir=final.parent))
    umask = os.umask(0)
    os.umask(umask)
    os.chmod(tmp, 0o777 & ~umask)  # mkdtemp makes it private; the output is the user's ordinary folder
    try:
        yield tmp
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    if final.exists():
        old = final.with_name(f".{final.name}.{uuid.uuid4().hex[:8]}.old")
        os.replace(final, old)
        os.replace(tmp, final)
        shutil.rmtree(old, ignore_errors=True)
    else:
        os.replace(tmp, final)
