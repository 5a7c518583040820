"""``report.html``: one self-contained page per enhance run.

What is in it: the headline numbers, an interactive 3D view of the scan before and after (the two
cameras move together), unlit renders of the held-out views (input, enhanced, ground truth when known),
the atlases before and after with a detail crop at full resolution, every metric, the per-stage
timings and the resolved config. Images are inline base64 PNGs and plotly.js is embedded once for both
3D views, so the file opens offline and can be mailed as it is.
"""

from __future__ import annotations

import base64
import html
import io
import json
import math
import time
from pathlib import Path

import numpy as np

from scantex.atlas.holes import untextured_faces
from scantex.atlas.seams import seam_edges
from scantex.io.atomic import atomic_files
from scantex.metrics.image import psnr
from scantex.scan import Scan
from scantex.views.camera import Camera
from scantex.views.raycast import RayCaster
from scantex.views.render import render, to_uint8

#: faces per 3D view at most (a random subset above; display only)
MAX_FACES = 100_000
#: held-out views shown as renders
MAX_VIEWS = 4
#: longest side of the whole-atlas thumbnails, pixels
THUMBNAIL = 512
#: the detail crop: this many input texels across, shown at CROP_DISPLAY pixels
CROP_TEXELS = 96
CROP_DISPLAY = 384


def write_report(result, path: str | Path, *, input_scan: Scan | None = None, ground_truth: Scan | None = None,
                 metrics: dict | None = None, max_faces: int = MAX_FACES) -> Path:
    """Write the report of an enhance run to ``path`` (atomically) and return the path.

    Args:
        result: the :class:`scantex.pipeline.enhance.EnhanceResult`.
        path: the HTML file.
        input_scan: the scan before enhancement (default: ``result.input_scan``); without one the page
            shows only the result.
        ground_truth: the true texture (default: ``result.ground_truth``), shown next to the renders.
        metrics: the metrics to show (default: ``result.metrics``).
        max_faces: faces per 3D view at most (a random subset above, for display only).
    """
    page = build_report(result, input_scan=input_scan, ground_truth=ground_truth, metrics=metrics,
                        max_faces=max_faces)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_files() as files:
        files.path(path).write_text(page, encoding="utf-8")
    return path


def build_report(result, *, input_scan: Scan | None = None, ground_truth: Scan | None = None,
                 metrics: dict | None = None, max_faces: int = MAX_FACES) -> str:
    """The report's HTML as a string (see :func:`write_report`)."""
    from plotly.offline import get_plotlyjs

    before = input_scan if input_scan is not None else getattr(result, "input_scan", None)
    truth = ground_truth if ground_truth is not None else getattr(result, "ground_truth", None)
    after = result.scan
    metrics = result.metrics if metrics is None else metrics
    views = result.views.views
    cameras = [views.cameras[i] for i in views.test[:MAX_VIEWS]] or list(views.cameras[:MAX_VIEWS])

    name = (before.source.name if before is not None and before.source is not None else "scan")
    sections = [
        _section("Summary", _headline(metrics)),
        _section("3D view", _views_3d(before, after, max_faces), "Drag to turn, scroll to zoom; both views "
                 "move together. Each face shows the mean texture colour at its corners and centre."),
        _section("Held-out views", _renders(before, after, truth, cameras),
                 "Unlit renders at views the field never trained on; PSNR against the ground truth where known."),
    ]
    if getattr(result, "comparisons", None):
        sections.append(_section("Held-out photos", _comparisons(result.comparisons),
                                 "Photos the field never trained on | the input rendered through their cameras "
                                 "| the result."))
    if before is not None:
        sections.append(_section("Atlas", _atlases(before, after),
                                 "The texture images themselves: whole (scaled to fit) and a detail at full "
                                 "resolution (nearest-neighbour, so texels stay visible)."))
    sections += [
        _section("Metrics", _metrics_tables(metrics)),
        _section("Timings", _timings(metrics.get("timings_s", {}))),
        _section("Config", f"<pre>{html.escape(json.dumps(result.config.to_dict(), indent=2))}</pre>"),
        _section("All metrics (metrics.json)", f"<details><summary>show</summary><pre>"
                 f"{html.escape(json.dumps(metrics, indent=2, default=json_default))}</pre></details>"),
    ]
    return PAGE.format(title=html.escape(f"scantex report: {name}"), plotlyjs=get_plotlyjs(),
                       style=STYLE, script=SYNC_SCRIPT, date=time.strftime("%Y-%m-%d %H:%M"),
                       body="\n".join(sections))


# -- pieces ---------------------------------------------------------------------------------------------


def _section(title: str, body: str, note: str = "") -> str:
    slug = "".join(c if c.isalnum() else "-" for c in title.lower())
    note = f'<p class="note">{html.escape(note)}</p>' if note else ""
    return f'<section id="{slug}"><h2>{html.escape(title)}</h2>{note}{body}</section>'


def _headline(m: dict) -> str:
    g = m.get("geometry", {})
    rows = []
    if g:
        same = g.get("arrays_identical")
        d = g.get("distance")
        text = (f"{'identical' if same else 'CHANGED'}: {g['vertices'][1]:,} vertices, {g['faces'][1]:,} faces")
        if d is not None:
            text += f"; Hausdorff {d['hausdorff']:.3g}, mean point-to-mesh {d['mean']:.3g}"
        rows.append(("Geometry", text, "good" if same else "bad"))
    scores = m.get("held_out_vs_ground_truth")
    if scores:
        i, e = scores["input"], scores["enhanced"]
        rows.append(("Held-out views vs ground truth",
                     f"PSNR {_num(i['psnr'])} → {_num(e['psnr'])} dB, SSIM {i['ssim']:.3f} → {e['ssim']:.3f}",
                     "good" if e["psnr"] > i["psnr"] else "bad"))
        if "hole_psnr" in i and "hole_psnr" in e:
            rows.append(("Holes vs ground truth", f"PSNR {_num(i['hole_psnr'])} → {_num(e['hole_psnr'])} dB", ""))
    elif "held_out_vs_input" in m:
        e = m["held_out_vs_input"]["enhanced"]
        rows.append(("Held-out views vs input renders", f"PSNR {_num(e['psnr'])} dB, SSIM {e['ssim']:.3f} "
                     "(fidelity to the input, not quality: no ground truth was given)", ""))
    photos = m.get("held_out_photos")
    if photos:
        i, e = photos["input"], photos["enhanced"]
        rows.append((f"Held-out photos ({i.get('photos', 0)})",
                     f"PSNR {_num(i['psnr'])} → {_num(e['psnr'])} dB (colour-matched {_num(i['psnr_matched'])} → "
                     f"{_num(e['psnr_matched'])}), SSIM {i['ssim']:.3f} → {e['ssim']:.3f}",
                     "good" if e["psnr_matched"] > i["psnr_matched"] else "bad"))
    sv = m.get("seam_visibility")
    if sv:
        rows.append(("Seam visibility", f"{sv['input']:.2f} → {sv['enhanced']:.2f} (mean RGB step across seams, "
                     "0–255)", "good" if sv["enhanced"] < sv["input"] else ""))
    if "timings_s" in m:
        rows.append(("Time", f"{m['timings_s'].get('total', 0):.1f} s", ""))
    body = "".join(f'<tr><th>{html.escape(k)}</th><td class="{c}">{html.escape(v)}</td></tr>' for k, v, c in rows)
    return f'<table class="headline">{body}</table>'


def _views_3d(before: Scan | None, after: Scan, max_faces: int) -> str:
    import plotly.io as pio

    from scantex.inspect.plotly_view import mesh_figure

    panels = []
    for key, scan, title in (("before", before, "before"), ("after", after, "after")):
        if scan is None:
            continue
        figure = mesh_figure(scan, max_faces=max_faces, title=title)
        lo, hi = scan.bounds
        extent = np.maximum(hi - lo, 1e-12)
        # plotly's aspectmode "data" scales by the mean extent, blowing a flat wall up past the view
        ratio = np.maximum(extent / extent.max(), 0.02)
        figure.update_layout(height=460, scene=dict(
            xaxis_visible=False, yaxis_visible=False, zaxis_visible=False, aspectmode="manual",
            aspectratio=dict(x=float(ratio[0]), y=float(ratio[1]), z=float(ratio[2])), camera=_facing_camera(scan)))
        spec = pio.to_json(figure, validate=False).replace("</", "<\\/")
        panels.append(f'<div class="view3d"><div id="view3d-{key}" class="plot3d"></div>'
                      f'<script type="application/json" class="figure" data-target="view3d-{key}">{spec}</script></div>')
    return f'<div class="row">{"".join(panels)}</div>'


def _facing_camera(scan: Scan) -> dict:
    """A plotly scene camera looking at the side the surface faces (a wall from the front, a room from
    above its open top); plotly's default diagonal view for closed objects, whose normals cancel."""
    normals = scan.face_normals * scan.face_areas[:, None]
    mean = normals.sum(axis=0) / max(scan.face_areas.sum(), 1e-300)
    length = float(np.linalg.norm(mean))
    if length < 0.3:
        return dict(eye=dict(x=1.25, y=1.25, z=1.25))
    eye = 1.05 * mean / length
    eye[2] += 0.2  # a little from above, so that depth reads
    up = (0.0, 1.0, 0.0) if abs(mean[2]) / length > 0.9 else (0.0, 0.0, 1.0)
    return dict(eye=dict(x=float(eye[0]), y=float(eye[1]), z=float(eye[2])),
                up=dict(x=up[0], y=up[1], z=up[2]))


def _renders(before: Scan | None, after: Scan, truth: Scan | None, cameras: list[Camera]) -> str:
    caster = RayCaster(after.positions, after.faces)  # the geometry is the same for all three
    columns = [("input", before), ("enhanced", after), ("ground truth", truth)]
    columns = [(n, s) for n, s in columns if s is not None]
    head = "".join(f"<th>{html.escape(n)}</th>" for n, _ in columns)
    rows = []
    for k, cam in enumerate(cameras):
        images = {n: render(s, cam, caster, supersample=2) for n, s in columns}
        cells = []
        for n, _ in columns:
            image, alpha = images[n]
            caption = ""
            if truth is not None and n != "ground truth":
                ref, ref_alpha = images["ground truth"]
                caption = f"PSNR {_num(psnr(image, ref, ref_alpha >= 0.999))} dB"
            cells.append(f"<td>{_img(to_uint8(image), f'{n}, view {k + 1}', 'render')}<div class='cap'>{caption}</div></td>")
        rows.append(f"<tr>{''.join(cells)}</tr>")
    return f'<table class="images"><tr>{head}</tr>{"".join(rows)}</table>'


def _atlases(before: Scan, after: Scan) -> str:
    from PIL import Image

    rows = []
    crop = _crop_centre(before)
    for m, (mb, ma) in enumerate(zip(before.materials, after.materials)):
        if mb.image is None or ma.image is None:
            continue
        cells_whole, cells_crop = [], []
        for label, image in (("before", mb.image), ("after", ma.image)):
            H, W = image.shape[:2]
            scale = min(1.0, THUMBNAIL / max(H, W))
            thumb = Image.fromarray(image[..., :3]).resize((max(1, round(W * scale)), max(1, round(H * scale))),
                                                           Image.LANCZOS)
            cells_whole.append(f"<td>{_img(np.asarray(thumb), f'{label} atlas', 'thumb')}"
                               f"<div class='cap'>{label}: {W}×{H}</div></td>")
            # the same region of the UV square in both atlases, whatever their sizes
            cu, cv = crop[:2] if crop is not None and crop[2] == m else (0.5, 0.5)
            size = CROP_TEXELS / mb.image.shape[1]
            x0 = int(round((cu - size / 2) * W))
            y0 = int(round((1 - cv - size / 2) * H))
            n = min(max(1, int(round(size * W))), W, H)
            x0, y0 = min(max(x0, 0), max(W - n, 0)), min(max(y0, 0), max(H - n, 0))
            region = image[y0:y0 + n, x0:x0 + n, :3]
            big = Image.fromarray(np.ascontiguousarray(region)).resize((CROP_DISPLAY, CROP_DISPLAY), Image.NEAREST)
            cells_crop.append(f"<td>{_img(np.asarray(big), f'{label} atlas detail')}"
                              f"<div class='cap'>{label}: texels {x0}–{x0 + n} × {y0}–{y0 + n}</div></td>")
        title = html.escape(mb.name)
        rows.append(f"<tr><th colspan=2>material {title}</th></tr><tr>{''.join(cells_whole)}</tr>"
                    f"<tr>{''.join(cells_crop)}</tr>")
    return f'<table class="images">{"".join(rows)}</table>' if rows else "<p>No atlas to show.</p>"


def _comparisons(images: dict) -> str:
    rows = "".join(f"<tr><td>{_img(to_uint8(image), name, 'sheet')}<div class='cap'>{html.escape(name)}</div></td></tr>"
                   for name, image in images.items())
    return f'<table class="images">{rows}</table>'


def _crop_centre(scan: Scan) -> tuple[float, float, int] | None:
    """UV centre and material of the detail crop: the first hole if the scan has one (where the input
    is at its worst), else the middle of the first seam edge, else none."""
    if not scan.is_textured:
        return None
    holes = np.flatnonzero(untextured_faces(scan))
    if holes.size:
        f = holes[len(holes) // 2]
    else:
        edges = seam_edges(scan)
        if not len(edges):
            return None
        f = edges.faces[len(edges) // 2, 0]
    u, v = scan.triangle_uvs[f].mean(axis=0)
    return float(u % 1.0), float(v % 1.0), int(scan.face_materials[f])


def _metrics_tables(m: dict) -> str:
    tables = []
    g = m.get("geometry")
    if g:
        rows = [("vertices", *g["vertices"]), ("faces", *g["faces"]), ("distinct positions", *g["distinct_positions"])]
        if "volume" in g:
            for key, label in (("area", "surface area"), ("volume", "volume")):
                rows.append((label, *[_num(v[key]) if v[key] is not None else "—" for v in g["volume"]]))
        body = "".join(f"<tr><th>{html.escape(r[0])}</th><td>{_fmt(r[1])}</td><td>{_fmt(r[2])}</td></tr>" for r in rows)
        extra = ""
        if "volume" in g:
            extra += f"<p class='note'>{html.escape(g['volume'][0]['note'])}</p>"
        if "distance" in g:
            d = g["distance"]
            extra += ("<table><tr><th></th><th>input → output</th><th>output → input</th><th>symmetric</th></tr>"
                      f"<tr><th>Hausdorff</th><td>{_num(d['hausdorff_a_to_b'])}</td><td>{_num(d['hausdorff_b_to_a'])}</td>"
                      f"<td>{_num(d['hausdorff'])}</td></tr>"
                      f"<tr><th>mean point-to-mesh</th><td>{_num(d['mean_a_to_b'])}</td><td>{_num(d['mean_b_to_a'])}</td>"
                      f"<td>{_num(d['mean'])}</td></tr></table>"
                      f"<p class='note'>Distances in the scan's units, from every vertex and {d['samples']:,} "
                      "random surface points per direction.</p>")
        tables.append(f"<h3>Geometry</h3><table><tr><th></th><th>input</th><th>output</th></tr>{body}</table>{extra}")
    for key, label in (("held_out_vs_ground_truth", "Held-out views vs ground truth"),
                       ("held_out_vs_input", "Held-out views vs input renders"),
                       ("held_out_photos", "Held-out photos"),
                       ("held_out_photos_vs_ground_truth", "Held-out photos' cameras vs ground truth")):
        scores = m.get(key)
        if not scores:
            continue
        names = list(scores)
        cols = sorted({c for s in scores.values() for c in s})
        head = "".join(f"<th>{html.escape(n)}</th>" for n in names)
        body = "".join(f"<tr><th>{html.escape(c)}</th>" + "".join(f"<td>{_fmt(scores[n].get(c))}</td>" for n in names)
                       + "</tr>" for c in cols)
        tables.append(f"<h3>{label}</h3><table><tr><th></th>{head}</tr>{body}</table>")
    texture = m.get("texture")
    if texture:
        names = list(texture)
        flat = {n: _flatten(texture[n]) for n in names}
        keys = list(dict.fromkeys(k for n in names for k in flat[n]))
        head = "".join(f"<th>{html.escape(n)}</th>" for n in names)
        body = "".join(f"<tr><th>{html.escape(k)}</th>" + "".join(f"<td>{_fmt(flat[n].get(k))}</td>" for n in names)
                       + "</tr>" for k in keys)
        tables.append(f"<h3>Texture</h3><table><tr><th></th>{head}</tr>{body}</table>")
    rest = {k: v for k, v in m.items() if k not in ("geometry", "held_out_vs_ground_truth", "held_out_vs_input",
                                                    "held_out_photos", "held_out_photos_vs_ground_truth",
                                                    "texture", "timings_s")}
    flat = _flatten(rest)
    body = "".join(f"<tr><th>{html.escape(k)}</th><td>{_fmt(v)}</td></tr>" for k, v in flat.items())
    tables.append(f"<h3>Run</h3><table>{body}</table>")
    return "".join(tables)


def _timings(t: dict) -> str:
    if not t:
        return "<p>No timings recorded.</p>"
    total = t.get("total") or sum(v for k, v in t.items() if k != "total") or 1.0
    rows = "".join(
        f"<tr><th>{html.escape(k)}</th><td>{v:.2f} s</td><td><div class='bar' style='width:{100 * v / total:.1f}%'>"
        f"</div></td></tr>" for k, v in t.items() if k != "total")
    return f"<table class='timings'>{rows}<tr><th>total</th><td>{total:.2f} s</td><td></td></tr></table>"


def _flatten(d: dict, prefix: str = "") -> dict:
    out = {}
    for k, v in d.items():
        key = f"{prefix}{k}"
        if isinstance(v, dict):
            out.update(_flatten(v, key + "."))
        else:
            out[key] = v
    return out


def _num(v) -> str:
    if v is None:
        return "—"
    v = float(v)
    if math.isinf(v):
        return "∞"
    if math.isnan(v):
        return "—"
    if v == 0:
        return "0"
    return f"{v:.4g}" if abs(v) < 1e5 else f"{v:,.0f}"


def _fmt(v) -> str:
    if isinstance(v, bool) or v is None or isinstance(v, str):
        return html.escape(str(v) if v is not None else "—")
    if isinstance(v, (int, np.integer)):
        return f"{int(v):,}"
    if isinstance(v, (float, np.floating)):
        return _num(v)
    return html.escape(json.dumps(v, default=json_default))


def _img(image: np.ndarray, alt: str, kind: str = "") -> str:
    from PIL import Image

    buffer = io.BytesIO()
    Image.fromarray(np.ascontiguousarray(image)).save(buffer, format="PNG", optimize=False)
    data = base64.b64encode(buffer.getvalue()).decode("ascii")
    return f'<img class="{kind}" alt="{html.escape(alt)}" src="data:image/png;base64,{data}">'


def json_default(value):
    """``json.dumps(default=...)`` for numpy scalars and arrays."""
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    raise TypeError(type(value))


STYLE = """
body { font: 14px/1.45 system-ui, sans-serif; margin: 0 auto; max-width: 1280px; padding: 0 16px 48px; color: #222; }
h1 { margin: 20px 0 4px; } h2 { margin-top: 32px; border-bottom: 1px solid #ddd; } h3 { margin-bottom: 4px; }
table { border-collapse: collapse; margin: 6px 0; } th, td { padding: 3px 10px; text-align: left; vertical-align: top; }
th { font-weight: 600; } table tr:nth-child(even) { background: #f6f6f6; }
table.images tr { background: none; } table.images img { display: block; max-width: 100%; image-rendering: pixelated; }
img.render { width: 300px; } img.thumb { width: 384px; } img.sheet { width: 960px; }
.headline td.good { color: #176b2c; } .headline td.bad { color: #a31515; font-weight: 600; }
.note, .cap { color: #666; font-size: 12px; } .row { display: flex; gap: 12px; flex-wrap: wrap; }
.view3d { flex: 1 1 480px; min-width: 360px; } .plot3d { height: 460px; }
.bar { background: #5b8def; height: 10px; min-width: 1px; } .timings td:last-child { width: 320px; }
pre { background: #f6f6f6; padding: 8px; overflow: auto; max-height: 480px; }
"""

#: plots every embedded figure, then keeps the 3D cameras of the views in step
SYNC_SCRIPT = """
(function () {
  var specs = document.querySelectorAll('script.figure');
  var plots = [];
  specs.forEach(function (node) {
    var fig = JSON.parse(node.textContent);
    var div = document.getElementById(node.dataset.target);
    Plotly.newPlot(div, fig.data, fig.layout, {displaylogo: false, responsive: true});
    plots.push(div);
  });
  var syncing = false;
  plots.forEach(function (src) {
    src.on('plotly_relayout', function (ev) {
      if (syncing || !ev || !ev['scene.camera']) { return; }
      syncing = true;
      var updates = plots.filter(function (p) { return p !== src; })
        .map(function (p) { return Plotly.relayout(p, {'scene.camera': ev['scene.camera']}); });
      Promise.all(updates).then(function () { syncing = false; }, function () { syncing = false; });
    });
  });
})();
"""

PAGE = """<!DOCTYPE html>
<html lang="en">
<head>
<meta charset="utf-8">
<title>{title}</title>
<style>{style}</style>
<script type="text/javascript">{plotlyjs}</script>
</head>
<body>
<h1>{title}</h1>
<p class="note">Written by scantex on {date}. Geometry is never changed: only the texture is new.</p>
{body}
<script type="text/javascript">{script}</script>
</body>
</html>
"""
