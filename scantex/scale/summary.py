"""A batch's summary: ``summary.json`` (every record), ``summary.csv`` (one row per scan) and
``index.html`` (a table linking each scan's report), written together and atomically."""

from __future__ import annotations

import csv
import html
import io
import time
from pathlib import Path

from scantex.io.atomic import atomic_files

COLUMNS = ("name", "status", "mesh", "score", "psnr_input", "psnr_enhanced", "ssim_input", "ssim_enhanced",
           "seconds", "peak_memory_gib", "faces", "host", "report", "reused", "error")


def rows(records: list[dict]) -> list[dict]:
    """One flat row per record, the columns of ``summary.csv``."""
    out = []
    for r in records:
        s = r.get("scores") or {}
        out.append({"name": r["name"], "status": r["status"], "mesh": r.get("mesh"), "score": s.get("kind", ""),
                    "psnr_input": _round(s.get("psnr_input")), "psnr_enhanced": _round(s.get("psnr_enhanced")),
                    "ssim_input": _round(s.get("ssim_input"), 4), "ssim_enhanced": _round(s.get("ssim_enhanced"), 4),
                    "seconds": r.get("seconds"), "peak_memory_gib": r.get("peak_memory_gib"),
                    "faces": r.get("faces"), "host": r.get("host"), "report": r.get("report"),
                    "reused": bool(r.get("reused", False)), "error": r.get("error") or ""})
    return out


def _round(x, digits: int = 2):
    return None if x is None else round(float(x), digits)


def write_summary(out_dir: Path, records: list[dict], *, executor: str, seconds: float | None = None) -> None:
    counts = {k: sum(r["status"] == k for r in records) for k in ("done", "failed", "pending")}
    summary = {"scans": len(records), **counts, "executor": executor,
               "seconds": None if seconds is None else round(seconds, 2),
               "updated": time.strftime("%Y-%m-%d %H:%M:%S"), "records": records}
    table = rows(records)
    text = io.StringIO()
    writer = csv.DictWriter(text, fieldnames=COLUMNS)
    writer.writeheader()
    writer.writerows(table)
    out_dir.mkdir(parents=True, exist_ok=True)
    from scantex.report.html import strict_json

    with atomic_files() as files:
        files.path(out_dir / "summary.json").write_text(strict_json(summary, indent=2))
        files.path(out_dir / "summary.csv").write_text(text.getvalue())
        files.path(out_dir / "index.html").write_text(index_html(summary, table), encoding="utf-8")


def index_html(summary: dict, table: list[dict]) -> str:
    def cell(row: dict) -> str:
        name = html.escape(row["name"])
        link = f'<a href="{html.escape(row["report"])}">{name}</a>' if row["status"] == "done" and row["report"] \
            else name
        scores = "" if row["psnr_enhanced"] is None else (
            f"{row['psnr_input']:.2f} → {row['psnr_enhanced']:.2f}" if row["psnr_input"] is not None
            else f"fidelity {row['psnr_enhanced']:.2f}")
        ssim = "" if row["ssim_enhanced"] is None else (
            f"{row['ssim_input']:.3f} → {row['ssim_enhanced']:.3f}" if row["ssim_input"] is not None
            else f"fidelity {row['ssim_enhanced']:.3f}")
        status = row["status"] + (" (earlier run)" if row["reused"] else "")
        return (f'<tr class="{row["status"]}"><td>{link}</td><td>{html.escape(status)}</td>'
                f'<td>{html.escape(row["score"])}</td><td>{scores}</td><td>{ssim}</td>'
                f'<td>{_fmt(row["seconds"], "{:.0f} s")}</td><td>{_fmt(row["peak_memory_gib"], "{:.2f} GiB")}</td>'
                f'<td>{_fmt(row["faces"], "{:,}")}</td><td>{html.escape(row["host"] or "")}</td>'
                f'<td class="error">{html.escape(row["error"])}</td></tr>')

    took = f", {summary['seconds']:.0f} s" if summary["seconds"] is not None else " (running)"
    head = (f"{summary['scans']} scans: {summary['done']} done, {summary['failed']} failed, "
            f"{summary['pending']} pending ({html.escape(summary['executor'])}{took}; updated {summary['updated']})")
    body = "\n".join(cell(r) for r in table)
    return f"""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8">
<meta name="viewport" content="width=device-width, initial-scale=1"><title>scantex batch</title>
<style>
body {{ font-family: system-ui, sans-serif; margin: 2em; }}
table {{ border-collapse: collapse; display: block; overflow-x: auto; max-width: 100%; }}
td, th {{ padding: 4px 10px; border-bottom: 1px solid #ddd; text-align: left; }}
tr.failed td {{ background: #fdecea; }} tr.pending td {{ color: #888; }} td.error {{ font-family: monospace; }}
</style></head><body>
<h1>scantex batch</h1>
<p>{head}</p>
<p>PSNR (dB) and SSIM on each scan's held-out views: input → enhanced. A scan with neither a ground truth nor
held-out photos has nothing to score against: its "fidelity" is the enhanced texture's renders against the input's
(high: little changed; not a gain). Also in <a href="summary.csv">summary.csv</a> and
<a href="summary.json">summary.json</a>.</p>
<table><tr><th>scan</th><th>status</th><th>scored</th><th>PSNR</th><th>SSIM</th><th>time</th><th>peak memory</th>
<th>faces</th><th>host</th><th>error</th></tr>
{body}
</table></body></html>
"""


def _fmt(value, pattern: str) -> str:
    return "" if value is None else html.escape(pattern.format(value))
