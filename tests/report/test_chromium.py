"""The report in a real browser: headless Chromium (Debian's ``chromium``; .ci/run installs it) loads
it with no console error, both 3D views draw, and the wipe viewers split, zoom and pan. Skipped where
Chromium is not installed."""

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


VIEW_RECT = """(function (sel) {
  var d = document.querySelector(sel);
  d.scrollIntoView({block: 'center'});
  var r = d.getBoundingClientRect();
  return {x: r.x + window.scrollX, y: r.y + window.scrollY, width: r.width, height: r.height,
          vx: r.x, vy: r.y};
})"""


def set_split(browser, sel: str, value: float) -> None:
    browser.evaluate(f"var s = document.querySelector('{sel} .cmp-split'); s.value = {value}; "
                     "s.dispatchEvent(new Event('input'));")


def mouse(browser, kind: str, x: float, y: float, **extra) -> None:
    browser.send("Input.dispatchMouseEvent", {"type": kind, "x": x, "y": y, "button": "left",
                                              "buttons": 1 if kind != "mouseReleased" else 0, **extra})


def test_wipe_viewer_splits_zooms_and_pans(report, tmp_path):
    """The held-out view's wipe viewer: both images drawn, the split follows its slider and a drag of its
    handle, the wheel and the buttons zoom, a drag pans; no console error."""
    sel = "#compare-view-1"
    with Browser(CHROMIUM) as browser:
        browser.open(report.as_uri())
        browser.pump(0.5)
        # the input on the left, the ground truth on the right: they differ everywhere the scan is degraded
        browser.evaluate(f"var m = document.querySelector('{sel} .cmp-right'); m.value = 'ground truth'; "
                         "m.dispatchEvent(new Event('change'));")
        browser.pump(0.3)
        assert browser.evaluate(f"Array.from(document.querySelectorAll('{sel} .cmp-img')).map(i => i.naturalWidth)") \
            == [768, 768]
        view = browser.evaluate(VIEW_RECT + f"('{sel} .cmp-view')")
        clip = {k: view[k] for k in ("x", "y", "width", "height")}
        set_split(browser, sel, 100)
        browser.pump(0.2)
        left_only = browser.screenshot(clip).astype(int)
        set_split(browser, sel, 0)
        browser.pump(0.2)
        right_only = browser.screenshot(clip).astype(int)
        assert drawn(left_only) and drawn(right_only)
        assert np.abs(left_only - right_only).mean() > 2  # two different images
        set_split(browser, sel, 30)
        browser.pump(0.2)
        split = browser.screenshot(clip).astype(int)
        save_png(split.astype(np.uint8), tmp_path / "split30.png")
        W = split.shape[1]
        a, b = int(0.3 * W) - 14, int(0.3 * W) + 14  # the divider and its handle
        assert np.abs(split[:, :a] - left_only[:, :a]).mean() < 1
        assert np.abs(split[:, b:] - right_only[:, b:]).mean() < 1
        assert browser.evaluate(f"document.querySelector('{sel}').dataset.split") == "30"

        # drag the handle to 75 %
        handle = browser.evaluate(VIEW_RECT + f"('{sel} .cmp-handle')")
        view = browser.evaluate(VIEW_RECT + f"('{sel} .cmp-view')")
        hx, hy = handle["vx"] + handle["width"] / 2, handle["vy"] + handle["height"] / 2
        mouse(browser, "mousePressed", hx, hy, clickCount=1)
        mouse(browser, "mouseMoved", view["vx"] + 0.5 * view["width"], hy)
        mouse(browser, "mouseMoved", view["vx"] + 0.75 * view["width"], hy)
        mouse(browser, "mouseReleased", view["vx"] + 0.75 * view["width"], hy, clickCount=1)
        browser.pump(0.2)
        assert abs(float(browser.evaluate(f"document.querySelector('{sel}').dataset.split")) - 75) < 1
        assert abs(float(browser.evaluate(f"document.querySelector('{sel} .cmp-split').value")) - 75) < 1

        def scale() -> float:
            t = browser.evaluate(f"document.querySelector('{sel} .cmp-b img').style.transform")
            return float(t.split("scale(")[1].rstrip(")"))

        def offset() -> tuple[float, float]:
            t = browser.evaluate(f"document.querySelector('{sel} .cmp-b img').style.transform")
            x, y = t.split("translate(")[1].split(")")[0].split(",")
            return float(x.strip().rstrip("px")), float(y.strip().rstrip("px"))

        fit = scale()
        assert fit == pytest.approx(720 / 768)  # opens fitted
        browser.evaluate(f"document.querySelector('{sel} button[data-zoom=\"1\"]').click()")
        assert scale() == 1 and browser.evaluate(f"document.querySelector('{sel} .cmp-zoom').textContent") == "1:1"
        browser.evaluate(f"document.querySelector('{sel} button[data-zoom=in]').click()")
        assert scale() == 2
        cx, cy = view["vx"] + view["width"] / 2, view["vy"] + view["height"] / 2
        browser.send("Input.dispatchMouseEvent", {"type": "mouseWheel", "x": cx, "y": cy, "deltaX": 0, "deltaY": -100})
        browser.pump(0.2)
        assert scale() == pytest.approx(2.5)
        # the two sides stay in register: both images carry the same transform
        assert browser.evaluate(f"(function(){{var i = document.querySelectorAll('{sel} .cmp-img'); "
                                "return i[0].style.transform === i[1].style.transform;})()")
        before = offset()
        mouse(browser, "mousePressed", cx - 100, cy, clickCount=1)  # left of the divider: pans
        mouse(browser, "mouseMoved", cx - 60, cy + 30)
        mouse(browser, "mouseReleased", cx - 60, cy + 30, clickCount=1)
        browser.pump(0.2)
        after = offset()
        assert after[0] - before[0] == pytest.approx(40) and after[1] - before[1] == pytest.approx(30)
        zoomed = browser.screenshot(clip)
        save_png(zoomed, tmp_path / "zoomed.png")
        assert drawn(zoomed)
        assert browser.console_errors() == []
