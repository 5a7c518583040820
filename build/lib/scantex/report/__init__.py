"""The self-contained ``report.html`` every enhance run writes (see :mod:`scantex.report.html`)."""

from scantex.report.html import build_report, write_report

__all__ = ["build_report", "write_report"]
