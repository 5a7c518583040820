"""Seeded fuzzing through the CLI entry: mutations of a textured OBJ (+ MTL + PNG), a GLB and a
cameras.json, from truncation and byte flips to lying headers, NaN and huge numbers, out-of-range
indices and absurd image sizes.

Every run must end with exit status 0, or 2 and one ``scantex ...: error:`` line (never an internal
error or a traceback), within a time limit, with the inputs untouched and, after a failure, no output,
work folder or temporary left behind.
"""

from __future__ import annotations

import dataclasses
import re
import shutil
import signal
import struct
import warnings

import numpy as np
import pytest

from tests.io.hostile import (TINY, fingerprint, png_claiming, run_cli, write_cube, write_glb, write_photos,
                              write_tiny_config)

SEED = 15
CASE_TIMEOUT_S = 60  # generous for a loaded, shared machine; a hang runs until it
NASTY = ["nan", "-inf", "1e308", "-1e400", "9223372036854775808", "-9223372036854775809", "0", "-1",
         "99999999", "abc", "", "1e-320", "3.4e39"]


class Hang(BaseException):
    """Raised by the alarm: a BaseException, so that the CLI's own handlers cannot swallow it."""


def _alarm(signum, frame):
    raise Hang()


def truncate(data: bytes, rng) -> bytes:
    return data[: int(rng.integers(0, len(data)))]


def flip(data: bytes, rng) -> bytes:
    out = bytearray(data)
    for at in rng.integers(0, len(out), int(rng.integers(1, 9))):
        out[at] ^= int(rng.integers(1, 256))
    return bytes(out)


def nasty_numbers(data: bytes, rng) -> bytes:
    """Replace a few numbers of a text file with NaN, huge, negative or unreadable ones."""
    text = data.decode("utf-8", errors="replace")
    spans = [m.span() for m in re.finditer(r"-?\d+(?:\.\d+)?(?:e[-+]?\d+)?", text)]
    for i in sorted(rng.choice(len(spans), min(len(spans), int(rng.integers(1, 4))), replace=False))[::-1]:
        a, b = spans[i]
        text = text[:a] + str(rng.choice(NASTY)) + text[b:]
    return text.encode()


def bad_index(data: bytes, rng) -> bytes:
    """An OBJ face corner pointing outside its list (too large, 0, or too negative)."""
    lines = data.decode().splitlines()
    faces = [i for i, ln in enumerate(lines) if ln.startswith("f ")]
    i = int(rng.choice(faces))
    parts = lines[i].split()
    k = int(rng.integers(1, len(parts)))
    sub = parts[k].split("/")
    j = int(rng.integers(0, len(sub)))
    sub[j] = str(rng.choice(["0", "-999", "999", "9223372036854775808", "-1"]))
    parts[k] = "/".join(sub)
    lines[i] = " ".join(parts)
    return "\n".join(lines).encode()


def lie_in_png(data: bytes, rng) -> bytes:
    """A PNG header claiming an absurd size (CRC fixed or not), or a bare bomb."""
    if rng.random() < 0.5:
        return png_claiming(int(rng.choice([30000, 100000, 2**31 - 1])), int(rng.choice([30000, 100000, 1])))
    out = bytearray(data)
    at = out.find(b"IHDR")
    out[at + 4:at + 12] = struct.pack(">II", *(int(v) for v in rng.choice([50000, 100000, 0], 2)))
    return bytes(out)


def lie_in_glb(data: bytes, rng) -> bytes:
    """A GLB whose total or chunk length lies."""
    out = bytearray(data)
    field = int(rng.choice([8, 12]))
    out[field:field + 4] = struct.pack("<I", int(rng.choice([0, 7, len(data) * 3, 2**32 - 1])))
    return bytes(out)


def nested(data: bytes, rng) -> bytes:
    depth = int(rng.choice([50, 5000, 200000]))
    return b'{"frames": ' + b"[" * depth + b"]" * depth + b"}"


OBJ_MUTATIONS = {"m.obj": [truncate, flip, nasty_numbers, bad_index], "m.mtl": [truncate, flip, nasty_numbers],
                 "m_tex0.png": [truncate, flip, lie_in_png]}
GLB_MUTATIONS = [truncate, flip, lie_in_glb]
CAMERA_MUTATIONS = [truncate, flip, nasty_numbers, nested]
RENDER = ["--views", "1", "--width", "16", "--height", "16", "--supersample", "1", "-q"]


def cases():
    rng = np.random.default_rng(SEED)
    out = []
    for k in range(36):
        name = ["m.obj", "m.mtl", "m_tex0.png"][k % 3]
        fn = OBJ_MUTATIONS[name][int(rng.integers(0, len(OBJ_MUTATIONS[name])))]
        out.append(("obj", name, fn, int(rng.integers(0, 2**31))))
    for k in range(18):
        out.append(("glb", "m.glb", GLB_MUTATIONS[k % len(GLB_MUTATIONS)], int(rng.integers(0, 2**31))))
    for k in range(12):
        out.append(("photos", "cameras.json", CAMERA_MUTATIONS[k % len(CAMERA_MUTATIONS)], int(rng.integers(0, 2**31))))
    return out


CASES = cases()


@pytest.fixture(scope="module")
def pristine(tmp_path_factory):
    """The unmutated inputs, written once."""
    root = tmp_path_factory.mktemp("pristine")
    write_cube(root / "obj")
    write_glb(root / "glb")
    write_cube(root / "photos")
    write_photos(root / "photos" / "cams")
    write_tiny_config(root / "tiny.json")
    # photos of noise are refused by the alignment check: without it, mutations that keep the cameras
    # valid run the whole (tiny) enhance, and its outputs are checked too
    write_tiny_config(root / "tiny_photos.json", dataclasses.replace(
        TINY, photos=dataclasses.replace(TINY.photos, check_alignment=False)))
    return root


@pytest.mark.parametrize("kind, name, mutate, seed", CASES,
                         ids=[f"{k}-{n}-{f.__name__}-{i}" for i, (k, n, f, _) in enumerate(CASES)])
def test_fuzzed_input_gets_a_clean_answer(tmp_path, capsys, monkeypatch, pristine, kind, name, mutate, seed):
    rng = np.random.default_rng(seed)
    shutil.copytree(pristine / kind, tmp_path / "in")
    monkeypatch.chdir(tmp_path)
    inputs = tmp_path / "in"
    target = inputs / ("cams/cameras.json" if kind == "photos" else name)
    target.write_bytes(mutate(target.read_bytes(), rng))
    before = fingerprint(inputs)
    out = tmp_path / "out"
    if kind == "photos":
        argv = ["enhance", inputs / "m.obj", "--photos", target, "-o", out, "--config", pristine / "tiny_photos.json", "-q"]
    else:
        argv = ["render", target if kind == "glb" else inputs / "m.obj", "-o", out, *RENDER]

    previous = signal.signal(signal.SIGALRM, _alarm)
    signal.alarm(CASE_TIMEOUT_S)
    try:
        with warnings.catch_warnings(record=True) as caught:  # the CLI would print them: more lines
            warnings.simplefilter("always")
            rc, err = run_cli(capsys, *argv)
    except Hang:
        pytest.fail(f"no answer within {CASE_TIMEOUT_S} s")
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, previous)
    noisy = [f"{w.category.__name__}: {w.message}" for w in caught if issubclass(w.category, RuntimeWarning)]
    assert not noisy, noisy

    assert fingerprint(inputs) == before, "an input was changed"
    assert rc in (0, 2), f"exit status {rc}: {err}"
    assert "Traceback" not in err and "internal error" not in err, err
    leftovers = sorted(p.name for p in tmp_path.iterdir() if p.name != "in")
    if rc == 2:
        lines = [ln for ln in err.strip().splitlines() if ln.strip()]
        assert len(lines) == 1 and lines[0].startswith("scantex") and ": error: " in lines[0], err
        assert leftovers == [], f"left behind after a failure: {leftovers}"
    else:
        assert leftovers == ["out"], leftovers
        assert (out / ("renders/cameras.json" if kind == "photos" else "cameras.json")).is_file()
