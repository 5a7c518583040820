"""Exceptions raised at scantex's public boundaries.

Every error a user can cause (a missing file, a broken mesh, a texture that is not an image) is a
:class:`ScanError` whose message is one line naming the file and the problem; the CLI prints that line
and exits non-zero without a traceback.
"""

from __future__ import annotations

from pathlib import Path


class ScanError(Exception):
    """A scan (mesh, material, texture, cameras) that scantex cannot use, with the reason."""

    def __init__(self, path: str | Path | None, problem: str):
        self.path = Path(path) if path is not None else None
        self.problem = problem
        super().__init__(f"{self.path}: {problem}" if self.path is not None else problem)


class OutputExistsError(ScanError):
    """An output folder exists and overwriting was not asked for."""
