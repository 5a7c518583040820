"""The radiance field fitted to the views: encodings, the field MLP, mesh-guided volume rendering.

The names below are imported on first use: the package's modules import torch (1.5-2 s), which a run
that trains no field never needs.
"""

from __future__ import annotations

import importlib

_HOME = {
    "FrequencyEncoding": "encoding", "HashGridEncoding": "encoding", "HashGridLayout": "encoding",
    "hash_grid_corners": "encoding", "hash_grid_encode": "encoding", "hash_grid_layout": "encoding",
    "hash_grid_reference": "encoding",
    "FieldConfig": "model", "RadianceField": "model", "evaluate_colour": "model", "trunc_exp": "model",
    "BoxNormaliser": "volume", "band_samples": "volume", "render_rays": "volume", "volume_render": "volume",
    "volume_render_reference": "volume",
    "RayDataset": "rays",
}

__all__ = sorted(_HOME)


def __getattr__(name: str):
    if name not in _HOME:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    return getattr(importlib.import_module(f"{__name__}.{_HOME[name]}"), name)


def __dir__() -> list[str]:
    return sorted([*globals(), *__all__])
