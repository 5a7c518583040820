"""Bundler's ``bundle.out`` (v0.3) with its image list: what RealityCapture, Metashape, VisualSfM, OpenSfM and COLMAP
export for other tools ("Bundler"), Bundler's own output.

Conventions (Bundler's manual, "Output format"), and what scantex does with them:

- ``# Bundle file v0.3``, then ``<cameras> <points>``, then per camera ``f k1 k2``, the rotation ``R`` (3 rows) and
  the translation ``t``; the points follow (not read). A camera of focal length 0 was not registered: skipped, with
  a count.
- Projection: ``P = R X + t``, ``p = -P / P.z``, ``p' = f (1 + k1 |p|^2 + k2 |p|^4) p``, in pixels from the image's
  centre with ``y`` up (the camera looks down its ``-z``, ``y`` up, as OpenGL's): scantex's world-to-camera is ``R``
  and ``t`` with their second and third rows negated, ``fx = fy = f``, the principal point the image's centre (``(w -
  1) / 2``, ``(h - 1) / 2`` with the top-left pixel's centre at 0, as OpenMVS's ``InterfaceVisualSFM`` reads it),
  the lens OpenCV's ``k1, k2``, undone as each photo is read where it moves pixels by more than
  ``max_distortion_px`` (:mod:`scantex.photos.lens`).
- The photos: one per camera, in order, in the image list beside the file (``<name>-list.txt``, ``<name>.txt``,
  ``<name>.lst``, COLMAP's ``<prefix>.list.txt`` beside ``<prefix>.bundle.out``, ``list.rd.txt`` beside Bundler's
  ``bundle.rd.out``, ``list.txt`` or ``image_list.txt``, one line a camera; a line's first word, relative to the
  list's folder, else by name in ``--images DIR`` or an ``images/`` folder); their sizes from their files.
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from scantex.errors import ScanError
from scantex.photos.conventions import MAX_DISTORTION_PX, check_intrinsics, pinhole_camera, world_to_camera_from
from scantex.photos.files import check_sizes, converts, find_photo, located
from scantex.photos.photoset import Distortion, PhotoSet, image_size
from scantex.views.camera import Camera

log = logging.getLogger(__name__)

FORMAT = "bundler"
HEADER = "# Bundle file v0.3"
#: Bundler's camera axes in OpenCV's: x the same, y and z reversed
FLIP = np.diag([1.0, -1.0, -1.0])


def is_bundle(path: Path) -> bool:
    """Whether ``path`` is a Bundler file (its first line ``# Bundle file``)."""
    try:
        with open(path, "rb") as f:
            return f.readline(64).strip().lower().startswith(b"# bundle file")
    except OSError:
        return False


def bundle_file(folder: Path) -> Path | None:
    """The Bundler file in ``folder`` (``bundle.out``, else the first ``.out`` by name that is one); ``None`` if
    none."""
    try:
        found = sorted(p for p in folder.glob("*.out") if p.is_file())
    except OSError:
        return None
    found.sort(key=lambda p: p.name != "bundle.out")
    return next((p for p in found if is_bundle(p)), None)


def list_file(file: Path) -> Path | None:
    """The image list beside a Bundler file (see the module docstring); ``None`` if none."""
    stem = file.name[:-len(file.suffix)] if file.suffix else file.name
    prefix = stem[:-len(".bundle")] if stem.lower().endswith(".bundle") else stem  # COLMAP's <prefix>.bundle.out
    # Bundler's RadialUndistort writes bundle.rd.out (its registered cameras alone) with list.rd.txt
    radial = [f"list{stem[len('bundle'):]}.txt"] if stem.lower().startswith("bundle.") else []
    for name in (f"{stem}-list.txt", f"{stem}.txt", f"{stem}.lst", f"{prefix}.list.txt", *radial, "list.txt",
                 "image_list.txt"):
        if (file.parent / name).is_file():
            return file.parent / name
    return None


def load_bundler(path: str | Path, *, image_dir: str | Path | None = None,
                 max_distortion_px: float = MAX_DISTORTION_PX) -> PhotoSet:
    """Read a Bundler file and its image list (or a folder holding them); conventions in the module docstring.
    ``image_dir``: where the photos are, by name, when they are not where the list says.

    Raises:
        ScanError: not a Bundler file, no image list or one shorter than the cameras, no registered camera, a
            photo not found.
    """
    path = Path(path)
    file = located(path, bundle_file, "no Bundler file (bundle.out) in it")
    if not is_bundle(file):
        raise ScanError(file, f"not a Bundler file (its first line is not '{HEADER}')")
    listed = list_file(file)
    if listed is None:
        raise ScanError(file, "no image list beside it (list.txt, image_list.txt or "
                              f"{file.stem}.txt: one photo a line, in the cameras' order)")
    names = [_listed_name(line, listed.parent) for line in
             listed.read_text(encoding="utf-8-sig", errors="replace").splitlines() if line.strip()]
    numbers = _numbers(file)
    if numbers.size < 2 or numbers[0] != int(numbers[0]) or numbers[0] < 1:
        raise ScanError(file, "no camera count after its header")
    n = int(numbers[0])
    if numbers.size < 2 + 15 * n:
        raise ScanError(file, f"it ends before its {n} cameras do")
    if len(names) != n:  # one line a camera: another count is another reconstruction's list (bundle.rd.out's)
        raise ScanError(listed, f"names {len(names)} photos, {file.name} has {n} cameras (one line a camera)")
    cameras, images, distortions, lenses = [], [], [], []
    unregistered = 0
    for i in range(n):
        values = numbers[2 + 15 * i:2 + 15 * (i + 1)]
        f, k1, k2 = values[:3]
        what = f"camera {i} ({Path(names[i]).name})"
        if f == 0:
            unregistered += 1
            continue
        image = find_photo(names[i] if Path(names[i]).is_absolute() else str(listed.parent / names[i]), file, what,
                           image_dir)
        w, h = image_size(image)
        K = np.array([[f, 0.0, (w - 1) / 2.0], [0.0, f, (h - 1) / 2.0], [0.0, 0.0, 1.0]])
        check_intrinsics(K, w, h, file, what)
        R, t = values[3:12].reshape(3, 3), values[12:15]
        w2c = world_to_camera_from(FLIP @ R, -(FLIP @ R).T @ (FLIP @ t), file, what)
        distortion = Distortion("Bundler", (k1, k2)) if (k1 or k2) else None
        camera, lens = pinhole_camera(distortion, Camera(K, w2c, w, h), max_distortion_px, file, what)
        cameras.append(camera)
        images.append(image)
        distortions.append(distortion)
        lenses.append(lens)
    if unregistered:
        log.warning("%s: %d of its %d cameras were not registered (focal length 0): skipped", file, unregistered, n)
    if not cameras:
        raise ScanError(file, "none of its cameras was registered (all of focal length 0)")
    check_sizes(cameras, images, file)
    return PhotoSet(cameras=tuple(cameras), images=tuple(images), source=file, format=FORMAT,
                    distortions=tuple(distortions), lenses=tuple(lenses))


def _listed_name(line: str, folder: Path) -> str:
    """The photo an image list's line names: ``path [0 focal]``, a path with spaces in it too where it is a file."""
    line = line.strip()
    words = line.split()
    if len(words) >= 3 and all(_is_number(w) for w in words[-2:]) and (folder / line.rsplit(None, 2)[0]).is_file():
        return line.rsplit(None, 2)[0]
    return line if (folder / line).is_file() else words[0]


def _is_number(word: str) -> bool:
    try:
        float(word)
    except ValueError:
        return False
    return True


def _numbers(file: Path) -> np.ndarray:
    """The numbers after the header lines (``#``), as far as the cameras need them: the points are not parsed."""
    values: list[float] = []
    with open(file, encoding="utf-8", errors="replace") as f:
        for line in f:
            if line.lstrip().startswith("#"):
                continue
            try:
                values.extend(float(v) for v in line.split())
            except ValueError:
                raise ScanError(file, f"a line that is not numbers: {line.strip()[:40]!r}") from None
            if len(values) >= 2 and len(values) >= 2 + 15 * values[0]:
                break
    out = np.array(values, np.float64)
    if not np.isfinite(out).all():
        raise ScanError(file, "a camera's numbers are not finite")
    return out


def write_bundler(photos: PhotoSet, out_dir: str | Path) -> Path:
    """Write ``out_dir/bundle.out`` and ``list.txt`` with the photos copied beside them as ``photo_000.<ext>``; returns
    the bundle's path. A photo undistorted when read is written as stored with its lens where Bundler's holds it (two
    radial terms), else undistorted (a PNG). No points are written (some readers, OpenMVS's ``InterfaceVisualSFM``
    among them, want a sparse cloud too).

    Raises:
        ValueError: a camera Bundler cannot hold (two focal lengths, a skew, or the principal point off the image's
            centre).
    """
    from scantex.io.atomic import atomic_files
    from scantex.photos.files import write_photo

    photos = photos.as_stored(_holds)
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    lines, names = [HEADER, f"{len(photos)} 0"], []
    with atomic_files() as files:
        for i, cam in enumerate(photos.cameras):
            if not centred(cam):
                raise ValueError(f"photo {i}: Bundler's cameras have one focal length, no skew and the principal point "
                                 f"at the image's centre (K {cam.K.tolist()})")
            k = _radial(photos.distortions[i], i)
            names.append(write_photo(files, photos, i, out_dir / f"photo_{i:03d}").name)
            R, t = FLIP @ cam.R, FLIP @ cam.t
            lines += [f"{float(cam.K[0, 0])!r} {k[0]!r} {k[1]!r}",
                      *(" ".join(repr(float(v)) for v in row) for row in (*R, t))]
        files.path(out_dir / "list.txt").write_text("\n".join(names) + "\n")
        files.path(out_dir / "bundle.out").write_text("\n".join(lines) + "\n")
    return out_dir / "bundle.out"


def centred(cam: Camera, tolerance: float = 1e-6) -> bool:
    """Whether a camera has one focal length, no skew and its principal point at the image's centre (to
    ``tolerance`` pixels): what Bundler's and VisualSfM's files can say."""
    K = cam.K
    return (K[0, 1] == 0 and abs(K[0, 0] - K[1, 1]) <= 1e-9 * K[0, 0]
            and abs(K[0, 2] - (cam.width - 1) / 2) <= tolerance and abs(K[1, 2] - (cam.height - 1) / 2) <= tolerance)


def _radial(distortion: Distortion | None, i: int) -> tuple[float, float]:
    if distortion is None or distortion.is_zero:
        return 0.0, 0.0
    k = tuple(distortion.radial)
    if (distortion.is_fisheye or distortion.radial_denominator or distortion.inverse_radial or len(k) > 2
            or any(distortion.tangential)):
        raise ValueError(f"photo {i}: Bundler's lens cannot hold a {distortion.model} distortion")
    return (float(k[0]), float(k[1]) if len(k) > 1 else 0.0)


def _holds(distortion: Distortion, cam: Camera) -> bool:
    return converts(lambda: _radial(distortion, 0))
