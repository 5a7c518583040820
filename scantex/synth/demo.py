"""Synthetic demo scans with a known ground truth: the scene, its degraded scan, and exact renders.

:func:`make_demo` runs the whole imitation of a capture for any panel scene; :mod:`scantex.synth.wall`
and :mod:`scantex.synth.room` describe the two built-in scenes.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from scantex.atlas.texelmap import texel_map
from scantex.scan import Material, Scan
from scantex.synth.charts import Unwrap, pack_charts, split_charts
from scantex.synth.degrade import Degradation, degrade_atlas, pick_holes
from scantex.synth.mesh import MeshNoise, PanelMesh, build_mesh
from scantex.synth.procedural import Panel, ProceduralAlbedo
from scantex.synth.texture import bake_albedo, dilate
from scantex.views.camera import Camera
from scantex.views.raycast import RayCaster, cast_gbuffer
from scantex.views.render import downsample, to_uint8

log = logging.getLogger(__name__)

SCAN_IMAGE_NAME = "scan_albedo.png"
GROUND_TRUTH_IMAGE_NAME = "ground_truth_albedo.png"


@dataclass(frozen=True, eq=False)
class DemoScan:
    """A synthetic scan and everything known about it.

    Attributes:
        scan: what a capture app would deliver: the mesh with a degraded atlas.
        ground_truth: the same geometry and UVs with the ideal atlas.
        albedo: the scene's true colour, ``(N, 3) points -> (N, 3) float32`` in [0, 1], for exact
            ground-truth renders from any camera (see :func:`render_ground_truth`).
        hole_faces: ``(K,) int64`` faces left untextured (black) in ``scan``.
        chart_of_face: ``(F,) int64`` chart id of every face.
        panels: the planar panels the scene is made of.
        name: ``"wall"``, ``"room"``, ...
        seed: the seed everything was drawn from.
    """

    scan: Scan
    ground_truth: Scan
    albedo: ProceduralAlbedo
    hole_faces: np.ndarray
    chart_of_face: np.ndarray
    panels: tuple[Panel, ...]
    name: str
    seed: int

    @property
    def n_charts(self) -> int:
        return int(self.chart_of_face.max()) + 1


def _streams(seed: int) -> list[np.random.Generator]:
    """Independent generators for geometry, charts and degradation."""
    return [np.random.default_rng(s) for s in np.random.SeedSequence(seed).spawn(3)]


def make_geometry(panels: tuple[Panel, ...], seed: int, mesh_noise: MeshNoise = MeshNoise()) -> PanelMesh:
    """The mesh :func:`make_demo` makes for the same panels and seed, without unwrapping or texturing."""
    return build_mesh(panels, _streams(seed)[0], mesh_noise)


def make_demo(panels: tuple[Panel, ...], seed: int, name: str, *, gt_texture_size: int, scan_texture_size: int,
              unwrap: Unwrap = Unwrap(), degradation: Degradation = Degradation(),
              mesh_noise: MeshNoise = MeshNoise(), supersample: int = 2) -> DemoScan:
    """Mesh, unwrap, bake and degrade a panel scene.

    Args:
        panels: the scene.
        seed: seeds everything; geometry, charts and degradation draw from separate streams, so
            changing a texture size does not move a vertex.
        name: the demo's name.
        gt_texture_size: ground-truth atlas width and height in texels.
        scan_texture_size: degraded atlas size; ``gt_texture_size`` must be a whole multiple of it.
        unwrap: how the atlas is cut and packed.
        degradation: how the scan's texture is degraded.
        mesh_noise: vertex jitter and scanner noise.
        supersample: albedo samples per texel along each axis in the ground-truth bake.
    """
    if gt_texture_size % scan_texture_size:
        raise ValueError(f"gt_texture_size ({gt_texture_size}) must be a whole multiple of "
                         f"scan_texture_size ({scan_texture_size})")
    start = time.perf_counter()
    _, chart_rng, degrade_rng = _streams(seed)
    mesh = make_geometry(panels, seed, mesh_noise)
    # a chart needs room for more than its gutters: cap the count by what the atlas can hold
    n_charts = min(unwrap.n_charts, max(1, int((scan_texture_size / (8 * unwrap.gutter_texels)) ** 2)))
    chart_of_face = split_charts(mesh, panels, n_charts, unwrap, chart_rng)
    layout = pack_charts(mesh, panels, chart_of_face, scan_texture_size, unwrap, chart_rng)
    geometry = Scan(mesh.positions, mesh.faces, layout.uvs, layout.face_uvs)
    triangles, triangle_uvs = geometry.triangles, geometry.triangle_uvs

    albedo = ProceduralAlbedo(panels, seed)
    factor = gt_texture_size // scan_texture_size
    truth, truth_texels = bake_albedo(triangles, triangle_uvs, albedo, gt_texture_size, supersample)
    truth = dilate(truth, truth_texels.mask, unwrap.gutter_texels * factor)

    hole_faces = pick_holes(mesh.positions, mesh.faces, degradation.hole_share, degradation.hole_clusters,
                                   degrade_rng)
    scan_texels = texel_map(triangle_uvs, scan_texture_size, scan_texture_size)
    degraded = degrade_atlas(truth, scan_texels, chart_of_face, hole_faces, unwrap.gutter_texels,
                             degradation, degrade_rng)

    scan = geometry.replace(materials=(Material("scan", degraded, image_name=SCAN_IMAGE_NAME),))
    ground_truth = geometry.replace(
        materials=(Material("ground_truth", to_uint8(truth), image_name=GROUND_TRUTH_IMAGE_NAME),))
    log.info("%s demo (seed %d): %d vertices, %d faces, %d charts, %d hole faces, atlases %d² / %d², %.1f s",
             name, seed, len(mesh.positions), len(mesh.faces), int(chart_of_face.max()) + 1,
             len(hole_faces), gt_texture_size, scan_texture_size, time.perf_counter() - start)
    return DemoScan(scan, ground_truth, albedo, hole_faces, chart_of_face, tuple(panels), name, seed)


def render_ground_truth(demo: DemoScan, camera: Camera, supersample: int = 1, *, caster: RayCaster | None = None,
                        background=(0.0, 0.0, 0.0)) -> tuple[np.ndarray, np.ndarray]:
    """The exact ground-truth view: the albedo at every ray's hit point, not looked up in an atlas.

    Args:
        demo: the demo scan.
        camera: the view.
        supersample: rays per pixel along each axis (box filtered).
        caster: a prebuilt :class:`RayCaster` of the demo's mesh (built here when ``None``).
        background: RGB of pixels that see nothing.

    Returns:
        ``(image, alpha)`` as :func:`scantex.views.render.render`: ``(H, W, 3) float32`` in [0, 1] and
        ``(H, W) float32`` coverage.
    """
    scan = demo.scan
    caster = caster or RayCaster(scan.positions, scan.faces)
    cam = camera.scaled(supersample) if supersample > 1 else camera
    g = cast_gbuffer(caster, cam)
    H, W = g.shape
    rgb = np.empty((H * W, 3), dtype=np.float32)
    rgb[:] = background
    hit = g.mask.reshape(-1)
    rgb[hit] = demo.albedo(g.points(scan.positions, scan.faces).reshape(-1, 3)[hit])
    alpha = g.mask.astype(np.float32)[..., None]
    return downsample(rgb.reshape(H, W, 3), supersample), downsample(alpha, supersample)[..., 0]


def write_demo(demo: DemoScan, out_dir: str | Path) -> dict[str, Path]:
    """Write ``scan.obj`` and ``ground_truth.obj`` (each with its MTL and PNG atlas) into ``out_dir``.

    Returns:
        the OBJ paths by name: ``{"scan": ..., "ground_truth": ...}``.
    """
    from scantex.io import save_scan

    out_dir = Path(out_dir)
    paths = {"scan": out_dir / "scan.obj", "ground_truth": out_dir / "ground_truth.obj"}
    save_scan(demo.scan, paths["scan"])
    save_scan(demo.ground_truth, paths["ground_truth"])
    return paths
