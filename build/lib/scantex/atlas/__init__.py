"""Texture atlases: which surface point every texel shows (the texel map), and later the UV plan."""
