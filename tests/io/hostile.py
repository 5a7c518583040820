"""Small inputs for the hostile-input tests: a textured cube (OBJ + MTL + PNG), a GLB, posed photos
(cameras.json), a tiny enhance config, and helpers that run the CLI in-process."""

from __future__ import annotations

import hashlib
import io
import json
import struct
import zlib
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from scantex.cli import main
from scantex.errors import ScanError
from scantex.io import save_scan
from scantex.pipeline.config import (BakeConfig, EnhanceConfig, FieldSettings, TrainConfig, UVConfig,
                                     ViewsConfig, save_config)
from scantex.refine.config import RefineConfig
from tests.conftest import textured_cube

#: an enhance config that runs in a few seconds on the cube (the tests check safety, not quality)
TINY = EnhanceConfig(
    preset="tiny",
    views=ViewsConfig(n_views=2, width=24, height=16, supersample=1, adaptive=False),
    field=FieldSettings(hidden=8, n_layers=1, n_levels=2, log2_table_size=8, max_resolution=16),
    train=TrainConfig(steps=4, batch_rays=256, start_levels=1, checkpoint_every=2, always=True),  # checkpoints
    uv=UVConfig(blend_seams=False), bake=BakeConfig(texture_size=32), refine=RefineConfig(enabled=False))


def run_cli(capsys, *argv) -> tuple[int, str]:
    """``(exit status, stderr)`` of ``scantex ARGV`` run in this process."""
    capsys.readouterr()
    try:
        rc = main([str(a) for a in argv])
    except SystemExit as e:  # argparse
        rc = e.code
    return rc, capsys.readouterr().err


def assert_clean_error(rc: int, err: str, *needles: str) -> None:
    """Exit status 2 and exactly one ``scantex...: error: ...`` line naming what is wrong."""
    lines = [ln for ln in err.strip().splitlines() if ln.strip()]
    assert rc == 2, f"exit status {rc}: {err}"
    assert len(lines) == 1 and ": error: " in lines[0] and "internal error" not in lines[0], err
    assert "Traceback" not in err
    for needle in needles:
        assert needle in lines[0], lines[0]


def assert_photos_refused(capsys, tmp_path: Path, photos: Path, message: str) -> None:
    """``load_photos(photos)`` raises a ScanError holding ``message``, and ``scantex enhance`` given them exits with
    that one line (a cube as the mesh)."""
    import re

    from scantex.photos import load_photos

    with pytest.raises(ScanError, match=re.escape(message)):
        load_photos(photos)
    mesh = write_cube(tmp_path / "scan")
    rc, err = run_cli(capsys, "enhance", mesh, "--photos", photos, "-o", tmp_path / "out", "-q")
    assert_clean_error(rc, err, message)


def write_cube(folder: Path, name: str = "m.obj") -> Path:
    """The textured cube as ``folder/m.obj`` + ``m.mtl`` + ``m_tex0.png``."""
    save_scan(textured_cube(materials=1), folder / name)
    return folder / name


def write_glb(folder: Path) -> Path:
    save_scan(textured_cube(materials=1), folder / "m.glb")
    return folder / "m.glb"


def png_claiming(width: int, height: int, mode: int = 2, depth: int = 8) -> bytes:
    """A few dozen bytes of PNG whose header claims ``width x height`` pixels (a decompression bomb)."""
    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", width, height, depth, mode, 0, 0, 0))
            + chunk(b"IDAT", zlib.compress(b"\x00" * 64)) + chunk(b"IEND", b""))


def write_photos(folder: Path, *, n: int = 3, depth: bool = False, **frame_changes) -> Path:
    """``folder/cameras.json`` with ``n`` photos of the cube (64x48, looking at it), optionally uint16 depth
    maps; ``frame_changes`` replace keys of every frame (``width="abc"``)."""
    folder.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(0)
    frames = []
    for i in range(n):
        Image.fromarray(rng.integers(0, 255, (48, 64, 3), dtype=np.uint8)).save(folder / f"p{i}.png")
        angle = 2 * np.pi * i / n
        eye = np.array([0.5 + 3 * np.cos(angle), 0.5 + 3 * np.sin(angle), 0.8])
        forward = (np.array([0.5, 0.5, 0.5]) - eye) / np.linalg.norm(np.array([0.5, 0.5, 0.5]) - eye)
        right = np.cross(forward, [0, 0, 1.0])
        right /= np.linalg.norm(right)
        down = np.cross(forward, right)
        R = np.stack([right, down, forward])
        w2c = np.eye(4)
        w2c[:3, :3], w2c[:3, 3] = R, -R @ eye
        frame = {"image": f"p{i}.png", "width": 64, "height": 48,
                 "K": [[60.0, 0, 31.5], [0, 60.0, 23.5], [0, 0, 1]], "world_to_camera": w2c.tolist()}
        if depth:
            Image.fromarray(rng.integers(500, 4000, (48, 64), dtype=np.uint16)).save(folder / f"d{i}.png")
            frame["depth"] = f"d{i}.png"
        frame.update(frame_changes)
        frames.append(frame)
    (folder / "cameras.json").write_text(json.dumps({"frames": frames}))
    return folder / "cameras.json"


def write_tiny_config(path: Path, config: EnhanceConfig = TINY) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    save_config(config, path)
    return path


def fingerprint(folder: Path) -> dict[str, str]:
    """Every file under ``folder`` with the hash of its bytes: equal before and after = nothing touched."""
    return {str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.rglob("*")) if p.is_file()}


def to_png_bytes(image: np.ndarray) -> bytes:
    buf = io.BytesIO()
    Image.fromarray(image).save(buf, format="PNG")
    return buf.getvalue()
