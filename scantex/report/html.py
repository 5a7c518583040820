"""``report.html``: one self-contained page per enhance run.

What is in it: the headline numbers, an interactive 3D view of the scan before and after (the two
cameras move together; it shows the geometry, each face in its mean colour), a wipe comparison of the
held-out views (input | enhanced | ground truth when known, rendered at a finer resolution than the
metric's, with each view's PSNR/SSIM from ``metrics.json`` beside it), the atlases before and after,
whole and as a wipe comparison of one region at 1:1, every metric, the per-stage timings and the
resolved config. The wipe viewers (split slider, zoom by wheel or buttons, pan by dragging) are a few
lines of plain JavaScript in :data:`COMPARE_SCRIPT`. Images are inline base64 PNGs and plotly.js is
embedded once for both 3D views, so the file opens offline and can be mailed as it is.
"""

from __future__ import annotations

import base64
import html
import io
import json
import logging
import math
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np

from scantex.arrays import uv_areas
from scantex.atlas.holes import untextured_faces
from scantex.atlas.seams import seam_edges
from scantex.io.atomic import atomic_files
from scantex.metrics.image import psnr, ssim
from scantex.metrics.texture import kept_faces
from scantex.metrics.views import PSNR_CAP_DB, SCORE_SUPERSAMPLE
from scantex.scan import Scan
from scantex.views.camera import Camera
from scantex.views.raycast import PAIR_THREADS, RayCaster
from scantex.views.render import downsample, render_scans, to_uint8

log = logging.getLogger(__name__)

#: faces per 3D view at most (a random subset above; display only)
MAX_FACES = 100_000
#: held-out views shown as renders
MAX_VIEWS = 4
#: longest side of the whole-atlas thumbnails, pixels
THUMBNAIL = 512
#: materials whose atlases are shown (those on the most surface): a Matterport export's hundreds made a report of
#: 830 MB (500 materials, each atlas's thumbnails and crops embedded) and took 7 GB more memory to write
MAX_ATLASES = 6
#: the atlas comparison: this many input texels across (the output's atlas shows the same UV square at
#: its own resolution)
CROP_TEXELS = 256
#: held-out views are shown as the metrics rendered them, before averaging their supersamples (twice the
#: scored size: a finer render shows the texels), halved for the page (or more) when over twice this size
RENDER_DISPLAY = 720
#: the wipe viewer's largest size on the page, CSS pixels
VIEWER_SIZE = (720, 540)
#: the share of faces a layout may map apart and still be "kept" (the faces the input gave no texture space)
KEPT_APART = 0.01
#: a 3D view's trace arrays that hold the mesh itself (positions, triangles), the same in both views
MESH_GEOMETRY = ("x", "y", "z", "i", "j", "k")


#: the held-out renders' fine detail below this share of the photos' own: the summary says the texture is softer
#: than the photos and names ``--detail sharp`` (bench/RESULTS.md, "sharp detail": a real apartment's blend of
#: 197 photos about half, the bolster's and the facade's 0.8 and more)
SOFT_DETAIL = 0.65


def fine_detail(scores: dict, texturing: dict) -> tuple[str, bool]:
    """The held-out photos' fine detail in words (mean |Laplacian of Gaussian| of the renders' grey and of the
    photos'), and whether photo mode's blend left the texture much softer than the photos (the words then name
    ``--detail sharp``); ``("", False)`` where it was not measured."""
    result, photos = scores["enhanced"].get("detail"), scores["enhanced"].get("photo_detail")
    if not photos or result is None:
        return "", False
    projective = texturing.get("mode") == "projective"
    # the best views' detail in full (--detail sharp; a run before the gain was reported: gain 1), or at a share
    full = "detail" in texturing and texturing["detail"].get("gain", 1.0) >= 1.0
    mode = "sharp" if full else "balanced" if "detail" in texturing else "blend"
    line = (f"photos {photos:.4f}, input {scores['input']['detail']:.4f}, result {result:.4f} (mean |Laplacian of "
            f"Gaussian| of the grey{f'; --detail {mode}' if projective else ''})")
    soft = result < SOFT_DETAIL * photos and projective and not full
    if soft:
        line += (": softer than the photos, whose registration differs by a few pixels (--detail sharp takes the "
                 "fine detail from the best views in full, at a lower held-out score)")
    return line, soft


def left_out_words(m: dict) -> str:
    """The photos left out as not showing what their cameras see (``photos.left_out``), in words; ``""``: none."""
    left_out = m.get("photos", {}).get("left_out") or []
    if not left_out:
        return ""
    return (f"{len(left_out)} (" + ", ".join(str(d["photo"]) for d in left_out)
            + f"), not showing what {'its camera sees' if len(left_out) == 1 else 'their cameras see'}: upside down, "
              "cropped or another frame's (each in metrics.json photos.left_out)")


def repeated_words(m: dict) -> str:
    """The photos set aside as repeating a sharper one's view (``photos.repeated``), in words; ``""``: none."""
    photos = m.get("photos", {})
    repeated = photos.get("repeated") or []
    if not repeated:
        return ""
    from scantex.photos.keyframes import REPEAT_ANGLE_DEG, REPEAT_DISTANCE

    total, one = photos.get("total", 0), len(repeated) == 1
    return (f"{total - len(repeated)} of the {total} photos kept; {len(repeated)} "
            f"{'repeats' if one else 'repeat'} the view of a sharper one (centres within {100 * REPEAT_DISTANCE:g} % "
            f"of the viewing distance, axes within {REPEAT_ANGLE_DEG:g} degrees) and {'was' if one else 'were'} set "
            "aside before the held-out split (photos.keyframes off keeps every one; each in metrics.json "
            "photos.repeated)")


def undistorted_words(summary: dict) -> str:
    """:func:`scantex.photos.lens.lens_summary` in words."""
    low, high = summary["focal_scale"]
    scale = f"{low:.3f}" + (f" to {high:.3f}" if high - low > 5e-4 else "")
    return (f"{summary['photos']} photos undistorted when read ({', '.join(summary['models'])}, the pinhole view's "
            f"focal length {scale} times the photo's)")


def untextured_seams_words(m: dict) -> str:
    """The result's seam visibility in words where the input had no texture (a bare mesh textured from its photos):
    ``""`` otherwise. An untextured input's seams are 0 by construction, so "0.00 -> 1.43" would read as seams
    made worse; the result's own figure is said, with the one before seam blending."""
    sv = m.get("seam_visibility")
    if not sv or m.get("input", {}).get("textured", True):
        return ""
    before = f", {sv['before_blending']:.2f} before seam blending" if "before_blending" in sv else ""
    return f"{sv['enhanced']:.2f} across the result's seams{before} (the input had no texture to compare)"


def blurred_words(m: dict) -> str:
    """The photos named shaken or out of focus (``photos.blurred``) and what became of them, in words; ``""``:
    none."""
    blurred = m.get("photos", {}).get("blurred") or []
    if not blurred:
        return ""
    named = ", ".join(f"{d['photo']} ({100 * d['detail']:.0f} %)" for d in blurred)
    if all(d.get("left_out") for d in blurred):
        then = ("left out, the texture made sharp from the other photos where they see the surface (--blurred keep "
                "blends them in; soften keeps their colour)")
    elif any(d.get("softened") for d in blurred):
        then = ("their colour blended with the others', their fine detail left to the sharp photos (--blurred keep "
                "blends them in whole: a softer texture)")
    else:
        then = ("blended like the others, they soften the texture a little (--blurred leave-out leaves them out, "
                "soften leaves their detail to the sharp photos; auto leaves them out when they are a quarter of the "
                "training photos or more)")
    return (f"{named} of the fine detail of the photos that see the same surface (shaken, out of focus or washed "
            f"out?): {then}")


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
    """The report's HTML as a string (see :func:`write_report`). Without plotly (the ``view`` extra)
    the 3D section says how to get it and the rest of the page is as usual."""
    from scantex.deps import has_module, missing_message

    before = input_scan if input_scan is not None else getattr(result, "input_scan", None)
    truth = ground_truth if ground_truth is not None else getattr(result, "ground_truth", None)
    after = result.scan
    metrics = result.metrics if metrics is None else metrics
    views = result.views.views
    cameras = [views.cameras[i] for i in views.test[:MAX_VIEWS]] or list(views.cameras[:MAX_VIEWS])

    source = before.source if before is not None else None
    # with its folder: a capture app names every export's mesh alike (3D Scanner App: textured_output.obj), and a
    # batch's reports were all titled by that one name
    name = "scan" if source is None else f"{source.parent.name}/{source.name}" if source.parent.name else source.name
    plotly = has_module("plotly")
    if not plotly:
        log.warning(missing_message("plotly", "the report's 3D view") + "; the report is written without it")
    plotlyjs = ""
    if plotly:
        from plotly.offline import get_plotlyjs

        plotlyjs = f'<script type="text/javascript">{get_plotlyjs()}</script>'
    sections = [
        _section("Summary", _headline(metrics)),
        _section("3D view", _views_3d(before, after, max_faces), "Drag to turn, scroll to zoom; both views "
                 "move together. Each face shows the mean texture colour at its corners and centre: this view "
                 "is for the geometry; judge the texture in the comparisons below.")
        if plotly else _section("3D view", f"<p>{html.escape(missing_message('plotly', 'The 3D view'))}.</p>"),
        _section("Held-out views", _renders(before, after, truth, cameras, _per_view_scores(metrics),
                                            getattr(result, "renders", None)),
                 "Unlit renders at views no stage trained on, compared with a wipe: drag the white "
                 "handle or the slider to move the split, scroll or use the buttons to zoom, drag the image to "
                 "pan; the menus pick which image is on each side. The scores are each view's own, from "
                 "metrics.json (computed at the views' resolution; the renders here are finer)."),
    ]
    if getattr(result, "comparisons", None):
        remade = _remade(metrics)
        aligned = "psnr_aligned" in (metrics.get("held_out_photos") or {}).get("enhanced", {})
        caption = "Photos the result was made without | the input rendered through their cameras | the result."
        if aligned:
            caption += (" Below each, as the training photos' poses were refined: the same, each render's camera "
                        "aligned to the photo (recorded poses are a few pixels off).")
        if remade:
            caption += (" The texture written was then made again from every photo, these included (photos.final); "
                        "these images and their scores are of the texture made without them.")
        sections.append(_section("Held-out photos", _comparisons(result.comparisons), caption))
    if before is not None:
        sections.append(_section("Atlas", _atlases(before, after),
                                 "The texture images themselves: whole (scaled to fit), then one region of the UV "
                                 "square in both atlases, compared with a wipe. It opens at 1:1 (one texel of the "
                                 "finer atlas per screen pixel); zoomed in, texels are drawn as squares."))
    sections += [
        _section("Metrics", _metrics_tables(metrics)),
        _section("Timings", _timings(metrics.get("timings_s", {}))),
        _section("Config", f"<pre>{html.escape(json.dumps(result.config.to_dict(), indent=2))}</pre>"),
        _section("All metrics (metrics.json)", f"<details><summary>show</summary><pre>"
                 f"{html.escape(strict_json(metrics, indent=2))}</pre></details>"),
    ]
    return PAGE.format(title=html.escape(f"scantex report: {name}"), plotlyjs=plotlyjs,
                       style=STYLE + COMPARE_STYLE, script=SYNC_SCRIPT + COMPARE_SCRIPT, date=time.strftime("%Y-%m-%d %H:%M"),
                       body="\n".join(sections))


# -- pieces ---------------------------------------------------------------------------------------------


def _section(title: str, body: str, note: str = "") -> str:
    slug = "".join(c if c.isalnum() else "-" for c in title.lower())
    note = f'<p class="note">{html.escape(note)}</p>' if note else ""
    return f'<section id="{slug}"><h2>{html.escape(title)}</h2>{note}{body}</section>'


def _remade(m: dict) -> bool:
    """Whether the texture written was made again from every photo once the held-out ones were scored."""
    return (m.get("photos", {}).get("final_texture") or {}).get("mode") == "all"


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
    safety = m.get("bake", {}).get("safety")
    if safety:
        rows.append(("Safety fallback", f"{safety['why']}: the result keeps the input's texels (holes filled, seams "
                     "blended)", ""))
    scores = m.get("held_out_vs_ground_truth")
    if scores:
        i, e = scores["input"], scores["enhanced"]
        rows.append(("Held-out views vs ground truth",
                     f"PSNR {_num(i['psnr'])} → {_num(e['psnr'])} dB, SSIM {i['ssim']:.3f} → {e['ssim']:.3f}",
                     "good" if e["psnr"] > i["psnr"] else "bad"))
        if "hole_psnr" in i and "hole_psnr" in e:
            rows.append(("Holes vs ground truth", f"PSNR {_num(i['hole_psnr'])} → {_num(e['hole_psnr'])} dB",
                         "good" if e["hole_psnr"] > i["hole_psnr"] else "bad"))
    elif "held_out_vs_input" in m:
        e = m["held_out_vs_input"]["enhanced"]
        rows.append(("Held-out views vs input renders", f"PSNR {_num(e['psnr'])} dB, SSIM {e['ssim']:.3f} "
                     "(fidelity to the input, not quality: no ground truth was given)", ""))
    photos = m.get("held_out_photos")
    if photos:
        i, e = photos["input"], photos["enhanced"]
        rows.append((f"Held-out photos ({i.get('photos', 0)})",
                     f"PSNR {_num(i['psnr'])} → {_num(e['psnr'])} dB (colour-matched {_num(i['psnr_matched'])} → "
                     f"{_num(e['psnr_matched'])}), SSIM {i['ssim']:.3f} → {e['ssim']:.3f}; held out from the "
                     "result only: a capture app's input texture was most likely made from these photos too, which "
                     "favours the input" + ("; the texture made without them (the one written was then made from "
                                            "every photo, these included: photos.final)" if _remade(m) else ""),
                     "good" if e["psnr_matched"] > i["psnr_matched"] else "bad"))
        detail, soft = fine_detail(photos, m.get("photos", {}).get("texturing", {}))
        if detail:
            rows.append(("Fine detail (held-out photos)", detail[0].upper() + detail[1:], "bad" if soft else ""))
        truth = m.get("held_out_photos_vs_ground_truth")
        if truth:
            rows.append(("Held-out photos' cameras vs ground truth",
                         f"PSNR {_num(truth['input']['psnr'])} → {_num(truth['enhanced']['psnr'])} dB, SSIM "
                         f"{truth['input']['ssim']:.3f} → {truth['enhanced']['ssim']:.3f}",
                         "good" if truth["enhanced"]["psnr"] > truth["input"]["psnr"] else "bad"))
        if "psnr_aligned" in i and "psnr_aligned" in e:
            rows.append(("Held-out photos, poses aligned",
                         f"colour-matched PSNR {_num(i['psnr_aligned'])} → {_num(e['psnr_aligned'])} dB, SSIM "
                         f"{i['ssim_aligned']:.3f} → {e['ssim_aligned']:.3f}: each held-out photo's pose aligned to "
                         "each texture on its own, as the training photos' poses were refined (the texture's "
                         "agreement with the photos, without the recorded poses' error)",
                         "good" if e["psnr_aligned"] > i["psnr_aligned"] else "bad"))
    from scantex.photos.poses import corrections_summary

    poses = corrections_summary(m.get("photos", {}).get("pose_refinement", "off"),
                                m.get("photos", {}).get("pose_corrections", []))
    if poses:
        rows.append(("Poses", poses, ""))
    undistorted = m.get("photos", {}).get("undistorted")
    if undistorted:
        words = undistorted_words(undistorted)
        rows.append(("Lens", words[0].upper() + words[1:], ""))
    for title, said in (("Keyframes", repeated_words(m)), ("Photos left out", left_out_words(m)),
                        ("Blurred photos", blurred_words(m))):
        if said:
            rows.append((title, said, ""))
    sv = m.get("seam_visibility")
    if untextured_seams_words(m):
        rows.append(("Seam visibility", untextured_seams_words(m)[:-1] + "; mean RGB step across seams, 0–255)", ""))
    elif sv:
        rows.append(("Seam visibility", f"{sv['input']:.2f} → {sv['enhanced']:.2f} (mean RGB step across seams, "
                     "0–255)", "good" if sv["enhanced"] < sv["input"] else ""))
        if "enhanced_at_input_seams" in sv:
            rows[-1] = ("Seam visibility", rows[-1][1][:-1] + f", each layout's own; at the input's seams "
                        f"{sv['input']:.2f} → {sv['enhanced_at_input_seams']:.2f})",
                        "good" if max(sv["enhanced"], sv["enhanced_at_input_seams"]) < sv["input"] else "")
    # a tiled run's fused result has only the held-out views' mean of it (the same measure, per view)
    share = (m.get("patches") or {}).get("enhanced_vs_input",
                                         m.get("held_out_vs_input", {}).get("enhanced", {}).get("patches"))
    if share is not None:
        rows.append(("Patches vs input", f"{100 * share:.2f} % of the held-out pixels have a hard-edged low-frequency "
                     "change against the input (about 0: none; exposure steps removed at seams count too"
                     + ("; in photo mode, so do the contrast and detail the photos show and the input lacks: compare "
                        "the held-out photos below" if "photos" in m else "") + ")",
                     "good" if share < 0.01 else ""))
    field = m.get("field", {})
    if field.get("trained") is False:
        rows.append(("Field", field.get("why", "not trained"), ""))
    if "timings_s" in m:
        rows.append(("Time", f"{m['timings_s'].get('total', 0):.1f} s", ""))
    body = "".join(f'<tr><th>{html.escape(k)}</th><td class="{c}">{html.escape(v)}</td></tr>' for k, v, c in rows)
    return f'<table class="headline">{body}</table>'


def _views_3d(before: Scan | None, after: Scan, max_faces: int) -> str:
    import plotly.io as pio

    from scantex.inspect.plotly_view import mesh_figure

    specs = {}
    for key, scan, title in (("before", before, "before"), ("after", after, "after")):
        if scan is None:
            continue
        figure = mesh_figure(scan, max_faces=max_faces, title=title)
        figure.update_layout(height=460, scene=dict(xaxis_visible=False, yaxis_visible=False, zaxis_visible=False))
        specs[key] = json.loads(pio.to_json(figure, validate=False))
    # the geometry is the same in both views (only its colours differ): written once (the 79,202-face demo wall's
    # report 15.4 -> 12.1 MB)
    traces = [spec["data"][0] for spec in specs.values()]
    shared = len(traces) == 2 and all(traces[0].get(k) == traces[1].get(k) for k in MESH_GEOMETRY)
    geometry = ""
    if shared:
        geometry = (f'<script type="application/json" class="geometry" id="geometry-3d">'
                    f'{_script_json({k: traces[0][k] for k in MESH_GEOMETRY})}</script>')
        for trace in traces:
            for k in MESH_GEOMETRY:
                del trace[k]
    panels = [f'<div class="view3d"><div id="view3d-{key}" class="plot3d"></div>'
              f'<script type="application/json" class="figure" data-target="view3d-{key}"'
              f'{" data-geometry=geometry-3d" if shared else ""}>{_script_json(spec)}</script></div>'
              for key, spec in specs.items()]
    return f'{geometry}<div class="row">{"".join(panels)}</div>'


def _script_json(value) -> str:
    """``value`` as JSON inside a ``<script>`` element (no ``</`` to end it early)."""
    return json.dumps(value, separators=(",", ":")).replace("</", "<\\/")


def _per_view_scores(m: dict) -> tuple[str, dict[str, dict[str, list]]] | None:
    """``(what the scores compare against, {scan name: {"psnr": [...], "ssim": [...]}})`` from the
    metrics' held-out scores, one entry per held-out view in ``views.test`` order; ``None`` without."""
    for key, against in (("held_out_vs_ground_truth", "ground truth"), ("held_out_vs_input", "input renders")):
        scores = m.get(key)
        if scores and all("per_view" in s for s in scores.values()):
            return against, {name: s["per_view"] for name, s in scores.items()}
    return None


def _renders(before: Scan | None, after: Scan, truth: Scan | None, cameras: list[Camera],
             scores: tuple[str, dict] | None = None, shown: list[dict[str, np.ndarray]] | None = None) -> str:
    """The held-out views' wipe comparisons. ``shown``: the renders the metrics were scored from, one dict a
    view in ``cameras`` order (:attr:`scantex.pipeline.enhance.EnhanceResult.renders`); views without
    them are rendered here the same way (one cast for the three scans)."""
    columns = [("input", before), ("enhanced", after), ("ground truth", truth)]
    columns = [(n, s) for n, s in columns if s is not None]
    shown = shown or []
    given = [k < len(shown) and all(n in shown[k] for n, _ in columns) for k in range(len(cameras))]
    # the geometry is the same for all three
    caster = None if all(given) else RayCaster(after.positions, after.faces)

    def widget(k: int, cam: Camera) -> str:
        view_scores = None
        if given[k]:
            images = {n: shown[k][n] for n, _ in columns}
        else:
            # as the metrics render a view: SCORE_SUPERSAMPLE rays a pixel side, the finer image shown
            images = {}
            scored = render_scans(dict(columns), cam, caster, supersample=SCORE_SUPERSAMPLE, fine=images)
            if scores is None and truth is not None:  # metrics without per-view scores: score here, as they would
                ref, ref_alpha = scored.pop("ground truth")
                mask = ref_alpha >= 0.999
                view_scores = ("ground truth", {n: {"psnr": min(psnr(im, ref, mask), PSNR_CAP_DB),
                                                    "ssim": ssim(im, ref, mask)} for n, (im, _) in scored.items()})
        if scores is not None:
            against, per_view = scores
            view_scores = (against, {n: {m: v[m][k] for m in ("psnr", "ssim") if k < len(v.get(m, []))}
                                     for n, v in per_view.items()})
        # a view far larger than the page shows is halved (or more) for it
        step = max(1, max(next(iter(images.values())).shape[:2]) // RENDER_DISPLAY)
        if step > 1:
            images = {n: to_uint8(downsample(im[:im.shape[0] // step * step, :im.shape[1] // step * step]
                                             .astype(np.float32) / 255, step)) for n, im in images.items()}
        height, width = next(iter(images.values())).shape[:2]
        table = _scores_table(view_scores, f"view {k + 1}: {cam.width}×{cam.height} px scored, "
                              f"{width}×{height} shown")
        right = "enhanced"
        left = "input" if "input" in images else "ground truth" if "ground truth" in images else "enhanced"
        return _compare(f"view-{k + 1}", images, left, right, table, fit=True, split=_split_at(images[right]))

    # the views side by side: Embree, numpy and PNG encoding release the interpreter lock
    with ThreadPoolExecutor(PAIR_THREADS) as pool:
        widgets = list(pool.map(widget, range(len(cameras)), cameras))
    return "".join(widgets)


def _scores_table(scores: tuple[str, dict] | None, caption: str) -> str:
    rows = ""
    if scores is not None:
        against, values = scores
        rows = "".join(f"<tr><th>{html.escape(n)}</th><td>{_num(v.get('psnr'))} dB</td><td>{_fmt(v.get('ssim'))}</td></tr>"
                       for n, v in values.items())
        rows = (f"<tr><th></th><th>PSNR</th><th>SSIM</th></tr>{rows}"
                f"<tr><td colspan=3 class='cap'>against the {html.escape(against)}</td></tr>")
    return f"<table class='cmp-scores'><caption>{html.escape(caption)}</caption>{rows}</table>"


def _split_at(image: np.ndarray) -> float:
    """Where a view's wipe opens, in percent of its width: the middle of the columns its surface covers (the
    middle of the image showed one side alone where the surface fills one half of the view)."""
    columns = np.flatnonzero(image[..., :3].max(axis=(0, 2)) > 0)
    if columns.size == 0:
        return 50.0
    return float(np.clip(100 * (columns[0] + columns[-1] + 1) / (2 * image.shape[1]), 10, 90))


def _compare(key: str, images: dict[str, np.ndarray], left: str, right: str, side: str, *, fit: bool,
             split: float = 50.0) -> str:
    """A wipe viewer over ``images`` (all shown over the same box: the largest image's size), ``left``
    and ``right`` shown first; ``side`` is HTML put beside it. ``fit``: open fitted to the box, else at
    1:1 (one pixel of the largest image per CSS pixel). ``split``: where the split opens, percent of the
    width."""
    H = max(im.shape[0] for im in images.values())
    W = max(im.shape[1] for im in images.values())
    # at 1:1, a box a little larger than a small image leaves room to zoom in
    box_w, box_h = min(max(W, 384), VIEWER_SIZE[0]), min(max(H, 384), VIEWER_SIZE[1])
    if fit:  # keep the image's aspect in the box
        scale = min(VIEWER_SIZE[0] / W, VIEWER_SIZE[1] / H)
        box_w, box_h = max(1, round(W * scale)), max(1, round(H * scale))
    sources = "".join(_img(im, name, "cmp-source", data_name=name) for name, im in images.items())

    def menu(side_name: str, chosen: str) -> str:
        options = "".join(f'<option value="{html.escape(n)}"{" selected" if n == chosen else ""}>{html.escape(n)}'
                          f"</option>" for n in images)
        return f'<label>{side_name} <select class="cmp-{side_name}">{options}</select></label>'

    return (f'<div class="compare" id="compare-{key}" data-width="{W}" data-height="{H}" '
            f'data-open="{"fit" if fit else "1"}">'
            f'<div class="cmp-controls">{menu("left", left)} {menu("right", right)} '
            '<button type="button" data-zoom="out" title="zoom out">−</button>'
            '<button type="button" data-zoom="in" title="zoom in">+</button>'
            '<button type="button" data-zoom="1" title="one image pixel per screen pixel">1:1</button>'
            '<button type="button" data-zoom="fit" title="the whole image">fit</button>'
            '<span class="cmp-zoom"></span></div>'
            f'<div class="cmp-body"><div class="cmp-view" style="width:{box_w}px;aspect-ratio:{box_w}/{box_h}">'
            '<div class="cmp-layer cmp-a"><img class="cmp-img" alt=""></div>'
            '<div class="cmp-layer cmp-b"><img class="cmp-img" alt=""></div>'
            '<div class="cmp-divider"><div class="cmp-handle"></div></div>'
            '<span class="cmp-label cmp-label-a"></span><span class="cmp-label cmp-label-b"></span></div>'
            f'<div class="cmp-side">{side}</div></div>'
            f'<input type="range" class="cmp-split" min="0" max="100" step="0.1" value="{split:.1f}" '
            f'style="width:{box_w}px" aria-label="split position">'
            f'<div class="cmp-sources" hidden>{sources}</div></div>')


def _atlases(before: Scan, after: Scan) -> str:
    from PIL import Image

    rows = []
    crop = _crop_centre(before)
    kept = kept_faces(before, after)
    apart = 0 if kept is None else int((~kept).sum())
    same = kept is not None and apart <= KEPT_APART * kept.size
    shown = [m for m, (mb, ma) in enumerate(zip(before.materials, after.materials))
             if mb.image is not None and ma.image is not None]
    textured = len(shown)
    if textured > MAX_ATLASES:
        area = np.bincount(before.face_materials, before.face_areas, minlength=len(before.materials))
        cropped = crop[2] if crop is not None else -1  # the material the crop shows a hole of, first
        shown = sorted(sorted(shown, key=lambda m: (m != cropped, -area[m]))[:MAX_ATLASES])
    for m in shown:
        mb, ma = before.materials[m], after.materials[m]
        cells_whole, crops, where = [], {}, {}
        for label, image in (("before", mb.image), ("after", ma.image)):
            H, W = image.shape[:2]
            scale = min(1.0, THUMBNAIL / max(H, W))
            # reduced by a whole factor first (box), then Lanczos over the last factor of 2 or more: a 2048^2
            # atlas 78 -> 31 ms, an 8192^2 one 92 -> 67 ms, the thumbnail within 0.15-0.35 of a level on average
            # (2-3 levels at the 99th percentile) of the one-step Lanczos
            thumb = Image.fromarray(image[..., :3]).resize((max(1, round(W * scale)), max(1, round(H * scale))),
                                                           Image.LANCZOS, reducing_gap=2.0)
            cells_whole.append(f"<div>{_img(np.asarray(thumb), f'{label} atlas', 'thumb')}"
                               f"<div class='cap'>{label}: {W}×{H}</div></div>")
            # the same region of the UV square in both atlases, whatever their sizes
            cu, cv = crop[:2] if crop is not None and crop[2] == m else (0.5, 0.5)
            size = CROP_TEXELS / mb.image.shape[1]
            x0 = int(round((cu - size / 2) * W))
            y0 = int(round((1 - cv - size / 2) * H))
            n = min(max(1, int(round(size * W))), W, H)
            x0, y0 = min(max(x0, 0), max(W - n, 0)), min(max(y0, 0), max(H - n, 0))
            crops[label] = np.ascontiguousarray(image[y0:y0 + n, x0:x0 + n, :3])
            where[label] = f"texels {x0}–{x0 + n} × {y0}–{y0 + n} of {W}×{H}"
        title = html.escape(mb.name)
        note = ("The same square of UV space in both atlases; the layouts differ, so it is not the same surface."
                if not same else "The same UV region of both atlases (the layout is kept, so the same surface)."
                if not apart else f"The same UV region of both atlases (the layout is kept, so the same surface; "
                f"{apart:,} faces the input gave no texture space have charts of their own in free space).")
        side = ("<table class='cmp-scores'><caption>material " + title + "</caption>"
                + "".join(f"<tr><th>{html.escape(k)}</th><td>{html.escape(v)}</td></tr>" for k, v in where.items())
                + f"<tr><td colspan=2 class='cap'>{html.escape(note)}</td></tr></table>")
        # divs, not a table: a viewer in a table cell widened the table past a phone's screen
        rows.append(f"<h3>material {title}</h3><div class='row'>{''.join(cells_whole)}</div>"
                    f"{_compare(f'atlas-{m}', crops, 'before', 'after', side, fit=False)}")
    more = (f"<p class='note'>The {len(shown)} of {textured} materials on the most surface; the others' atlases "
            "are in the output folder.</p>" if textured > len(shown) else "")
    return more + "".join(rows) if rows else "<p>No atlas to show.</p>"


def _comparisons(images: dict) -> str:
    rows = "".join(f"<tr><td>{_img(to_uint8(image), name, 'sheet')}<div class='cap'>{html.escape(name)}</div></td></tr>"
                   for name, image in images.items())
    return f'<table class="images">{rows}</table>'


def _crop_centre(scan: Scan) -> tuple[float, float, int] | None:
    """UV centre and material of the detail crop: a hole if the scan has one (where the input is at its
    worst), else a face on a seam, else none; of those (up to 200, spread over them), the one whose crop
    the most surface fills (a hole at a chart's edge showed a crop of gutter, the unused texels between
    charts, more than of surface)."""
    if not scan.is_textured:
        return None
    candidates = np.flatnonzero(untextured_faces(scan))
    if not candidates.size:
        edges = seam_edges(scan)
        if not len(edges):
            return None
        candidates = edges.faces[:, 0]
    candidates = candidates[np.linspace(0, len(candidates) - 1, min(200, len(candidates))).astype(int)]
    uv = scan.triangle_uvs
    centres = uv.mean(axis=1) % 1.0
    faces = np.arange(scan.n_faces)
    if faces.size > 50_000:  # a sample of the surface is enough to rank the crops
        faces = np.sort(np.random.default_rng(0).choice(faces, 50_000, replace=False))
    material, centre, surface = scan.face_materials[faces], centres[faces], uv_areas(uv[faces])
    best, filled = candidates[0], -1.0
    for f in candidates:
        m = scan.face_materials[f]
        image = scan.materials[m].image
        half = CROP_TEXELS / 2 / (image.shape[1] if image is not None else CROP_TEXELS)
        inside = surface[(material == m) & (np.abs(centre - centres[f]) < half).all(axis=1)].sum()
        if inside > filled:
            best, filled = f, inside
    u, v = centres[best]
    return float(u), float(v), int(scan.face_materials[best])


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
                      + (f"<p class='note'>Distances in the scan's units, from every vertex and {d['samples']:,} "
                         "random surface points per direction.</p>" if d.get("samples") else
                         f"<p class='note'>{html.escape(d.get('note', 'not sampled'))}.</p>"))
        tables.append(f"<h3>Geometry</h3><table><tr><th></th><th>input</th><th>output</th></tr>{body}</table>{extra}")
    for key, label in (("held_out_vs_ground_truth", "Held-out views vs ground truth"),
                       ("held_out_vs_input", "Held-out views vs input renders"),
                       ("held_out_photos", "Held-out photos"),
                       ("held_out_photos_vs_ground_truth", "Held-out photos' cameras vs ground truth")):
        scores = m.get(key)
        if not scores:
            continue
        if key.startswith("held_out_photos") and _remade(m):
            label += " (the texture made without these photos; the one written was made from all)"
        names = list(scores)
        cols = sorted({c for s in scores.values() for c in s if c != "per_view"})
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
    if isinstance(v, bool):
        return "yes" if v else "no"
    if v is None or isinstance(v, str):
        return html.escape(str(v) if v is not None else "—")
    if isinstance(v, (int, np.integer)):
        return f"{int(v):,}"
    if isinstance(v, (float, np.floating)):
        return _num(v)
    return html.escape(strict_json(v))


def _img(image: np.ndarray, alt: str, kind: str = "", data_name: str | None = None) -> str:
    from PIL import Image

    from scantex.io.images import PNG_COMPRESS_LEVEL

    buffer = io.BytesIO()
    Image.fromarray(np.ascontiguousarray(image)).save(buffer, format="PNG", compress_level=PNG_COMPRESS_LEVEL)
    data = base64.b64encode(buffer.getvalue()).decode("ascii")
    name = f' data-name="{html.escape(data_name)}"' if data_name is not None else ""
    return f'<img class="{kind}"{name} alt="{html.escape(alt)}" src="data:image/png;base64,{data}">'


def json_safe(value):
    """``value`` as strict JSON holds it: numpy scalars and arrays as Python's, and a float that is not finite
    (NaN, infinity) as ``null``. ``json.dumps`` writes those as ``NaN`` and ``Infinity``, which no JSON parser
    but Python's reads (a photo that sees nothing has no pose error: ``NaN`` made ``metrics.json`` unreadable
    to a browser's ``JSON.parse``)."""
    if isinstance(value, dict):
        return {k: json_safe(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [json_safe(v) for v in value]
    if isinstance(value, np.ndarray):
        return json_safe(value.tolist())
    if isinstance(value, (float, np.floating)):
        return float(value) if math.isfinite(value) else None
    if isinstance(value, np.generic):
        return value.item()
    return value


def strict_json(value, **kwargs) -> str:
    """``json.dumps`` of :func:`json_safe` ``(value)``: JSON every parser reads."""
    return json.dumps(json_safe(value), allow_nan=False, **kwargs)


STYLE = """
body { font: 14px/1.45 system-ui, sans-serif; margin: 0 auto; max-width: 1280px; padding: 0 16px 48px; color: #222; }
h1 { margin: 20px 0 4px; } h2 { margin-top: 32px; border-bottom: 1px solid #ddd; } h3 { margin-bottom: 4px; }
table { border-collapse: collapse; margin: 6px 0; display: block; overflow-x: auto; max-width: 100%; }
th, td { padding: 3px 10px; text-align: left; vertical-align: top; }
th { font-weight: 600; } table tr:nth-child(even) { background: #f6f6f6; }
table.images tr { background: none; } table.images img { display: block; max-width: 100%; image-rendering: pixelated; }
img.render { width: 300px; } img.thumb { width: 384px; } img.sheet { width: 960px; }
img.render, img.thumb, img.sheet { max-width: 100%; height: auto; }
.headline td.good { color: #176b2c; } .headline td.bad { color: #a31515; font-weight: 600; }
.note, .cap { color: #666; font-size: 12px; } .row { display: flex; gap: 12px; flex-wrap: wrap; }
.view3d { flex: 1 1 480px; min-width: min(360px, 100%); } .plot3d { height: 460px; }
.bar { background: #5b8def; height: 10px; min-width: 1px; } .timings td:last-child { width: 320px; }
pre { background: #f6f6f6; padding: 8px; overflow: auto; max-height: 480px; }
"""

#: plots every embedded figure, then keeps the 3D cameras of the views in step
SYNC_SCRIPT = """
(function () {
  var specs = document.querySelectorAll('script.figure');
  if (!specs.length) { return; }
  var plots = [];
  specs.forEach(function (node) {
    var fig = JSON.parse(node.textContent);
    if (node.dataset.geometry) {  // the positions and triangles both views share, written once
      Object.assign(fig.data[0], JSON.parse(document.getElementById(node.dataset.geometry).textContent));
    }
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

COMPARE_STYLE = """
.compare { margin: 10px 0 22px; } .cmp-controls { margin-bottom: 4px; } .cmp-controls button { min-width: 32px; }
.cmp-controls label { margin-right: 6px; } .cmp-zoom { color: #666; margin-left: 6px; font-size: 12px; }
.cmp-body { display: flex; gap: 16px; align-items: flex-start; flex-wrap: wrap; }
.cmp-view { position: relative; overflow: hidden; background: #333; cursor: grab; touch-action: none;
            user-select: none; flex: none; max-width: 100%; }
.cmp-view.panning { cursor: grabbing; }
.cmp-layer { position: absolute; inset: 0; overflow: hidden; }
.cmp-layer img { position: absolute; left: 0; top: 0; transform-origin: 0 0; max-width: none;
                 image-rendering: pixelated; pointer-events: none; }
.cmp-divider { position: absolute; top: 0; bottom: 0; left: 50%; width: 24px; margin-left: -12px; cursor: ew-resize; }
.cmp-divider::before { content: ""; position: absolute; left: 11px; top: 0; bottom: 0; width: 2px; background: #fff;
                       box-shadow: 0 0 3px #000; }
.cmp-handle { position: absolute; left: 0; top: 50%; width: 20px; height: 20px; margin-top: -12px; border-radius: 50%;
              background: #fff; border: 2px solid #333; }
.cmp-label { position: absolute; top: 6px; padding: 1px 6px; background: rgba(0,0,0,.6); color: #fff; font-size: 12px;
             pointer-events: none; } .cmp-label-a { left: 6px; } .cmp-label-b { right: 6px; }
.cmp-split { display: block; margin: 4px 0 0; max-width: 100%; }
.cmp-scores caption { text-align: left; color: #666; font-size: 12px; }
"""

#: the wipe viewers: the right image is clipped to the right of the split; both images share one zoom
#: and pan (a CSS transform), so the same texel is under the cursor on both sides of the split
COMPARE_SCRIPT = """
(function () {
  function setup(root) {
    var W = +root.dataset.width, H = +root.dataset.height;
    var view = root.querySelector('.cmp-view'), layerB = root.querySelector('.cmp-b');
    var images = [root.querySelector('.cmp-a img'), root.querySelector('.cmp-b img')];
    var menus = [root.querySelector('.cmp-left'), root.querySelector('.cmp-right')];
    var labels = [root.querySelector('.cmp-label-a'), root.querySelector('.cmp-label-b')];
    var divider = root.querySelector('.cmp-divider'), split = root.querySelector('.cmp-split');
    var zoomText = root.querySelector('.cmp-zoom');
    var sources = {};
    root.querySelectorAll('.cmp-source').forEach(function (img) { sources[img.dataset.name] = img.src; });
    var state = {s: 1, x: 0, y: 0};
    function fitScale() { return Math.min(view.clientWidth / W, view.clientHeight / H); }
    function place(size, box, offset) {  // centred when smaller than the box, else no empty margin
      return size <= box ? (box - size) / 2 : Math.min(0, Math.max(box - size, offset));
    }
    function apply() {
      state.x = place(W * state.s, view.clientWidth, state.x);
      state.y = place(H * state.s, view.clientHeight, state.y);
      var t = 'translate(' + state.x + 'px,' + state.y + 'px) scale(' + state.s + ')';
      images.forEach(function (img) { img.style.transform = t; });
      zoomText.textContent = Math.abs(state.s - 1) < 1e-6 ? '1:1' : Math.round(state.s * 100) + ' %';
    }
    function zoomAt(s, mx, my) {
      s = Math.min(64, Math.max(Math.min(1, fitScale()) / 2, s));
      state.fitted = false;
      state.x = mx - (mx - state.x) * s / state.s;
      state.y = my - (my - state.y) * s / state.s;
      state.s = s;
      apply();
    }
    function setSplit(p) {
      p = Math.min(100, Math.max(0, +p));
      layerB.style.clipPath = 'inset(0 0 0 ' + p + '%)';
      divider.style.left = p + '%';
      if (+split.value !== p) { split.value = p; }
      root.dataset.split = p;
    }
    function choose() {
      for (var i = 0; i < 2; i++) {
        images[i].src = sources[menus[i].value];
        labels[i].textContent = menus[i].value;
      }
    }
    images.forEach(function (img) { img.style.width = W + 'px'; img.style.height = H + 'px'; });
    menus.forEach(function (m) { m.addEventListener('change', choose); });
    split.addEventListener('input', function () { setSplit(split.value); });
    root.querySelectorAll('button[data-zoom]').forEach(function (b) {
      b.addEventListener('click', function () {
        var z = b.dataset.zoom, cx = view.clientWidth / 2, cy = view.clientHeight / 2;
        if (z === 'in') { zoomAt(state.s * 2, cx, cy); }
        else if (z === 'out') { zoomAt(state.s / 2, cx, cy); }
        else if (z === '1') { zoomAt(1, cx, cy); }
        else { zoomAt(fitScale(), cx, cy); state.fitted = true; }
      });
    });
    view.addEventListener('wheel', function (e) {
      e.preventDefault();
      var r = view.getBoundingClientRect();
      zoomAt(state.s * (e.deltaY < 0 ? 1.25 : 0.8), e.clientX - r.left, e.clientY - r.top);
    }, {passive: false});
    var drag = null;
    view.addEventListener('pointerdown', function (e) {
      drag = {mode: divider.contains(e.target) ? 'split' : 'pan', x: e.clientX, y: e.clientY};
      if (drag.mode === 'pan') { view.classList.add('panning'); }
      if (view.setPointerCapture) { try { view.setPointerCapture(e.pointerId); } catch (err) { /* synthetic */ } }
      e.preventDefault();
    });
    view.addEventListener('pointermove', function (e) {
      if (!drag) { return; }
      if (drag.mode === 'split') {
        var r = view.getBoundingClientRect();
        setSplit(100 * (e.clientX - r.left) / r.width);
      } else {
        state.x += e.clientX - drag.x;
        state.y += e.clientY - drag.y;
        apply();
      }
      drag.x = e.clientX;
      drag.y = e.clientY;
    });
    function end() { drag = null; view.classList.remove('panning'); }
    view.addEventListener('pointerup', end);
    view.addEventListener('pointercancel', end);
    choose();
    setSplit(split.value);
    state.s = root.dataset.open === 'fit' ? fitScale() : 1;
    state.fitted = root.dataset.open === 'fit';
    apply();
    // the box follows the page's width (a phone turned, a window resized): a fitted image fits it again
    window.addEventListener('resize', function () {
      if (state.fitted) { state.s = fitScale(); }
      apply();
    });
  }
  document.querySelectorAll('.compare').forEach(setup);
})();
"""

PAGE = """<!DOCTYPE html>
<html lang="en">
<head>
<meta charset="utf-8">
<meta name="viewport" content="width=device-width, initial-scale=1">
<title>{title}</title>
<style>{style}</style>
{plotlyjs}
</head>
<body>
<h1>{title}</h1>
<p class="note">Written by scantex on {date}. Geometry is never changed: only the texture is new.</p>
{body}
<script type="text/javascript">{script}</script>
</body>
</html>
"""
