"""``scantex precompile``: every compiled loop of the package is compiled (or loaded) ahead of the first run."""

from __future__ import annotations

import re
import sys
from pathlib import Path

import pytest

import scantex
from scantex import jit
from scantex.cli import main
from scantex.pipeline.precompile import precompile


def kernel_names() -> set[str]:
    """The functions the package hands to :func:`scantex.jit.compiled`, read from its sources."""
    names = set()
    for path in Path(scantex.__file__).parent.rglob("*.py"):
        names |= set(re.findall(r"\bcompiled\((_\w+)\)", path.read_text()))
    return names


def test_precompile_runs_every_loop_of_the_package(tmp_path, monkeypatch):
    """A new loop that mesh-only, photo mode and a fresh UV layout do not reach on the small wall would be compiled
    in a user's first run after all: each must be made by the precompile's runs."""
    pytest.importorskip("numba")
    names = kernel_names()
    assert {"_blend", "_edge_kernel", "_rasterise", "_skyline_kernel"} <= names  # the scan finds them
    monkeypatch.setattr(jit, "_made", {})  # the kernels earlier tests made do not count
    jit.compiled.cache_clear()
    try:
        done = precompile(tmp_path)
    finally:
        jit.compiled.cache_clear()
    made = {function.__name__ for function in jit._made}
    assert names <= made, f"not run by precompile: {sorted(names - made)}"
    # each kernel made anew: every version it was called with is compiled now or loaded from numba's cache
    assert done.cached and done.compiled + done.loaded >= len(names) and done.seconds > 0
    assert (tmp_path / "photos" / "cameras.json").is_file()  # its work folder is the one given


def test_precompile_command(capsys, monkeypatch):
    pytest.importorskip("numba")
    assert main(["precompile"]) == 0
    assert "later runs load them all from it" in capsys.readouterr().out
    monkeypatch.setitem(sys.modules, "numba", None)  # as if it were not installed
    assert precompile() is None
    assert main(["precompile"]) == 0
    assert "nothing to compile" in capsys.readouterr().out


def test_a_run_that_compiled_says_so(monkeypatch):
    """The first run on a machine is slower by the loops it compiles: its summary says how much, and what keeps
    the next runs from it; a run that loaded them all says nothing."""
    from scantex.cli import compiled_note

    versions, seconds = jit.compile_seconds()
    assert versions >= 0 and seconds >= 0.0
    monkeypatch.setattr(jit, "compile_seconds", lambda: (17, 11.6))
    note = compiled_note()
    assert note.startswith("12 s of this run compiled 17 of scantex's loops") and "scantex precompile" in note
    monkeypatch.setattr(jit, "keeps_cache", lambda: False)
    assert "NUMBA_CACHE_DIR" in compiled_note()
    monkeypatch.setattr(jit, "compile_seconds", lambda: (0, 0.0))
    assert compiled_note() is None
