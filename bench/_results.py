"""Keep bench/RESULTS.md up to date: each benchmark owns a section between markers."""

from __future__ import annotations

import json
import platform
import time
from pathlib import Path

import numpy as np

RESULTS = Path(__file__).with_name("RESULTS.md")


def parse_override(item: str) -> dict:
    """``SECTION__NAME=VALUE`` (a JSON value, or else a string) as a config override ``{key: value}``."""
    key, _, value = item.partition("=")
    try:
        return {key: json.loads(value)}
    except json.JSONDecodeError:
        return {key: value}


def machine() -> str:
    import os

    return f"{platform.processor() or platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}"


def update_section(name: str, markdown: str) -> None:
    begin, end = f"<!-- {name}:begin -->", f"<!-- {name}:end -->"
    text = RESULTS.read_text() if RESULTS.exists() else "# Benchmark results\n\n"
    block = f"{begin}\n{markdown.strip()}\n\n_{time.strftime('%Y-%m-%d')}, {machine()}_\n{end}"
    if begin in text:
        head, rest = text.split(begin, 1)
        text = head + block + rest.split(end, 1)[1]
    else:
        text = text.rstrip() + "\n\n" + block + "\n"
    RESULTS.write_text(text)


def median_time(fn, repeats: int = 5) -> float:
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return float(np.median(times))


def run_worker(code: str, spec: dict) -> dict:
    """Run ``code`` in a fresh Python process (its peak memory and time its own) with ``spec`` as JSON in
    ``sys.argv[1]``; return the JSON object it prints last."""
    import json
    import subprocess
    import sys

    proc = subprocess.run([sys.executable, "-c", code, json.dumps(spec)], capture_output=True, text=True,
                          cwd=RESULTS.parents[1])
    if proc.returncode != 0:
        raise RuntimeError(proc.stderr[-3000:])
    return json.loads(proc.stdout.strip().splitlines()[-1])
