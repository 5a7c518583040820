"""The ``scantex`` command line: parses arguments, calls the library, shows progress.

Every subcommand is a thin wrapper over the public API; errors a user can cause are printed as one
line (``scantex: error: FILE: problem``) with a non-zero exit, and a traceback only with ``--debug``.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import logging
import math
import sys
import time
import traceback
from pathlib import Path

from scantex import __version__
from scantex.errors import ScanError

log = logging.getLogger("scantex")


@contextlib.contextmanager
def progress_bar(description: str, quiet: bool = False):
    """A rich progress bar; yields a ``(done, total)`` callback for the library's progress hooks."""
    if quiet:
        yield lambda done, total: None
        return
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn, \
        TimeRemainingColumn

    with Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(),
                  TimeElapsedColumn(), TextColumn("eta"), TimeRemainingColumn(),
                  transient=False, redirect_stdout=False) as bar:
        task = bar.add_task(description, total=None)

        def update(done: int, total: int) -> None:
            bar.update(task, completed=done, total=total)

        yield update


class Parser(argparse.ArgumentParser):
    """argparse with the CLI's one-line error style (``scantex render: error: ...``, exit status 2)."""

    def error(self, message: str):
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def whole(lo: int, hi: int | None = None):
    """An argparse type: a whole number in ``[lo, hi]``."""
    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a whole number, got '{text}'") from None
        if value < lo or (hi is not None and value > hi):
            raise argparse.ArgumentTypeError(f"expected {lo} to {hi}, got {value}" if hi is not None
                                             else f"expected at least {lo}, got {value}")
        return value
    parse.__name__ = "whole number"
    return parse


def real(lo: float, hi: float, *, open_low: bool = False):
    """An argparse type: a finite number in ``[lo, hi]`` (``(lo, hi]`` with ``open_low``)."""
    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a number, got '{text}'") from None
        if not math.isfinite(value) or value < lo or value > hi or (open_low and value == lo):
            raise argparse.ArgumentTypeError(f"expected a finite number {'above' if open_low else 'from'} {lo:g} "
                                             f"up to {hi:g}, got '{text}'")
        return value
    parse.__name__ = "number"
    return parse


SEED = whole(0, 2**32 - 1)


def _echo(args, message: str) -> None:
    if not args.quiet:
        print(message)


def cmd_demo_scan(args) -> int:
    from scantex.io.atomic import atomic_dir
    from scantex.synth import make_app_wall, make_room, make_wall, write_demo

    check_output_early(args.output, args.overwrite)
    steps = 3 if args.photos else 2
    with progress_bar(f"making the {args.variant} demo scan", args.quiet) as update:
        update(0, steps)
        make = {"wall": make_wall, "room": make_room, "app": make_app_wall}[args.variant]
        demo = make(seed=args.seed)
        update(1, steps)
        with atomic_dir(args.output, overwrite=args.overwrite) as tmp:
            write_demo(demo, tmp)
            update(2, steps)
            if args.photos:
                from scantex.synth.photos import PhotoCapture, capture_photos

                capture_photos(demo, tmp / "photos", PhotoCapture(n_photos=args.photos), seed=args.seed,
                               up=(0.0, 0.0, 1.0))
                update(3, steps)
    _echo(args, f"demo scan ({demo.scan.summary()}) written to {args.output}/scan.obj, "
                f"ground truth to {args.output}/ground_truth.obj"
                + (f", {args.photos} posed photos to {args.output}/photos/cameras.json" if args.photos else ""))
    return 0


def check_output_early(output: Path, overwrite: bool) -> None:
    """The checks on an output folder that need no input read: fail before minutes of work."""
    from scantex.errors import OutputExistsError
    from scantex.io.atomic import check_output, check_replaceable

    check_output(output)
    if output.exists() and not output.is_dir():
        raise OutputExistsError(output, "is a file, not a folder: choose another path")
    if output.exists() and not overwrite:
        raise OutputExistsError(output, "already exists (pass --overwrite to replace it)")
    check_replaceable(output)


def cmd_render(args) -> int:
    from scantex.io import load_scan
    from scantex.io.atomic import atomic_dir, check_output
    from scantex.scan import up_axis
    from scantex.views.planning import face_coverage, plan_views
    from scantex.views.raycast import RayCaster
    from scantex.views.viewset import render_views, write_views

    check_output_early(args.output, args.overwrite)
    scan = load_scan(args.mesh)
    check_output(args.output, scan.inputs)
    _echo(args, f"{args.mesh}: {scan.summary()}")
    caster = RayCaster(scan.positions, scan.faces)
    cameras = plan_views(scan, args.views, mode=args.mode, width=args.width, height=args.height,
                         fov_deg=args.fov, seed=args.seed, up=up_axis(scan, args.up), caster=caster)
    coverage = face_coverage(scan, cameras, caster=caster)
    _echo(args, f"{len(cameras)} views planned ({args.mode}); {coverage.summary()}")
    with atomic_dir(args.output, overwrite=args.overwrite, inputs=scan.inputs) as tmp:
        with progress_bar("rendering", args.quiet) as update:
            views = render_views(scan, cameras, lit=not args.unlit, supersample=args.supersample,
                                 seed=args.seed, caster=caster, progress=update)
        write_views(views, tmp)
    _echo(args, f"{len(cameras)} renders and cameras.json written to {args.output}")
    return 0


def cmd_view(args) -> int:
    from scantex.deps import require
    from scantex.inspect.plotly_view import view_html
    from scantex.io import load_scan
    from scantex.io.atomic import check_output

    require("plotly", "scantex view")  # before the (possibly long) load
    if args.output.is_dir():
        raise ScanError(args.output, "is a folder: name the HTML file to write (e.g. -o view.html)")
    scan = load_scan(args.mesh)
    check_output(args.output, scan.inputs)
    out = view_html(scan, args.output, max_faces=args.max_faces)
    _echo(args, f"interactive view of {args.mesh} written to {out}")
    return 0


class BarReporter:
    """Progress bars for the pipeline's stages (see :class:`scantex.pipeline.enhance.Reporter`)."""

    def __init__(self, quiet: bool):
        self.quiet = quiet

    @contextlib.contextmanager
    def stage(self, name: str):
        with progress_bar(name, self.quiet) as update:
            yield update


def _check_device(name: str) -> None:
    """A device that cannot be had is the user's error, said before any work is done. Only ``cuda`` can be
    missing: ``auto`` and ``cpu`` are not checked, so a run that trains nothing never imports torch."""
    if name in ("auto", "cpu"):
        return
    from scantex.field.train import resolve_device

    try:
        resolve_device(name)
    except ValueError as e:
        raise ScanError(None, str(e)) from None


def cmd_enhance(args) -> int:
    from scantex.io.atomic import check_output
    from scantex.io.discover import find_capture
    from scantex.pipeline.config import load_config, preset, validate
    from scantex.pipeline.outputs import work_dir_for

    config = load_config(args.config) if args.config else preset(args.preset)
    if args.diffusion and args.refine is False:
        raise ScanError(None, "--diffusion denoises the refiner's views: it cannot run with --no-refine")
    refine = True if args.diffusion and args.refine is None else args.refine  # diffusion needs the refiner
    config = validate(config.override(seed=args.seed, device=args.device, bake__texture_size=args.texture_size,
                                      train__steps=args.steps, views__n_views=args.views, uv__mode=args.uv,
                                      photos__holdout=args.holdout, photos__refine_poses=args.refine_poses,
                                      photos__final=args.final_texture, photos__detail=args.detail,
                                      refine__enabled=refine, refine__over_input=refine,
                                      photos__check_alignment=False if args.no_alignment_check else None,
                                      photos__blurred=args.blurred,
                                      refine__diffusion=True if args.diffusion else None,
                                      tiling__tiles=None if args.tiles is None else 0 if args.tiles == "auto"
                                      else args.tiles, tiling__max_faces=args.tile_faces,
                                      tiling__overlap=args.tile_overlap, **texture_settings(args)), "the options")
    check_output_early(args.output, args.overwrite)
    check_output(work_dir_for(args.output), role="the work folder")
    _check_device(config.device)
    with find_capture(args.mesh, photos=not args.no_photos and not args.photos) as capture:
        return _enhance_capture(args, config, capture)


def _enhance_capture(args, config, capture) -> int:
    from scantex.io import load_scan
    from scantex.io.atomic import atomic_dir, check_output
    from scantex.pipeline.enhance import enhance
    from scantex.pipeline.outputs import remove_work_dir, usd_input, work_dir_for, write_outputs

    if capture.kind != "file" or capture.photos is not None:
        _echo(args, capture.describe())
    started = time.perf_counter()
    scan = load_scan(capture.mesh)
    truth = load_scan(args.ground_truth) if args.ground_truth else None
    _echo(args, f"{capture.shown(capture.mesh)}: {scan.summary()}")
    photos = None
    photos_path = args.photos or capture.photos
    if photos_path:
        from scantex.photos import load_photos

        photos = load_photos(photos_path, **photo_read_settings(args))
        if capture.extracted is not None:  # named inside the zip in messages and metrics, not where it was unpacked
            photos = dataclasses.replace(photos, source=capture.shown(photos.source))
        _echo(args, f"{capture.shown(photos_path)}: {len(photos)} photos ({photos.format})")
        if (args.refine or args.diffusion) and not config.refine.with_photos:
            log.warning("--%s: photo mode does not run the refiner (it learns from renders of the input texture, "
                        "which the photos outclass: -0.12 dB on the demo wall); refine.with_photos in a --config "
                        "runs it", "diffusion" if args.diffusion else "refine")
    around = {"reading the inputs": time.perf_counter() - started}
    tiles = tile_count(args, scan, photos, config)
    work = work_dir_for(args.output)
    # whatever -o and --overwrite say, no input is replaced or deleted: not by the output, not by the
    # work folder (which is removed at the end)
    inputs = list(scan.inputs) + (list(truth.inputs) if truth else []) + ([args.config] if args.config else [])
    inputs.append(args.mesh)  # the mesh file, or the export's folder or zip as the user named it
    folders = []
    if photos is not None:
        inputs += [*photos.images, *(d for d in photos.depths if d is not None), photos.source]
        for folder in (photos.source, args.photos):  # a folder of photos (as found, or as named by --photos):
            if folder is not None and Path(folder).is_dir():  # an output inside it would mix into the photos
                folders.append(Path(folder))
        # a poses file lists its photos (inputs above): an output beside them, in a folder of its own inside
        # the capture's folder (`cd capture && scantex enhance scan.obj --photos cameras.json -o out`), is
        # none of them and holds none of them
    check_output(args.output, inputs, folders)
    check_output(work, inputs, folders, role="the work folder")
    try:
        work.mkdir(parents=True, exist_ok=True)
        if not args.resume:  # a fresh run: a checkpoint left by an earlier one is not this run's state
            remove_work_dir(work, keep_checkpoint=False, remove_folder=False)
        if tiles > 1:
            from scantex.scale.executors import executor
            from scantex.scale.tiles import enhance_tiled

            _echo(args, f"enhancing in {tiles} overlapping tiles" + (" on Ray" if args.ray else ""))
            result = enhance_tiled(scan, config, dataclasses.replace(config.tiling, tiles=tiles),
                                   ground_truth=truth, photos=photos, runner=executor(args.ray, args.workers),
                                   reporter=BarReporter(args.quiet))
        else:
            if args.ray or args.workers:
                log.warning("--ray and --workers place tiles; this scan is enhanced whole, here (see --tiles)")
            result = enhance(scan, config, ground_truth=truth, photos=photos, work_dir=work, resume=args.resume,
                             reporter=BarReporter(args.quiet))
        started = time.perf_counter()
        with atomic_dir(args.output, overwrite=args.overwrite, inputs=inputs, folders=folders) as tmp:
            written = write_outputs(result, tmp)
        around["writing the outputs"] = time.perf_counter() - started
    except BaseException as e:
        kept = remove_work_dir(work, keep_checkpoint=True)
        if kept is not None and not (isinstance(e, ScanError) and e.path == kept):
            log.warning("kept the checkpoint %s: run the same command with --resume to continue", kept)
        raise
    remove_work_dir(work, keep_checkpoint=False)
    _echo(args, enhance_summary(result.metrics, around))
    for line in (shading_summary(result.input_scan, result.scan), jpeg_summary(written.get("output"))):
        if line:
            _echo(args, line)
    usdz = ", enhanced.usdz" if usd_input(result) else ""
    _echo(args, f"enhanced scan written to {args.output}/enhanced.obj (+ .mtl, textures, enhanced.glb{usdz}, "
                f"metrics.json, config.json, report.html)")
    hint = png_size_hint(result, args.output)
    if hint:
        _echo(args, hint)
    compiled = compiled_note()
    if compiled:
        _echo(args, compiled)
    return 0


def compiled_note() -> str | None:
    """A line for a run that compiled scantex's loops (numba's cache had none of them yet), else ``None``."""
    from scantex import jit

    versions, seconds = jit.compile_seconds()
    if versions == 0 or seconds < 1.0:
        return None
    kept = ("numba keeps them: later runs load them; 'scantex precompile' compiles them all ahead"
            if jit.keeps_cache() else "numba cannot keep them here (NUMBA_CACHE_DIR names a folder it may write)")
    return f"{seconds:.0f} s of this run compiled {versions} of scantex's loops ({kept})"


def tile_count(args, scan, photos, config) -> int:
    """Tiles for this run: ``tiling.tiles`` (``--tiles N``), or automatically (0, ``auto``) one per ``--tile-faces``
    faces (textured scans in the kept UV layout, with photos or without; untextured ones with photos or vertex
    colours, in a layout made for the whole scan; others run whole)."""
    from scantex.pipeline.enhance import has_colour

    auto = config.tiling.tiles == 0
    n = config.tiling.count(scan.n_faces)
    if n <= 1 or (photos is None and not has_colour(scan)):  # nothing to enhance: enhance says so
        return 1
    if not scan.is_textured:  # laid out whole first, for the photos or the vertex colours; else nothing to lay out
        why = None if photos is not None or scan.vertex_colors is not None else \
            "an untextured scan without photos or vertex colours"
    else:
        why = f"--uv {config.uv.mode}" if config.uv.mode != "keep" else None
    if why is None:
        return n
    if auto:
        log.warning("%s: %d faces, but %s cannot be tiled: enhancing it whole", args.mesh, scan.n_faces, why)
        return 1
    raise ScanError(args.mesh, f"--tiles is not supported with {why} (tiles share the input's UV layout)")


def cmd_batch(args) -> int:
    from scantex.pipeline.config import load_config, preset, validate
    from scantex.scale.batch import batch
    from scantex.scale.inputs import collect_inputs

    collect_inputs(args.inputs, exclude=args.output)  # a missing input is reported before any progress bar
    config = load_config(args.config) if args.config else preset(args.preset)
    config = validate(config.override(seed=args.seed, device=args.device, bake__texture_size=args.texture_size,
                                      train__steps=args.steps, views__n_views=args.views, refine__enabled=args.refine,
                                      refine__over_input=args.refine, **texture_settings(args)), "the options")
    _check_device(config.device)
    with progress_bar("enhancing scans", args.quiet) as update:
        result = batch(args.inputs, args.output, config, ray=args.ray, workers=args.workers,
                       cpus_per_scan=args.cpus_per_scan, gpus_per_scan=args.gpus_per_scan, overwrite=args.overwrite,
                       progress=update)
    reused = sum(bool(r.get("reused")) for r in result.records)
    _echo(args, f"{len(result.records)} scans: {len(result.done)} done ({reused} from an earlier run), "
                f"{len(result.failed)} failed, in {result.seconds:.0f} s ({result.executor})")
    for r in result.failed:
        print(f"scantex: {r['name']}: {r['error']}", file=sys.stderr)
    _echo(args, f"summary: {result.index} (+ summary.json, summary.csv)")
    return 1 if result.failed else 0


def shading_summary(before, after) -> str | None:
    """A line on what shades the surface besides its colour (vertex normals, a material's other maps): kept,
    or which maps a new UV layout left out; ``None`` when the input has neither."""
    if before is None:
        return None
    maps, kept = before.map_kinds, after.map_kinds
    parts = ["the vertex normals"] if before.normals is not None and after.normals is not None else []
    if kept:
        parts.append(f"the {' and '.join(k.replace('_', '-') for k in kept)} maps")
    lines = [f"shading kept as it came: {', '.join(parts)}"] if parts else []
    lost = [k.replace("_", "-") for k in maps if k not in kept]
    if lost:
        lines.append(f"shading: the input's {' and '.join(lost)} maps are left out (they are drawn in its UV layout, "
                     "not the new one)")
    return "\n".join(lines) or None


def jpeg_summary(output: dict | None) -> str | None:
    """A line on the JPEG atlases written (``metrics.json``'s ``output``): their codec's loss against the atlas
    the run made; ``None`` for PNG (lossless)."""
    if not output:
        return None
    psnr = list(output["atlas_psnr_db"].values())
    worst = min(psnr)
    figure = "no loss" if worst == float("inf") else f"{worst:.1f} dB PSNR against the lossless atlas" + (
        " (the worst of its materials)" if len(psnr) > 1 else "")
    return f"atlas written as JPEG, quality {output['jpeg_quality']}: {figure}"


def png_size_hint(result, folder: Path) -> str | None:
    """A line when the lossless PNG atlases written in ``folder`` are over twice the size of the input's JPEG
    textures (a capture app's heavily compressed atlas), or ``enhanced.glb`` over twice the input GLB's size:
    ``--texture-format jpeg`` writes smaller files. ``None`` otherwise, and for JPEG outputs."""
    from scantex.io.obj import texture_names

    before = result.input_scan
    if before is None or before.source is None or result.config.output.texture_format != "png":
        return None
    source = Path(before.source)
    if source.suffix.lower() == ".glb":  # its textures are inside it: the files compared whole
        said, what = "enhanced.glb holds its atlas as a lossless PNG:", "the input GLB"
        size_in, written = source.stat().st_size, [Path(folder) / "enhanced.glb"]
    else:
        read = {Path(p).resolve() for p in before.inputs}
        jpegs = {source.parent.resolve() / m.image_name for m in before.materials if m.image_name}
        jpegs = {p for p in jpegs if p in read and p.suffix.lower() in (".jpg", ".jpeg") and p.is_file()}
        said, what = "atlas written losslessly as PNG,", "the input's JPEG"
        size_in = sum(p.stat().st_size for p in jpegs)
        written = [Path(folder) / n for n in texture_names(result.scan, "enhanced") if n]
    if not size_in or not written or not all(p.is_file() for p in written):
        return None
    size_out = sum(p.stat().st_size for p in written)
    if size_out <= 2 * size_in:
        return None
    return (f"{said} {size_out / 1e6:.1f} MB ({what}: {size_in / 1e6:.1f} MB); "
            "--texture-format jpeg writes a smaller one")


def enhance_summary(m: dict, around: dict[str, float] | None = None) -> str:
    """The terminal's summary of an enhance run's metrics; ``around``: seconds spent outside the run (reading the
    inputs, writing the outputs), said beside its time so that the times add up to what the user waited."""
    from scantex.photos.poses import corrections_summary
    from scantex.report.html import (blurred_words, fine_detail, left_out_words, repeated_words, undistorted_words,
                                     untextured_seams_words)

    g, sv = m["geometry"], m["seam_visibility"]
    # an untextured input's seams are 0 by construction: "0.00 -> 1.43" would read as seams made worse
    seams = untextured_seams_words(m) or f"{sv['input']:.2f} -> {sv['enhanced']:.2f}"
    lines = [f"geometry: {'identical' if g['arrays_identical'] else 'CHANGED'} "
             f"({g['vertices'][1]:,} vertices, {g['faces'][1]:,} faces; Hausdorff "
             f"{g['distance']['hausdorff']:.3g}, mean distance {g['distance']['mean']:.3g})",
             f"seam visibility: {seams}"]
    at_input = sv.get("enhanced_at_input_seams")
    if not untextured_seams_words(m) and at_input is not None and round(at_input, 2) != round(sv["enhanced"], 2):
        # a new layout (a kept one differs by a few faces charted apart: the same figure, said once)
        lines[-1] += f" along each layout's own seams; at the input's seams {sv['input']:.2f} -> {at_input:.2f}"
    unmapped = m.get("uv", {}).get("unmapped") or {}
    if unmapped.get("charted"):
        lines.append(f"UV layout: {unmapped['charted']} faces it gave no texture space (every UV corner on one point, "
                     f"or outside the atlas) charted in free atlas space and filled"
                     + (f"; {unmapped['left']} found no free space" if unmapped.get("left") else ""))
    if unmapped.get("wrapped"):
        lines.append(f"UV layout: {unmapped['wrapped']} faces whose UVs lie in one whole tile outside [0, 1] moved "
                     "into the atlas (the texture repeats there: the same texels)")
    if "held_out_vs_ground_truth" in m:
        s = m["held_out_vs_ground_truth"]
        lines.append(f"held-out views vs ground truth: PSNR {s['input']['psnr']:.2f} -> {s['enhanced']['psnr']:.2f} dB, "
                     f"SSIM {s['input']['ssim']:.3f} -> {s['enhanced']['ssim']:.3f}")
        if "hole_psnr" in s["input"]:
            lines.append(f"holes: PSNR {s['input']['hole_psnr']:.2f} -> {s['enhanced']['hole_psnr']:.2f} dB")
    elif "held_out_vs_input" in m:
        s = m["held_out_vs_input"]["enhanced"]
        outside = (f" ({s['psnr_outside_holes']:.2f} dB outside the input's holes, which are filled)"
                   if "psnr_outside_holes" in s else "")
        lines.append(f"held-out views, enhanced vs input renders (fidelity, not quality): PSNR {s['psnr']:.2f} dB"
                     + outside)
    if "held_out_photos" in m:
        s, n = m["held_out_photos"], m["held_out_photos"]["input"].get("photos", 0)
        blind = len(m.get("photos", {}).get("held_out", [])) - n  # held out, but they see none of the mesh
        unseen = f" ({blind} more held out see{'s' if blind == 1 else ''} none of the mesh)" if blind > 0 else ""
        lines.append(f"{n} held-out photo{'' if n == 1 else 's'}{unseen}"
                     f": PSNR {s['input']['psnr']:.2f} -> {s['enhanced']['psnr']:.2f} dB "
                     f"(colour-matched {s['input']['psnr_matched']:.2f} -> {s['enhanced']['psnr_matched']:.2f}), "
                     f"SSIM {s['input']['ssim']:.3f} -> {s['enhanced']['ssim']:.3f}")
        detail, _ = fine_detail(s, m.get("photos", {}).get("texturing", {}))
        if detail:
            lines.append("  fine detail: " + detail)
        if "psnr_aligned" in s["input"] and "psnr_aligned" in s["enhanced"]:
            lines.append(f"  each held-out photo's pose aligned to each texture, as the training photos' were: "
                         f"colour-matched PSNR {s['input']['psnr_aligned']:.2f} -> {s['enhanced']['psnr_aligned']:.2f} "
                         f"dB, SSIM {s['input']['ssim_aligned']:.3f} -> {s['enhanced']['ssim_aligned']:.3f} (the "
                         f"texture's agreement with the photos, without the recorded poses' error)")
        if m.get("input", {}).get("textured", True):
            lines.append("  (held out from the result only: a capture app's input texture was most likely made from "
                         "these photos too, which favours the input)")
        if "held_out_photos_vs_ground_truth" in m:
            s = m["held_out_photos_vs_ground_truth"]
            lines.append(f"held-out photo cameras vs ground truth: PSNR {s['input']['psnr']:.2f} -> "
                         f"{s['enhanced']['psnr']:.2f} dB, SSIM {s['input']['ssim']:.3f} -> "
                         f"{s['enhanced']['ssim']:.3f}")
        final = m.get("photos", {}).get("final_texture", {})
        if final.get("mode") == "all":
            views = ("; the held-out views' score vs ground truth is the texture written"
                     if "held_out_vs_ground_truth" in m else "")
            lines.append(f"texture written: made from all {final['photos']} photos, the held-out ones included (the "
                         f"held-out photos' scores above are the texture made without them{views}; photos.final "
                         f"{final.get('setting', 'all')})")
    if m.get("photos", {}).get("undistorted"):
        lines.append(f"lens: {undistorted_words(m['photos']['undistorted'])}")
    poses = corrections_summary(m.get("photos", {}).get("pose_refinement", "off"),
                                m.get("photos", {}).get("pose_corrections", []))
    if poses:
        lines.append(f"poses: {poses}")
    left_out, blurred, repeated = left_out_words(m), blurred_words(m), repeated_words(m)
    if repeated:
        lines.append(f"keyframes: {repeated}")
    if left_out:
        lines.append(f"photos left out: {left_out}")
    if blurred:
        lines.append(f"blurred photos: {blurred}")
    clipped = (m.get("photos", {}).get("texturing") or {}).get("clipped", {})
    if clipped.get("gave_way"):
        lines.append(f"over-exposed photos: {100 * clipped['clipped'] / max(clipped['samples'], 1):.1f} % of the "
                     f"photos' samples clipped; {100 * clipped['gave_way'] / max(clipped['samples'], 1):.2f} % "
                     f"gave way to photos that saw the surface unclipped (photos.clip_overshoot)")
    if "safety" in m.get("bake", {}):
        lines.append(f"safety fallback: {m['bake']['safety']['why']}; the result keeps the input's texels "
                     f"(holes filled, seams blended)")
    field = m.get("field", {})
    if not field.get("trained", True):
        lines.append(f"field: {field['why']}")
    elif field.get("steps_run", 0) < field.get("steps", 0):
        lines.append(f"field: resumed from its checkpoint: {field['steps'] - field['steps_run']} of its "
                     f"{field['steps']} steps were trained by the interrupted run, {field['steps_run']} by this one")
    lines.append(f"time: {m['timings_s']['total']:.0f} s " + ", ".join(
        f"{k} {v:.0f}" for k, v in m["timings_s"].items() if k != "total")
        + "".join(f"; {k} {v:.0f} s" for k, v in (around or {}).items()))
    return "\n".join(lines)


def cmd_compare(args) -> int:
    from scantex.io import load_scan
    from scantex.metrics.compare import compare, photo_files, summary_lines

    a, b = load_scan(args.a), load_scan(args.b)
    photos = None
    if args.cameras:
        from scantex.photos import load_photos

        photos = load_photos(args.cameras, **photo_read_settings(args))
        _echo(args, f"{args.cameras}: {len(photos)} photos ({photos.format})")
        if not args.no_alignment_check:
            from scantex.photos.alignment import check_alignment

            # scores through cameras described wrongly (intrinsics for another size) mean nothing: said, not
            # refused, since comparing is measuring
            report = check_alignment(a, photos)
            if not report.ok:
                log.warning("%s: %s does not look aligned with these photos (%s): the scores against them may mean "
                            "little; check the cameras (intrinsics for the photos' own size, poses world-to-camera)",
                            args.cameras, args.a, report.problem)
    if args.json:
        from scantex.io.atomic import check_output

        cameras = [args.cameras, *photo_files(photos)] if photos is not None else []
        check_output(args.json, [*a.inputs, *b.inputs, *cameras])
    result = compare(a, b, photos=photos, n_views=args.views, samples=args.samples, seed=args.seed)
    if args.json:
        from scantex.io.atomic import atomic_files
        from scantex.report.html import strict_json

        args.json.parent.mkdir(parents=True, exist_ok=True)
        with atomic_files() as files:
            files.path(args.json).write_text(strict_json(result, indent=2))
    _echo(args, summary_lines(result))
    if args.json:
        _echo(args, f"metrics written to {args.json}")
    return 0


def cmd_info(args) -> int:
    from scantex.io import load_scan
    from scantex.io.discover import find_capture

    with find_capture(args.mesh, photos=not args.photos) as capture:
        if capture.kind != "file" or capture.photos is not None:
            print(capture.describe())
        scan = load_scan(capture.mesh)
        lo, hi = scan.bounds
        print(f"{capture.shown(capture.mesh)}: {scan.summary()}")
        print(f"bounds: {lo.round(4).tolist()} .. {hi.round(4).tolist()} (size {(hi - lo).round(4).tolist()})")
        print(f"surface area: {scan.face_areas.sum():.4g}")
        print(f"colour: {colour_source(scan)}")
        photos_path = args.photos or capture.photos
        if photos_path:
            from scantex.photos import load_photos

            photos = load_photos(photos_path, **photo_read_settings(args))
            for line in photos_summary(photos):
                print(f"{capture.shown(photos_path)}: {line}")
    return 0


def photos_summary(photos) -> list[str]:
    """What ``scantex info`` says of a capture's photos: their number and layout, sizes, lenses, depth maps and
    distortion, as scantex reads them."""
    import numpy as np

    sizes = sorted({(c.width, c.height) for c in photos.cameras}, key=lambda s: -s[0] * s[1])
    fov = [np.degrees(2 * np.arctan(c.width / (2 * c.K[0, 0]))) for c in photos.cameras]
    lines = [f"{len(photos)} photos ({photos.format}), " + ", ".join(f"{w}x{h}" for w, h in sizes[:3])
             + (f" and {len(sizes) - 3} more sizes" if len(sizes) > 3 else ""),
             f"horizontal field of view {min(fov):.1f}" + (f" to {max(fov):.1f}" if max(fov) - min(fov) > 0.05 else "")
             + " degrees"]
    with_depth = [i for i, d in enumerate(photos.depths) if d is not None]
    if with_depth:
        from scantex.photos.photoset import image_size

        w, h = image_size(photos.depths[with_depth[0]], "depth map")
        warped = sum(photos.depth_warps[i] is not None for i in with_depth)
        lines.append(f"depth maps: {len(with_depth)} of {len(photos)} ({w}x{h}"
                     + (f"; {warped} through a lens of their own, resampled into their photos' view" if warped else "")
                     + ")")
    else:
        lines.append("depth maps: none")
    from scantex.photos.lens import lens_summary
    from scantex.report.html import undistorted_words

    undistorted = lens_summary(photos.lenses)
    ignored = sum(d is not None and not d.is_zero for d in photos.distortions) - (undistorted or {}).get("photos", 0)
    if undistorted:
        lines.append("lens distortion: " + undistorted_words(undistorted))
    if ignored:
        lines.append(f"lens distortion: {ignored} photos (small enough to ignore, under --max-distortion)")
    return lines


def colour_source(scan) -> str:
    """What colour ``scan`` carries, for ``scantex info``; and, where none, what enhancing it needs."""
    from scantex.pipeline.enhance import has_colour

    if scan.is_textured:
        return "texture atlas (enhance improves it; with --photos, from the capture's photos)"
    if scan.vertex_colors is not None:
        return "vertex colours (enhance bakes them into a texture first)"
    if scan.face_colors is not None:
        return "face colours"
    if has_colour(scan):
        return "material colours only"
    return "none: enhance needs the capture's posed photos (--photos) to texture it"


def cmd_precompile(args) -> int:
    from scantex.pipeline.precompile import precompile

    with progress_bar("compiling scantex's loops (numba)", args.quiet) as update:
        update(0, 1)
        done = precompile()
        update(1, 1)
    if done is None:
        _echo(args, "numba is not installed: scantex's loops run in numpy, nothing to compile "
                    "(pip install numba for the faster loops)")
    elif not done.cached:
        _echo(args, f"numba cannot keep its cache here (set NUMBA_CACHE_DIR to a writable folder): every run "
                    f"compiles its loops again ({done.seconds:.0f} s now)")
        return 1
    else:
        _echo(args, f"{done.compiled} loop versions compiled and {done.loaded} loaded from numba's cache in "
                    f"{done.seconds:.0f} s: later runs load them all from it")
    return 0


def tiles_arg(text: str):
    if text == "auto":
        return text
    try:
        n = int(text)
    except ValueError:
        n = 0
    if n < 1:
        raise argparse.ArgumentTypeError(f"expected a positive number of tiles or 'auto', got '{text}'")
    return n


def add_texture_options(p) -> None:
    """The options of how the enhanced atlases are written (``output`` in a config)."""
    p.add_argument("--texture-format", choices=("png", "jpeg", "jpg"), default=None,
                   help="file format of the enhanced atlases: png, lossless (default), or jpeg (or jpg): several "
                        "times smaller files (OBJ, GLB and USDZ alike), at a loss the summary measures")
    p.add_argument("--jpeg-quality", type=whole(1, 100), metavar="Q",
                   help="quality of the JPEG atlases, from 1 to 100 (default: 90); alone, it asks for "
                        "--texture-format jpeg")


def texture_settings(args) -> dict:
    """The config overrides of ``--texture-format`` and ``--jpeg-quality``: a quality alone asks for JPEG."""
    if args.texture_format == "png" and args.jpeg_quality is not None:
        raise ScanError(None, "--jpeg-quality is the JPEG atlases' quality: it goes with --texture-format jpeg, "
                              "not png")
    texture_format = {"jpg": "jpeg"}.get(args.texture_format, args.texture_format)
    texture_format = texture_format or ("jpeg" if args.jpeg_quality is not None else None)
    return {"output__texture_format": texture_format, "output__jpeg_quality": args.jpeg_quality}


def add_photo_read_options(p, photos_option: str) -> None:
    """``--max-distortion`` and ``--images``: enhance, compare and info read the photos alike."""
    p.add_argument("--max-distortion", type=real(0, 1e6), default=None, metavar="PX",
                   help=f"with {photos_option}: the largest lens distortion of the photos' camera model scantex "
                        "ignores, in pixels it moves a pixel by (with a warning: it treats the photos as pinhole "
                        "images); stronger distortion is undone when the photos are read (default: 1)")
    p.add_argument("--images", type=Path, default=None, metavar="DIR",
                   help=f"with {photos_option}: the folder holding the photos a COLMAP model, a Metashape XML, a "
                        "Meshroom cameras.sfm, an OpenMVG sfm_data.json, an OpenMVS scene, a Bundler list, a "
                        "VisualSfM .nvm, RealityCapture's .xmp files or an OpenSfM reconstruction name, where it is not beside the camera file (default: looked for there, in "
                        "its images/ folder, and where the format says)")


def photo_read_settings(args) -> dict:
    """:func:`scantex.photos.load_photos`' ``max_distortion_px`` and ``image_dir`` where the options give them."""
    settings = {} if args.max_distortion is None else {"max_distortion_px": args.max_distortion}
    return settings | ({} if args.images is None else {"image_dir": args.images})


def add_executor_options(p, job: str) -> None:
    p.add_argument("--ray", metavar="auto|ADDRESS",
                   help=f"run each {job} as a Ray task declaring its CPUs, GPUs and memory: auto (this machine's "
                        "cluster, started with 'ray start', or else a new local one) or a cluster address "
                        "(needs pip install 'scantex[ray]'; default: a local process pool)")
    p.add_argument("--workers", type=whole(0, 4096), metavar="N",
                   help=f"local pool: {job}s at once (default: the cores, fewer when their estimated memory "
                        "does not fit)")
    if job == "scan":
        p.add_argument("--cpus-per-scan", type=int, metavar="N",
                       help="threads per scan (torch's, the bake's, the photos'), and the CPUs a Ray task declares "
                            "(default: local, the cores shared among the scans running at once; Ray, 1)")
        p.add_argument("--gpus-per-scan", type=float, metavar="N",
                       help="GPUs a Ray task declares (default: 1 with --device cuda, else 0)")


def build_parser() -> argparse.ArgumentParser:
    parser = Parser(
        prog="scantex",
        description="Better textures for LiDAR-scanned meshes; the geometry stays exactly as it was.",
        epilog="Run 'scantex COMMAND --help' for a command's options.")
    parser.add_argument("--version", action="version", version=f"scantex {__version__}")
    common = Parser(add_help=False)
    common.add_argument("--debug", action="store_true", help="show tracebacks and debug logging")
    common.add_argument("-q", "--quiet", action="store_true", help="print only errors")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True, parser_class=Parser)

    p = sub.add_parser("demo-scan", parents=[common], help="write the built-in synthetic demo scan",
                       description="Write a procedural LiDAR-like scan with known ground truth: "
                                   "DIR/scan.obj (degraded atlas: what a capture app gives you) and "
                                   "DIR/ground_truth.obj (same geometry, ground-truth texture).")
    p.add_argument("-o", "--output", type=Path, required=True, metavar="DIR", help="output folder")
    p.add_argument("--variant", choices=["wall", "room", "app"], default="wall",
                   help="wall: a paper-scale brick wall (40k vertices, 79k faces) with a poor 1024² atlas (strong "
                        "exposure jumps, JPEG q50, blur, 3 %% holes); app: the same wall as a good capture app "
                        "delivers it (sharp 4096² atlas, exposure within ±8 %%, JPEG q80, a few small holes); "
                        "room: a small room (default: wall)")
    p.add_argument("--seed", type=SEED, default=0, help="random seed (default: 0)")
    p.add_argument("--photos", type=whole(0, 10_000), default=0, metavar="N",
                   help="also take N synthetic posed photos of the true scene (own exposure, blur, noise, JPEG, "
                        "small pose errors) into DIR/photos, for enhance --photos (default: none)")
    p.add_argument("--overwrite", action="store_true",
                   help="replace DIR if it is an earlier output (scantex wrote it, or it is empty)")
    p.set_defaults(func=cmd_demo_scan)

    p = sub.add_parser("render", parents=[common], help="render views of a mesh (PNG + cameras.json)",
                       description="Plan cameras around the mesh (or in front of the side its normals "
                                   "face, for walls and rooms), ray-cast them with Embree and write "
                                   "view_NNN.png and cameras.json (OpenCV convention).")
    p.add_argument("mesh", type=Path, help="mesh file (OBJ, GLB/GLTF, USDZ, PLY, ...)")
    p.add_argument("-o", "--output", type=Path, required=True, metavar="DIR", help="output folder")
    p.add_argument("--views", type=whole(1, 10_000), default=8, help="number of views (default: 8)")
    p.add_argument("--mode", choices=["auto", "orbit", "hemisphere", "surface"], default="auto",
                   help="camera placement: around a closed object, above it, or in front of an open "
                        "surface; auto picks (default: auto)")
    p.add_argument("--width", type=whole(8, 8192), default=640, help="image width in pixels (default: 640)")
    p.add_argument("--height", type=whole(8, 8192), default=480, help="image height in pixels (default: 480)")
    p.add_argument("--fov", type=real(1, 170), default=60.0,
                   help="horizontal field of view, degrees, 1 to 170 (default: 60)")
    p.add_argument("--up", choices=["auto", "x", "y", "z"], default="auto",
                   help="the scan's up axis; auto: y for GLB/GLTF (the format's rule), z otherwise")
    p.add_argument("--unlit", action="store_true",
                   help="plain texture colour instead of the lit preview (directional light + ambient)")
    p.add_argument("--supersample", type=whole(1, 8), default=2, help="rays per pixel per axis (default: 2)")
    p.add_argument("--seed", type=SEED, default=0,
                   help="random seed for planning the views and their train/test split (default: 0)")
    p.add_argument("--overwrite", action="store_true",
                   help="replace DIR if it is an earlier output (scantex wrote it, or it is empty)")
    p.set_defaults(func=cmd_render)

    p = sub.add_parser("enhance", parents=[common], help="enhance a scan's texture (the main job)",
                       description="Make the scan's texture better and measure how much. Without photos "
                                   "(the paper's setting), the input's own texels are kept: exposure seams "
                                   "levelled, holes filled, UV seams blended (a radiance field and a Vision "
                                   "Transformer refiner are there on request). With the capture's posed "
                                   "photos, each texel is sampled from the photos that see it, brought to one "
                                   "exposure and blended (a room's many photos with the best views' fine detail "
                                   "added; a small capture's poses refined first), and held-out photos "
                                   "score the result. The texture is baked into the scan's own UV layout; vertex "
                                   "positions and faces are written back unchanged.")
    p.add_argument("mesh", type=Path, metavar="PATH",
                   help="the scan: a mesh file (OBJ, GLB/GLTF, USDZ, PLY with UVs, ...), or a capture app's "
                        "export as written (a 3D Scanner App folder, a Polycam zip, ...): its mesh is found, and "
                        "its posed photos are used when it holds them")
    p.add_argument("-o", "--output", type=Path, required=True, metavar="DIR", help="output folder")
    settings = p.add_mutually_exclusive_group()
    settings.add_argument("--preset", choices=["fast", "default", "best"], default="default",
                          help="speed/quality preset: the synthetic views' number and size, and the field's size "
                               "where one is trained (default: default; the 80k-face demo scan takes about 20 s fast, "
                               "30 s default on 2 CPU cores)")
    settings.add_argument("--config", type=Path,
                          help="a config.json from an earlier run, in place of --preset (it names its own)")
    p.add_argument("--texture-size", type=whole(16, 16384),
                   help="output atlas size (default: the input's when its texels are kept, the default bake; 2x the input, at most 8192, for the field bake, and for photo mode when the photos resolve the surface at least twice as finely as the input's texels, else the input's; an untextured mesh with photos: 2048 or 4096, as fine as its photos)")
    p.add_argument("--uv", choices=["keep", "optimize", "unwrap"],
                   help="texture layout: keep the input's (default; faces it gives no texture space, every UV "
                        "corner on one point, get a small chart each in free atlas space), optimize it (flatten "
                        "over-stretched charts again, split those that still stretch, merge neighbours while they "
                        "stay under the stretch threshold; uniform texel density) or unwrap afresh; meshes without "
                        "UVs are unwrapped. A new layout leaves the input's normal, occlusion and other maps out: "
                        "they are drawn in its own")
    p.add_argument("--views", type=whole(2, 10_000),
                   help="number of synthetic views, at least 2: one is held out (preset's by default)")
    p.add_argument("--steps", type=whole(1), help="field training steps (preset's by default)")
    p.add_argument("--device", choices=["auto", "cpu", "cuda"], help="torch device (default: auto)")
    p.add_argument("--seed", type=SEED, help="random seed (default: 0)")
    p.add_argument("--ground-truth", type=Path, metavar="MESH",
                   help="the same geometry with its true texture (synthetic scans): scores held-out views")
    source = p.add_mutually_exclusive_group()
    source.add_argument("--photos", type=Path, metavar="PATH",
                        help="the capture's posed photos: a nerfstudio transforms.json, a COLMAP model (text or "
                             "binary), a 3D Scanner App or Polycam export, a cameras.json, or a folder holding one; "
                             "or ScanNet's exported frames, RGB-D frame files (frame-000000.color.png + .pose.txt: "
                             "Intrinsic3D, a .sens export), an ARKitScenes capture (lowres_wide.traj), an MVE scene "
                             "(views/*.mve), texrecon's scene folder (photos beside .cam files), a Metashape "
                             "cameras .xml, a Meshroom cameras.sfm, an OpenMVG sfm_data.json, an OpenMVS scene.mvs, a "
                             "Bundler bundle.out with its list.txt, a VisualSfM .nvm, photos with RealityCapture's "
                             ".xmp files beside them, or an OpenSfM reconstruction.json (an OpenDroneMap project); "
                             "the texture is then learnt from them (default: the photos PATH's export holds, if any)")
    source.add_argument("--no-photos", action="store_true",
                        help="ignore the posed photos found in PATH's export (mesh-only enhancement)")
    add_photo_read_options(p, "--photos")
    p.add_argument("--holdout", type=real(0, 1e6), metavar="X",
                   help="with --photos: photos held out for scoring, a share (default 0.1) or a count if >= 1")
    p.add_argument("--final-texture", choices=("auto", "training", "all"), default=None,
                   help="with --photos: write the texture the held-out photos scored (training) or the one made "
                        "from every photo (all: one run, both the score and every photo in the texture; the scored "
                        "texture is baked again where they see it); auto (the default): all for fewer than 50 "
                        "photos, else training")
    p.add_argument("--no-alignment-check", action="store_true",
                   help="with --photos: skip the check that the mesh sits where the photos see it (it refuses "
                        "a mesh moved or turned out of the cameras' frame) and the check that each photo shows "
                        "what its camera sees (it leaves out a photo stored upside down or cropped)")
    p.add_argument("--blurred", choices=("auto", "leave-out", "keep", "soften"), default=None,
                   help="with --photos: what becomes of the photos with under 30 %% of the fine detail of the photos "
                        "that see the same surface (shaken or out of focus; named in the summary either way): "
                        "leave-out (a sharper texture, the photos beside them painting what they saw), keep (blended "
                        "in, they soften it), soften (their colour blended with the others', their fine detail left "
                        "to the sharp photos where any sees the surface: sharper than keep), or auto (the default: "
                        "left out when they are a quarter of the training photos or more; in a tiled run, of a tile's)")
    p.add_argument("--refine-poses", choices=("auto", "off", "input", "consensus"), default=None,
                   help="with --photos: refine each training photo's pose photometrically, against the input "
                        "texture or the other photos' consensus (default auto: for fewer than 50 photos, "
                        "against the input texture for a textured scan and the consensus for an untextured "
                        "one; off otherwise)")
    p.add_argument("--detail", choices=("auto", "blend", "balanced", "sharp"), default=None,
                   help="with --photos: the texture's fine detail blended from every photo that sees it (blend: "
                        "the best held-out scores; a room's many photos, registered a few pixels apart, blur into "
                        "one another, each edge in several faint copies), taken from the best views (sharp: "
                        "colour and exposure still from every photo; as sharp as the photos, at a lower held-out "
                        "score), or the best views' at half its contrast (balanced: one clean copy of each edge, "
                        "nearly the blend's score); default auto: balanced for 50 photos or more, blend below")
    p.add_argument("--refine", action=argparse.BooleanOptionalAction, default=None,
                   help="refine views with a Vision Transformer trained self-supervised on the scan's own "
                        "views (masked completion, cross-view consistency, internal super-resolution) and fuse "
                        "them back into the atlas (default: where the bake is the field's colour, +0.35 dB on "
                        "the demo wall; not over the input's own texels, mesh-only mode's default bake, where it "
                        "measured -0.26 dB: --refine asks for it there too)")
    p.add_argument("--diffusion", action="store_true",
                   help="run the refiner (as --refine) and also denoise its refined views with a small "
                        "diffusion model trained on them (SDEdit-style partial noising; off by default: it "
                        "removes detail along with noise on the demo scans)")
    p.add_argument("--resume", action="store_true",
                   help="continue an interrupted run from its field checkpoint in DIR.partial (kept by a run "
                        "that was killed or failed after a checkpoint; refused if it is of another input or "
                        "other settings)")
    p.add_argument("--tiles", type=tiles_arg, metavar="N|auto",
                   help="cut the surface into N overlapping tiles, enhance each as its own job (local processes, "
                        "or Ray tasks with --ray) and fuse them with smooth weights; with --photos, each tile is "
                        "textured from the photos that see it and the held-out photos score the fused result; an "
                        "untextured scan (with --photos, or vertex colours) is laid out whole first; "
                        "auto: one tile per --tile-faces faces (default: auto, or --config's tiling.tiles)")
    p.add_argument("--tile-faces", type=whole(1), metavar="F",
                   help="--tiles auto: the most faces one tile holds (default: 1000000)")
    p.add_argument("--tile-overlap", type=real(0.0, 1.0), metavar="X",
                   help="overlap of neighbouring tiles on each side of a border, share of a tile (default: 0.15)")
    add_executor_options(p, "tile")
    add_texture_options(p)
    p.add_argument("--overwrite", action="store_true",
                   help="replace DIR if it is an earlier output (scantex wrote it, or it is empty; never an "
                        "input: DIR may not be or hold the scan, its textures, the photos or the config)")
    p.set_defaults(func=cmd_enhance)

    p = sub.add_parser("batch", parents=[common], help="enhance many scans: a local process pool or a Ray cluster",
                       description="Enhance every scan of INPUTS with one config into OUTDIR/<name>/ (the files of "
                                   "'scantex enhance'). One scan's failure is recorded and never stops the others; "
                                   "a rerun skips the scans already finished and retries the rest. OUTDIR/index.html, "
                                   "summary.json and summary.csv list every scan with its status, held-out scores, "
                                   "time, peak memory and a link to its report. Exit status 1 if a scan failed.",
                       epilog="Manifests: .json ([{\"mesh\": ..., \"photos\": ..., \"ground_truth\": ..., \"name\": ...}]), "
                              ".csv (a header row with those columns) or .txt (one 'mesh [photos]' per line, quotes "
                              "around a path with spaces); paths relative to the manifest. In a folder, every mesh file "
                              "below it is a scan, and one named ground_truth.* is the ground truth of the scans beside "
                              "it. A scan without photos named is read as 'scantex enhance' reads it: an app's zip, "
                              "the posed photos an app wrote beside its mesh. With --ray, every node must "
                              "see INPUTS and OUTDIR at the same paths (a shared filesystem) and have scantex installed.")
    p.add_argument("inputs", type=Path, nargs="+", metavar="INPUT",
                   help="mesh files, apps' zipped exports, folders of meshes, or manifests (.json, .csv, .txt) "
                        "listing scans and their photos")
    p.add_argument("-o", "--output", type=Path, required=True, metavar="OUTDIR", help="the batch's output folder")
    settings = p.add_mutually_exclusive_group()
    settings.add_argument("--preset", choices=["fast", "default", "best"], default="default",
                          help="speed/quality preset for every scan (default: default)")
    settings.add_argument("--config", type=Path,
                          help="a config.json from an earlier run, in place of --preset (it names its own)")
    p.add_argument("--texture-size", type=whole(16, 16384),
                   help="output atlas size (default: the input's when its texels are kept, the default bake; 2x the "
                        "input, at most 8192, for the field bake and photo mode; an untextured mesh with photos: "
                        "2048 or 4096, as fine as its photos)")
    p.add_argument("--views", type=whole(2, 10_000), help="number of synthetic views (preset's by default)")
    p.add_argument("--steps", type=whole(1), help="field training steps (preset's by default)")
    p.add_argument("--refine", action=argparse.BooleanOptionalAction, default=None,
                   help="the ViT refinement stage (default: where the bake is the field's colour; --refine "
                        "also over the input's own texels)")
    p.add_argument("--device", choices=["auto", "cpu", "cuda"], help="torch device (default: auto)")
    p.add_argument("--seed", type=SEED, help="random seed (default: 0)")
    add_executor_options(p, "scan")
    add_texture_options(p)
    p.add_argument("--overwrite", action="store_true",
                   help="redo the scans finished by an earlier run (and accept a config other than OUTDIR's first)")
    p.set_defaults(func=cmd_batch)

    p = sub.add_parser("view", parents=[common], help="write an interactive 3D view (self-contained HTML)",
                       description="An offline Plotly 3D view of the mesh, coloured from its texture.")
    p.add_argument("mesh", type=Path, help="mesh file")
    p.add_argument("-o", "--output", type=Path, default=Path("view.html"), help="HTML file (default: view.html)")
    p.add_argument("--max-faces", type=whole(1), default=200_000,
                   help="show a random subset of faces above this count (display only; default 200000)")
    p.set_defaults(func=cmd_view)

    p = sub.add_parser("compare", parents=[common], help="geometry and texture metrics between two meshes",
                       description="Measure B against A: vertex/face counts, volume, Hausdorff and mean "
                                   "point-to-mesh distance both ways; seam visibility, texel density and "
                                   "coverage of each atlas; atlas-space PSNR/SSIM over the faces both UV "
                                   "layouts map alike; and render PSNR/SSIM, against photos when --cameras is "
                                   "given, else of B's renders against A's (PSNR of the views' mean squared "
                                   "error, SSIM their mean; against photos as recorded, on the pixels A covers: "
                                   "enhance's held-out score also fits each photo's exposure, so it differs).")
    p.add_argument("a", type=Path, help="the reference mesh (e.g. the input scan, or a ground truth)")
    p.add_argument("b", type=Path, help="the mesh measured against it (e.g. enhanced.obj)")
    p.add_argument("--cameras", type=Path, metavar="PATH",
                   help="the posed photos, read as 'enhance --photos' reads them: a nerfstudio transforms.json, a "
                        "COLMAP model (text or binary), a 3D Scanner App or Polycam export, a cameras.json, or a "
                        "folder holding one, ScanNet's exported frames, RGB-D frame files (frame-000000.color.png "
                        "+ .pose.txt), an ARKitScenes capture, an MVE scene or texrecon's scene folder (photos "
                        "beside .cam files): both meshes' "
                        "renders are scored against the photos, on the pixels A covers (photos that see none of A "
                        "are left out with a warning; none seeing it is an error: A is not in the cameras' frame)")
    add_photo_read_options(p, "--cameras")
    p.add_argument("--no-alignment-check", action="store_true",
                   help="with --cameras: skip the check that A sits where the photos see it (a misfit is warned "
                        "about, not refused)")
    p.add_argument("--views", type=whole(1, 10_000), default=8,
                   help="views planned on A when there are no photos (default: 8)")
    p.add_argument("--samples", type=whole(1, 100_000_000), default=100_000,
                   help="surface points per direction for the distances, besides every vertex (default: 100000)")
    p.add_argument("--seed", type=SEED, default=0, help="random seed for samples and views (default: 0)")
    p.add_argument("--json", type=Path, metavar="FILE", help="also write every metric to this JSON file")
    p.set_defaults(func=cmd_compare)

    p = sub.add_parser("precompile", parents=[common],
                       help="compile scantex's loops once now, not in the first run",
                       description="numba compiles scantex's loops the first time a run calls them and caches "
                                   "them for later runs; on a new machine, or after an update, the first "
                                   "photo-mode run spends about 12 s of its time (2 cores) compiling. This "
                                   "compiles them all now by enhancing a small synthetic wall, mesh-only and "
                                   "with photos; nothing is written but numba's cache (beside the installed "
                                   "package, or in NUMBA_CACHE_DIR).")
    p.set_defaults(func=cmd_precompile)

    p = sub.add_parser("info", parents=[common], help="print what a scan holds (its mesh, and its photos)",
                       description="Print what a scan holds: its mesh's vertices, faces, UVs and materials with "
                                   "their textures, its bounds and surface area, and what colour it carries (what "
                                   "enhance would do with it); and, where the capture holds posed photos (or "
                                   "--photos names them), how scantex reads them: their number and layout, sizes, "
                                   "field of view, depth maps. Reads only; writes nothing.")
    p.add_argument("mesh", type=Path, metavar="PATH",
                   help="a mesh file, or a capture app's export as written (its mesh and photos are found, as "
                        "enhance finds them)")
    p.add_argument("--photos", type=Path, metavar="PATH", help="the capture's posed photos, read as 'enhance "
                                                                "--photos' reads them")
    add_photo_read_options(p, "--photos")
    p.set_defaults(func=cmd_info)
    return parser


#: the command's collector thresholds (Python's: 700, 10, 10): the oldest generation, the whole heap, is collected
#: after 100 collections of the middle one instead of 10. A run's heap is mostly the modules it imports (numba,
#: scipy, plotly), whose objects live until the end: each full collection walked them all for 50 ms, three times
#: in a photo-mode run of the bolster, to free next to nothing (its arrays go by reference count); at 100 that
#: run makes none, and its peak memory is the same
GC_THRESHOLDS = (700, 10, 100)


class Terminated(KeyboardInterrupt):
    """SIGTERM (``kill``, a job scheduler stopping the run): unwound as Ctrl-C is, so that the run's work folder
    ``OUT.partial`` goes (a run killed by SIGTERM left an empty one behind)."""


def stop_on_sigterm() -> None:
    """From now on SIGTERM raises :class:`Terminated` in this process (a tiled run's local pool then stops its
    workers). A process forked from this one ends on SIGTERM as it would have."""
    import os
    import signal

    pid = os.getpid()

    def handler(signum, frame):
        if os.getpid() != pid:
            signal.signal(signum, signal.SIG_DFL)
            os.kill(os.getpid(), signum)
            return
        raise Terminated

    signal.signal(signal.SIGTERM, handler)


def run() -> None:
    """The command's entry point (``scantex``, ``python -m scantex``): :func:`main`, then the process's exit.

    The collector runs its full collections less often (:data:`GC_THRESHOLDS`), and before exiting every object is
    moved out of its reach (``gc.freeze``): the interpreter's shutdown collects the whole heap again as it clears
    each module, and with numba, scipy, trimesh and plotly loaded that took 0.4-0.6 s after the last output was
    written (a photo-mode run of the bolster: 0.5 s of its 10). Nothing is lost: the outputs are written and closed
    by then, and objects are still freed as their last reference goes. :func:`main` itself, which tests and other
    programs call, leaves the collector alone."""
    import gc

    gc.set_threshold(*GC_THRESHOLDS)
    code = main(catch_sigterm=True)
    gc.freeze()
    raise SystemExit(code)


def main(argv: list[str] | None = None, *, catch_sigterm: bool = False) -> int:
    """Run the command ``argv`` names; its exit status. With ``catch_sigterm`` (the command line's own process),
    SIGTERM unwinds the command as Ctrl-C does (:func:`stop_on_sigterm`), except ``batch``'s, which ends outright
    as before: its scans' workers end with it (:func:`scantex.scale.executors.exit_with_parent`)."""
    args = build_parser().parse_args(argv)
    if catch_sigterm and args.func is not cmd_batch:
        stop_on_sigterm()
    logging.basicConfig(level=logging.DEBUG if args.debug else logging.ERROR if args.quiet else logging.WARNING,
                        format="%(levelname)s: %(message)s")
    repeated = None if args.debug else RepeatedWarnings.attach()
    try:
        return run_command(args)
    finally:
        if repeated is not None:
            repeated.detach()


class RepeatedWarnings(logging.Filter):
    """Shows the first :attr:`SHOWN` log records of each kind (a module's message, whatever its values) and
    counts the rest, said in one line at the end: a capture's hundred depth maps in centimetres gave a hundred
    lines of the same warning, each photo's. ``--debug`` shows every one."""

    SHOWN = 3

    def __init__(self):
        super().__init__()
        from collections import Counter

        self.counts: Counter = Counter()
        self.first: dict = {}

    @classmethod
    def attach(cls) -> RepeatedWarnings:
        repeated = cls()
        for handler in logging.getLogger().handlers:
            handler.addFilter(repeated)
        return repeated

    def filter(self, record: logging.LogRecord) -> bool:
        shown = getattr(record, "scantex_shown", None)  # decided by another handler already: counted once
        if shown is None:
            key = (record.name, str(record.msg))
            self.counts[key] += 1
            self.first.setdefault(key, record)
            shown = record.scantex_shown = self.counts[key] <= self.SHOWN
        return shown

    def detach(self) -> None:
        for handler in logging.getLogger().handlers:
            handler.removeFilter(self)
        for key, n in self.counts.items():
            if n > self.SHOWN:
                first = self.first[key]
                words = first.getMessage().split()
                gist = " ".join(words[1:12] if words and words[0].endswith(":") else words[:11])
                print(f"{first.levelname}: {n - self.SHOWN} more like \"{gist} ...\" (--debug shows each)",
                      file=sys.stderr)


def run_command(args) -> int:
    """The parsed command, its errors turned into one line each and an exit status."""
    try:
        return args.func(args)
    except ScanError as e:
        if args.debug:  # the traceback, and the same line and exit status as without --debug
            traceback.print_exc()
        print(f"scantex: error: {e}", file=sys.stderr)
        return 2
    except Terminated:
        print("scantex: terminated", file=sys.stderr)
        return 143
    except KeyboardInterrupt:
        print("scantex: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:
        # the reader of our output went away (`scantex info scan.glb | head -1`): not the input's fault; stdout
        # goes to nothing so that Python's own flush at exit does not complain again
        import os

        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 141
    except ImportError as e:
        from scantex.deps import MissingDependency

        if args.debug or not isinstance(e, MissingDependency):
            raise
        print(f"scantex: error: {e}", file=sys.stderr)  # names the pip install that provides it
        return 1
    except OSError as e:  # the system refused a read or write: a full disk, a read-only folder, a long name
        if args.debug:
            traceback.print_exc()
        where = e.filename or getattr(args, "output", None) or getattr(args, "mesh", None)
        problem = e.strerror or (str(e).strip().splitlines() or [type(e).__name__])[0]
        print(f"scantex: error: {where}: {problem}" if where else f"scantex: error: {problem}", file=sys.stderr)
        return 2
    except Exception as e:  # anything else is a bug: one line, the traceback with --debug
        if args.debug:
            raise
        print(f"scantex: internal error: {type(e).__name__}: {e} (run with --debug for the traceback)",
              file=sys.stderr)
        return 1
