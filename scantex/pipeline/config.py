"""One config dataclass per stage, composed into :class:`EnhanceConfig`; named presets.

Every field's docstring (the string right after it) is the ``--help`` text of the matching option.
The resolved config is written as ``config.json`` next to every output and loads back with
:func:`load_config` (plain JSON; nothing executable).
"""

from __future__ import annotations

import dataclasses
import json
import math
from dataclasses import dataclass
from dataclasses import field as default
from pathlib import Path

from scantex.errors import ScanError
from scantex.refine.config import RefineConfig


@dataclass(frozen=True)
class ViewsConfig:
    n_views: int = 24
    """number of synthetic views rendered from the scan (80 % train, 20 % held out)"""
    width: int = 320
    """render width in pixels"""
    height: int = 240
    """render height in pixels"""
    fov_deg: float = 60.0
    """horizontal field of view of the views, degrees"""
    mode: str = "auto"
    """camera placement: auto, orbit, hemisphere or surface"""
    up: str = "auto"
    """the scan's up axis (x, y, z); auto: y for glTF, z otherwise"""
    supersample: int = 2
    """rays per pixel per axis when rendering the training views"""
    test_fraction: float = 0.2
    """share of views held out for scoring"""
    adaptive: bool = True
    """add views where per-face coverage is low (the paper's future work); not in photo mode when nothing is
    trained on the synthetic views (they only score the result's fidelity there)"""


@dataclass(frozen=True)
class FieldSettings:
    encoding: str = "hash"
    """positional encoding of the field: hash (multiresolution hash grid) or frequency (the paper's)"""
    hidden: int = 64
    """width of the field's MLP"""
    n_layers: int = 3
    """layers of the field's MLP (a skip connection re-injects the encoding)"""
    log2_table_size: int = 19
    """hash grid: log2 of entries per level"""
    n_levels: int = 16
    """hash grid: resolution levels"""
    max_resolution: int = 2048
    """hash grid: finest grid resolution over the scan's bounding box"""
    n_freqs: int = 10
    """frequency encoding: octaves"""
    use_viewdirs: bool = False
    """feed the view direction to the colour head (textures are view-independent; off by default)"""


@dataclass(frozen=True)
class TrainConfig:
    steps: int = 800
    """optimisation steps"""
    batch_rays: int = 16384
    """rays per step"""
    lr: float = 1e-2
    """Adam learning rate of the field"""
    n_samples: int = 1
    """samples per ray inside the band around the surface (1: a surface colour field)"""
    band_width: float = 0.01
    """width of the sampling band around the mesh surface, as a share of the bounding-box diagonal"""
    appearance: bool = True
    """learn a per-chart affine colour transform so exposure jumps between charts stay out of the field"""
    appearance_lr: float = 2e-3
    """Adam learning rate of the per-chart colour transforms"""
    appearance_reg: float = 1.0
    """weight keeping the charts' mean gain at 1 and mean offset at 0"""
    seam_levelling: bool = False
    """start every chart's transform at the exposure its seams imply (off: measured to hurt the room)"""
    coarse_to_fine: float = 0.3
    """share of the steps over which hash-grid levels are switched on, coarse first (0: all at once)"""
    start_levels: int = 4
    """hash-grid levels active at the first step"""
    checkpoint_every: int = 250
    """steps between checkpoints (for --resume)"""
    always: bool = False
    """train the field even when nothing uses it: mesh-only mode with bake.source input uses it only to
    denoise (bake.denoise, off by default), which is skipped on an atlas whose noise is below what
    denoising can change"""


@dataclass(frozen=True)
class UVConfig:
    mode: str = "keep"
    """texture layout: keep the input's, optimize it (flatten, split and merge shells by stretch), or unwrap
    afresh"""
    threshold: float = 1.1
    """largest per-chart L2 stretch allowed when merging/splitting/unwrapping (1 = no distortion)"""
    time_budget_s: float = 60.0
    """time allowed for optimize/unwrap"""
    blend_seams: bool = True
    """after baking, give texels on both sides of every seam the same colour (no line when filtered)"""
    band_texels: float = 3.0
    """width of the seam-blending band, texels"""
    chart_unmapped: bool = True
    """keep: give faces the input layout leaves no texture space (every UV corner on one point, as OpenMVS
    leaves unseen faces) a small chart each in free atlas space, so that the hole fill can colour them"""


@dataclass(frozen=True)
class BakeConfig:
    texture_size: int = 0
    """output atlas size in texels (0: the input atlas's size when bake.source is input on the input's UVs,
    so its texels are kept exactly; the field bake twice it, at most 8192; photo mode twice it where the photos
    resolve the surface at least twice as finely as the input's texels, else its size; an untextured mesh with
    photos: 2048 or 4096, as fine as its photos)"""
    chunk: int = 65536
    """texels coloured per call (bounded memory; photo mode samples the photos about 20 % faster than at
    16384)"""
    source: str = "input"
    """mesh-only colour source: input (the input's own texels, seam-levelled and denoised against the
    field; holes filled) or field (the paper's: the field's colour replaces every taught texel)"""
    levelling: bool = True
    """source input: smooth per-chart offsets that make both sides of every seam agree (local seam levelling)"""
    denoise: float = 0.0
    """source input: differences from the field up to this many times the input's estimated noise level
    are removed as noise, the field trained for it (0, the default: the input's texels are kept exactly
    and no field is trained; 1 measured +0.00 to +0.01 dB on real app atlases for 8-10x the time)"""
    detail: float = 0.0
    """source field: share of the input's own detail put back: field + detail x (input through its chart's
    inverse colour transform - field); 0 bakes the field alone"""


@dataclass(frozen=True)
class PhotosConfig:
    holdout: float = 0.1
    """photos held out for scoring: a share of them (rounded up, spread over the capture), or a count if >= 1"""
    keyframes: str = "auto"
    """photos repeating another's view (centres within 3 % of the viewing distance, axes within 3 degrees: a video's
    neighbouring frames) thinned to the sharpest of each before the held-out split: on, off, or auto (on from 300
    photos: the real apartment's photos four times over scored the same in 5-6x the time; the captures measured are
    keyframes already; scantex.photos.keyframes)"""
    max_side: int = 640
    """photos are box-filtered down to this longer side for training and scoring"""
    sample_memory_mb: float = 1024.0
    """projective texturing samples each photo at the resolution the atlas wants (2 photo pixels a texel, at most
    the photo's own); when all of them would hold more than this (MiB: 4 bytes a pixel, 8 with two bands: --detail
    balanced or sharp), every photo is sampled smaller by one factor, with a warning (0: no bound); the same for the
    consensus poses' reference (refine_poses consensus). The captures measured hold 80-280 MB (a hundred
    12-megapixel photos: 282); 300 phone frames of 1920x1440 at full resolution would hold 3.2 GB"""
    synthetic_weight: float = 0.1
    """weight of the synthetic views of the input texture relative to the photos (they teach what no photo sees)"""
    edge_margin_px: int = 1
    """photo pixels this close to a silhouette or depth discontinuity teach nothing (working pixels; 1 rather than 2:
    the façade +0.15 dB held out, the other captures +0.00 to +0.05, bench/RESULTS.md "edge margin")"""
    max_angle_deg: float = 75.0
    """photo pixels seeing the surface more obliquely than this teach nothing"""
    depth_tolerance: float = 0.05
    """with capture depth maps: relative disagreement with the mesh beyond which a pixel teaches nothing"""
    depth_gaps: str = "auto"
    """with dense capture depth maps (measured on 90 % of the mesh's pixels): a line of missing depth narrower than
    depth_gap_px, and 2 pixels around it, teaches nothing and is not scored: a thin object the sensor lost, and the
    mesh with it (a lamp's pole), which each photo showing it would paint on the wall behind: on, off (missing depth
    always teaches), or auto (on from 50 photos, where many photos paint it in many places; a few photos, each
    pixel of which counts for more, lost 0.02-0.08 dB by it on parts of a real apartment; bench/RESULTS.md "depth
    gaps")"""
    depth_gap_px: int = 7
    """depth_gaps: the widest line of missing depth taken for a thin object (working pixels)"""
    check_alignment: bool = True
    """refuse to train when the mesh is clearly not in the photos' frame, and leave out a photo that does not show
    what its camera sees (stored upside down, cropped; checked against a textured scan's texture, an untextured
    scan's photos against one another)"""
    blurred: str = "auto"
    """photos with under 30 % of the fine detail of the photos that see the same surface, along one axis at least
    (shaken or out of focus: scantex.photos.sharpness; named in the summary whatever this says): leave-out (left out
    of the texture and the score), keep (blended like the others), soften (their colour and coverage blended with
    the others', their fine detail left to the sharp photos where any sees the surface; projective texturing: a
    field's colour everywhere keeps them), or auto (left out when they
    are a quarter of the training photos or more, else kept). Three smeared photos of nine, blended in, smeared the
    bolster's texture visibly at the same held-out score (+0.99 dB over the input), left out it was sharp (+0.75;
    softened, as sharp, +0.76); one of nine, blended in, softened a real capture's texture slightly, and left out,
    the photos beside it painted what it saw from further off (+0.85 kept, +0.42 left out, +0.65 softened: sharper
    than kept); three of nine smeared further (15 working pixels) there, +0.47 kept, +0.37 left out, +0.24 softened
    (bench/RESULTS.md "shaken photos"). No sharp photo of the captures measured was called blurred. In a tiled run
    each tile judges and treats the training photos that see it, by their share there"""
    refine_poses: str = "auto"
    """refine each training photo's pose (small rotation, translation, focal) photometrically: off, input (against the input texture; textured scans), consensus (against the texture the other training photos make together, repeated refine_iterations times), or auto (for fewer than 50 photos: input for a textured scan, consensus for an untextured one; off otherwise). A correction under half a working pixel is not applied. Refined textures are as sharp as the photos where blending through poses a few pixels off doubles and blurs every edge; through held-out photos whose own recorded poses are as far off they score about the same on average (bench/RESULTS.md, "real photos")"""
    refine_iterations: int = 1
    """refine_poses consensus: rounds of aligning every photo to the others"""
    detail: str = "auto"
    """projective texturing's fine detail: blend (every photo's, as their colour: a room's many photos, whose registration differs by a few pixels, blur into one another, each edge in several faint copies), sharp (colour and exposure from every photo, detail finer than a Gaussian of 4 working pixels from the best views: as sharp as the input on a real apartment, at a lower held-out score through photos that are themselves a few pixels off), balanced (the best views' detail at half its contrast: one clean copy of each edge, at nearly the blend's held-out score), or auto (balanced from 50 photos, blend below: a few photos, aligned by default, blend into a sharp texture) (bench/RESULTS.md, "sharp detail" and "balanced detail")"""
    texturing: str = "projective"
    """texel colours: projective (sampled from the photos that see them, at full resolution, blended smoothly; the input's texels, or the field when it is trained, fill the rest) or field (the field's colour everywhere)"""
    final: str = "auto"
    """the texture written: training (the texture the held-out photos scored, made without them: the score is
    exactly the written texture's), all (the texture made from every photo, the held-out ones included; the
    held-out photos score the one made without them, baked again only where they see the surface; projective
    texturing without a trained field only) or auto (all for a capture of fewer than 50 photos, where each
    held-out photo is a large share of the evidence; training above, where a second bake costs more than it
    gives). Where refine_poses moved the training photos, all aligns the held-out photos to them too before
    they join the texture written (they are scored through their recorded poses).
    Measured on the real captures, scored on photos neither texture saw, over several draws of the run's
    held-out photos: training 16.66-17.26 dB (mean 17.07) on the bolster, 21.77-22.35 (22.09) on the facade;
    all 17.12 and 22.12 whatever the draw, for 6-20 s more (bench/RESULTS.md, "real photos final")"""
    temperature: float = 5.0
    """projective texturing: softmax temperature on the view quality (log units). High (the default, 5) blends every photo that sees a texel almost equally: noise, occluders and the poses' errors average out; low (0.15) lets the best view dominate: sharper where poses are exact, ghosted where they are not"""
    pairs: str = "auto"
    """closed-form colour transforms (a textured scan, no field): also level the photos' exposures against one another where they see the same surface (pair_weight), not only each against the input texture's charts: on, off, or auto (on from 50 photos: without them a synthetic room of 110 photos scored 27.26 dB against 28.16; on 12-photo captures they gained nothing and on one part of a real apartment drew a hard exposure step across a white wall that clips, 25.83 against 26.39 dB; bench/RESULTS.md "photo pairs")"""
    pair_weight: float = 4.0
    """pairs: weight of what photos seeing the same surface say of their exposures relative to one another, against what each says relative to the input texture's charts (the texture's charts alone, which a capture app's patchwork atlas misleads, left the facade's photos disagreeing by 7 % in exposure, 0.6 % with 4; its held-out score the same)"""
    tones: bool = True
    """closed-form colour transforms: first bring the photos to one tone curve (a gamma per photo, levelled against the others where they see the same flat surface), then fit each photo's gains: an auto-exposure lifts a photo's mid-tones and shadows but not a near-white wall, which one gain cannot follow, and draws an exposure step across the wall where that photo's frame ends (bench/RESULTS.md "photo tones")"""
    consistency: float = 0.0
    """projective texturing: photo-consistency scale (RGB distance, 0-1 units). A photo's sample this far from what the others say of the same point keeps half its weight (occluders the mesh lacks, highlights, misregistered edges); 0 blends every sample by its view quality alone"""
    clip_overshoot: float = 0.1
    """projective texturing: a photo's clipped sample (a channel at its white point) gives way where the other photos' unclipped samples say that photo overshot its white point there; its weight is 1/1000 at this overshoot (0-1 units of the photo's range) and beyond (an over-exposed photo's clipped red otherwise turns a yellow wall blue; the synthetic room with an over-exposed photo +0.27 dB, the real bolster and facade unchanged); 0 blends clipped samples as any other"""
    level_fallback: bool = False
    """projective texturing: bring the fallback (the input's texels, holes filled, where no photo sees the surface) to the photos' colours where they meet, by a smooth additive offset (as seam levelling does between charts). It removes the step in tone where the photos end (a real apartment's unseen upper walls), but the offset spreads over the mesh into other surfaces (a synthetic room's unseen box took the bricks' offset): apartment +0.01 dB, synthetic wall +0.07, synthetic room -0.10, bolster and facade unchanged (bench/RESULTS.md, "apartment"), so off by default"""
    canonical: str = "input"
    """overall colour balance of the result: input (the scan's own texture's, when it has one) or photos (their average)"""


@dataclass(frozen=True)
class TilingConfig:
    """How :func:`scantex.scale.tiles.enhance_tiled` cuts a huge scan into tiles (kept here, with the other
    settings, so that a run deciding whether to tile imports none of the tiling machinery)."""

    tiles: int = 0
    """tiles to cut the surface into (0: automatic, one per max_faces faces; 1: no tiling)"""
    max_faces: int = 1_000_000
    """automatic tiling: the most faces one tile should hold"""
    overlap: float = 0.15
    """overlap of neighbouring tiles on each side of their border, as a share of a tile's size"""
    harmonize: bool = False
    """level each tile's overall colour with a per-channel gain fitted on the overlaps before fusing (off: it
    cost 0.12 dB on the toy wall and did not change the steps at the borders; bench/bench_tiles.py)"""

    def __post_init__(self):
        numbers = all(isinstance(v, (int, float)) and not isinstance(v, bool)
                      for v in (self.tiles, self.max_faces, self.overlap))  # else validate() names the type
        if numbers and (self.tiles < 0 or self.max_faces < 1 or not 0.0 <= self.overlap <= 1.0):  # NaN fails too
            raise ScanError(None, f"tiling needs tiles >= 0, max_faces >= 1 and overlap from 0 to 1, not "
                                  f"{self.tiles}, {self.max_faces} and {self.overlap}")

    def count(self, n_faces: int) -> int:
        """The number of tiles for a scan of ``n_faces`` faces."""
        return self.tiles if self.tiles > 0 else max(1, math.ceil(n_faces / self.max_faces))


@dataclass(frozen=True)
class OutputConfig:
    """How the outputs are written (:func:`scantex.pipeline.outputs.write_outputs`)."""

    texture_format: str = "png"
    """file format of the enhanced colour atlases: png (lossless) or jpeg (several times smaller, at the loss
    the run's summary measures)"""
    jpeg_quality: int = 90
    """JPEG quality from 1 to 100 (texture_format jpeg)"""

    def encoder(self):
        """A :class:`scantex.io.images.TextureEncoder` that writes as these settings say."""
        from scantex.io.images import TextureEncoder

        return TextureEncoder(self.texture_format, self.jpeg_quality)


@dataclass(frozen=True)
class EnhanceConfig:
    preset: str = "default"
    """the preset these settings started from"""
    seed: int = 0
    """random seed (views, split, training)"""
    device: str = "auto"
    """torch device: auto (CUDA when present), cpu or cuda"""
    threads: int = 0
    """CPU threads for torch, the bake, and the stages that handle photos or views side by side (0: all cores)"""
    views: ViewsConfig = default(default_factory=ViewsConfig)
    field: FieldSettings = default(default_factory=FieldSettings)
    train: TrainConfig = default(default_factory=TrainConfig)
    uv: UVConfig = default(default_factory=UVConfig)
    bake: BakeConfig = default(default_factory=BakeConfig)
    photos: PhotosConfig = default(default_factory=PhotosConfig)
    refine: RefineConfig = default(default_factory=RefineConfig)
    tiling: TilingConfig = default(default_factory=TilingConfig)
    """how a huge scan is cut into tiles (the CLI's --tiles, --tile-faces, --tile-overlap); :func:`enhance` itself
    enhances whatever it is given whole"""
    output: OutputConfig = default(default_factory=OutputConfig)
    """how the outputs are written (the CLI's --texture-format, --jpeg-quality)"""

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, d: dict, where=None) -> EnhanceConfig:
        """The config a ``config.json`` document describes; every value is checked (:func:`validate`).

        A setting the document leaves out is its ``preset``'s (``{"preset": "fast", "train": {"steps": 50}}``
        is the fast preset with 50 steps); the default preset's where ``preset`` is missing or names none of
        :data:`PRESETS` (a label of one's own, kept as it is).

        Raises:
            ScanError: an unknown key, or a value of the wrong type or out of its range.
        """
        if not isinstance(d, dict):
            raise ScanError(where, f"a config is a JSON object of settings, not a {type(d).__name__}")
        name = d.get("preset", "default")
        base = PRESETS.get(name, PRESETS["default"]) if isinstance(name, str) else PRESETS["default"]
        sections = {f.name for f in dataclasses.fields(cls) if dataclasses.is_dataclass(getattr(base, f.name))}
        kwargs = {}
        for key, value in d.items():
            if key in sections:
                kwargs[key] = _build(getattr(base, key), value, where, key)
            elif key in {f.name for f in dataclasses.fields(cls)}:
                kwargs[key] = value
            else:
                raise ScanError(where, f"unknown config key '{key}'")
        return validate(dataclasses.replace(base, **kwargs), where)

    def override(self, **dotted) -> EnhanceConfig:
        """A copy with ``section__name=value`` (or top-level ``name=value``) settings changed."""
        cfg = self
        for key, value in dotted.items():
            if value is None:
                continue
            section, _, name = key.partition("__")
            if name:
                cfg = dataclasses.replace(cfg, **{section: dataclasses.replace(getattr(cfg, section), **{name: value})})
            else:
                cfg = dataclasses.replace(cfg, **{section: value})
        return cfg


def _build(base, values: dict, where, section: str):
    """``base`` (a section's settings) with ``values`` set."""
    if not isinstance(values, dict):
        raise ScanError(where, f"config '{section}' must be an object of settings, not {str(values)[:40]!r}")
    names = {f.name for f in dataclasses.fields(base)}
    unknown = set(values) - names
    if unknown:
        raise ScanError(where, f"unknown config key '{section}.{sorted(unknown)[0]}'")
    try:
        return dataclasses.replace(base, **values)
    except ScanError as e:  # a section's own check (tiling): named by the file
        raise ScanError(where, e.problem) from None


PRESETS: dict[str, EnhanceConfig] = {
    "fast": EnhanceConfig(
        preset="fast",
        views=ViewsConfig(n_views=16, width=256, height=192, adaptive=False),
        field=FieldSettings(hidden=32, n_layers=2, n_levels=12, log2_table_size=18),
        train=TrainConfig(steps=500, batch_rays=8192),
    ),
    "default": EnhanceConfig(),
    "best": EnhanceConfig(
        preset="best",
        views=ViewsConfig(n_views=40, width=480, height=360),
        field=FieldSettings(hidden=64, n_layers=3, log2_table_size=20, max_resolution=4096),
        train=TrainConfig(steps=5000, batch_rays=16384),
    ),
}


def preset(name: str) -> EnhanceConfig:
    if name not in PRESETS:
        raise ScanError(None, f"unknown preset '{name}' (choose from {', '.join(PRESETS)})")
    return PRESETS[name]


def load_config(path: str | Path) -> EnhanceConfig:
    path = Path(path)
    try:
        d = json.loads(path.read_text())
    except FileNotFoundError:
        raise ScanError(path, "config file not found") from None
    except (json.JSONDecodeError, UnicodeDecodeError) as e:
        raise ScanError(path, f"not a JSON config ({e})") from None
    except RecursionError:
        raise ScanError(path, "not a config (JSON nested too deeply)") from None
    except OSError as e:
        raise ScanError(path, f"cannot read the config ({e.strerror})") from None
    return EnhanceConfig.from_dict(d, path)


def save_config(config: EnhanceConfig, path: str | Path) -> None:
    Path(path).write_text(json.dumps(config.to_dict(), indent=2))


# -- validation ---------------------------------------------------------------------------------

#: allowed values of every setting that is not free: ``(low, high)`` inclusive bounds for numbers
#: (``None``: unbounded), or a tuple of choices for strings. Types come from the dataclasses' annotations.
BIG = 1 << 31
RANGES: dict[str, tuple] = {
    "seed": (0, 2**32 - 1), "threads": (0, 4096), "device": ("auto", "cpu", "cuda"),
    "views.n_views": (2, 10_000), "views.width": (8, 8192), "views.height": (8, 8192),
    "views.fov_deg": (1.0, 170.0), "views.mode": ("auto", "orbit", "hemisphere", "surface"),
    "views.up": ("auto", "x", "y", "z"), "views.supersample": (1, 8), "views.test_fraction": (0.01, 0.9),
    "field.encoding": ("hash", "frequency"), "field.hidden": (1, 4096), "field.n_layers": (1, 32),
    "field.log2_table_size": (4, 26), "field.n_levels": (1, 32), "field.max_resolution": (2, 1 << 20),
    "field.n_freqs": (1, 24),
    "train.steps": (1, BIG), "train.batch_rays": (1, 1 << 24), "train.lr": (1e-12, 100.0),
    "train.n_samples": (1, 256), "train.band_width": (1e-9, 1.0), "train.appearance_lr": (0.0, 100.0),
    "train.appearance_reg": (0.0, 1e9), "train.coarse_to_fine": (0.0, 1.0), "train.start_levels": (1, 32),
    "train.checkpoint_every": (1, BIG),
    "uv.mode": ("keep", "optimize", "unwrap"), "uv.threshold": (1.0, 1e6), "uv.time_budget_s": (0.0, 1e9),
    "uv.band_texels": (0.0, 1024.0),
    "bake.texture_size": (0, 16384), "bake.source": ("input", "field"), "bake.chunk": (1, 1 << 26), "bake.detail": (0.0, 10.0),
    "photos.holdout": (0.0, 1e9), "photos.max_side": (16, 16384), "photos.synthetic_weight": (0.0, 1e9),
    "photos.edge_margin_px": (0, 1024), "photos.max_angle_deg": (0.0, 90.0),
    "photos.depth_tolerance": (0.0, 1e9), "photos.depth_gaps": ("auto", "on", "off"),
    "photos.depth_gap_px": (0, 1024),
    "photos.canonical": ("input", "photos"),
    "photos.texturing": ("projective", "field"), "photos.detail": ("auto", "blend", "balanced", "sharp"),
    "photos.blurred": ("auto", "leave-out", "keep", "soften"),
    "photos.refine_poses": ("auto", "off", "input", "consensus"),
    "photos.refine_iterations": (1, 10), "photos.final": ("all", "training", "auto"), "photos.consistency": (0.0, 10.0),
    "photos.pair_weight": (0.0, 1e6), "photos.pairs": ("auto", "on", "off"), "photos.keyframes": ("auto", "on", "off"), "photos.clip_overshoot": (0.0, 10.0), "photos.sample_memory_mb": (0.0, 1e9),
    "refine.model": ("tiny", "small", "base"), "refine.patch": (1, 256), "refine.crop": (1, 4096),
    "refine.steps": (0, BIG), "refine.batch": (1, 4096), "refine.lr": (1e-12, 100.0),
    "refine.mask_share": (0.0, 0.95), "refine.mask_weight": (0.0, 1e9), "refine.cross_view_weight": (0.0, 1e9),
    "refine.view_scale": (1.0, 8.0), "refine.max_views": (1, 10_000), "refine.diffusion_strength": (0.0, 1.0),
    "refine.diffusion_steps": (1, BIG), "photos.temperature": (1e-3, 1e6), "bake.denoise": (0.0, 1e3),
    "tiling.tiles": (0, 100_000), "tiling.max_faces": (1, BIG), "tiling.overlap": (0.0, 1.0),
    "output.texture_format": ("png", "jpeg"), "output.jpeg_quality": (1, 100),
}


def validate(config: EnhanceConfig, where=None) -> EnhanceConfig:
    """Return ``config`` when every setting has its field's type (int, float, bool, str) and lies in its
    range (:data:`RANGES`), else raise a one-line :class:`ScanError` naming the setting.

    Driven by the dataclasses' own annotations, so a new field is type-checked without being listed.
    """
    import math
    import typing

    def check(obj, prefix: str) -> None:
        hints = typing.get_type_hints(type(obj))
        for f in dataclasses.fields(obj):
            name, value, kind = prefix + f.name, getattr(obj, f.name), hints[f.name]
            if dataclasses.is_dataclass(kind):
                check(value, name + ".")
                continue
            bad = f"config '{name}' is {repr(value)[:40]}, expected"
            if kind is bool:
                if not isinstance(value, bool):
                    raise ScanError(where, f"{bad} true or false")
            elif kind is int:
                if isinstance(value, bool) or not isinstance(value, int):
                    raise ScanError(where, f"{bad} a whole number")
            elif kind is float:
                if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
                    raise ScanError(where, f"{bad} a finite number")
            elif kind is str and not isinstance(value, str):
                raise ScanError(where, f"{bad} a string")
            allowed = RANGES.get(name)
            if allowed is None:
                continue
            if isinstance(allowed[0], str):
                if value not in allowed:
                    raise ScanError(where, f"{bad} one of {', '.join(allowed)}")
            elif not allowed[0] <= value <= allowed[1]:
                raise ScanError(where, f"{bad} {allowed[0]!r} to {allowed[1]!r}")

    check(config, "")
    if config.photos.holdout > 1 and config.photos.holdout != int(config.photos.holdout):
        raise ScanError(where, f"config 'photos.holdout' is {config.photos.holdout}, expected a share below 1 or a "
                               f"whole number of photos")
    if 0 < config.bake.texture_size < 16:
        raise ScanError(where, f"config 'bake.texture_size' is {config.bake.texture_size}, expected 0 (automatic) "
                               f"or 16 to 16384")
    if config.train.start_levels > config.field.n_levels:
        raise ScanError(where, f"config 'train.start_levels' ({config.train.start_levels}) is more than "
                               f"'field.n_levels' ({config.field.n_levels})")
    if config.refine.crop % config.refine.patch:
        raise ScanError(where, f"config 'refine.crop' ({config.refine.crop}) is not a multiple of "
                               f"'refine.patch' ({config.refine.patch})")
    return config
