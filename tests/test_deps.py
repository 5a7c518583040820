"""Optional dependencies (scantex/deps.py): without one, the feature that needs it says which
``pip install`` provides it, in one line, and the rest keeps working."""

from __future__ import annotations

import sys

import numpy as np
import pytest
import trimesh

from scantex.deps import MissingDependency, has_module, require


def hide(monkeypatch, *names):
    """Make ``names`` unimportable, as if not installed (None in sys.modules blocks an import)."""
    for name in names:
        for loaded in [m for m in sys.modules if m == name or m.startswith(name + ".")]:
            monkeypatch.delitem(sys.modules, loaded)
        monkeypatch.setitem(sys.modules, name, None)


def test_require_names_the_extra(monkeypatch):
    hide(monkeypatch, "skimage")
    assert not has_module("skimage")
    with pytest.raises(MissingDependency) as error:
        require("skimage.restoration", "the inpainting baseline")
    message = str(error.value)
    assert message == ("the inpainting baseline needs the Python package scikit-image, which is not installed: "
                       "pip install 'scantex[bench]'")
    assert "\n" not in message


def test_require_returns_the_module_when_present():
    assert require("numpy", "anything") is np and has_module("numpy")


def test_unwrap_without_xatlas_keeps_planar_charts_and_says_why(monkeypatch, caplog):
    from scantex.uv.unwrap import UnwrapLog, UnwrapOptions, unwrap

    hide(monkeypatch, "xatlas")
    sphere = trimesh.creation.icosphere(2)
    record = UnwrapLog()
    with caplog.at_level("WARNING"):
        charts = unwrap(sphere.vertices, sphere.faces, UnwrapOptions(min_chart_faces=10**6), record=record)
    assert record.xatlas_regions == 0
    assert charts.n_charts > 1  # every face still charted
    (message,) = [r.getMessage() for r in caplog.records if "xatlas" in r.getMessage()]
    assert "pip install 'scantex[unwrap]'" in message and message in record.fallbacks


def test_report_without_plotly_has_everything_but_the_3d_view(monkeypatch):
    from scantex.report import build_report
    from tests.report.toy import toy_result

    hide(monkeypatch, "plotly")
    page = build_report(toy_result())
    assert "plotly.js v" not in page and 'class="figure"' not in page
    assert "The 3D view needs the Python package plotly, which is not installed: pip install &#x27;scantex[view]&#x27;" in page
    assert page.count('<div class="compare"') >= 2  # the texture comparisons need no plotly


def test_view_command_without_plotly_prints_one_line(monkeypatch, tmp_path, capsys):
    from scantex.cli import main
    from tests.conftest import textured_cube

    mesh = tmp_path / "cube.obj"
    from scantex.io import save_scan

    save_scan(textured_cube(), mesh)
    hide(monkeypatch, "plotly")
    assert main(["view", str(mesh), "-o", str(tmp_path / "view.html")]) == 1
    err = capsys.readouterr().err.strip()
    assert err == ("scantex: error: scantex view needs the Python package plotly, which is not installed: "
                   "pip install 'scantex[view]'")
    assert not (tmp_path / "view.html").exists()
