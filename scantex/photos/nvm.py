"""VisualSfM's N-View Match file (``.nvm``): VisualSfM's reconstruction, which RealityCapture, COLMAP and others
export too.

Conventions (VisualSfM's documentation; the reader of Changchang Wu's bundle adjustment that OpenMVS's
``InterfaceVisualSFM`` uses), and what scantex does with them:

- The header ``NVM_V3``, optionally followed by ``FixedK fx cx fy cy [r]`` (one calibration for every photo), then
  the number of cameras and one line each: ``<photo> <f> <qw qx qy qz> <cx cy cz> <r> 0``: the focal length in
  pixels, the *world-to-camera* rotation as a quaternion, the camera's centre, OpenCV's camera axes (``x_cam = R (X -
  C)``, ``y`` down). ``NVM_V3_R9T`` files hold the rotation's 9 numbers (row by row) and the translation ``t`` instead.
  The points follow (not read); a file of several models is read for its first, with a warning.
- The principal point is the image's centre (``(w - 1) / 2``, ``(h - 1) / 2`` with the top-left pixel's centre at 0,
  as OpenMVS's ``InterfaceVisualSFM`` reads it), or FixedK's.
- ``r``: VisualSfM's radial distortion of the focal-normalised point, an *undistortion*: ``x_u = x_d (1 + r |x_d|^2)``
  (FixedK's ``r`` where it is given and not 0), solved per point when each photo is read where it moves pixels by
  more than ``max_distortion_px`` (:mod:`scantex.photos.lens`).
- The photos are named relative to the file's folder; else looked for by name in ``--images DIR`` or an ``images/``
  folder. Their sizes come from their files.
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from scantex.errors import ScanError
from scantex.photos.conventions import MAX_DISTORTION_PX, check_intrinsics, pinhole_camera, world_to_camera_from
from scantex.photos.files import check_sizes, find_photo, located
from scantex.photos.photoset import Distortion, PhotoSet, image_size
from scantex.views.camera import Camera

log = logging.getLogger(__name__)

FORMAT = "nvm"


def is_nvm(path: Path) -> bool:
    """Whether ``path`` is an N-View Match file (it starts ``NVM_V3``)."""
    try:
        with open(path, "rb") as f:
            return f.read(6) == b"NVM_V3"
    except OSError:
        return False


def nvm_file(folder: Path) -> Path | None:
    """The first ``.nvm`` by name in ``folder`` that is one; ``None`` if none."""
    try:
        return next((p for p in sorted(folder.glob("*.nvm")) if p.is_file() and is_nvm(p)), None)
    except OSError:
        return None


def load_nvm(path: str | Path, *, image_dir: str | Path | None = None,
             max_distortion_px: float = MAX_DISTORTION_PX) -> PhotoSet:
    """Read an N-View Match file (or a folder holding one); conventions in the module docstring. ``image_dir``: where
    the photos are, by name, when they are not where the file says.

    Raises:
        ScanError: not an NVM file, one that ends before its cameras, a camera that is not numbers, a photo not
            found or of another size than its calibration says.
    """
    path = Path(path)
    file = located(path, nvm_file, "no VisualSfM .nvm file in it")
    if not is_nvm(file):
        raise ScanError(file, "not an N-View Match file (it does not start 'NVM_V3')")
    header, _, rest = file.read_text(encoding="utf-8", errors="replace").partition("\n")
    header = header.split()
    r9t = "R9T" in header[0]
    fixed = None
    if len(header) > 1 and header[1] == "FixedK":  # NVM_V3 FixedK fx cx fy cy [r]
        if len(header) not in (6, 7):
            raise ScanError(file, f"its FixedK calibration is not 4 or 5 numbers ({' '.join(header[2:])[:60]})")
        fixed = list(_floats(header[2:], file, "FixedK")) + [0.0]
    words = rest.split()
    at = 0
    n = _count(words, at, file, "camera count")
    at += 1
    per_camera = 1 + 1 + (9 if r9t else 4) + 3 + 2
    if len(words) < at + per_camera * n:
        raise ScanError(file, f"it ends before its {n} cameras do")
    cameras, images, distortions, lenses = [], [], [], []
    warned_focal = False
    for i in range(n):
        fields = words[at:at + per_camera]
        at += per_camera
        name = fields[0]
        what = f"camera {i} ({Path(name).name})"
        values = _floats(fields[1:], file, what)
        f, rotation, centre, r = values[0], values[1:-5], values[-5:-2], values[-2]
        image = find_photo(name if Path(name).is_absolute() else str(file.parent / name), file, what, image_dir)
        w, h = image_size(image)
        if fixed is not None:
            fx, cx, fy, cy = fixed[:4]
            r = fixed[4] or r
            if abs(f - fx) > 1e-6 * fx and not warned_focal:
                log.warning("%s: %s: its focal length %g is not FixedK's fx %g: FixedK's calibration is used", file,
                            what, f, fx)
                warned_focal = True
        else:
            fx = fy = f
            cx, cy = (w - 1) / 2.0, (h - 1) / 2.0
        K = np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
        check_intrinsics(K, w, h, file, what)
        if r9t:
            R = rotation.reshape(3, 3)
            centre = -R.T @ centre  # the file's translation
        else:
            if not np.linalg.norm(rotation) > 0:
                raise ScanError(file, f"{what}: its quaternion is zero")
            q = rotation / np.linalg.norm(rotation)  # w, x, y, z
            R = Rotation.from_quat([q[1], q[2], q[3], q[0]]).as_matrix()
        w2c = world_to_camera_from(R, centre, file, what)
        distortion = Distortion("VisualSfM", (-r,), inverse_radial=(r,)) if r else None
        camera, lens = pinhole_camera(distortion, Camera(K, w2c, w, h), max_distortion_px, file, what)
        cameras.append(camera)
        images.append(image)
        distortions.append(distortion)
        lenses.append(lens)
    if _more_models(words, at, per_camera):
        log.warning("%s holds more than one model: reading the first (%d cameras)", file, n)
    check_sizes(cameras, images, file)
    return PhotoSet(cameras=tuple(cameras), images=tuple(images), source=file, format=FORMAT,
                    distortions=tuple(distortions), lenses=tuple(lenses))


def _floats(words: list[str], file: Path, what: str) -> np.ndarray:
    try:
        values = np.array([float(w) for w in words], np.float64)
    except ValueError:
        raise ScanError(file, f"{what}: not numbers ({' '.join(words)[:60]})") from None
    if not np.isfinite(values).all():
        raise ScanError(file, f"{what}: numbers that are not finite")
    return values


def _count(words: list[str], at: int, file: Path, what: str) -> int:
    if at >= len(words) or not words[at].isdigit() or int(words[at]) < 1:
        raise ScanError(file, f"no {what} where it should be ({' '.join(words[at:at + 2])[:40]!r})")
    return int(words[at])


def _more_models(words: list[str], at: int, per_camera: int) -> bool:
    """Whether another model of cameras and points follows the first's points (VisualSfM ends its file with a model of
    the images it did not register, of no points, or a 0). Only a warning depends on it: any word that is not a
    count where one should be ends the search."""
    def count(k: int) -> int | None:
        return int(words[k]) if k < len(words) and words[k].isdigit() else None

    points = count(at)
    at += 1
    for _ in range(points or 0):  # x y z r g b n, then n measurements of 4 numbers
        measured = count(at + 6)
        if measured is None:
            return False
        at += 7 + 4 * measured
    cameras = count(at)
    if not cameras:
        return False
    return bool(count(at + 1 + per_camera * cameras))


def write_nvm(photos: PhotoSet, out_dir: str | Path) -> Path:
    """Write ``out_dir/scene.nvm`` (``NVM_V3``, no points) with the photos copied beside it as ``photo_000.<ext>``;
    returns its path. A photo undistorted when read is written as stored with its lens where VisualSfM's holds it (its
    own one-term model), else undistorted (a PNG). No points are written (some readers, OpenMVS's
    ``InterfaceVisualSFM`` among them, want a sparse cloud too).

    Raises:
        ValueError: a camera VisualSfM's lines cannot hold (two focal lengths, a skew, or the principal point off the
            image's centre).
    """
    from scantex.io.atomic import atomic_files
    from scantex.photos.bundler import centred
    from scantex.photos.files import write_photo

    photos = photos.as_stored(_holds)
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    lines = ["NVM_V3", "", str(len(photos))]
    with atomic_files() as files:
        for i, cam in enumerate(photos.cameras):
            if not centred(cam):
                raise ValueError(f"photo {i}: VisualSfM's cameras have one focal length, no skew and the principal "
                                 f"point at the image's centre (K {cam.K.tolist()})")
            name = write_photo(files, photos, i, out_dir / f"photo_{i:03d}").name
            x, y, z, w = Rotation.from_matrix(cam.R).as_quat()
            centre = -cam.R.T @ cam.t
            r = _inverse_radial(photos.distortions[i], i)
            lines.append(" ".join([name, repr(float(cam.K[0, 0]))] + [repr(float(v)) for v in (w, x, y, z, *centre)]
                                  + [repr(r), "0"]))
        lines += ["", "0", "", "0", ""]
        files.path(out_dir / "scene.nvm").write_text("\n".join(lines))
    return out_dir / "scene.nvm"


def _inverse_radial(distortion: Distortion | None, i: int) -> float:
    if distortion is None or distortion.is_zero:
        return 0.0
    if not _holds(distortion, None):
        raise ValueError(f"photo {i}: VisualSfM's lens cannot hold a {distortion.model} distortion")
    return float(distortion.inverse_radial[0])


def _holds(distortion: Distortion, cam: Camera | None) -> bool:
    return (len(distortion.inverse_radial) == 1 and not distortion.is_fisheye and not any(distortion.tangential)
            and not distortion.radial_denominator)
