"""The report in a real browser: headless Chromium (Debian's ``chromium``; .ci/run installs it) loads
it with no console error and both 3D views draw. Skipped where Chromium is not installed."""

from __future__ import annotations

import time

import numpy as np
import pytest

from tests.report.chromium import Browser, find_chromium, save_png
from tests.report.toy import toy_result

CHROMIUM = find_chromium()
pytestmark = pytest.mark.skipif(CHROMIUM is None, reason="needs Debian's chromium (apt-get install chromium)")

PLOT_RECTS = """Array.from(document.querySelectorAll('.plot3d')).map(function (d) {
  var r = d.getBoundingClientRect();
  return {x: r.x + window.scrollX, y: r.y + window.scrollY, width: r.width, height: r.height};
})"""


def drawn(image: np.ndarray) -> bool:
    """A 3D view has drawn when a good part of it is neither the white page nor one flat colour."""
    coloured = (image.min(axis=2) < 235).mean()
    return coloured > 0.1 and float(image.std()) > 10.0


@pytest.fixture(scope="module")
def report(tmp_path_factory):
    from scantex.report import write_report

    return write_report(toy_result(), tmp_path_factory.mktemp("report") / "report.html")


def test_report_loads_without_errors_and_draws_in_3d(report, tmp_path):
    with Browser(CHROMIUM) as browser:
        browser.open(report.as_uri())
        rects = browser.evaluate(PLOT_RECTS)
        assert len(rects) == 2 and all(r["width"] > 300 and r["height"] > 300 for r in rects)
        deadline = time.monotonic() + 30
        while True:  # WebGL draws on animation frames: give the software renderer time
            shots = [browser.screenshot(r) for r in rects]
            if all(drawn(s) for s in shots) or time.monotonic() > deadline:
                break
            browser.pump(0.5)
        browser.pump(0.5)
        for i, shot in enumerate(shots):
            save_png(shot, tmp_path / f"view3d_{i}.png")  # for a look when the test fails
        assert all(drawn(s) for s in shots), f"a 3D view stayed blank (screenshots in {tmp_path})"
        assert browser.evaluate("document.querySelectorAll('.plot3d canvas').length") >= 2
        assert browser.console_errors() == []


def test_the_checks_can_fail(tmp_path):
    """The same checks on a page with an error and an empty plot area do fail."""
    page = tmp_path / "broken.html"
    page.write_text('<html><body><div class="plot3d" style="width:400px;height:400px"></div>'
                    '<script>console.error("boom"); missing_function();</script></body></html>')
    with Browser(CHROMIUM) as browser:
        browser.open(page.as_uri())
        browser.pump(0.3)
        (rect,) = browser.evaluate(PLOT_RECTS)
        assert not drawn(browser.screenshot(rect))
        errors = browser.console_errors()
        assert any("boom" in e for e in errors) and any("missing_function" in e for e in errors)
