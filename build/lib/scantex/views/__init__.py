"""Views of a scan: cameras, view planning, G-buffers by ray casting, and rendering."""
