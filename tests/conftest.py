"""Shared fixtures: small scans made in code, and the optional real scans in ../shared/data."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from scantex.scan import Material, Scan

SHARED_DATA = Path(__file__).resolve().parents[2] / "shared" / "data"


def checker(size: int, cells: int, colors=((230, 60, 40), (40, 90, 220))) -> np.ndarray:
    y, x = np.mgrid[0:size, 0:size] * cells // size
    img = np.where(((x + y) % 2)[..., None] == 0, colors[0], colors[1]).astype(np.uint8)
    return img


def textured_cube(materials: int = 2, seed: int = 0) -> Scan:
    """A unit cube, 8 shared positions, 6 UV shells (one per side), ``materials`` atlases."""
    rng = np.random.default_rng(seed)
    positions = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)], dtype=np.float64)
    positions += rng.normal(0, 1e-3, positions.shape)  # arbitrary float64 coordinates
    quads = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    faces, face_uvs, uvs = [], [], []
    for s, q in enumerate(quads):
        u0, v0 = (s % 3) / 3, (s // 3) / 2
        base = len(uvs)
        uvs += [[u0 + 0.02, v0 + 0.02], [u0 + 0.31, v0 + 0.02], [u0 + 0.31, v0 + 0.48], [u0 + 0.02, v0 + 0.48]]
        faces += [[q[0], q[1], q[2]], [q[0], q[2], q[3]]]
        face_uvs += [[base, base + 1, base + 2], [base, base + 2, base + 3]]
    mats = tuple(Material(f"mat{i}", checker(64, 4 + 2 * i), image_name=f"tex{i}.png") for i in range(materials))
    face_materials = np.arange(12) // 2 % materials
    return Scan(positions, np.array(faces), np.array(uvs), np.array(face_uvs), face_materials, mats)


def grid_wall(n: int = 12, size: float = 2.0, seed: int = 0) -> Scan:
    """An ``n x n`` vertex wall in the x-z plane, normals towards -y, one UV chart, checker texture."""
    rng = np.random.default_rng(seed)
    u, v = np.meshgrid(np.linspace(0, 1, n), np.linspace(0, 1, n))
    positions = np.stack([u.ravel() * size, rng.normal(0, 0.002, n * n), v.ravel() * size], axis=1)
    idx = np.arange(n * n).reshape(n, n)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, 1:].ravel(), idx[1:, :-1].ravel()
    faces = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])  # normals -y
    uvs = np.stack([u.ravel(), v.ravel()], axis=1)
    return Scan(positions, faces, uvs, faces.copy(), None, (Material("wall", checker(128, 8)),))


@pytest.fixture
def cube() -> Scan:
    return textured_cube()


@pytest.fixture
def wall() -> Scan:
    return grid_wall()


def shared_scan(*parts: str) -> Path:
    path = SHARED_DATA.joinpath(*parts)
    if not path.exists():
        pytest.skip(f"{path} not present (real scans live in ../shared/data)")
    return path
