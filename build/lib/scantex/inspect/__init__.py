"""Inspection: looking at a scan interactively (plotly.js is loaded only when a view is written)."""

from scantex.inspect.plotly_view import face_display_colors, view_html

__all__ = ["face_display_colors", "view_html"]
