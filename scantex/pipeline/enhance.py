"""``enhance``: the whole pipeline, stage after stage, on one scan.

views (plan, ray-cast, render, split 80/20) -> rays -> field (fit) -> bake into the scan's own UV
layout -> metrics. Each stage is a function of its own module; this one only wires them and times them.
"""

from __future__ import annotations

import contextlib
import dataclasses
import logging
import os
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from scantex.arrays import uv_areas
from scantex.atlas.bake import SurfaceColour, bake, output_size, with_base_colours_of
from scantex.atlas.holes import untextured_faces, visible_holes
from scantex.atlas.inpaint import grow_faces
from scantex.atlas.levelling import MAX_CREASE_DEG, chart_gains
from scantex.atlas.seams import seam_edges, seam_visibility, uv_shells, with_seams_of
from scantex.metrics.geometry import geometry_metrics
from scantex.metrics.views import score_views
from scantex.photos.photoset import PhotoSet
from scantex.photos.training import PhotoView
from scantex.pipeline.config import BakeConfig, EnhanceConfig, PhotosConfig
from scantex.scan import Scan, up_axis
from scantex.threads import side_by_side, using_cores
from scantex.views.camera import Camera
from scantex.views.planning import add_views_for_coverage, face_coverage, plan_views
from scantex.views.raycast import PAIR_THREADS, RayCaster, cast_gbuffer, interpolate, pixel_footprints
from scantex.views.render import downsample, render_gbuffer, render_scans, shade_hits
from scantex.views.viewset import ViewSet, split_train_test

log = logging.getLogger(__name__)

Update = Callable[[int, int], None]


class Reporter:
    """How the pipeline reports progress: one ``stage`` context per stage, yielding an update callback.

    The default reports nothing; the CLI passes one that draws progress bars.
    """

    @contextlib.contextmanager
    def stage(self, name: str) -> Iterator[Update]:
        yield lambda done, total: None


@dataclass(frozen=True, eq=False)
class TrainingViews:
    """Rendered views with what training needs from their G-buffers (views left unrendered: no pixel valid,
    no face, infinite depth)."""

    views: ViewSet
    face_id: np.ndarray  # [N, H, W] int32 centre-sample face, -1 where unusable
    depth: np.ndarray  # [N, H, W] float32 mean depth of the sub-samples
    valid: np.ndarray  # [N, H, W] bool: every sub-sample sees the same usable surface


@dataclass(frozen=True, eq=False)
class EnhanceResult:
    """What ``enhance`` made: the new scan (same geometry), its metrics and the renders used."""

    scan: Scan
    metrics: dict
    config: EnhanceConfig
    views: TrainingViews
    comparisons: dict[str, np.ndarray] = field(default_factory=dict)
    """images for people to look at, by name (photo mode: each held-out photo | the input | the result)"""
    input_scan: Scan | None = None
    """the scan that was enhanced (for the report's before/after)"""
    ground_truth: Scan | None = None
    """the ground truth it was scored against, if any"""
    renders: list[dict[str, np.ndarray]] = field(default_factory=list)
    """the held-out views as scored, one dict a view (``views.test`` order) of ``uint8`` renders at the
    scoring's supersampled size by name (input, enhanced, ground truth): the report shows them"""


def has_colour(scan: Scan) -> bool:
    """Whether ``scan`` carries any colour of its own: a texture, vertex or face colours, or materials of
    different base colours. Without photos, a scan that has none gives a plain colour whatever is trained."""
    if scan.is_textured or scan.vertex_colors is not None or scan.face_colors is not None:
        return True
    bases = {tuple(np.round(np.asarray(m.diffuse[:3], np.float64), 4)) for m in scan.materials}
    return len(bases) > 1


def render_training_views(scan: Scan, cameras: list[Camera], usable: np.ndarray, supersample: int,
                          caster: RayCaster, test_fraction: float, seed: int,
                          update: Update, render_train: bool = True, render_test: bool = True) -> TrainingViews:
    """Unlit renders (box-filtered supersamples) plus per-pixel validity for training. With ``render_train``
    False only the held-out (test) views are rendered; the training views are left empty (no pixel valid):
    for a run that trains nothing on them. With ``render_test`` False the held-out views are left empty too,
    for :func:`measure` to fill their images with the input's renders it scores against (the same renders:
    rendering them here as well cost the bolster's photo-mode run 0.3 s)."""
    s = supersample
    train, test = split_train_test(len(cameras), test_fraction, seed)
    rendered = np.zeros(len(cameras), bool)
    rendered[test] = render_test
    rendered[train] = render_train

    # every view's arrays, filled as each view is rendered; an unrendered one stays empty (no pixel valid).
    # Written in place: stacking the views' arrays took longer than rendering the five a photo-mode run renders
    n = len(cameras)
    H, W = (cameras[0].height, cameras[0].width) if n else (0, 0)
    images, alpha = np.zeros((n, H, W, 3), np.float32), np.zeros((n, H, W), np.float32)
    fids, depths = np.full((n, H, W), -1, np.int32), np.full((n, H, W), np.inf, np.float32)
    valids = np.zeros((n, H, W), bool)

    def view(i: int) -> None:
        """Renders view ``i`` into the arrays: its image, alpha, face ids, depths and valid pixels."""
        cam = cameras[i]
        if (cam.height, cam.width) != (H, W):
            raise ValueError(f"view {i} is {cam.width}x{cam.height}, the first {W}x{H}: views share one size")
        g = cast_gbuffer(caster, cam.scaled(s) if s > 1 else cam)
        rgb = render_gbuffer(scan, g)
        _, all_usable, mean_depth, spread = pixel_footprints(g.face_id, g.depth, s, usable)
        # a pixel is a clean sample of one surface when all its sub-samples hit usable faces at
        # nearly the same depth (no silhouette, no hole border)
        valids[i] = all_usable & (spread < 0.02 * mean_depth)
        images[i], alpha[i] = downsample(rgb, s), downsample(g.mask.astype(np.float32)[..., None], s)[..., 0]
        fids[i], depths[i] = g.face_id.reshape(H, s, W, s)[:, s // 2, :, s // 2], mean_depth

    # the views side by side (Embree and numpy release the interpreter lock)
    drawn = np.flatnonzero(rendered)
    for k, _ in enumerate(side_by_side(view, drawn, PAIR_THREADS)):
        update(k + 1, len(drawn))
    views = ViewSet(tuple(cameras), images, alpha, train, test, rendered=rendered)
    return TrainingViews(views, fids, depths, valids)


def gather_rays(tv: TrainingViews, chart_of_face: np.ndarray, indices: np.ndarray):
    """Training rays of the views ``indices`` (see :class:`scantex.field.rays.RayDataset`)."""
    from scantex.field.rays import RayDataset

    parts = []
    for i in indices:
        cam = tv.views.cameras[i]
        _, directions = cam.pixel_rays()
        valid = tv.valid[i].reshape(-1)
        n = int(valid.sum())
        parts.append(RayDataset(
            origins=np.broadcast_to(cam.center.astype(np.float32), (n, 3)).copy(),
            directions=directions[valid],
            depth=tv.depth[i].reshape(-1)[valid],
            rgb=tv.views.images[i].reshape(-1, 3)[valid].astype(np.float32),
            chart=chart_of_face[tv.face_id[i].reshape(-1)[valid]].astype(np.int64),
        ))
    return RayDataset.concatenate(parts)


def taught_faces(tv: TrainingViews, n_faces: int, min_rays: int = 4) -> np.ndarray:
    """``(F,) bool`` faces that at least ``min_rays`` training rays landed on."""
    train = tv.views.train
    hit = tv.face_id[train][tv.valid[train]]
    return np.bincount(hit, minlength=n_faces) >= min_rays


#: share of the held-out views' pixels with a patch against the input (:func:`patch_metrics`) above which
#: the default bake's levelling and refining are not trusted ...
PATCH_LIMIT = 0.01
#: ... unless they removed at least this share of the input's seam visibility at the seams levelling levels
#: (:func:`levelled_seams`: what levelling is for; before seam blending: the demo wall's levelling removes 52 % with
#: 0.9 % patches, a synthetic room's 58 % with 2.0 %; on a Polycam plant it removed 16 % while drawing 5.4 %)
SEAM_GAIN = 0.3
#: photos this many times finer than the input atlas (pixels vs texels per cm) have photo mode bake an atlas
#: twice as fine (:func:`photo_atlas_scale`)
PHOTO_DENSITY_FOR_2X = 2.0
#: ``photos.final`` auto: a capture of fewer photos than this writes the texture made from all of them, its
#: held-out photos scoring the one made without them (a held-out photo is a large share of so few; the second,
#: partial bake costs seconds); larger ones write the texture scored (:func:`final_texture_mode`)
FINAL_ALL_BELOW = 50
#: ``photos.refine_poses`` auto: a textured scan's photos are aligned to its texture when they are fewer than this.
#: A few photos blended through poses a few pixels off leave distinct ghost copies of every edge (a 9-photo
#: RGB-D capture: its pattern doubled and blurred, visibly worse than the input); aligned, the texture is as
#: sharp as the photos, at the same held-out scores on average. A room's hundred photos blur into one another
#: instead, and their alignment cost a real apartment 0.16 dB and 1.6x its time (bench/RESULTS.md)
REFINE_BELOW = 50
#: ``photos.detail`` balanced and sharp: the softmax temperature of the photos' fine band (their coarse band keeps
#: ``photos.temperature``). On a real apartment's 197 photos, 0.1 gives about the best view's detail: the held-out
#: renders' 0.0055 against the input's 0.0072 and the blend's 0.0027 (``score_photos``'s ``detail``;
#: bench/RESULTS.md, "sharp detail")
SHARP_DETAIL_TEMPERATURE = 0.1
#: ``photos.detail`` balanced: the best views' fine band at half its contrast. A room's blend of photos registered a
#: few pixels apart smears each edge into several faint copies (a real apartment's tiles, dish rack and lamp
#: pole); at 0.5 each edge is one clean copy at half its contrast, held out 0.14 dB under the blend where the full
#: detail (sharp) costs 0.5 (bench/RESULTS.md, "balanced detail")
BALANCED_DETAIL_GAIN = 0.5
#: ``photos.detail`` auto: balanced from this many photos (a room's video frames, blended as recorded), blend
#: below it (a few photos, aligned by default, blend into a sharp texture already; the best views' detail brings
#: their occluders and their registration with it: a façade's trees, 22.39 against 21.16 dB sharp)
BALANCED_FROM = 50
#: ``photos.depth_gaps`` auto: on from this many photos. A room's photos paint a thin object the mesh lost in many
#: places (a real apartment's lamp pole: four or five lines on its wall, fainter with the gaps, its held-out score
#: the same); on 12-photo parts of it the gaps cost 0.02-0.08 dB, each photo's pixels counting for more
GAPS_FROM = 50
#: ``photos.pairs`` auto: the photos' exposures levelled against one another from this many photos (a synthetic
#: room's 110: 28.16 dB with them, 27.26 without); below, against the input texture alone (nine photos of a real
#: apartment whose white wall clips: 26.39 against 25.83, a hard step gone; the bolster and the façade the same)
PAIRS_FROM = 50


def by_capture_size(setting: str, n_photos: int, at_least: int, room: str, below: str) -> str:
    """A photo setting as a run applies it: ``auto`` is ``room`` for a capture of ``at_least`` photos or more,
    ``below`` for a smaller one; any other value is itself."""
    if setting != "auto":
        return setting
    return room if n_photos >= at_least else below


def pair_weight(pc: PhotosConfig, n_photos: int) -> float:
    """The closed-form colour fit's weight of the photo pairs for ``photos.pairs`` (auto: from ``PAIRS_FROM``)."""
    return pc.pair_weight if pairs_mode(pc.pairs, n_photos) == "on" else 0.0


def keyframes_mode(keyframes: str, n_photos: int) -> str:
    """``photos.keyframes`` as a run applies it: ``on`` or ``off`` (``auto``: on from ``KEYFRAMES_FROM`` photos)."""
    from scantex.photos.keyframes import KEYFRAMES_FROM

    return by_capture_size(keyframes, n_photos, KEYFRAMES_FROM, "on", "off")


def pairs_mode(pairs: str, n_photos: int) -> str:
    """``photos.pairs`` as a run applies it: ``on`` or ``off`` (``auto``: on from ``PAIRS_FROM`` photos)."""
    return by_capture_size(pairs, n_photos, PAIRS_FROM, "on", "off")


def detail_mode(detail: str, n_photos: int) -> str:
    """``photos.detail`` as a run applies it: ``blend``, ``balanced`` or ``sharp`` (``auto``: balanced from
    ``BALANCED_FROM`` photos, blend below)."""
    return by_capture_size(detail, n_photos, BALANCED_FROM, "balanced", "blend")


def detail_settings(detail: str, n_photos: int) -> dict:
    """Projective texturing's two-band settings for ``photos.detail`` (``{}``: one band, the blend)."""
    mode = detail_mode(detail, n_photos)
    if mode == "blend":
        return {}
    return {"detail_temperature": SHARP_DETAIL_TEMPERATURE,
            "detail_gain": BALANCED_DETAIL_GAIN if mode == "balanced" else 1.0}


#: the atlas sizes photo mode lays an untextured scan out at (:func:`untextured_atlas_size`): a fused apartment
#: (106 m², photos 3.5 px/cm) scored 24.21 dB at 2048², 25.26 at 4096², 25.29 at 8192² in 1.4x the time and
#: 4.5 GB against 3.5 (bench/RESULTS.md); ``--texture-size`` asks for another
UNTEXTURED_ATLASES = (2048, 4096)
#: the smallest atlas a vertex-coloured mesh's colours are baked into, and the texels each of its vertices gets at
#: least (a larger atlas where the charts leave too few: :func:`scantex.atlas.bake.texture_from_vertex_colours`;
#: the colour of a fused depth scan varies per vertex, a centimetre or so apart)
VERTEX_COLOUR_ATLAS = 2048
TEXELS_PER_VERTEX = 16


def keeps_input_texels(scan: Scan, config: EnhanceConfig, photos) -> bool:
    """Whether the run bakes the input's own texels (mesh-only mode, ``bake.source`` input, a textured scan)."""
    return photos is None and scan.is_textured and config.bake.source == "input"


def photos_need_no_field(scan: Scan, config: EnhanceConfig, photos) -> bool:
    """Whether photo mode can do without the field: projective texturing of a textured scan in the input's
    colour balance takes each photo's colour transform in closed form against the input texture and fills
    what no photo sees with the input's own texels; of an untextured scan, it takes the transforms in closed
    form from the photos' overlaps and fills what no photo sees from the photos' colours around it."""
    pc = config.photos
    return (photos is not None and pc.texturing == "projective" and not config.train.always
            and (pc.canonical == "input" or not scan.is_textured))


def views_teach(scan: Scan, config: EnhanceConfig, photos) -> bool:
    """Whether anything trains on the synthetic views (the field, or the refiner over the photos' colour): if
    not, only the held-out views are rendered, for the report's fidelity score, and none are added for
    coverage."""
    return not photos_need_no_field(scan, config, photos) or (config.refine.enabled and config.refine.with_photos)


def mesh_only_colour(scan: Scan, fitted, fill: np.ndarray, taught: np.ndarray, charts: np.ndarray, device,
                     config: BakeConfig, noise: float | None = None) -> tuple[SurfaceColour, dict]:
    """The colour mesh-only mode bakes (``bake.source``; see :mod:`scantex.atlas.colour`) and a report.

    ``fitted`` may be ``None`` with ``bake.source`` input: no denoising (the field was not trained,
    see :func:`enhance`). ``noise``: the atlas's noise level when already estimated; without a field it sets
    nothing, and is not estimated (``None`` in the report: 0.3 s of a photo-mode run on the bolster)."""
    from scantex.atlas.colour import atlas_noise, field_colour, levelled_input_colour
    from scantex.atlas.levelling import seam_offsets

    if config.source == "field" or not scan.is_textured:
        return field_colour(scan, fitted, fill, taught, charts, device, detail=config.detail), {"source": "field"}
    offsets = seam_offsets(scan, exclude=fill) if config.levelling else np.zeros((len(scan.uvs), 3))
    if noise is None and fitted is not None:
        noise = atlas_noise(scan, exclude=fill)
    threshold = config.denoise * noise if noise is not None else 0.0
    colour = levelled_input_colour(scan, offsets, fill, fitted=fitted, taught=taught, charts=charts, device=device,
                                   noise_threshold=threshold)
    return colour, {"source": "input", "noise_level": None if noise is None else round(noise, 5),
                    "denoised": fitted is not None and threshold > 0, "noise_threshold": round(threshold, 5),
                    "levelling_offset_mean": round(float(np.abs(offsets).mean()) if offsets.size else 0.0, 5),
                    "levelling_offset_max": round(float(np.abs(offsets).max()) if offsets.size else 0.0, 5)}


@dataclass(frozen=True, eq=False)
class PhotoData:
    """The capture's photos as the pipeline uses them (photo mode)."""

    photos: PhotoSet
    train: list[PhotoView]
    held_out: list[PhotoView]
    alignment: object | None
    """the :class:`scantex.photos.alignment.AlignmentReport`, when checked"""
    pose_corrections: list = field(default_factory=list)
    """:class:`scantex.photos.poses.PoseCorrection` per training photo, when refined"""
    final: tuple | None = None
    """``(photos, views, corrections)``: where the training photos' poses were refined and ``photos.final``
    all bakes the texture written from every photo, the photo set with the held-out photos aligned to the
    training photos' frame too, their G-buffers there, and their corrections (they are scored as recorded)"""
    pose_mode: str = "off"
    """``photos.refine_poses`` as applied (:func:`pose_refinement_mode`): off, input or consensus"""
    left_out: list = field(default_factory=list)
    """the photos left out as not showing what their cameras see
    (:func:`scantex.photos.matching.leave_out_mismatched`)"""
    repeated: list = field(default_factory=list)
    """the photos given way to a sharper one whose view they repeat (``photos.keyframes``:
    :func:`scantex.photos.keyframes.keyframes`)"""
    blurred: list = field(default_factory=list)
    """the photos with under 30 % of the fine detail (along one axis) of the photos that see the same surface
    (:func:`scantex.photos.sharpness.blurred_photos`, with ``image``, ``left_out`` and ``softened``:
    ``photos.blurred``)"""


def checked_split(scan: Scan, photos: PhotoSet, pc: PhotosConfig, caster: RayCaster, seed: int,
                  update: Update | None = None) -> tuple[object | None, np.ndarray, np.ndarray, list, list]:
    """Photo mode's first step, whole or tiled: ``(alignment report, train, held, left_out, repeated)``. The
    photos that repeat a sharper one's view set aside (``photos.keyframes``), the alignment check (refuses a mesh
    out of the cameras' frame; ``None`` when skipped), the held-out split of the photos kept (without thinning,
    moved off views another photo repeats: :func:`scantex.photos.keyframes.held_apart`), and the photos that do not
    show what their cameras see left out of both (:func:`scantex.photos.matching.leave_out_mismatched`).
    ``update(done, total)`` counts the photos the thinning looks at."""
    from scantex.photos.alignment import require_alignment
    from scantex.photos.training import split_photos

    kept, repeated = np.arange(len(photos)), []
    thinned = keyframes_mode(pc.keyframes, len(photos)) == "on"
    if thinned:
        from scantex.photos.keyframes import keyframes

        chosen, repeated = keyframes(photos, kept, caster, update)
        kept = np.asarray(chosen, dtype=kept.dtype)
        log.info("keyframes: %d of %d photos kept; %d repeat a sharper one's view", len(kept), len(photos),
                 len(repeated))
    train, held = split_photos(len(kept), pc.holdout, seed)
    train, held = kept[train], kept[held]
    if len(held) and not thinned:
        from scantex.photos.keyframes import held_apart

        train, held = held_apart(photos, train, held, caster)  # a held-out photo scores a view no photo repeats
    if not pc.check_alignment:
        return None, train, held, [], repeated
    from scantex.photos.matching import leave_out_mismatched

    report = require_alignment(scan, photos, caster=caster)  # logs its summary
    return report, *leave_out_mismatched(scan, photos, train, held, caster), repeated


def read_photos(scan: Scan, photos: PhotoSet, pc: PhotosConfig, caster: RayCaster, seed: int,
                update: Update) -> PhotoData:
    """Check the photos' alignment with the mesh, split them, and prepare them at working resolution."""
    from scantex.photos.training import prepare_photos

    report, train, held, left_out, repeated = checked_split(scan, photos, pc, caster, seed, update)
    corrections = []
    canonicalise = fallback = None
    mode = pose_refinement_mode(pc.refine_poses, scan, len(photos))
    # the stage's progress counts the training photos refined (input mode), then every photo prepared
    refined = len(train) if mode == "input" else 0
    prepared = len(train) + len(held)
    if mode == "input":
        from scantex.photos.poses import reference_faces, refine_poses

        def texture(face_ids, bary):
            return shade_hits(scan, face_ids, bary)

        usable_faces = reference_faces(scan)  # once for the training photos and, below, the held-out ones
        # held-out photos keep their recorded poses: they are the score's reference, not training data
        photos, corrections = refine_poses(scan, photos, train, texture, caster, faces=usable_faces,
                                           update=lambda done, total: update(done, refined + prepared))
    settings = visibility_settings(pc, len(photos))
    views = prepare_photos(scan, photos, [*train, *held], caster, pc.max_side, settings,
                           lambda done, total: update(refined + done, refined + total))
    # softening is projective texturing's (a field trained on the photos takes each photo whole)
    blurred_mode = "keep" if pc.blurred == "soften" and pc.texturing != "projective" else pc.blurred
    views, train, held, blurred = judge_detail(photos, views, train, held, blurred_mode)
    train_views, held_views = views[:len(train)], views[len(train):]
    if mode == "consensus" and len(train) > 1:
        from scantex.photos.poses import consensus_poses

        if scan.is_textured:
            canonicalise, _, _ = closed_form_transforms(scan, train_views, caster, uv_shells(scan),
                                                        pair_weight(pc, len(photos)))

            def input_colour(points, normals, face_ids, bary):
                return shade_hits(scan, face_ids, bary)

            fallback = input_colour
        else:
            canonicalise = None

            fallback = flat_grey
        photos, train_views, corrections = consensus_poses(
            scan, photos, train_views, canonicalise, caster, fallback, pc.refine_iterations, pc.temperature,
            prepare=lambda refined: prepare_photos(scan, judged(refined, train_views), train, caster, pc.max_side,
                                                   settings),
            update=update, memory_mb=pc.sample_memory_mb)
    final = None
    if (corrections and len(held) and pc.texturing == "projective"
            and final_texture_mode(pc.final, len(photos)) == "all"):
        # the texture written from every photo: the held-out photos join the training photos' refined frame
        # (a texture from both frames would be doubled); they are still scored through their recorded poses
        if mode == "input":
            aligned, moved = refine_poses(scan, photos, held, texture, caster, faces=usable_faces)
        else:
            from scantex.photos.poses import align_to_consensus

            aligned, moved = align_to_consensus(scan, photos, held, train_views, canonicalise, caster, fallback,
                                                pc.temperature, memory_mb=pc.sample_memory_mb)
        final = aligned, prepare_photos(scan, judged(aligned, held_views), held, caster, pc.max_side, settings), moved
    return PhotoData(photos, train_views, held_views, report, corrections, final, mode, left_out, repeated, blurred)


def judge_detail(photos: PhotoSet, views: list, train, held, mode: str) -> tuple[list, list, list, list[dict]]:
    """``(views, train, held, blurred)``: the photos (``views`` of ``train`` then ``held``) whose fine detail is
    under 30 % of their partners' (:func:`scantex.photos.sharpness.blurred_photos`) named in a warning, and treated
    as ``photos.blurred`` ``mode`` says: left out of the three lists (leave-out; all kept when they would leave no
    training photo), softened (soften: ``softened`` in their ``blurred`` entry, for :func:`soft_photos`),
    blended in whole (keep), or auto: left out when they are :data:`scantex.photos.sharpness.LEAVE_OUT_SHARE` of the
    training photos or more, else blended in whole."""
    from scantex.photos.sharpness import LEAVE_OUT_SHARE, blurred_photos

    found = blurred_photos(views)
    if not found:
        return views, train, held, []
    named, training = {d["photo"] for d in found}, {int(i) for i in train}
    if mode == "auto":
        mode = "leave-out" if len(named & training) >= LEAVE_OUT_SHARE * len(training) else "keep"
    gone = named if mode == "leave-out" else set()
    if gone >= training:
        gone, mode = set(), "keep"
    then = {"leave-out": ": left out", "soften": ": its detail left to the sharp photos", "keep": ""}[mode]
    for d in found:
        log.warning("%s: photo %d has %.0f %% of the fine detail of the photos that see the same surface (shaken, out "
                    "of focus or washed out?)%s", photos.images[d["photo"]], photos.number(d["photo"]),
                    100 * d["detail"], then)
    blurred = [{**d, "image": str(photos.images[d["photo"]]), "left_out": d["photo"] in gone,
                "softened": mode == "soften"} for d in found]
    if gone:
        views = [v for v in views if v.index not in gone]
        train = np.array([i for i in train if int(i) not in gone], dtype=np.asarray(train).dtype)
        held = np.array([i for i in held if int(i) not in gone], dtype=np.asarray(held).dtype)
    return views, train, held, blurred


def soft_photos(blurred: list[dict]) -> tuple[int, ...]:
    """The shaken photos softened (``PhotoData.blurred``, ``photos.blurred`` soften): their fine band gives way to
    the sharp photos' (``ProjectiveSettings.soft_photos``)."""
    return tuple(d["photo"] for d in blurred if d.get("softened"))


def judged(photos: PhotoSet, views) -> PhotoSet:
    """``photos`` with the depth maps' judgements ``views`` (prepared photos) made: a photo prepared again at
    another pose keeps its map's factor (not judged, nor warned about, twice)."""
    found = {v.index: v.depth_factor for v in views}
    return dataclasses.replace(photos, depth_factors=tuple(found.get(i, f) for i, f in enumerate(photos.depth_factors)))


def depth_gaps_mode(depth_gaps: str, n_photos: int) -> str:
    """``photos.depth_gaps`` as a run applies it: ``on`` or ``off`` (``auto``: on from ``GAPS_FROM`` photos)."""
    return by_capture_size(depth_gaps, n_photos, GAPS_FROM, "on", "off")


def visibility_settings(pc: PhotosConfig, n_photos: int):
    """The photo-pixel visibility test ``pc`` asks for (the training and the held-out photos alike) of a capture of
    ``n_photos`` photos."""
    from scantex.photos.training import VisibilitySettings

    gaps = pc.depth_gap_px if depth_gaps_mode(pc.depth_gaps, n_photos) == "on" else 0
    return VisibilitySettings(supersample=2, edge_margin_px=pc.edge_margin_px, max_angle_deg=pc.max_angle_deg,
                              depth_tolerance=pc.depth_tolerance, depth_gap_px=gaps)


def flat_grey(points, normals, face_ids, bary) -> np.ndarray:
    """An untextured scan's colour of its own, where nothing else gives one: ``(n, 3)`` mid grey."""
    return np.full((len(points), 3), 0.5, np.float32)


def closed_form_transforms(scan: Scan, views: list, caster: RayCaster, charts: np.ndarray,
                           pair_weight: float = 0.0, tones: bool = False):
    """``(canonicalise, transforms, gammas)``: each photo's colour transform onto the input texture's appearance,
    fitted in closed form (:func:`scantex.photos.texturing.fit_photo_transforms`; ``charts``: the input
    atlas's chart of each face; ``pair_weight``: the weight of the photos' ratios to one another), and the
    function that undoes it. An untextured scan's photos are brought to their average appearance, from
    their overlaps alone. ``tones``: the views' photos are first brought to one tone curve
    (:func:`scantex.photos.tones.fit_photo_tones`), ``gammas`` ``(P,)`` each view's (``None`` without)."""
    from scantex.photos.texturing import fit_photo_transforms, inverse_transforms
    from scantex.photos.tones import fit_photo_tones, toned_view
    from scantex.photos.training import halved, texture_seen

    # exposure is a few numbers a photo: half the working resolution has pixels enough, at a quarter the cost
    small = [halved(view) for view in views]
    gammas = None
    if tones:
        gammas = fit_photo_tones(small)
        small = [toned_view(view, gamma) for view, gamma in zip(small, gammas)]
    # each photo's view of the input texture, rendered when the fit asks for it (the photos side by side: Embree
    # and numpy release the interpreter lock), not all held at once (a room's 400 photos: 0.4 GB)
    references = (lambda k: texture_seen(scan, small[k], caster)) if scan.is_textured else None
    transforms = fit_photo_transforms(references, small, charts,
                                      np.bincount(charts, scan.face_areas, int(charts.max()) + 1),
                                      blur_px=0.5, pair_weight=pair_weight)
    return inverse_transforms(transforms), transforms, gammas


def with_tones(photos: PhotoSet, views: list, gammas: np.ndarray) -> PhotoSet:
    """``photos`` reading the views' photos on the common tone curve (``gammas`` ``(P,)``: each view's, from
    :func:`closed_form_transforms`)."""
    per_photo = list(photos.tones)
    for view, gamma in zip(views, gammas):
        per_photo[view.index] = float(gamma)
    return dataclasses.replace(photos, tones=tuple(per_photo))


def photo_mode_rays(synthetic, photo: PhotoData, n_charts: int, synthetic_weight: float,
                    canonical: str = "input"):
    """All training rays of photo mode and their appearance groups.

    Groups ``0 .. P-1`` are the training photos (one exposure / white balance each), ``P .. P+C-1``
    the input atlas's charts seen in the synthetic views (``synthetic`` may be ``None``: an untextured
    scan has nothing to render). The synthetic rays weigh ``synthetic_weight`` each against a photo
    ray's 1 (in the loss; not in fixing the colour balance).

    ``canonical`` says whose appearance is the one baked: ``"input"``, the input texture's average over
    its charts (the result keeps the scan's overall colour balance; the photos only add what they see),
    or ``"photos"``, the photos' average; an untextured scan always takes the photos'. Either is an
    average of independently exposed images, and so only an estimate of the true colour.

    Returns:
        ``(rays, chart_offset, appearance_weights)``: the synthetic rays' groups are their chart + offset.
    """
    from scantex.errors import ScanError
    from scantex.field.rays import RayDataset
    from scantex.photos.training import photo_rays

    if canonical not in ("input", "photos"):
        raise ScanError(None, f"photos.canonical must be 'input' or 'photos', not '{canonical}'")
    P = len(photo.train)
    seen = photo_rays(photo.train, range(P))
    parts = [dataclasses.replace(seen, weight=np.ones(len(seen), np.float32))]
    if synthetic is not None and len(synthetic) and synthetic_weight > 0:
        parts.append(dataclasses.replace(synthetic, chart=synthetic.chart + P,
                                         weight=np.full(len(synthetic), synthetic_weight, np.float32)))
    rays = RayDataset.concatenate(parts)
    counts = np.bincount(rays.chart, minlength=P + n_charts).astype(np.float32)
    weights = np.zeros(P + n_charts, np.float32)
    if canonical == "input" and counts[P:].sum() > 0:
        weights[P:] = counts[P:]
    else:
        weights[:P] = counts[:P]
    return rays, P, weights


def photo_texture(scan: Scan, photo: PhotoData, fitted, fallback, pc: PhotosConfig, caster: RayCaster,
                  charts: np.ndarray, device, texel_px_per_cm: float = 0.0, threads: int | None = None,
                  release: bool = False):
    """Photo mode's colour source: texels sampled from the training photos at full resolution, brought
    to the canonical appearance by each photo's inverse colour transform, with ``fallback`` (the field, or
    the input's texels) where no photo sees them. The transforms are the field's (training photo ``k`` is
    appearance group ``k``) when it was trained, else fitted in closed form against the input texture
    (``charts``: the input atlas's chart of each face). ``texel_px_per_cm``: the output atlas's texel density
    (photos much finer than it are sampled at a lower resolution; 0: full resolution). ``threads``: how many
    sample one call's photos side by side (``None``: the cores; 1 when the bake colours chunks in parallel).
    ``release``: ``photo.train`` (a list) has its views replaced by their sampled copies as the photos are
    sampled (:func:`~scantex.photos.texturing.projective_colour`'s ``release``)."""
    from scantex.photos.texturing import ProjectiveSettings, loose_fragments, projective_colour, recorded_transforms

    report: dict = {}
    recorded = transforms = None
    photos = photo.photos
    if fitted is None:
        canonicalise, transforms, gammas = closed_form_transforms(scan, photo.train, caster, charts,
                                                                  pair_weight(pc, len(photo.photos)), pc.tones)
        if gammas is not None:
            photos = with_tones(photos, photo.train, gammas)
            report["photo_tones"] = [round(float(gamma), 3) for gamma in gammas]
        recorded = recorded_transforms(transforms)
        report["colour_transforms"] = ("closed form, against the input texture" if scan.is_textured else
                                       "closed form, from the photos' overlaps")
        report["photo_gains"] = [[round(float(g), 3) for g in np.diagonal(t[:3])] for t in transforms]
    elif fitted.appearance is not None:
        import torch

        def canonicalise(rgb, group):
            return fitted.appearance.canonical(torch.as_tensor(rgb, device=device),
                                               torch.as_tensor(group, device=device)).cpu().numpy()

        @torch.no_grad()
        def recorded(rgb, group):
            return fitted.appearance(torch.as_tensor(rgb, device=device),
                                     torch.as_tensor(group, device=device)).cpu().numpy()
        report["colour_transforms"] = "the field's"
    else:
        canonicalise = None
    settings = ProjectiveSettings(temperature=pc.temperature, texel_px_per_cm=texel_px_per_cm,
                                  consistency=pc.consistency, overshoot=pc.clip_overshoot,
                                  memory_mb=pc.sample_memory_mb, soft_photos=soft_photos(photo.blurred),
                                  **detail_settings(pc.detail, len(photo.photos)))
    corner_offsets: list[np.ndarray] = []  # the fallback's levelling offsets at each face's corners, once known

    def levelled(points, normals, face_ids, bary):
        rgb = fallback(points, normals, face_ids, bary)
        if not corner_offsets:
            return rgb
        return np.clip(rgb + interpolate(face_ids, bary, corner_offsets[0]), 0, 1)

    # an untextured scan without a field has no colour of its own where no photo looks: the photos' colours
    # around it are carried there (the fallback's offsets from a flat grey, ungated, harmonic over the mesh)
    from_photos = fitted is None and not scan.is_textured
    level = (pc.level_fallback or from_photos) and bool(photo.train)
    welded = scan.welded[scan.faces]
    through = loose_fragments(welded)
    report["loose_fragment_faces"] = int(through.sum()) if through is not None else 0
    colour, sampled = projective_colour(photos, photo.train, range(len(photo.train)), canonicalise,
                                        levelled if level else fallback, settings, faces=welded,
                                        recorded=recorded, threads=threads, through=through, transforms=transforms,
                                        release=release)
    if level:
        from scantex.photos.texturing import MAX_FALLBACK_STEP, fallback_offsets

        offsets, report["fallback_levelling"] = fallback_offsets(scan, colour, fallback,
                                                                 max_step=None if from_photos else MAX_FALLBACK_STEP)
        corner_offsets.append(offsets[scan.faces])
    return colour, {"mode": "projective", **sampled, **report}


def vertex_colour_texture(scan: Scan, reporter: Reporter) -> Scan:
    """``scan``'s vertex colours baked into a texture (a stage of its own), on a new layout; positions and faces are
    the same arrays.

    A fused RGB-D mesh's colour per vertex, made a texture that both modes treat as a capture app's atlas: mesh-only
    mode keeps its texels (holes filled, seams blended; a field trained on its renders took 145 s on a 12,712-face
    scan and drew seams the colours do not have), photo mode takes it as the photos' colour reference, the fill
    where no photo reaches, and texture edges for the alignment check."""
    from scantex.atlas.bake import texture_from_vertex_colours

    with reporter.stage("texture from the vertex colours") as update:
        textured = texture_from_vertex_colours(scan, VERTEX_COLOUR_ATLAS, texels_per_vertex=TEXELS_PER_VERTEX)
        update(1, 1)
    return textured


def vertex_texture_note(size: int, blends: bool) -> str:
    """What the metrics say of a texture baked from the vertex colours (``size`` square; ``blends``: its seams
    blended)."""
    return (f"baked from the vertex colours ({size}x{size}; not levelled{'' if blends else ' nor blended'} at its "
            "seams: the colours are continuous across them)")


def photo_atlas_scale(scan: Scan, photos_px_per_cm: float) -> tuple[int, dict]:
    """How much finer than the input atlas photo mode bakes: 2 when the photos resolve the surface at least
    ``PHOTO_DENSITY_FOR_2X`` (2) times finer than the input atlas's texels do (median over the training
    photos' usable pixels of full-resolution pixels per centimetre), else 1 (a finer atlas would only
    resample the same detail). ``photos_px_per_cm``: :func:`photo_density`. At 1.4 (before), a real apartment
    (photos 1.52x the atlas's density) scored +0.02 dB for 1.6x the time and +1.1 GB, and the synthetic room
    (1.93x) 0.07 dB less (bench/RESULTS.md)."""
    from scantex.metrics.texture import texel_density

    atlas = texel_density(scan)["px_per_cm_mean"] if scan.is_textured else 0.0
    scale = 2 if atlas <= 0 or photos_px_per_cm >= PHOTO_DENSITY_FOR_2X * atlas else 1
    return scale, {"photos_px_per_cm": round(photos_px_per_cm, 2), "atlas_px_per_cm": round(atlas, 2),
                   "atlas_scale": scale}


def atlas_growth(scan: Scan, requested: int, scale: int) -> float:
    """How many times finer than the input's atlas the output's is on the input's own layout: ``requested``
    (``bake.texture_size``, 0: none) or ``scale`` times the input's size, at most 8192 (:func:`output_size`), over
    the input's size; the largest over the materials. The photos are sampled for that atlas: for ``scale`` (2)
    alone they were sampled twice too finely for an 8192 input, whose atlas cannot grow, and too coarsely for a
    texture size asked above twice the input's."""
    growth = [output_size(scan, m, requested, scale=scale)[1] / m_image.shape[1]
              for m, m_image in enumerate(material.image for material in scan.materials) if m_image is not None]
    return max(growth, default=float(scale))


def photo_density(photo: PhotoData) -> float:
    """How finely the training photos resolve the surface: the median over the photos of their usable pixels'
    median full-resolution pixels per centimetre (0 when none has usable pixels)."""
    per_photo = [photo_px_per_cm(photo.photos.cameras[v.index], v.depth[v.valid]) for v in photo.train
                 if v.valid.any()]
    return float(np.median(per_photo)) if per_photo else 0.0


def photo_px_per_cm(camera: Camera, depths: np.ndarray) -> float:
    """How finely one photo resolves the surface: the median full-resolution pixels per centimetre of its pixels
    that see it, from ``camera`` and those pixels' depths (metres; at least one)."""
    return float(np.median(camera.K[0, 0] / depths)) / 100.0


def untextured_atlas_size(scan: Scan, photos_px_per_cm: float) -> int:
    """The atlas an untextured scan's photos are baked into: the smallest of ``UNTEXTURED_ATLASES`` whose
    texels, spread over the whole surface without gutters, would be as fine as the photos' pixels there
    (the charts and their gutters then leave a fraction of that: a fused apartment of 31,000 charts, 106 m²,
    photos 3.5 pixels per cm, gets 0.56 texels per cm at 2048², 2.2 at 4096²). ``photos_px_per_cm``:
    :func:`photo_density`."""
    wanted = photos_px_per_cm * np.sqrt(float(scan.face_areas.sum()) * 1e4)  # texels a side
    return next((size for size in UNTEXTURED_ATLASES if size >= wanted), UNTEXTURED_ATLASES[-1])


def pose_refinement_mode(refine_poses: str, scan: Scan, n_photos: int) -> str:
    """``photos.refine_poses`` as a run applies it: ``off``, ``input`` or ``consensus`` (``auto``: below
    ``REFINE_BELOW`` photos, input for a textured scan and consensus for an untextured one, which has no
    texture to align to; else off)."""
    if refine_poses == "auto":
        if n_photos >= REFINE_BELOW:
            return "off"
        return "input" if scan.is_textured else "consensus"
    if refine_poses == "input" and not scan.is_textured:
        return "off"
    return refine_poses


def final_texture_mode(final: str, n_photos: int) -> str:
    """``photos.final`` as a run applies it: ``training`` or ``all`` (``auto``: all below ``FINAL_ALL_BELOW``
    photos)."""
    return by_capture_size(final, n_photos, FINAL_ALL_BELOW, "training", "all")


def faces_in_view(scan: Scan, views, rings: int = 2) -> np.ndarray:
    """``(F,) bool``: the faces the views' pixels hit, grown by ``rings`` rings of faces sharing a position with
    them (what bilinear lookups and seam blending beside them read)."""
    seen = np.zeros(scan.n_faces, bool)
    for view in views:
        seen[view.face_id[(view.face_id >= 0) & (view.face_id < scan.n_faces)]] = True
    return grow_faces(scan, seen, rings, welded=True)


def run_key(scan: Scan, config: EnhanceConfig, photos: PhotoSet | None) -> str:
    """A digest of what a field checkpoint depends on: the scan's geometry and UVs, the photos' cameras
    and the settings (but the step count, which a resumed run may raise): ``--resume`` refuses another's."""
    import hashlib
    import json

    h = hashlib.sha256()
    for array in (scan.positions, scan.faces, scan.uvs, scan.face_uvs):
        if array is not None:
            h.update(np.ascontiguousarray(array).tobytes())
    settings = config.to_dict()
    settings["train"] = {k: v for k, v in settings["train"].items() if k not in ("steps", "checkpoint_every")}
    for key in ("device", "threads", "output"):  # where and how it runs, how its outputs are written
        settings.pop(key, None)
    h.update(json.dumps(settings, sort_keys=True, default=str).encode())
    if photos is not None:
        h.update(json.dumps([c.to_dict() for c in photos.cameras], default=str).encode())
    return h.hexdigest()[:16]


def torch_device(config: EnhanceConfig):
    """The ``torch.device`` of ``config.device``, torch's threads set to ``config.threads``. Only what trains
    the field or runs the refiner calls it: torch takes 1.5-2 s to import, a run that needs neither
    (photo mode's projective texturing) never pays it."""
    import torch

    from scantex.field.train import resolve_device

    torch.set_num_threads(config.threads or os.cpu_count() or 1)
    return resolve_device(config.device)


def enhance(scan: Scan, config: EnhanceConfig | str = EnhanceConfig(), *, ground_truth: Scan | None = None,
            photos: PhotoSet | None = None, work_dir: str | Path | None = None, resume: bool = False,
            reporter: Reporter | None = None) -> EnhanceResult:
    """Enhance ``scan``'s texture; its positions and faces are returned untouched.

    Args:
        scan: the input scan (with UVs: the input layout is kept).
        config: all settings (see :mod:`scantex.pipeline.config`), or a preset's name (``"fast"``).
        ground_truth: the same geometry with the true texture, when known (synthetic scans): held-out
            views are then scored against it, for the input and for the result.
        photos: the capture's posed photos (photo mode): the field learns from them, with the
            synthetic views of the input texture at a lower weight for surface no photo sees; a share
            of them is held out and the input and the result are scored against it.
        work_dir: where field checkpoints go (for ``resume``).
        resume: continue from the checkpoint in ``work_dir`` if there is one.
        reporter: progress reporting (default: silent).

    ``config.threads`` (0: every core) bounds the threads of the stages that handle photos or views side by
    side (:func:`scantex.threads.cores`), as it bounds torch's and the bake's.
    """
    if isinstance(config, str):
        from scantex.pipeline.config import preset

        config = preset(config)
    with using_cores(config.threads):
        return _enhance(scan, config, ground_truth=ground_truth, photos=photos, work_dir=work_dir, resume=resume,
                        reporter=reporter)


def _enhance(scan: Scan, config: EnhanceConfig, *, ground_truth: Scan | None, photos: PhotoSet | None,
             work_dir: str | Path | None, resume: bool, reporter: Reporter | None) -> EnhanceResult:
    """:func:`enhance`, within its cores."""
    from scantex.errors import ScanError
    from scantex.pipeline.config import validate
    from scantex.uv import blend_seams, plan_uvs

    validate(config)
    if photos is not None:
        photos.prefetch()  # decoded on a thread while the views are planned and rendered
    reporter = reporter or Reporter()
    timings: dict[str, float] = {}
    if photos is None and not has_colour(scan):
        raise ScanError(scan.source, "has no colour to enhance: no texture (or its texture files are missing), no "
                                     "vertex or face colours, one plain material colour; give the capture's posed "
                                     "photos (--photos) to texture it from them")
    from_vertex_colours = not scan.is_textured and scan.vertex_colors is not None
    if from_vertex_colours:
        t = time.perf_counter()
        scan = vertex_colour_texture(scan, reporter)
        vertex_atlas = scan.materials[0].image.shape[0]
        timings["vertex_colours"] = time.perf_counter() - t
    # such a texture has no exposure steps at its seams (the colours are continuous across them): what differs
    # there is detail a texel or two apart, which seam levelling would take for a step and blending would smear
    bake_config = dataclasses.replace(config.bake, levelling=False) if from_vertex_colours else config.bake
    blends = config.uv.blend_seams and not (from_vertex_colours and photos is None)
    if ground_truth is not None and (ground_truth.positions.shape != scan.positions.shape
                                     or ground_truth.faces.shape != scan.faces.shape):
        raise ScanError(ground_truth.source, "the ground truth does not have the scan's geometry")
    # the torch device, resolved (and torch imported) only by what trains or runs a network; CUDA asked for
    # and missing is an error whether or not this run would have used it
    device = torch_device(config) if config.device == "cuda" else None
    rng_seed = config.seed
    vc, tc = config.views, config.train

    t = time.perf_counter()
    caster = RayCaster(scan.positions, scan.faces)
    holes = untextured_faces(scan)
    # bilinear lookups at a hole's border read its black texels: keep one ring of faces out of training
    excluded = grow_faces(scan, holes, rings=1)
    charts = uv_shells(scan)
    up = up_axis(scan, vc.up)
    # photo mode without a field (and without the refiner) trains nothing on the synthetic views: only the
    # held-out ones are rendered, for the report's fidelity score, and no views are added for coverage
    trains_on_views = views_teach(scan, config, photos)
    with reporter.stage("planning views") as update:
        cameras = plan_views(scan, vc.n_views, mode=vc.mode, width=vc.width, height=vc.height,
                             fov_deg=vc.fov_deg, seed=rng_seed, up=up, caster=caster)
        if vc.adaptive and trains_on_views:
            cameras = add_views_for_coverage(scan, cameras, min_views=2, max_new=max(2, vc.n_views // 4),
                                             up=up, seed=rng_seed, caster=caster)
        update(1, 1)
    timings["plan"] = time.perf_counter() - t

    t = time.perf_counter()
    render_test = not held_out_rendered_when_scored(scan, trains_on_views)
    with reporter.stage("rendering views" if trains_on_views or render_test else "views' coverage") as update:
        tv = render_training_views(scan, cameras, ~excluded, vc.supersample, caster, vc.test_fraction,
                                   rng_seed, update, render_train=trains_on_views, render_test=render_test)
        # the surface the rendered views see: all of them, or the held-out ones a photo-mode run renders alone
        # (casting the other views' G-buffers only for this count took 0.24 s of the bolster's 10)
        coverage = face_coverage(scan, cameras if trains_on_views else [cameras[i] for i in tv.views.test],
                                 caster=caster)
        if not (trains_on_views or render_test):
            update(1, 1)
    timings["render"] = time.perf_counter() - t

    photo = None
    if photos is not None:
        t = time.perf_counter()
        with reporter.stage("reading photos") as update:
            photo = read_photos(scan, photos, config.photos, caster, rng_seed, update)
        timings["photos"] = time.perf_counter() - t

    t = time.perf_counter()
    data = gather_rays(tv, charts, tv.views.train)
    n_groups, chart_offset, appearance_weights = int(charts.max()) + 1, 0, None
    ray_counts = (0, len(data))
    if photo is not None:
        synthetic_rays = len(data) if scan.is_textured and config.photos.synthetic_weight > 0 else 0
        ray_counts = (sum(int(v.valid.sum()) for v in photo.train), synthetic_rays)
        if not photos_need_no_field(scan, config, photos):
            # every photo pixel as a ray (48 bytes each: 1.5 GB for a hundred VGA photos): only for the field
            synthetic = data if scan.is_textured else None  # an untextured scan's renders teach nothing
            data, chart_offset, appearance_weights = photo_mode_rays(synthetic, photo, n_groups,
                                                                     config.photos.synthetic_weight,
                                                                     config.photos.canonical)
            n_groups += chart_offset
    if sum(ray_counts) == 0:
        raise ScanError(scan.source, "no view sees any of the surface: the mesh has no area to texture "
                                     "(are its faces degenerate or collinear?)")
    # the default bake keeps the input's texels; the field would only denoise them (bake.denoise, off by
    # default: no measured gain on real app atlases), and not at all where the noise is below what
    # denoising can change
    noise, field_skipped = None, None
    if keeps_input_texels(scan, config, photos):
        from scantex.atlas.colour import atlas_noise, denoising_matters

        noise = atlas_noise(scan, exclude=excluded)
        if not (tc.always or denoising_matters(noise, config.bake.denoise)):
            field_skipped = (
                f"not trained: the input's texels are kept ({'levelled, ' if bake_config.levelling else ''}holes "
                "filled) and denoising against the field is off (bake.denoise 0, the default; set train.always "
                "to train it all the same)"
                if config.bake.denoise == 0 else
                f"not trained: the atlas's estimated noise ({noise:.4f}) times bake.denoise "
                f"({config.bake.denoise:g}) is below half an 8-bit step, so denoising against the "
                f"field could not change a texel (set train.always to train it all the same)")
            log.info("field %s", field_skipped)
    if photos_need_no_field(scan, config, photos):
        curve = "one tone curve and " if config.photos.tones else ""
        field_skipped = ("not trained: projective texturing samples the photos themselves, each brought to "
                         + (f"{curve}the input texture's colours by transforms fitted in closed form; the input's "
                            "own texels fill what no photo sees" if scan.is_textured else
                            f"{curve}the photos' average colours by transforms fitted in closed form from their "
                            "overlaps; what no photo sees takes the photos' colours around it")
                         + " (set train.always to train it all the same)")
        log.info("field %s", field_skipped)
    fitted = None
    if field_skipped is None:
        from scantex.field.model import FieldConfig
        from scantex.field.train import fit_field
        from scantex.field.volume import BoxNormaliser
        from scantex.pipeline.outputs import CHECKPOINT

        device = torch_device(config)
        lo, hi = scan.bounds
        normaliser = BoxNormaliser.from_points(np.stack([lo, hi]))
        band = tc.band_width * float(np.linalg.norm(hi - lo))
        fs = config.field
        field_config = FieldConfig(encoding=fs.encoding, hidden=fs.hidden, n_layers=fs.n_layers,
                                   skip_at=fs.n_layers // 2,
                                   log2_table_size=fs.log2_table_size, n_levels=fs.n_levels,
                                   max_resolution=fs.max_resolution, n_freqs=fs.n_freqs,
                                   use_viewdirs=fs.use_viewdirs)
        checkpoint = Path(work_dir) / CHECKPOINT if work_dir is not None else None
        with reporter.stage("training the field") as update:
            gains = chart_gains(scan, charts) if tc.seam_levelling and tc.appearance else None
            if gains is not None and chart_offset:
                gains = np.concatenate([np.ones((chart_offset, 3), gains.dtype), gains])
            fitted = fit_field(data, normaliser, field_config, tc, n_groups, band, device=device,
                               seed=rng_seed, progress=update, checkpoint=checkpoint, resume=resume,
                               run_key=run_key(scan, config, photos),
                               initial_gains=gains, appearance_weights=appearance_weights)
    timings["train"] = time.perf_counter() - t

    t = time.perf_counter()
    uc = config.uv
    mode = uc.mode if scan.has_uvs else "unwrap"  # an untextured mesh needs an atlas to hold its texture
    photos_px_per_cm = photo_density(photo) if photo is not None else 0.0
    size = config.bake.texture_size or max(output_size(scan, m)[0] for m in range(len(scan.materials)))
    if photo is not None and not scan.is_textured and not config.bake.texture_size:
        # photos hold far more detail than the 1024 atlas given to an untextured mesh; laid out at the size it
        # is baked at (gutters and all): a layout made for a smaller atlas and baked larger wastes its texels
        size = untextured_atlas_size(scan, photos_px_per_cm)
    with reporter.stage(f"UV layout ({mode})") as update:
        plan = plan_uvs(scan, mode, threshold=uc.threshold, texture_size=size, time_budget_s=uc.time_budget_s,
                        chart_unmapped=uc.chart_unmapped, progress=update)
    timings["uv"] = time.perf_counter() - t

    t = time.perf_counter()
    fill = excluded
    if photo is None:
        taught = taught_faces(tv, scan.n_faces)
    else:
        from scantex.photos.training import taught_by_photos

        seen = taught_by_photos(photo.train, scan.n_faces)
        taught = seen | (taught_faces(tv, scan.n_faces) if scan.is_textured else False)
        # the photos teach the holes they see; an untextured scan knows nothing where no photo looked
        fill = (excluded & ~seen) | (~taught if not scan.is_textured else False)
    if photo is not None and fitted is None and not scan.is_textured:
        # nothing but the photos: where none sees the surface, their colours around it (photo_texture)
        colour, bake_report = flat_grey, {"source": "photos"}
    elif photo is None or fitted is None:
        # every hole of the input is filled, in photo mode too, seen by a photo or not: this colour is what the
        # photos' samples fall back to (where they are too few to cover a hole, its black texels showed
        # through: a real apartment's photo mode scored 1.3 dB below its mesh-only mode)
        colour, bake_report = mesh_only_colour(scan, fitted, excluded, taught, charts, device, bake_config, noise)
    else:
        from scantex.atlas.colour import field_colour

        colour = field_colour(scan, fitted, fill, taught, charts + chart_offset, device, detail=config.bake.detail)
        bake_report = {"source": "field"}
    projective_report = None
    photo_scale = 2
    if photo is not None:
        photo_scale, density = photo_atlas_scale(scan, photos_px_per_cm)
        bake_report.update(density)
    photo_fallback = colour
    refines_photos = config.refine.enabled and config.refine.with_photos
    final = final_texture_mode(config.photos.final, len(photo.photos)) if photo is not None else "training"
    remakes = False  # photos.final all: the texture from every photo; the held-out photos score the training one
    final_report = None
    # the photos' colour is baked a chunk per thread (each chunk sampling its photos one after another): 1.3x
    # faster than the photos of one chunk side by side; the refiner, when it wraps the colour, takes one chunk
    # at a time
    workers = 1
    if photo is not None and config.photos.texturing != "field":
        atlas_density = bake_report.get("atlas_px_per_cm", 0.0) * (
            atlas_growth(scan, config.bake.texture_size, photo_scale) if mode == "keep" else photo_scale)
        if not refines_photos:
            workers = min(8, config.threads or os.cpu_count() or 1)
        sampling_threads = 1 if workers > 1 else None  # a chunk's photos one after another, or side by side
        remakes = bool(photo.held_out) and final == "all" and fitted is None and not refines_photos
        if remakes:
            # the texture written is made from every photo; the held-out photos score the one made without them,
            # baked after it (one set of photos in memory at a time) and only where they see the surface
            aligned, held, _ = photo.final or (photo.photos, photo.held_out, [])
            every = dataclasses.replace(photo, photos=aligned, train=[*photo.train, *held], held_out=[])
            colour, final_report = photo_texture(scan, every, None, photo_fallback, config.photos, caster, charts,
                                                 device, atlas_density, threads=sampling_threads)
        else:
            # the training views' maps go as their photos are sampled (nothing else here holds them)
            photo = dataclasses.replace(photo, train=list(photo.train))
            colour, projective_report = photo_texture(scan, photo, fitted, colour, config.photos, caster, charts,
                                                      device, atlas_density, threads=sampling_threads, release=True)
    bake_seconds = time.perf_counter() - t

    refine_report = None
    # mesh-only mode's default bake keeps the input's own texels, levelled: refining them measured a loss
    over_input = photo is None and bake_report["source"] == "input"
    if (config.refine.enabled and (photo is None or refines_photos)
            and (not over_input or config.refine.over_input)):
        from scantex.refine.stage import refine_colour

        t = time.perf_counter()
        device = device or torch_device(config)
        with reporter.stage("refining (ViT)") as update:
            refined = refine_colour(scan, fitted, tv, caster, colour, config.refine, device, update, fill=fill,
                                    charts=charts + chart_offset, seed=rng_seed,
                                    canonical=bake_report["source"] == "field")
            colour, refine_report = refined.colour, refined.report
        timings["refine"] = time.perf_counter() - t

    if photo is None and fitted is None and refine_report is None and bake_report["source"] == "input":
        # the input's own texels, levelled and filled: lookups in numpy and compiled loops, no network, so chunks
        # colour side by side too (the bathroom's 8192^2 atlas: see bench/RESULTS.md)
        workers = min(8, config.threads or os.cpu_count() or 1)

    def bake_and_blend(colour: SurfaceColour, stage: str, workers: int = 1,
                       only: np.ndarray | None = None) -> tuple[Scan, Scan]:
        with reporter.stage(stage) as update:
            target = plan.scan
            # the input's own texels on the input's own layout: its atlas size keeps each texel exactly (twice
            # the size would only resample them); a field or the photos hold detail worth a finer atlas
            if photo is not None:
                scale = photo_scale
            else:
                scale = 1 if mode == "keep" and bake_report["source"] == "input" else 2
            layouts: list = []  # the atlas's texel map and gutter padding, for the seam blending to reuse
            images = bake(target, colour, size=config.bake.texture_size if mode == "keep" else size, scale=scale,
                          chunk=config.bake.chunk, progress=update, layouts=layouts if blends else None,
                          workers=workers, only=only)
        materials = tuple(
            m if img is None else dataclasses.replace(m, image=img, image_name=f"enhanced_{m.name}.png",
                                                      diffuse=(1.0, 1.0, 1.0, m.diffuse[3]))
            for m, img in zip(target.materials, images))
        baked = target.replace(materials=materials, source=None)
        if not blends:
            return baked, baked
        edges = None
        if mode != "keep" and photo is None and bake_report["source"] == "input" and scan.is_textured:
            # the input's texels moved onto a new layout carry the input's seam steps, inside the new charts
            # where the layout's own seams no longer are: those are blended as well
            edges = with_seams_of(seam_edges(baked), seam_edges(scan))
        return baked, blend_seams(baked, band_texels=uc.band_texels, layouts=layouts, edges=edges)

    t = time.perf_counter() - bake_seconds
    baked, enhanced = bake_and_blend(colour, "baking the texture", workers)
    patches = None  # the result's patch measure, when the safety net below has taken it
    if photo is None and bake_report["source"] == "input" and scan.is_textured:
        # never a patch the input does not have: a result that paints them without removing most of the
        # input's seam steps falls back to the input's texels, holes filled and seams blended only (on a new
        # layout, the input's steps are read where the input's seams now lie inside its charts)
        patches = patch_metrics(scan, enhanced, [tv.views.cameras[i] for i in tv.views.test], caster)
        share = patches["enhanced_vs_input"]
        seams_in, seams_out = levelled_seams(scan, baked)
        if share > PATCH_LIMIT and seams_out > (1 - SEAM_GAIN) * seams_in:
            patches = None
            removed = 1 - seams_out / max(seams_in, 1e-9)
            seams = (f"removing only {100 * removed:.0f} % of the input's seam visibility where no crease is"
                     if removed >= 0 else "making the seams more visible, not less")
            safety = {"fallback": "no levelling, no refiner", "patches_before_fallback": round(share, 5),
                      # the steps before seam blending, which both ways blend: the summary's seam visibility
                      # is the result's, after it
                      "why": f"levelling and refining drew patches on {100 * share:.1f} % of the held-out views' "
                             f"pixels while {seams} ({seams_in:.2f} -> {seams_out:.2f} before seam blending)"}
            log.warning("%s: falling back to the input's texels (holes filled, seams blended)", safety["why"])
            colour, bake_report = mesh_only_colour(scan, fitted, excluded, taught, charts, device,
                                                   dataclasses.replace(bake_config, levelling=False), noise)
            if refine_report is not None:  # it ran; its colour is not in the result
                safety["refine_discarded"] = refine_report
            refine_report = None
            baked, enhanced = bake_and_blend(colour, "baking the texture again (fallback)", workers)
            bake_report["safety"] = safety
            if field_skipped is not None:  # the fallback's texels are not levelled
                field_skipped = field_skipped.replace("levelled, ", "", 1)
    if photo is None:  # the input's texels, times their base colour: that colour again, outside the texture
        enhanced = with_base_colours_of(enhanced, scan)
    timings["bake"] = time.perf_counter() - t
    # baked: what made the colour goes (photo mode's photos at their sampling resolution, their depth and feather
    # maps: 0.7 GB of a real apartment's 197 photos, which the measuring would otherwise hold to the end)
    colour = None
    scored = enhanced
    if remakes:
        t_scored = time.perf_counter()
        scored_colour, projective_report = photo_texture(scan, photo, None, photo_fallback, config.photos, caster,
                                                         charts, device, atlas_density, threads=sampling_threads)
        photo = dataclasses.replace(photo, train=[view.sampled() for view in photo.train])
        _, scored = bake_and_blend(scored_colour, "baking without the held-out photos", workers,
                                   only=faces_in_view(scan, photo.held_out))
        del scored_colour
        timings["scored"] = time.perf_counter() - t_scored

    t = time.perf_counter()
    comparisons: dict[str, np.ndarray] = {}
    shown: list[dict[str, np.ndarray]] = []
    with reporter.stage("measuring") as update:
        metrics = measure(scan, enhanced, ground_truth, tv, holes, charts, caster, coverage, fitted, patches,
                          renders=shown)
        if from_vertex_colours:
            metrics["input"]["texture"] = vertex_texture_note(vertex_atlas, blends)
        metrics["seam_visibility"]["before_blending"] = round(seam_visibility(baked), 3)
        metrics["uv"] = {"mode": mode, **plan.report}
        if mode == "keep":  # the kept layout's atlas is baked at its own size, not at the size a new one is made at
            metrics["uv"]["texture_size"] = max((max(m.image.shape[:2]) for m in enhanced.materials
                                                 if m.image is not None), default=size)
        metrics["field"]["train_rays"] = int(tv.valid[tv.views.train].sum())
        metrics["field"]["untaught_faces"] = int((~taught & ~fill).sum())
        if field_skipped is not None:
            metrics["field"]["why"] = field_skipped
        metrics["bake"] = bake_report
        metrics["sampling"] = sampling_report(scan, tv, taught, fill)
        if refine_report is not None:
            metrics["refine"] = refine_report
        if photo is not None:
            sheets: dict = {}
            metrics.update(photo_metrics(scan, scored, ground_truth, photo, ray_counts, holes, caster, sheets))
            metrics["photos"]["texturing"] = projective_report or {"mode": "field"}
            comparisons.update({f"held_out_photo_{i:03d}": im for i, im in sheets.items()})
        update(1, 1)
    timings["metrics"] = time.perf_counter() - t
    if photo is not None and photo.held_out and projective_report is not None and fitted is None:
        metrics["photos"]["final_texture"] = {"photos": len(photo.train), "mode": "training",
                                              "setting": config.photos.final}
        if remakes:
            n = len(photo.train) + len(photo.held_out)
            metrics["photos"]["final_texture"].update(
                photos=n, mode="all", texturing=final_report,
                note=f"the held-out scores are those of the texture made from the {len(photo.train)} training photos "
                     f"(baked where the held-out photos see the surface); the texture written was made from all {n}")
            if photo.final is not None:
                metrics["photos"]["final_texture"]["held_out_pose_corrections"] = [c.to_dict() for c in photo.final[2]]
    metrics["timings_s"] = {k: round(v, 2) for k, v in timings.items()}
    metrics["timings_s"]["total"] = round(sum(timings.values()), 2)
    return EnhanceResult(enhanced, metrics, config, tv, comparisons, input_scan=scan, ground_truth=ground_truth,
                         renders=shown)


def photo_metrics(scan: Scan, enhanced: Scan, ground_truth: Scan | None, photo: PhotoData,
                  ray_counts: tuple[int, int], holes: np.ndarray, caster: RayCaster,
                  images: dict | None = None) -> dict:
    """Photo mode: what the photos gave, and the input and the result scored on the held-out photos
    (and, when known, against the ground truth rendered through the held-out photos' cameras).
    ``ray_counts``: the training photos' usable pixels and the synthetic views' rays.
    ``images`` receives a photo | input | result image per held-out photo."""
    from scantex.photos.training import score_photos

    rejected = {k: sum(v.rejected.get(k, 0) for v in photo.train) for k in ("edge", "grazing", "depth_map", "hidden")}
    out: dict = {"photos": {
        "source": str(photo.photos.source), "format": photo.photos.format, "total": len(photo.photos),
        "train": [int(v.index) for v in photo.train], "held_out": [int(v.index) for v in photo.held_out],
        "size": [photo.train[0].camera.width, photo.train[0].camera.height] if photo.train else None,
        "photo_rays": ray_counts[0], "synthetic_rays": ray_counts[1],
        "rejected_pixels": rejected,
        "pose_refinement": photo.pose_mode,
        "pose_corrections": [c.to_dict() for c in photo.pose_corrections],
        "alignment": alignment_metrics(photo.alignment),
        "left_out": photo.left_out,
        "repeated": photo.repeated,
        "blurred": photo.blurred,
    }}
    from scantex.photos.lens import lens_summary

    undistorted = lens_summary(photo.photos.lenses)
    if undistorted:
        out["photos"]["undistorted"] = undistorted
    if photo.held_out:
        # where the training photos' poses were refined, each held-out photo's pose is aligned too, to each texture
        # on its own, for a second score: the texture's, where the recorded pose's error no longer counts
        out["held_out_photos"] = score_photos({"input": scan, "enhanced": enhanced}, photo.held_out, caster,
                                              images=images, align=photo.pose_mode != "off")
        if ground_truth is not None:
            out["held_out_photos_vs_ground_truth"] = score_views(
                ground_truth, {"input": scan, "enhanced": enhanced}, [v.camera for v in photo.held_out], caster, holes)
    return out


def alignment_metrics(report) -> dict | None:
    """The alignment check's report for metrics.json (``None``: the check was skipped)."""
    if report is None:
        return None
    return {"edge_distance_px": round(report.edge_distance_px, 2), "ratio": round(report.ratio, 3),
            "offset_m": round(report.offset_m, 4), "turn_deg": round(report.turn_deg, 2),
            "displacement": round(report.displacement, 5), "summary": report.summary()}


def held_out_rendered_when_scored(scan: Scan, trains_on_views: bool) -> bool:
    """Whether the held-out views are left for :func:`measure` to render: when nothing trains on the views
    (photo mode without a field), the only use of their input renders is the score, which renders them."""
    return not trains_on_views and scan.is_textured


def fill_held_out(views: ViewSet, scored: list[dict]) -> None:
    """The held-out views of ``views`` that were not rendered take the input's renders as scored (``scored``:
    :func:`scantex.metrics.views.score_views`'s, one dict a held-out view in order, holding ``"input"``)."""
    for i, renders in zip(views.test, scored):
        if views.rendered is not None and not views.rendered[i]:
            views.images[i], views.alpha[i] = renders["input"]
            views.rendered[i] = True


def measure(scan: Scan, enhanced: Scan, ground_truth: Scan | None, tv: TrainingViews, holes: np.ndarray,
            charts: np.ndarray, caster: RayCaster, coverage, fitted, patches: dict | None = None,
            renders: list | None = None) -> dict:
    """The run's metrics: geometry identity always; texture scores on the held-out views. ``patches``: the
    result's :func:`patch_metrics`, when already taken. ``renders``: if given, receives the scored views'
    renders (:func:`scantex.metrics.views.score_views`), for the report. Held-out views of ``tv`` left
    unrendered (``render_training_views``'s ``render_test``) take the input's renders scored here."""
    test_cams = [tv.views.cameras[i] for i in tv.views.test]
    scores: dict = {}
    scored: list[dict] = []
    if ground_truth is not None:
        scores["held_out_vs_ground_truth"] = score_views(ground_truth, {"input": scan, "enhanced": enhanced},
                                                         test_cams, caster, holes, renders=renders,
                                                         reference_name="ground truth", scored=scored)
    elif scan.is_textured:
        # no truth: how faithfully the result reproduces the input where the input has colour
        scores["held_out_vs_input"] = score_views(scan, {"enhanced": enhanced}, test_cams, caster, holes,
                                                  renders=renders, reference_name="input", scored=scored,
                                                  pooled=True)
        if patches is None:  # scored against the input's renders, that is the patch measure: not twice
            patches = patch_summary(scores["held_out_vs_input"]["enhanced"]["per_view"]["patches"])
    fill_held_out(tv.views, scored)
    edges = seam_edges(scan)
    metrics: dict = {
        "geometry": geometry_metrics(scan, enhanced),
        "input": {"vertices": scan.n_vertices, "faces": scan.n_faces, "textured": scan.is_textured,
                  "charts": int(charts.max()) + 1, "hole_faces": int(visible_holes(scan).sum()),
                  "seam_edges": len(edges)},
        "views": {"total": len(tv.views), "train": len(tv.views.train), "test": len(tv.views.test),
                  # photo mode without a field renders the held-out views alone (nothing trains on the others)
                  "rendered": len(tv.views) if tv.views.rendered is None else int(tv.views.rendered.sum()),
                  "coverage": coverage.summary()},
        "field": {"trained": True, "train_seconds": round(fitted.seconds, 2), "steps_run": fitted.steps_run,
                  "steps": len(fitted.losses),
                  "final_loss": float(np.mean(fitted.losses[-50:]))} if fitted is not None else {"trained": False},
        # each texture is measured along its own layout's seams
        "seam_visibility": {"input": round(seam_visibility(scan, edges), 3),
                            "enhanced": round(seam_visibility(enhanced), 3)},
    }
    if scan.is_textured and not _same_layout(scan, enhanced):
        # a new layout's seams are not the input's: the input's seam steps, now inside the new charts, are read
        # there too (the same surface points, through the new layout)
        metrics["seam_visibility"]["enhanced_at_input_seams"] = round(seam_visibility(enhanced, edges), 3)
    metrics.update(scores)
    if scan.is_textured:
        metrics["patches"] = patches if patches is not None else patch_metrics(scan, enhanced, test_cams, caster)
    return metrics


def _same_layout(scan: Scan, other: Scan) -> bool:
    """Whether ``other`` keeps ``scan``'s UV layout (its texture coordinates and their indices)."""
    return ((other.uvs is scan.uvs or np.array_equal(other.uvs, scan.uvs))
            and (other.face_uvs is scan.face_uvs or np.array_equal(other.face_uvs, scan.face_uvs)))


def levelled_seams(scan: Scan, baked: Scan) -> tuple[float, float]:
    """The seam visibility of ``scan`` and of ``baked`` (its texels, levelled, before seam blending; in its layout
    or another) at the seams levelling levels: the input's seams on no crease sharper than
    :data:`~scantex.atlas.levelling.MAX_CREASE_DEG`. A crease's seam joins two surfaces whose colours differ for
    real: counted, it kept a synthetic room's levelling, which removed 58 % of the steps it is for, at 30 % of all
    of them, under :data:`SEAM_GAIN`."""
    edges = seam_edges(scan).smooth(scan.face_normals, MAX_CREASE_DEG)
    return seam_visibility(scan, edges), seam_visibility(baked, edges)


def patch_metrics(scan: Scan, enhanced: Scan, cameras: list[Camera], caster: RayCaster) -> dict:
    """The patch measure of the result against the input at ``cameras`` (see :mod:`scantex.metrics.patches`):
    the share of pixels where the result has a low-frequency edge the input does not. A result that only
    levels exposure smoothly, fills holes and removes noise scores about 0."""
    from scantex.metrics.patches import patch_score

    scores = []
    for cam in cameras:
        shown = render_scans({"before": scan, "after": enhanced}, cam, caster, supersample=2)
        (before, alpha), (after, _) = shown["before"], shown["after"]
        scores.append(patch_score(after, before, alpha >= 0.999))
    return patch_summary(scores)


def patch_summary(scores: list[float]) -> dict:
    """:func:`patch_metrics`'s dict from each view's patch share."""
    from scantex.metrics.patches import SIGMA_SHARE, THRESHOLD

    return {"enhanced_vs_input": round(float(np.mean(scores)), 5) if scores else 0.0,
            "per_view": [round(s, 5) for s in scores], "sigma_share": SIGMA_SHARE, "threshold": THRESHOLD}


def used_texels(scan: Scan) -> int:
    """About how many texels of the input's atlases its faces cover (their UV area in texels)."""
    if not scan.is_textured:
        return 0
    area = uv_areas(scan.triangle_uvs)
    total = 0.0
    for m, material in enumerate(scan.materials):
        if material.image is not None:
            H, W = material.image.shape[:2]
            total += float(area[scan.face_materials == m].sum()) * H * W
    return int(total)


def sampling_report(scan: Scan, tv: TrainingViews, taught: np.ndarray, fill: np.ndarray) -> dict:
    """How densely the training views sample the input: rays per used texel, and the faces they teach."""
    rays = int(tv.valid[tv.views.train].sum())
    texels = used_texels(scan)
    usable = ~fill
    return {"train_rays": rays, "used_input_texels": texels,
            "rays_per_used_texel": round(rays / texels, 4) if texels else None,
            "taught_face_share": round(float(taught[usable].mean()) if usable.any() else 0.0, 4)}
