"""The radiance field fitted to the views: encodings, the field MLP, mesh-guided volume rendering."""

from scantex.field.encoding import (
    FrequencyEncoding,
    HashGridEncoding,
    HashGridLayout,
    hash_grid_corners,
    hash_grid_encode,
    hash_grid_layout,
    hash_grid_reference,
)
from scantex.field.model import FieldConfig, RadianceField, evaluate_colour, trunc_exp
from scantex.field.volume import (
    BoxNormaliser,
    band_samples,
    render_rays,
    volume_render,
    volume_render_reference,
)

__all__ = [
    "BoxNormaliser",
    "FieldConfig",
    "FrequencyEncoding",
    "HashGridEncoding",
    "HashGridLayout",
    "RadianceField",
    "band_samples",
    "evaluate_colour",
    "hash_grid_corners",
    "hash_grid_encode",
    "hash_grid_layout",
    "hash_grid_reference",
    "render_rays",
    "trunc_exp",
    "volume_render",
    "volume_render_reference",
]
