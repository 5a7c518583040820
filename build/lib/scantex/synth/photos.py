"""Synthetic posed photos of a demo scan: what a capture app keeps besides its mesh, with known truth.

Each photo is an exact render of the scene's true albedo (:func:`scantex.synth.demo.render_ground_truth`)
through a camera that is slightly off the recorded pose, then degraded the way a phone degrades a
photo: its own exposure and white balance (auto-exposure), a little lens blur, sensor noise and JPEG
compression. The recorded poses are the unjittered ones, so a method trained on them has to live with
the same small misregistration a real capture has.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from scantex.photos.photoset import PhotoSet
from scantex.synth.demo import DemoScan, render_ground_truth
from scantex.views.camera import Camera
from scantex.views.raycast import RayCaster


@dataclass(frozen=True)
class PhotoCapture:
    """How the synthetic photos are taken and degraded.

    Attributes:
        n_photos: photos to take (cameras in front of spread-out points of the surface).
        width, height: photo size in pixels.
        fov_deg: horizontal field of view.
        distance: camera-to-surface distance in metres (``None``: the view planner's choice).
        exposure: standard deviation of the per-photo log gain (all channels).
        white_balance: standard deviation of the per-channel log gain on top of it.
        offset: standard deviation of the per-channel black-level offset.
        blur_px: Gaussian lens blur, pixels (sigma).
        noise: Gaussian sensor noise, standard deviation in [0, 1] units.
        jpeg_quality: JPEG quality of the saved photos.
        jitter_deg: standard deviation of the pose's rotation error per axis, degrees (0.2: about 0.3
            degrees in all, as real captures' poses are off).
        jitter_m: standard deviation of the pose's position error per axis, metres (0.006: about 1 cm in
            all; with the rotation, 1-5 px at 640 px and 1.2 m, as measured on real captures).
    """

    n_photos: int = 24
    width: int = 640
    height: int = 480
    fov_deg: float = 55.0
    distance: float | None = 1.2
    exposure: float = 0.15
    white_balance: float = 0.05
    offset: float = 0.02
    blur_px: float = 0.6
    noise: float = 0.015
    jpeg_quality: int = 90
    jitter_deg: float = 0.2
    jitter_m: float = 0.006


def jitter(camera: Camera, rng: np.random.Generator, rotation_deg: float, translation_m: float) -> Camera:
    """``camera`` moved by a small random rotation (about its own centre) and translation."""
    from scipy.spatial.transform import Rotation

    dR = Rotation.from_rotvec(rng.normal(0, np.radians(rotation_deg), 3)).as_matrix()
    R = dR @ camera.R
    centre = camera.center + rng.normal(0, translation_m, 3)
    w2c = np.eye(4)
    w2c[:3, :3] = R
    w2c[:3, 3] = -R @ centre
    return Camera(camera.K, w2c, camera.width, camera.height)


def degrade_photo(image: np.ndarray, rng: np.random.Generator, capture: PhotoCapture) -> np.ndarray:
    """``(H, W, 3) float32`` photo after exposure, white balance, blur and noise (before JPEG)."""
    from scipy import ndimage

    gain = np.exp(rng.normal(0, capture.exposure) + rng.normal(0, capture.white_balance, 3))
    offset = rng.normal(0, capture.offset, 3)
    out = image * gain + offset
    if capture.blur_px > 0:
        out = ndimage.gaussian_filter(out, (capture.blur_px, capture.blur_px, 0))
    out = out + rng.normal(0, capture.noise, out.shape)
    return np.clip(out, 0, 1).astype(np.float32)


def capture_photos(demo: DemoScan, out_dir: str | Path, capture: PhotoCapture = PhotoCapture(), *,
                   seed: int = 0, up=(0.0, 0.0, 1.0)) -> PhotoSet:
    """Take ``capture.n_photos`` degraded photos of ``demo``'s true scene; write them as JPEGs with a
    ``cameras.json`` (the recorded, unjittered poses) into ``out_dir``, and the poses the photos were
    really taken from in ``true_cameras.json`` (``{"cameras": [camera dicts]}``, for measuring pose
    refinement); return the set as read back."""
    import json

    import tempfile

    from PIL import Image

    from scantex.photos.cameras_json import load_cameras_json, write_cameras_json
    from scantex.views.planning import surface_cameras
    from scantex.views.render import to_uint8

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(np.random.SeedSequence([seed, 7]))
    scan = demo.scan
    caster = RayCaster(scan.positions, scan.faces)
    cameras = surface_cameras(scan, capture.n_photos, width=capture.width, height=capture.height,
                              fov_deg=capture.fov_deg, distance=capture.distance, up=up, seed=seed + 1,
                              caster=caster)
    with tempfile.TemporaryDirectory() as tmp:
        paths, truth = [], []
        for i, cam in enumerate(cameras):
            true_pose = jitter(cam, rng, capture.jitter_deg, capture.jitter_m)
            truth.append(true_pose.to_dict())
            image, _ = render_ground_truth(demo, true_pose, supersample=2, caster=caster)
            photo = degrade_photo(image, rng, capture)
            path = Path(tmp) / f"{i:03d}.jpg"
            Image.fromarray(to_uint8(photo)).save(path, quality=capture.jpeg_quality)
            paths.append(path)
        (out_dir / "true_cameras.json").write_text(json.dumps({"cameras": truth}))
        taken = PhotoSet(cameras=tuple(cameras), images=tuple(paths), source=Path(tmp), format="synthetic")
        # the writer copies them next to the file and refers to them by relative name
        return load_cameras_json(write_cameras_json(taken, out_dir))
