"""The interactive Plotly view: self-contained HTML, faithful colours, display-only decimation."""

from __future__ import annotations

import base64
import json
import os

import numpy as np
import pytest
import trimesh

from scantex.io import atomic
from scantex.inspect import view_html
from scantex.scan import Material, Scan
from tests.conftest import grid_wall, textured_cube


def mesh_trace(html: str) -> dict:
    """The first trace of the figure embedded in ``html``, typed arrays decoded to numpy."""
    start = html.index("Plotly.newPlot(")
    start = html.index("[", start)
    traces, _ = json.JSONDecoder().raw_decode(html, start)
    trace = traces[0]
    for key, value in trace.items():
        if isinstance(value, dict) and "bdata" in value:
            trace[key] = np.frombuffer(base64.b64decode(value["bdata"]), dtype=np.dtype(value["dtype"]))
    return trace


def two_tone_quad() -> Scan:
    """Two triangles mapped onto the red and the blue half of a texture."""
    image = np.zeros((8, 16, 3), dtype=np.uint8)
    image[:, :8] = (255, 0, 0)
    image[:, 8:] = (0, 0, 255)
    positions = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], dtype=np.float64)
    faces = np.array([[0, 1, 2], [0, 2, 3]])
    # each triangle's UVs stay well inside one half, away from the bilinear blend at the middle
    uvs = np.array([[0.05, 0.1], [0.4, 0.1], [0.4, 0.9], [0.6, 0.1], [0.95, 0.9], [0.6, 0.9]])
    face_uvs = np.array([[0, 1, 2], [3, 4, 5]])
    return Scan(positions, faces, uvs, face_uvs, None, (Material("two", image),))


def test_writes_self_contained_html(tmp_path, cube):
    path = view_html(cube, tmp_path / "sub" / "view.html")
    assert path == tmp_path / "sub" / "view.html"
    html = path.read_text(encoding="utf-8")
    assert path.stat().st_size > 3_000_000  # plotly.js is embedded, not linked
    assert "plotly.js v" in html
    assert '<script src="https://cdn.plot.ly' not in html
    assert os.listdir(path.parent) == ["view.html"]  # no temporary file left
    trace = mesh_trace(html)
    assert trace["type"] == "mesh3d"
    assert len(trace["facecolor"]) == cube.n_faces
    assert len(trace["i"]) == cube.n_faces
    assert '"aspectmode":"manual"' in html  # "data" scaled by the mean extent: a flat wall opened zoomed far in


def test_face_colours_come_from_the_texture(tmp_path):
    scan = two_tone_quad()
    trace = mesh_trace(view_html(scan, tmp_path / "quad.html").read_text(encoding="utf-8"))
    assert trace["facecolor"] == ["#ff0000", "#0000ff"]
    corners = np.stack([trace["i"], trace["j"], trace["k"]], axis=1)
    xyz = np.stack([trace["x"], trace["y"], trace["z"]], axis=1)
    np.testing.assert_array_equal(xyz[corners], scan.triangles)


def test_vertex_colours_are_kept_per_vertex(tmp_path):
    m = trimesh.creation.box()
    colors = np.zeros((len(m.vertices), 4), dtype=np.uint8)
    colors[:, 0] = np.arange(len(m.vertices)) * 30
    colors[:, 3] = 255
    scan = Scan(m.vertices, m.faces, vertex_colors=colors)
    trace = mesh_trace(view_html(scan, tmp_path / "v.html").read_text(encoding="utf-8"))
    assert "facecolor" not in trace
    expected = [f"#{30 * i:02x}0000" for i in range(len(m.vertices))]
    assert trace["vertexcolor"] == expected


def test_untextured_scan_is_grey(tmp_path):
    m = trimesh.creation.icosphere(subdivisions=1)
    trace = mesh_trace(view_html(Scan(m.vertices, m.faces), tmp_path / "g.html").read_text(encoding="utf-8"))
    colours = set(trace["facecolor"])
    assert len(colours) == 1
    (grey,) = colours
    assert grey[1:3] == grey[3:5] == grey[5:7]


def test_decimation_respects_max_faces_and_leaves_the_scan_alone(tmp_path):
    m = trimesh.creation.icosphere(subdivisions=3)
    positions, faces = m.vertices.copy(), m.faces.copy()
    scan = Scan(positions, faces)
    html = view_html(scan, tmp_path / "d.html", max_faces=300).read_text(encoding="utf-8")
    trace = mesh_trace(html)
    assert len(trace["i"]) == len(trace["facecolor"]) == 300
    assert len(trace["x"]) <= 3 * 300  # only the vertices the shown faces use
    assert f"300 of {len(faces):,} faces" in html
    # every shown triangle is one of the scan's triangles
    xyz = np.stack([trace["x"], trace["y"], trace["z"]], axis=1)
    shown = xyz[np.stack([trace["i"], trace["j"], trace["k"]], axis=1)]
    original = {tuple(t.ravel()) for t in scan.triangles}
    assert all(tuple(t.ravel()) in original for t in shown)
    np.testing.assert_array_equal(scan.positions, m.vertices)
    np.testing.assert_array_equal(scan.faces, m.faces)


def test_failed_write_leaves_no_file(tmp_path, cube, monkeypatch):
    def fail(src, dst):
        raise OSError("disk full")

    monkeypatch.setattr(atomic.os, "replace", fail)
    with pytest.raises(OSError, match="disk full"):
        view_html(cube, tmp_path / "view.html")
    assert os.listdir(tmp_path) == []


def test_title_and_bad_max_faces(tmp_path):
    scan = textured_cube()
    html = view_html(scan, tmp_path / "t.html", title="my cube").read_text(encoding="utf-8")
    assert "my cube" in html
    with pytest.raises(ValueError):
        view_html(scan, tmp_path / "x.html", max_faces=0)
    # plotly reads a title as HTML: a file name's own markup is shown as it is, and the page has a title
    html = view_html(scan, tmp_path / "t.html", title="a<br>b & c").read_text(encoding="utf-8")
    assert "a&lt;br&gt;b &amp; c" in html and "a<br>b" not in html
    assert "<title>a&lt;br&gt;b &amp; c</title>" in html


@pytest.mark.parametrize("up", [None, "y"])
def test_the_view_stands_the_scan_on_its_up_axis(up):
    """A glTF scan is y-up: its view had z up, and an upright object lay on its side."""
    from scantex.inspect.plotly_view import mesh_figure

    wall = grid_wall()  # facing -y when z-up
    scan = wall if up is None else Scan(wall.positions[:, [0, 2, 1]], wall.faces[:, ::-1], wall.uvs, wall.face_uvs,
                                         None, wall.materials, up="y")
    camera = mesh_figure(scan).layout.scene.camera
    assert (camera.up.x, camera.up.y, camera.up.z) == ((0, 0, 1) if up is None else (0, 1, 0))
    eye = np.array([camera.eye.x, camera.eye.y, camera.eye.z])
    normal = scan.face_normals.mean(axis=0)
    assert eye @ normal > 0.9  # from the side the wall faces
