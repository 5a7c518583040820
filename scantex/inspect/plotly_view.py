"""An interactive 3D view of a scan in one self-contained HTML file (the paper's inspection step).

Plotly's ``Mesh3d`` cannot map a texture, so the texture is shown as one colour per face: the mean of
the unlit colour at the face's three corners and its centre, looked up exactly as the renderer does
(:func:`scantex.views.render.shade_hits`). Per-face colours stay faithful where UVs are split at
seams, which per-vertex colours would smear across. Scans coloured per vertex (PLY) keep their vertex
colours. plotly.js is embedded, so the file opens offline.
"""

from __future__ import annotations

import html
import logging
from pathlib import Path

import numpy as np

from scantex.io.atomic import atomic_files
from scantex.scan import Scan, up_axis
from scantex.views.render import shade_hits, to_uint8

log = logging.getLogger(__name__)

#: barycentrics (Embree's ``(u, v)``) of a face's three corners and its centre
_FACE_SAMPLES = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0], [1 / 3, 1 / 3]], dtype=np.float32)


def view_html(scan: Scan, path: str | Path, *, max_faces: int = 200_000, title: str | None = None,
              seed: int = 0) -> Path:
    """Write an interactive Plotly view of ``scan`` to ``path`` and return the path.

    Args:
        scan: the scan; never changed.
        path: the HTML file to write; its folder is created if missing. Written through a temporary
            file in the same folder, so a failure never leaves a half-written file.
        max_faces: above this many faces, a random subset of this size is shown (browsers slow down
            beyond a few hundred thousand triangles); the title says so.
        title: the figure's title; ``None``: the scan's file name, or "scan".
        seed: seeds the display subset.
    """
    pio = _plotly_io()
    figure = mesh_figure(scan, max_faces=max_faces, title=title, seed=seed)
    page = pio.to_html(figure, include_plotlyjs=True, full_html=True, config={"displaylogo": False})
    page = page.replace("<head>", f"<head><title>{html.escape(_name(scan, title))}</title>", 1)

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_files() as files:
        files.path(path).write_text(page, encoding="utf-8")
    return path


def mesh_figure(scan: Scan, *, max_faces: int = 200_000, title: str | None = None, seed: int = 0):
    """A ``plotly.graph_objects.Figure`` holding :func:`mesh_trace` of ``scan``, titled with what it shows,
    seen from the side its surface faces with its up axis up (:func:`facing_camera`)."""
    _plotly_io()
    import plotly.graph_objects as go

    trace, note = mesh_trace(scan, max_faces=max_faces, seed=seed)
    figure = go.Figure(trace)
    lo, hi = scan.bounds
    extent = np.maximum(hi - lo, 1e-12)
    # plotly's aspectmode "data" scales by the mean extent, blowing a flat wall up past the view
    ratio = np.maximum(extent / extent.max(), 0.02)
    figure.update_layout(
        # plotly reads its titles as HTML: a file name's own < and & are escaped
        title=dict(text=f"{html.escape(_name(scan, title))} — {note}", x=0.01, xanchor="left"),
        modebar=dict(orientation="v"),  # down the right side: across the top it covered a narrow view's title
        scene=dict(aspectmode="manual", aspectratio=dict(x=float(ratio[0]), y=float(ratio[1]), z=float(ratio[2])),
                   camera=facing_camera(scan), xaxis_title="x", yaxis_title="y", zaxis_title="z"),
        margin=dict(l=0, r=0, t=40, b=0),
    )
    return figure


def _name(scan: Scan, title: str | None) -> str:
    return title if title is not None else (scan.source.name if scan.source is not None else "scan")


def facing_camera(scan: Scan) -> dict:
    """A plotly scene camera looking at the side the surface faces (a wall from the front, a little from
    above; a floor or a room with an open top from 45 degrees above), with the scan's up axis up
    (:func:`scantex.scan.up_axis`: y for glTF); plotly's diagonal view for closed objects, whose normals
    cancel."""
    up = np.array(up_axis(scan))
    normals = scan.face_normals * scan.face_areas[:, None]
    mean = normals.sum(axis=0) / max(scan.face_areas.sum(), 1e-300)
    length = float(np.linalg.norm(mean))
    if length < 0.3:
        eye = np.full(3, 1.25)
    elif abs(mean @ up) / length > 0.9:  # facing along its up axis (a floor, a room from above): at 45 degrees,
        eye = 0.9 * (mean / length + np.roll(up, -1))  # so that what stands on it reads
    else:
        eye = 1.05 * mean / length + 0.2 * up
    return dict(eye=dict(zip("xyz", map(float, eye))), up=dict(zip("xyz", map(float, up))))


def mesh_trace(scan: Scan, *, max_faces: int = 200_000, seed: int = 0):
    """A plotly ``Mesh3d`` trace of ``scan`` coloured from its texture, and a note of what it shows.

    Above ``max_faces`` faces a random subset (seeded by ``seed``) is shown, for display only.

    Returns:
        ``(trace, note)``: the trace and e.g. ``"1,200 faces"`` or ``"200,000 of 1,000,000 faces (...)"``.
    """
    _plotly_io()
    import plotly.graph_objects as go

    if max_faces < 1:
        raise ValueError(f"max_faces must be positive, got {max_faces}")
    F = scan.n_faces
    if F > max_faces:
        shown = np.sort(np.random.default_rng(seed).choice(F, size=max_faces, replace=False))
        note = f"{max_faces:,} of {F:,} faces (random subset, for display only)"
    else:
        shown = np.arange(F)
        note = f"{F:,} faces"
    log.debug("3D view: %s", note)
    # only the vertices the shown faces use travel to the browser
    used, corners = np.unique(scan.faces[shown], return_inverse=True)
    corners = corners.reshape(-1, 3)
    xyz = scan.positions[used]

    mesh = dict(x=xyz[:, 0], y=xyz[:, 1], z=xyz[:, 2],
                i=corners[:, 0].astype(np.int32), j=corners[:, 1].astype(np.int32),
                k=corners[:, 2].astype(np.int32),
                # high ambient: the point is to read the texture's colours, the light only hints shape
                lighting=dict(ambient=0.75, diffuse=0.35, specular=0.05, roughness=0.9, fresnel=0.05),
                flatshading=False, hoverinfo="skip", name="scan")
    if not scan.is_textured and scan.vertex_colors is not None:
        mesh["vertexcolor"] = _hex(scan.vertex_colors[used, :3])
    else:
        mesh["facecolor"] = _hex(to_uint8(face_display_colors(scan, shown)))
    # built unvalidated: plotly checks each of the colour strings in Python (0.2-0.45 s for the bolster's
    # 12,712 faces), and these arrays are of the types it takes; the trace's JSON is the same
    return go.Mesh3d(**mesh, _validate=False), note


def _plotly_io():
    from scantex.deps import require

    require("plotly.graph_objects", "the 3D view")
    return require("plotly.io", "the 3D view")


def face_display_colors(scan: Scan, faces: np.ndarray) -> np.ndarray:
    """``(M, 3) float32`` unlit colour in [0, 1] of ``faces (M,)``: the mean over corners and centre."""
    M, S = len(faces), len(_FACE_SAMPLES)
    face_id = np.repeat(faces, S)  # [M*S]
    bary = np.tile(_FACE_SAMPLES, (M, 1))  # [M*S, 2]
    return shade_hits(scan, face_id, bary).reshape(M, S, 3).mean(axis=1)


#: each byte's two lowercase hex digits, as character codes: ``(256, 2) uint8``
_HEX_DIGITS = np.frombuffer("".join(f"{v:02x}" for v in range(256)).encode(), np.uint8).reshape(256, 2)


def _hex(rgb: np.ndarray) -> np.ndarray:
    """``(N, 3) uint8`` colours as ``(N,)`` '#rrggbb' strings (the most compact colour plotly.js reads)."""
    # each byte's two hex digits from a table, the seven characters of a colour as one fixed-width string
    # (np.char's formatting took 0.15 s for the bathroom's 132,317 faces)
    chars = np.empty((len(rgb), 7), np.uint8)
    chars[:, 0] = ord("#")
    chars[:, 1:] = _HEX_DIGITS[np.asarray(rgb, np.uint8)].reshape(len(rgb), 6)
    return chars.view("S7").reshape(-1).astype("U7")
