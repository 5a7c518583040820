"""Procedural scenes made of planar panels: their layout, surface relief and albedo.

A scene is a tuple of :class:`Panel` rectangles (a wall, a floor, the sides of a box), each with a
:class:`Finish` (brick, plaster, wood). The albedo is a function of the 3D point: the point is given to
its nearest panel and the panel's finish is evaluated at the point's in-plane coordinates. So an exact
ground truth can be computed anywhere (texel centres, G-buffer hits) without going through an atlas.
The relief (mortar joints, plank gaps, plaster unevenness) comes from the same brick and plank layout,
so geometry and colour agree.
"""

from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field

import numpy as np

from scantex.synth.noise import NoiseField, hash_uniform, smoothstep

#: points per evaluation chunk: the working set of one chunk stays in cache (4x faster than 1M chunks)
CHUNK = 1 << 16

#: brick module in metres: brick length and course height including one 10 mm joint
BRICK_MODULE = (0.225, 0.075)
MORTAR_WIDTH = 0.010
#: floor plank module: width across and length along the plank
PLANK_MODULE = (0.15, 1.2)
PLANK_GAP = 0.002
FINISH_KINDS = ("brick", "plaster", "wood")


@dataclass(frozen=True)
class Finish:
    """What a panel is made of and how it has aged.

    Attributes:
        kind: ``"brick"`` (bricks, partly painted over), ``"plaster"`` (painted plaster) or ``"wood"`` (planks).
        base_rgb: paint, plaster or wood colour in [0, 1].
        accent_rgb: brick colour (``"brick"`` only).
        paint_cover: share of a brick surface that is painted over (0: bare brick, 1: all painted).
        cracks: how much of the surface is crossed by hairline cracks (0: none, 1: a lot).
        relief_mm: depth of mortar joints or plank gaps.
        unevenness_mm: amplitude of the low-frequency waviness of the surface.
    """

    kind: str = "brick"
    base_rgb: tuple[float, float, float] = (0.86, 0.84, 0.78)
    accent_rgb: tuple[float, float, float] = (0.62, 0.30, 0.20)
    paint_cover: float = 0.5
    cracks: float = 0.5
    relief_mm: float = 4.0
    unevenness_mm: float = 2.5

    def __post_init__(self) -> None:
        if self.kind not in FINISH_KINDS:
            raise ValueError(f"unknown finish {self.kind!r}; expected one of {FINISH_KINDS}")


@dataclass(frozen=True)
class Panel:
    """A planar rectangle of the scene, meshed as a grid of quads split into two triangles.

    Attributes:
        origin: ``(3,)`` corner of the rectangle in metres.
        u_axis, v_axis: ``(3,)`` orthonormal in-plane directions; the visible side faces ``u_axis x v_axis``.
        size: extent along ``u_axis`` and ``v_axis`` in metres.
        cells: grid cells along ``u_axis`` and ``v_axis``.
        finish: the surface material.
    """

    origin: tuple[float, float, float]
    u_axis: tuple[float, float, float]
    v_axis: tuple[float, float, float]
    size: tuple[float, float]
    cells: tuple[int, int]
    finish: Finish = Finish()

    @property
    def normal(self) -> np.ndarray:
        """``(3,)`` unit normal of the visible side."""
        return np.cross(self.u_axis, self.v_axis)

    @property
    def area(self) -> float:
        return self.size[0] * self.size[1]

    def plane_coordinates(self, points: np.ndarray) -> np.ndarray:
        """``(N, 2)`` in-plane coordinates ``(u, v)`` in metres of points ``(N, 3)``."""
        d = np.asarray(points, dtype=np.float64) - np.asarray(self.origin)
        return np.stack([d @ np.asarray(self.u_axis), d @ np.asarray(self.v_axis)], axis=1)


@dataclass(frozen=True, eq=False)
class _Noises:
    """The random fields a finish draws on, one set per scene."""

    low: NoiseField  # large-scale paint and plaster variation, ~0.5 m
    tint: NoiseField  # colour drift of the large-scale variation
    stain: NoiseField  # water and dirt stains, ~0.2 m
    mid: NoiseField  # mottling within bricks and plaster, ~2 cm
    warp: NoiseField  # joint and crack waviness, ~5 cm
    crack: NoiseField  # zero crossings are the crack lines, ~8 cm
    crack_mask: NoiseField  # where cracks appear, ~0.4 m
    fine: NoiseField  # mm-scale grain
    fine2: NoiseField  # a second grain at another period, so the grain does not visibly repeat

    @classmethod
    def random(cls, rng: np.random.Generator) -> _Noises:
        return cls(
            low=NoiseField.random(rng, 0.12, 64, smooth=2.0),
            tint=NoiseField.random(rng, 0.15, 64, smooth=2.0),
            stain=NoiseField.random(rng, 0.05, 128, smooth=2.0),
            mid=NoiseField.random(rng, 0.006, 256, smooth=1.5),
            warp=NoiseField.random(rng, 0.02, 256, smooth=1.5),
            crack=NoiseField.random(rng, 0.03, 256, smooth=1.2),
            crack_mask=NoiseField.random(rng, 0.1, 64, smooth=2.0),
            fine=NoiseField.random(rng, 0.0009, 1024, smooth=0.8),
            fine2=NoiseField.random(rng, 0.0013, 1024, smooth=0.8),
        )


@dataclass(frozen=True, eq=False)
class ProceduralAlbedo:
    """The albedo of a scene of panels: ``albedo(points (N, 3)) -> (N, 3) float32`` in [0, 1].

    Deterministic in ``seed``; vectorised and evaluated in cache-sized chunks over two threads.

    Attributes:
        panels: the scene's panels; each point takes the finish of the nearest one.
        seed: seeds the random fields and per-brick colours.
    """

    panels: tuple[Panel, ...]
    seed: int = 0
    _noises: _Noises = field(init=False, repr=False)
    _offsets: np.ndarray = field(init=False, repr=False)

    def __post_init__(self) -> None:
        if not self.panels:
            raise ValueError("a procedural albedo needs at least one panel")
        rng = np.random.default_rng(np.random.SeedSequence([self.seed, 0xA1BE]))
        object.__setattr__(self, "_noises", _Noises.random(rng))
        # shift every panel's noise so that two walls of a room do not show the same pattern
        object.__setattr__(self, "_offsets", rng.uniform(0, 100, (len(self.panels), 2)))

    def __call__(self, points: np.ndarray) -> np.ndarray:
        points = np.asarray(points, dtype=np.float64)
        if points.ndim != 2 or points.shape[1] != 3:
            raise ValueError(f"points must be (N, 3), got {points.shape}")
        N = len(points)
        out = np.empty((N, 3), dtype=np.float32)
        starts = range(0, N, CHUNK)

        def run(start: int) -> None:
            out[start:start + CHUNK] = self._evaluate(points[start:start + CHUNK])

        threads = max(1, min(2, os.cpu_count() or 1))
        if threads > 1 and N > CHUNK:
            with ThreadPoolExecutor(threads) as pool:
                list(pool.map(run, starts))
        else:
            for s in starts:
                run(s)
        return out

    def panel_of(self, points: np.ndarray) -> np.ndarray:
        """``(N,) int`` index of the panel nearest to each point ``(N, 3)``."""
        if len(self.panels) == 1:
            return np.zeros(len(points), dtype=np.int64)
        dist = np.empty((len(self.panels), len(points)))
        for k, panel in enumerate(self.panels):
            uv = panel.plane_coordinates(points)
            outside = np.maximum(0.0, np.maximum(-uv, uv - np.asarray(panel.size)))
            height = (np.asarray(points) - np.asarray(panel.origin)) @ panel.normal
            dist[k] = (outside ** 2).sum(axis=1) + height ** 2
        return dist.argmin(axis=0)

    def _evaluate(self, points: np.ndarray) -> np.ndarray:
        rgb = np.empty((len(points), 3), dtype=np.float32)
        owner = self.panel_of(points)
        for k, panel in enumerate(self.panels):
            sel = np.flatnonzero(owner == k) if len(self.panels) > 1 else slice(None)
            uv = panel.plane_coordinates(points[sel])
            u = uv[:, 0].astype(np.float32)
            v = uv[:, 1].astype(np.float32)
            ou, ov = self._offsets[k].astype(np.float32)
            rgb[sel] = finish_albedo(panel.finish, u, v, u + ou, v + ov, self._noises, self.seed + 7919 * k)
        return rgb


def brick_layout(u: np.ndarray, v: np.ndarray):
    """Running-bond bricks at plane coordinates ``u, v (N,)`` in metres.

    Returns:
        ``(column, course, joint_distance)``: the brick's integer indices ``(N,)`` and the distance in
        metres from the point to the nearest joint centre line ``(N,)``.
    """
    length, height = BRICK_MODULE
    course = np.floor(v / np.float32(height))
    shifted = u + np.float32(0.5 * length) * (course.astype(np.int64) & 1)
    column = np.floor(shifted / np.float32(length))
    fu = shifted - column * np.float32(length)
    fv = v - course * np.float32(height)
    distance = np.minimum(np.minimum(fu, length - fu), np.minimum(fv, height - fv))
    return column.astype(np.int64), course.astype(np.int64), distance


def plank_layout(u: np.ndarray, v: np.ndarray):
    """Staggered floor planks running along ``v``: ``(row, segment, gap_distance)`` like :func:`brick_layout`."""
    width, length = PLANK_MODULE
    row = np.floor(u / np.float32(width))
    # each row of planks starts at its own offset, as laid floors do
    shift = hash_uniform(row.astype(np.int64), 0, 17) * np.float32(length)
    shifted = v + shift
    segment = np.floor(shifted / np.float32(length))
    fu = u - row * np.float32(width)
    fv = shifted - segment * np.float32(length)
    distance = np.minimum(np.minimum(fu, width - fu), np.minimum(fv, length - fv))
    return row.astype(np.int64), segment.astype(np.int64), distance


def finish_albedo(finish: Finish, u: np.ndarray, v: np.ndarray, nu: np.ndarray, nv: np.ndarray,
                  noises: _Noises, salt: int) -> np.ndarray:
    """Albedo ``(N, 3) float32`` of a finish at layout coordinates ``u, v`` and noise coordinates ``nu, nv``.

    Layout coordinates place bricks and planks on the panel; noise coordinates are the same shifted per
    panel, so that panels do not share their stains.
    """
    base = np.asarray(finish.base_rgb, dtype=np.float32)
    accent = np.asarray(finish.accent_rgb, dtype=np.float32)
    mid = noises.mid(nu, nv)[:, None]
    warp_u = np.float32(0.0015) * noises.warp(nu, nv)
    warp_v = np.float32(0.0015) * noises.warp(nv + 31.7, nu)
    if finish.kind == "brick":
        column, course, joint = brick_layout(u + warp_u, v + warp_v)
        mortar = smoothstep(0.5 * MORTAR_WIDTH + 0.0006, 0.5 * MORTAR_WIDTH - 0.0006, joint)[:, None]
        r1 = hash_uniform(column, course, salt)[:, None]
        r2 = hash_uniform(column, course, salt + 1)[:, None]
        r3 = hash_uniform(column, course, salt + 2)[:, None]
        # per-brick tone, a shift between red and brown, and a few dark over-fired bricks
        brick = accent * (0.78 + 0.4 * r1) * (1 + np.float32(0.12) * (r2 - 0.5) * np.array([1, -0.6, -1], np.float32))
        brick = brick * np.where(r3 > 0.92, np.float32(0.6), np.float32(1.0)) * (1 + np.float32(0.07) * mid)
        mortar_rgb = np.array([0.66, 0.64, 0.60], np.float32) * (1 + np.float32(0.05) * mid)
        bare = brick + (mortar_rgb - brick) * mortar
        cover = smoothstep(-0.35, 0.35, noises.low(nu, nv) + np.float32(2.0 * finish.paint_cover - 1.0) * 1.6)[:, None]
        # paint follows the relief, so the joints stay faintly visible through it
        painted = base * (1 - np.float32(0.12) * mortar) * (1 + np.float32(0.02) * mid)
        rgb = bare + (painted - bare) * cover
    elif finish.kind == "plaster":
        rgb = base * (1 + np.float32(0.025) * mid)
    else:
        row, segment, gap = plank_layout(u + warp_u, v)
        r1 = hash_uniform(row, segment, salt)[:, None]
        # wood grain: noise stretched along the plank into streaks, with a per-plank phase
        grain = noises.mid(nu * np.float32(0.15) + r1[:, 0] * 50, nv * np.float32(0.02))[:, None]
        rgb = base * (0.82 + 0.3 * r1) * (1 + np.float32(0.1) * grain)
        seam = smoothstep(0.5 * PLANK_GAP + 0.0005, 0.5 * PLANK_GAP - 0.0005, gap)[:, None]
        rgb = rgb * (1 - np.float32(0.6) * seam)

    # weathering shared by all finishes: large-scale colour drift, stains, cracks, grain
    low = noises.low(nu + 17.3, nv)[:, None]
    tint = noises.tint(nu, nv)[:, None]
    rgb = rgb * (1 + np.float32(0.07) * low) * (1 + np.float32(0.03) * tint * np.array([1, 0, -1], np.float32))
    stain = smoothstep(0.9, 1.9, noises.stain(nu, nv))[:, None] * np.float32(0.55)
    stain_rgb = rgb * np.array([0.78, 0.70, 0.56], np.float32) if finish.kind != "wood" else rgb * np.float32(0.7)
    rgb = rgb + (stain_rgb - rgb) * stain
    if finish.cracks > 0:
        # a noise field divided by its typical gradient (about 2/spacing) is roughly the distance in
        # metres to its zero crossings, which form thin meandering lines
        crack_distance = np.abs(noises.crack(nu + warp_u * 4, nv + warp_v * 4)) * np.float32(noises.crack.spacing / 2.0)
        line = smoothstep(0.0011, 0.0003, crack_distance)
        where = smoothstep(1.4 - 1.2 * finish.cracks, 2.0 - 1.2 * finish.cracks, noises.crack_mask(nu, nv))
        rgb = rgb * (1 - np.float32(0.55) * line * where)[:, None]
    fine = noises.fine(nu, nv) + np.float32(0.7) * noises.fine2(nv, nu)
    speckle = smoothstep(2.0, 2.6, fine)
    rgb = rgb * (1 + np.float32(0.045) * fine - np.float32(0.25) * speckle)[:, None]
    return np.clip(rgb, 0.0, 1.0).astype(np.float32, copy=False)


def finish_relief(finish: Finish, u: np.ndarray, v: np.ndarray, noises_low: NoiseField) -> np.ndarray:
    """Surface height ``(N,)`` in metres along the panel normal at plane coordinates ``u, v`` (negative = recessed).

    The mortar joints and plank gaps are blurred to the few-centimetre footprint of a depth sensor, which
    cannot resolve a 10 mm joint cleanly.
    """
    u = np.asarray(u, dtype=np.float32)
    v = np.asarray(v, dtype=np.float32)
    height = np.float32(finish.unevenness_mm * 1e-3) * noises_low(u, v)
    if finish.kind == "brick":
        _, _, joint = brick_layout(u, v)
        height -= np.float32(finish.relief_mm * 1e-3) * smoothstep(0.012, 0.0, joint)
    elif finish.kind == "wood":
        _, _, gap = plank_layout(u, v)
        height -= np.float32(finish.relief_mm * 1e-3) * smoothstep(0.006, 0.0, gap)
    return height
