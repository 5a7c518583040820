"""ARKitScenes' captures (Apple's dataset of iPad Pro LiDAR scans of rooms): a video's frames with the ARKit poses
and mesh they were scanned with.

Layout: the video's folder ``<video_id>/`` holds the mesh ``<video_id>_3dod_mesh.ply`` and the frames, in
``<video_id>_frames/`` (the 3DOD subset) or beside the mesh (the raw subset): ``lowres_wide.traj`` and, per stream,
``<stream>/<video_id>_<timestamp>.png`` (or a JPEG) with
``<stream>_intrinsics/<video_id>_<timestamp>.pincam``.

Conventions, and what scantex does with them:

- The stream read is the sharpest there is: ``wide`` (1920x1440, the raw and depth-upsampling subsets), else
  ``vga_wide`` (640x480), else ``lowres_wide`` (256x192, every subset). All three are the wide camera's; the
  ``ultrawide`` camera (another lens, another pose) is not read.
- ``lowres_wide.traj``: a line per pose, ``timestamp ax ay az tx ty tz``, the *world-to-camera* rotation (axis and
  angle in radians, Rodrigues) and translation (metres), OpenCV's camera axes, in the world frame of the mesh:
  scantex's ``world_to_camera`` as it is. A frame takes the pose within 5 ms of its timestamp (as ARKitScenes' own
  loader does); one between two poses at most :data:`MAX_GAP_S` apart takes their interpolation (the centre
  linearly, the rotation by slerp; a raw video's frames do not fall on the poses' times); others are skipped,
  with a warning.
- ``.pincam``: one line, ``width height fx fy cx cy``, ARKit's intrinsics for that frame, the principal point from
  the image's corner (as ARKit measures it, and as scaling it with the image keeps it): scantex's ``cx - 0.5``,
  ``cy - 0.5``. A frame without one (nor one a millisecond off, as ARKitScenes' timestamps are rounded) is
  skipped. The image size is checked against the image file's.
- Depth: ``highres_depth/`` (the laser scan's depth, registered to ``wide``) else ``lowres_depth/`` (the LiDAR's,
  256x192) at the frame's timestamp, uint16 millimetres: the wide camera's view, as its photo's.
- Frames are taken in the order of their timestamps. A stream none of whose frames has a pose and a ``.pincam`` (a
  partial download) gives way to the next, with a warning.
"""

from __future__ import annotations

import logging
import re
from pathlib import Path

import numpy as np

from scantex.errors import ScanError
from scantex.photos.conventions import (
    CORNER_CONVENTION,
    MAX_DISTORTION_PX,
    check_intrinsics,
    check_pose,
    intrinsics,
    pixel_count,
)
from scantex.photos.files import check_sizes, quiet_loadtxt
from scantex.photos.photoset import PhotoSet
from scantex.views.camera import Camera

log = logging.getLogger(__name__)

FORMAT = "arkitscenes"
TRAJECTORY = "lowres_wide.traj"
#: the wide camera's streams, sharpest first
STREAMS = ("wide", "vga_wide", "lowres_wide")
#: depth maps of the wide camera's view, best first
DEPTHS = ("highres_depth", "lowres_depth")
#: a pose within this many seconds of a frame's timestamp is the frame's
SAME_TIME_S = 0.005
#: a frame between two poses at most this many seconds apart takes their interpolation
MAX_GAP_S = 0.25
FRAME = re.compile(r"^(?P<video>.+)_(?P<time>\d+(?:\.\d+)?)\.(?:png|jpe?g)$", re.IGNORECASE)


def capture_folder(path: Path) -> Path | None:
    """The folder holding ``lowres_wide.traj`` that ``path`` is, holds (in a ``<video_id>_frames/``) or lies in,
    else ``None``."""
    path = Path(path)
    if path.is_file():
        path = path.parent
    frames = sorted(path.glob("*_frames")) if path.is_dir() else []
    for folder in (path, *frames, path.parent, path.parent.parent):
        if (folder / TRAJECTORY).is_file() and any((folder / s).is_dir() for s in STREAMS):
            return folder
    return None


def load_arkitscenes(path: str | Path, *, max_distortion_px: float = MAX_DISTORTION_PX) -> PhotoSet:
    """Read an ARKitScenes capture (its video folder, its frames folder or one of its files); conventions in the
    module docstring. ``max_distortion_px`` is accepted for symmetry: ARKit's images are undistorted.

    Raises:
        ScanError: no trajectory and stream, a malformed trajectory or ``.pincam``, no frame with a pose and
            intrinsics.
    """
    folder = capture_folder(Path(path))
    if folder is None:
        raise ScanError(Path(path), f"not an ARKitScenes capture: expected {TRAJECTORY} beside lowres_wide/ (or in "
                                    "<video_id>_frames/)")
    times, poses = _trajectory(folder / TRAJECTORY)
    streams = [s for s in STREAMS if (folder / s).is_dir()]
    tried = []
    for stream in streams:
        frames = sorted(((float(m["time"]), p) for p in (folder / stream).iterdir()
                         if (m := FRAME.match(p.name)) and p.is_file()), key=lambda f: f[0])
        if not frames:
            continue
        cameras, images, depths, no_pose, no_lens = _stream(folder, stream, frames, times, poses)
        if images:
            break
        tried.append(f"none of its {len(frames)} {stream} frames has both a pose in {TRAJECTORY} (within "
                     f"{MAX_GAP_S:g} s) and its .pincam")
    else:
        if tried:
            raise ScanError(folder, "; ".join(tried))
        raise ScanError(folder, f"no frames in {', '.join(s + '/' for s in streams)}: expected "
                                "<video_id>_<timestamp>.png")
    if tried:
        log.warning("%s: %s: reading its %s frames", folder, "; ".join(tried), stream)
    if no_pose:
        log.warning("%s: %d of the %d %s frames lie outside the trajectory's poses (more than %g s from one, or "
                    "in a gap of more than %g s): skipped", folder, no_pose, len(frames), stream, SAME_TIME_S,
                    MAX_GAP_S)
    if no_lens:
        log.warning("%s: %d of the %d %s frames have no .pincam in %s_intrinsics/: skipped", folder, no_lens,
                    len(frames), stream, stream)
    check_sizes(cameras, images, folder)
    return PhotoSet(cameras=tuple(cameras), images=tuple(images), depths=tuple(depths), source=folder, format=FORMAT)


def _stream(folder: Path, stream: str, frames: list, times: np.ndarray, poses: np.ndarray):
    """``(cameras, images, depths, frames without a pose, frames without a .pincam)`` of one stream's frames."""
    cameras, images, depths = [], [], []
    no_pose = no_lens = 0
    for time, image in frames:
        pincam = _pincam_file(folder / f"{stream}_intrinsics", image.stem)
        if pincam is None:
            no_lens += 1
            continue
        w2c = _pose_at(time, times, poses)
        if w2c is None:
            no_pose += 1
            continue
        K, width, height = _read_pincam(pincam)
        cameras.append(Camera(K, check_pose(w2c, folder / TRAJECTORY, f"the pose at {time:.3f} s"), width, height))
        images.append(image)
        depth = next((folder / d / f"{image.stem}.png" for d in DEPTHS if (folder / d / f"{image.stem}.png").is_file()),
                     None)
        depths.append(depth)
    return cameras, images, depths, no_pose, no_lens


def _trajectory(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """``(times (n,), world-to-camera (n, 4, 4))`` of a ``.traj`` file, in time order."""
    from scipy.spatial.transform import Rotation

    try:
        rows = quiet_loadtxt(path, ndmin=2)
    except (OSError, ValueError) as e:
        raise ScanError(path, f"not a trajectory ({str(e).splitlines()[0] if str(e) else type(e).__name__}): "
                              "expected lines of 'timestamp ax ay az tx ty tz'") from None
    if rows.size == 0 or rows.shape[1] != 7:
        raise ScanError(path, f"not a trajectory: {rows.shape[1] if rows.size else 0} numbers a line, expected 7 "
                              "(timestamp, axis-angle rotation, translation)")
    finite = np.isfinite(rows).all(axis=1)
    if not finite.any():
        raise ScanError(path, "the trajectory holds no pose of finite numbers")
    if not finite.all():
        log.warning("%s: %d of its %d poses hold non-finite numbers (tracking lost): left out", path,
                    int((~finite).sum()), len(rows))
        rows = rows[finite]
    rows = rows[np.argsort(rows[:, 0], kind="stable")]
    poses = np.tile(np.eye(4), (len(rows), 1, 1))
    poses[:, :3, :3] = Rotation.from_rotvec(rows[:, 1:4]).as_matrix()
    poses[:, :3, 3] = rows[:, 4:7]
    return rows[:, 0], poses


def _pose_at(time: float, times: np.ndarray, poses: np.ndarray) -> np.ndarray | None:
    """The world-to-camera at ``time``: the pose within :data:`SAME_TIME_S`, else the interpolation of the two
    about it when they are at most :data:`MAX_GAP_S` apart, else ``None``."""
    from scipy.spatial.transform import Rotation, Slerp

    k = int(np.searchsorted(times, time))
    near = [j for j in (k - 1, k) if 0 <= j < len(times)]
    best = min(near, key=lambda j: abs(times[j] - time))
    if abs(times[best] - time) <= SAME_TIME_S:
        return poses[best]
    if not (0 < k < len(times)) or times[k] - times[k - 1] > MAX_GAP_S:
        return None
    a, b = k - 1, k
    s = (time - times[a]) / (times[b] - times[a])
    rotation = Slerp([0.0, 1.0], Rotation.from_matrix(poses[[a, b], :3, :3]))([s]).as_matrix()[0]
    centres = [-poses[j, :3, :3].T @ poses[j, :3, 3] for j in (a, b)]
    centre = (1 - s) * centres[0] + s * centres[1]
    w2c = np.eye(4)
    w2c[:3, :3] = rotation
    w2c[:3, 3] = -rotation @ centre
    return w2c


def _pincam_file(folder: Path, stem: str) -> Path | None:
    """The ``.pincam`` of a frame (or of one a millisecond off: ARKitScenes' timestamps are rounded)."""
    path = folder / f"{stem}.pincam"
    if path.is_file():
        return path
    match = FRAME.match(f"{stem}.png")
    if match is None:
        return None
    for off in (-0.001, 0.001):
        other = folder / f"{match['video']}_{float(match['time']) + off:.3f}.pincam"
        if other.is_file():
            return other
    return None


def _read_pincam(path: Path) -> tuple[np.ndarray, int, int]:
    """``(K, width, height)`` of a ``.pincam`` file."""
    try:
        values = quiet_loadtxt(path, ndmin=1)
    except (OSError, ValueError) as e:
        raise ScanError(path, f"not a .pincam file ({str(e).splitlines()[0] if str(e) else type(e).__name__})"
                        ) from None
    if values.shape != (6,):
        raise ScanError(path, f"not a .pincam file: {values.size} numbers, expected 6 (width height fx fy cx cy)")
    width = pixel_count(values[0], "width", path, "intrinsics")
    height = pixel_count(values[1], "height", path, "intrinsics")
    K = intrinsics(*values[2:6], pixel_centre=CORNER_CONVENTION)
    return K, *check_intrinsics(K, width, height, path, "intrinsics")
