"""Writing an enhance run's outputs into a folder."""

from __future__ import annotations

from pathlib import Path


from scantex.io import save_scan
from scantex.io.images import PNG_COMPRESS_LEVEL
from scantex.pipeline.config import OutputConfig, save_config
from scantex.views.viewset import write_views


#: the files an enhance run keeps in its work folder: the field checkpoint and its temporary
CHECKPOINT, CHECKPOINT_TMP = "field.pt", "field.tmp"


def work_dir_for(output: Path) -> Path:
    """Where an unfinished run keeps its checkpoints (kept for --resume until the run completes)."""
    return output.with_name(output.name + ".partial")


def remove_work_dir(work: Path, keep_checkpoint: bool, remove_folder: bool = True) -> Path | None:
    """Clean up an enhance run's work folder; returns the checkpoint kept, if any.

    Only the files the run writes there are removed, then the folder if it is empty: a failed run
    leaves no ``OUT.partial/`` behind unless it holds a field checkpoint that ``--resume`` continues
    from (``keep_checkpoint``; a kill -9 during training leaves one the same way).
    """
    work = Path(work)
    if not work.is_dir():
        return None  # never made, or a file of the user's that only has the work folder's name
    checkpoint = work / CHECKPOINT
    (work / CHECKPOINT_TMP).unlink(missing_ok=True)
    if keep_checkpoint and checkpoint.is_file():
        return checkpoint
    checkpoint.unlink(missing_ok=True)
    if not remove_folder:
        return None
    try:
        work.rmdir()
    except OSError:
        pass  # missing, or holding files that are not the run's: left as they are
    return None


def write_outputs(result, out_dir: str | Path) -> dict:
    """``enhanced.obj`` (+ MTL, atlases), ``enhanced.glb``, ``enhanced.usdz`` (a USD input's), ``metrics.json``,
    ``config.json``, ``renders/``, ``comparisons/`` (photo mode: held-out photo | input | result, and with
    refined poses a second row aligned to the photo), ``report.html``. The atlases are PNG or JPEG as
    ``result.config.output`` says (a config without it: PNG).

    Returns:
        the metrics written (``metrics.json``): ``result.metrics`` with what :func:`completed_metrics` adds and,
        for JPEG atlases, ``output``: the format, the quality and each JPEG atlas's PSNR against the lossless
        atlas (``atlas_psnr_db``, by material).
    """
    from concurrent.futures import ThreadPoolExecutor

    out_dir = Path(out_dir)
    settings = getattr(getattr(result, "config", None), "output", None) or OutputConfig()
    encoder = settings.encoder()  # the OBJ's atlas and the GLB's embedded one are the same bytes: encoded once
    images = [m for m in result.scan.materials if m.image is not None]
    output = None
    if any(encoder.writes_jpeg(m.image) for m in images):  # the codec's loss, measured before it is reported
        output = {"texture_format": "jpeg", "jpeg_quality": settings.jpeg_quality,
                  "atlas_psnr_db": {m.name: encoder.jpeg_psnr(m.image) for m in images
                                    if encoder.writes_jpeg(m.image)}}
    # on a second core, while the metrics and the report are made: the atlases encoded (zlib releases the
    # interpreter lock), then the OBJ and the GLB written from those bytes (the GLB imports trimesh: the
    # bolster's outputs written in about 0.9 s instead of 1.1)
    with ThreadPoolExecutor(1) as pool:
        writing = [pool.submit(encoder.colour, m.image) for m in images]
        writing += [pool.submit(save_scan, result.scan, out_dir / name, encoder=encoder)
                    for name in ("enhanced.obj", "enhanced.glb")]
        metrics = _write_the_rest(result, out_dir, output)
        for done in writing:
            done.result()
    if usd_input(result):  # a USDZ given, a USDZ back (what iOS opens), beside the OBJ and the GLB
        save_scan(result.scan, out_dir / "enhanced.usdz", encoder=encoder)
    return metrics


def usd_input(result) -> bool:
    """Whether the run's input scan was read from a USD file."""
    from scantex.io import USD_FORMATS

    source = getattr(getattr(result, "input_scan", None), "source", None)
    return source is not None and Path(source).suffix.lower() in USD_FORMATS


def _write_the_rest(result, out_dir: Path, output: dict | None) -> dict:
    """What :func:`write_outputs` writes besides the scan: metrics (with ``output`` when it is not ``None``),
    config, renders, comparisons, report; returns the metrics written."""
    from scantex.report import write_report
    from scantex.report.html import strict_json

    metrics = completed_metrics(result)
    if output is not None:
        metrics["output"] = output
    (out_dir / "metrics.json").write_text(strict_json(metrics, indent=2))
    save_config(result.config, out_dir / "config.json")
    write_views(result.views.views, out_dir / "renders")
    if result.comparisons:
        from PIL import Image

        from scantex.views.render import to_uint8

        (out_dir / "comparisons").mkdir()
        for name, image in result.comparisons.items():
            Image.fromarray(to_uint8(image)).save(out_dir / "comparisons" / f"{name}.png",
                                                  compress_level=PNG_COMPRESS_LEVEL)
    write_report(result, out_dir / "report.html", metrics=metrics)
    return metrics


def completed_metrics(result) -> dict:
    """``result.metrics`` with what the written outputs report besides: the surface distances and volume
    between input and output, and each atlas's own properties (texel density, coverage), when the run
    did not measure them already and knows its input scan. ``result`` is not changed."""
    from scantex.metrics.geometry import geometry_metrics
    from scantex.metrics.texture import texture_summary

    metrics = dict(result.metrics)
    before = getattr(result, "input_scan", None)
    if before is None:
        return metrics
    if "distance" not in metrics.get("geometry", {}):
        metrics["geometry"] = geometry_metrics(before, result.scan)
    if "texture" not in metrics:
        measured = metrics.get("seam_visibility", {})  # the run's own measure of both (a second on a room)
        metrics["texture"] = {name: texture_summary(scan, visibility=measured.get(name))
                              for name, scan in (("input", before), ("enhanced", result.scan))}
    return metrics
