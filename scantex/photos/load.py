"""One entry point for every photo format: :func:`load_photos` finds the layout and calls its importer."""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from scantex.errors import ScanError
from scantex.photos import (
    arkitscenes,
    bundler,
    cameras_json,
    colmap,
    meshroom,
    metashape,
    mve,
    mve_scene,
    nerfstudio,
    nvm,
    openmvg,
    openmvs,
    opensfm,
    polycam,
    realitycapture,
    rgbd_frames,
    scannerapp,
    scannet,
)
from scantex.photos.conventions import MAX_DISTORTION_PX
from scantex.photos.files import load_json
from scantex.photos.photoset import PhotoSet

log = logging.getLogger(__name__)

LAYOUTS = ("transforms.json (nerfstudio), cameras.json (scantex), cameras + images .txt/.bin (COLMAP, "
           "also under sparse/0), keyframes/ (Polycam raw data), frame_*.json (3D Scanner App), color/ + pose/ + "
           "intrinsic/ (ScanNet), frame-*.color.png + .pose.txt (Intrinsic3D, a .sens export), lowres_wide.traj + "
           "lowres_wide/ (ARKitScenes), views/*.mve/meta.ini (MVE), a cameras .xml (Metashape), cameras.sfm "
           "(Meshroom), sfm_data.json (OpenMVG), scene.mvs (OpenMVS), bundle.out + list.txt (Bundler), a .nvm "
           "(VisualSfM), photos beside .xmp files (RealityCapture), reconstruction.json (OpenSfM, OpenDroneMap's "
           "opensfm/) or photos beside .cam files (texrecon)")


def detect_format(path: str | Path) -> tuple[str, Path]:
    """``(format, path to hand to its importer)`` for a file or folder; formats as in
    :attr:`PhotoSet.format` (``"colmap"`` for either COLMAP kind).

    Raises:
        ScanError: the path does not exist or holds none of the known layouts.
    """
    path = Path(path)
    if not path.exists():
        raise ScanError(path, "no such file or folder")
    if path.is_file():
        name = path.name.lower()
        if name in ("cameras.txt", "images.txt", "points3d.txt", "cameras.bin", "images.bin",
                    "points3d.bin"):
            return "colmap", path
        if path.suffix.lower() == ".cam":
            return mve.FORMAT, path.parent
        if ((path.name.lower() == "meta.ini" or path.parent.suffix.lower() == ".mve")
                and mve_scene.views_folder(path) is not None):
            return mve_scene.FORMAT, mve_scene.views_folder(path)
        if path.suffix.lower() in (".txt", ".jpg", ".jpeg", ".png") and scannet.export_folder(path.parent) is not None:
            return scannet.FORMAT, scannet.export_folder(path.parent)
        if path.suffix.lower() in (".txt", ".png", ".jpg", ".jpeg") and rgbd_frames.is_frames_folder(path.parent):
            return rgbd_frames.FORMAT, path.parent
        if (path.suffix.lower() in (".traj", ".pincam", ".png", ".jpg", ".jpeg")
                and arkitscenes.capture_folder(path) is not None):
            return arkitscenes.FORMAT, arkitscenes.capture_folder(path)
        if path.suffix.lower() == ".xml" and metashape.is_cameras_xml(path):
            return metashape.FORMAT, path
        if path.suffix.lower() == ".sfm":
            return meshroom.FORMAT, path
        if path.suffix.lower() == ".mvs":
            return openmvs.FORMAT, path
        if path.suffix.lower() == ".bin" and path.stem.lower().startswith("sfm_data"):
            return openmvg.FORMAT, path
        if path.suffix.lower() == ".out" or bundler.is_bundle(path):
            return bundler.FORMAT, path
        if path.suffix.lower() == ".nvm" or nvm.is_nvm(path):
            return nvm.FORMAT, path
        if path.suffix.lower() == ".xmp" and realitycapture.is_xmp(path):
            return realitycapture.FORMAT, path.parent
        if path.suffix.lower() != ".json":
            raise ScanError(path, f"not a camera file scantex knows: expected {LAYOUTS}")
        if scannerapp.FRAME.match(path.name):
            return scannerapp.FORMAT, path.parent
        if polycam.keyframes_folder(path) is not None:
            return polycam.FORMAT, polycam.keyframes_folder(path)
        doc = load_json(path)
        if cameras_json.is_cameras_json(doc):
            return cameras_json.FORMAT, path
        if opensfm.is_reconstruction(doc):
            return opensfm.FORMAT, path
        if opensfm.is_camera_models(doc):
            raise ScanError(path, opensfm.CAMERA_MODELS_ONLY)
        if openmvg.is_sfm_data(doc):  # before Meshroom's: both hold views and intrinsics
            return openmvg.FORMAT, path
        if meshroom.is_sfm(doc):
            return meshroom.FORMAT, path
        frames = doc.get("frames") if isinstance(doc, dict) else None
        if frames == []:
            raise ScanError(path, "its 'frames' list is empty: no photos")
        if name == "transforms.json" or (isinstance(frames, list) and frames
                                         and isinstance(frames[0], dict) and "transform_matrix" in frames[0]):
            return nerfstudio.FORMAT, path
        raise ScanError(path, f"a JSON file of no known camera layout: expected {LAYOUTS}")
    if (path / "transforms.json").is_file():
        if (path / "cameras.json").is_file():
            log.warning("%s holds transforms.json and cameras.json: reading transforms.json (name the file to "
                        "read the other)", path)
        return nerfstudio.FORMAT, path / "transforms.json"
    if (path / "cameras.json").is_file():
        if not _odm_camera_models(path / "cameras.json"):
            return cameras_json.FORMAT, path / "cameras.json"
        if opensfm.reconstruction_file(path) is None:  # an OpenDroneMap project's is found below
            raise ScanError(path / "cameras.json", opensfm.CAMERA_MODELS_ONLY)
    def whole(found: bool):
        """A finder of a layout that is the folder itself."""
        return lambda folder: folder if found(folder) else None

    # in this order: the first layout found is read, each looked for once
    for fmt, find in (("colmap", colmap.find_model), (polycam.FORMAT, polycam.keyframes_folder),
                      (scannerapp.FORMAT, whole(scannerapp.frame_files)), (scannet.FORMAT, scannet.export_folder),
                      (rgbd_frames.FORMAT, whole(rgbd_frames.is_frames_folder)),
                      (arkitscenes.FORMAT, arkitscenes.capture_folder), (mve_scene.FORMAT, mve_scene.views_folder),
                      (metashape.FORMAT, metashape.cameras_file), (meshroom.FORMAT, meshroom.sfm_file),
                      (openmvs.FORMAT, openmvs.scene_file), (openmvg.FORMAT, openmvg.sfm_data_file),
                      (bundler.FORMAT, bundler.bundle_file), (nvm.FORMAT, nvm.nvm_file),
                      (realitycapture.FORMAT, realitycapture.xmp_folder),
                      (opensfm.FORMAT, opensfm.reconstruction_file),
                      (mve.FORMAT, whole(mve.is_scene_folder)),
                      # OpenMVG's default output: refused, saying how to convert it
                      (openmvg.FORMAT, lambda folder: openmvg.sfm_data_file(folder, ".bin"))):
        found = find(path)
        if found is not None:
            return fmt, found
    raise ScanError(path, f"no posed photos found: expected {LAYOUTS}")


def _odm_camera_models(path: Path) -> bool:
    """Whether a folder's ``cameras.json`` is OpenDroneMap's camera models, not scantex's frames."""
    try:
        return opensfm.is_camera_models(load_json(path))
    except ScanError:
        return False  # scantex's importer says what is wrong with it


#: the formats whose camera files name their photos relative to a folder the user may give (``image_dir``)
IMAGE_DIR_FORMATS = ("colmap", metashape.FORMAT, meshroom.FORMAT, openmvg.FORMAT, openmvs.FORMAT, bundler.FORMAT,
                     nvm.FORMAT, realitycapture.FORMAT, opensfm.FORMAT)


def load_photos(path: str | Path, *, max_distortion_px: float = MAX_DISTORTION_PX,
                image_dir: str | Path | None = None) -> PhotoSet:
    """Read posed photos in any supported format (see :data:`LAYOUTS`), as a :class:`PhotoSet` in
    scantex's camera convention.

    Args:
        path: a camera file (``transforms.json``, ``cameras.json``, ``images.bin``, ``frame_00000.json``,
            ...) or a folder that holds one.
        max_distortion_px: the largest lens distortion (in pixels) ignored with a warning; a stronger
            one is undone when a photo is read (:mod:`scantex.photos.lens`).
        image_dir: the folder holding the photos a COLMAP model, a Metashape XML, a Meshroom ``cameras.sfm``, an
            OpenMVG ``sfm_data.json``, an OpenMVS scene, a Bundler file's list, a VisualSfM ``.nvm``, RealityCapture's
            XMPs or an OpenSfM reconstruction name, where they are elsewhere than the formats look (the photo-taking
            folder of a Metashape project); other formats name their photos' files themselves (a warning says it is
            not used).

    Raises:
        ScanError: one line naming the file: missing path, unknown layout, missing images, malformed
            JSON or binary, non-finite poses, unsupported camera models.
    """
    fmt, target = detect_format(path)
    loaders = {nerfstudio.FORMAT: nerfstudio.load_nerfstudio, "colmap": colmap.load_colmap,
               cameras_json.FORMAT: cameras_json.load_cameras_json, polycam.FORMAT: polycam.load_polycam,
               scannerapp.FORMAT: scannerapp.load_3dscannerapp, mve.FORMAT: mve.load_mve,
               scannet.FORMAT: scannet.load_scannet, rgbd_frames.FORMAT: rgbd_frames.load_rgbd_frames,
               arkitscenes.FORMAT: arkitscenes.load_arkitscenes, mve_scene.FORMAT: mve_scene.load_mve_scene,
               metashape.FORMAT: metashape.load_metashape, meshroom.FORMAT: meshroom.load_meshroom,
               openmvs.FORMAT: openmvs.load_openmvs, openmvg.FORMAT: openmvg.load_openmvg,
               bundler.FORMAT: bundler.load_bundler, nvm.FORMAT: nvm.load_nvm,
               realitycapture.FORMAT: realitycapture.load_realitycapture, opensfm.FORMAT: opensfm.load_opensfm}
    options = {"max_distortion_px": max_distortion_px}
    if image_dir is not None:
        if not Path(image_dir).is_dir():
            raise ScanError(Path(image_dir), "no such folder (the photos' folder)")
        if fmt in IMAGE_DIR_FORMATS:
            options["image_dir"] = image_dir
        else:
            log.warning("%s: %s cameras name their photos' files themselves: the photos' folder %s is not used",
                        target, fmt, image_dir)
    return without_repeats(loaders[fmt](target, **options))


def without_repeats(photos: PhotoSet) -> PhotoSet:
    """``photos`` less the frames that name a photo file an earlier frame names (a camera file listing a frame
    twice), with a warning. A repeated photo adds nothing to the texture, and one of its copies held out for
    the score would be scored on a photo the texture was made from."""
    first: dict[Path, int] = {}
    keep: list[int] = []
    for i, image in enumerate(photos.images):
        key = image.resolve()
        if key not in first:
            first[key] = i
            keep.append(i)
    if len(keep) == len(photos):
        return photos
    repeated = sorted(set(range(len(photos))) - set(keep))
    # a copy at another pose is no copy: the file list or the poses are wrong, and the first frame's pose may be
    # the wrong one (the photos' own check leaves the photo out if so)
    moved = [i for i in repeated if not np.allclose(photos.cameras[i].world_to_camera,
                                                    photos.cameras[first[photos.images[i].resolve()]].world_to_camera,
                                                    atol=1e-6)]
    log.warning("%s: %d frames name a photo an earlier frame names (e.g. %s)%s: each photo is used once, at its "
                "first frame's pose", photos.source, len(repeated), photos.images[repeated[0]].name,
                f", {len(moved)} of them at another pose" if moved else "")
    return photos.subset(keep)
