"""Per-photo pose refinement: small 6-DoF and focal corrections that make each photo agree with the mesh.

Real captures' recorded poses are off by 1-5 px (tracking drift, rolling shutter, a LiDAR frame a few
milliseconds from the colour frame). A texture sampled or fitted through such poses is blurred and
ghosted by exactly that much. Each photo's pose is refined by *direct photometric alignment* against a
reference colour of the surface (the input texture, which is in the mesh's frame):

- the mesh is ray cast once through the recorded camera at a working size; the surface points of
  usable pixels (clean hits, not grazing, away from contours), weighted towards pixels with texture
  gradient, and their reference colours ``c(X)`` are fixed;
- the photo is sampled where each point projects under a perturbed camera ``x' = dR (R X + t) + dt``,
  ``f' = f (1 + df)`` (rotation about the camera centre, translation in camera coordinates scaled by the
  median depth, a focal scale): residual ``photo(pi(X)) - (a c(X) + b)`` per channel, the gain ``a`` and
  offset ``b`` (the photo's exposure) re-fitted in closed form at every evaluation;
- robust least squares (soft-L1), coarse to fine over blurred copies of the photo (sigma 3, then 1 working
  pixel), a step kept only when the sharp photo agrees better.

The correction is reported per photo (rotation in degrees, translation in metres, focal scale, the
photometric error before and after), and photos whose correction is implausibly large (more than
``max_rotation_deg`` or ``max_translation`` of the depth), or smaller than the alignment's precision (it moves
the photo by less than ``min_shift_px`` working pixels on average), keep their recorded pose.
"""

from __future__ import annotations

import dataclasses
import logging
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from scantex.photos.photoset import PhotoSet
from scantex.scan import Scan
from scantex.views.camera import Camera

log = logging.getLogger(__name__)

#: typical size of each correction parameter (rotation vector in radians: 0.5 degrees; translation as a
#: share of the depth: 1 %; focal change: 1 %), the unit of the prior towards the recorded pose
PRIOR_SCALE = np.array([np.radians(0.5)] * 3 + [0.01] * 3 + [0.01])

#: ``colour(face_ids (n,), bary (n, 2)) -> (n, 3)`` reference colour of surface points
Reference = Callable[[np.ndarray, np.ndarray], np.ndarray]


#: the pose fit's step tolerance (scipy's ``xtol``: it stops at a step under ``xtol * (xtol + |x|)``)
POSE_XTOL = 1e-2


@dataclass(frozen=True)
class PoseSettings:
    """How poses are refined."""

    max_side: int = 480
    """longer image side the alignment runs at"""
    n_points: int = 3000
    """surface points per photo"""
    coarse_points: int = 1000
    """of which the coarse level (the photo blurred) fits the first (a random sample of them all)"""
    max_rotation_deg: float = 3.0
    """a larger correction is implausible: the recorded pose is kept"""
    max_translation: float = 0.05
    """the same for the translation, as a share of the median depth"""
    refine_focal: bool = True
    """also correct the focal length (a scale)"""
    search_px: int = 16
    """the widest whole-image shift (working pixels) searched for a start nearer than the recorded pose"""
    min_shift_px: float = 0.5
    """a correction that moves the photo's surface points by less than this on average (working pixels) is
    not applied: below the alignment's own precision, it only adds noise to a pose that was already right"""


@dataclass(frozen=True)
class PoseCorrection:
    """One photo's refined pose.

    Attributes:
        index: the photo's index in its :class:`PhotoSet`.
        camera: the refined camera at the photo's full size.
        rotation_deg: angle of the rotation correction.
        translation_m: length of the camera centre's move.
        focal_scale: refined focal / recorded focal.
        error_before, error_after: robust photometric error (mean soft-L1 of the residuals, [0, 1] colour
            units) at the recorded and the refined pose, on the sharp photo.
        applied: False when the correction was rejected as implausible, not an improvement, or under
            ``PoseSettings.min_shift_px``.
        shift_px: how far the best correction found moves the photo's surface points, on average, in working
            pixels (applied or not: a correction under half a pixel is kept out by it).
    """

    index: int
    camera: Camera
    rotation_deg: float
    translation_m: float
    focal_scale: float
    error_before: float
    error_after: float
    applied: bool
    shift_px: float = 0.0

    def to_dict(self) -> dict:
        return {"photo": self.index, "rotation_deg": round(float(self.rotation_deg), 3),
                "translation_mm": round(1000 * float(self.translation_m), 2),
                "focal_scale": round(float(self.focal_scale), 5),
                "error_before": round(float(self.error_before), 5), "error_after": round(float(self.error_after), 5),
                "applied": self.applied, "shift_px": round(float(self.shift_px), 3)}


def corrections_summary(mode: str, corrections: list[dict]) -> str | None:
    """One line on a run's pose refinement (``mode``: ``photos.refine_poses`` as applied; ``corrections``: the
    :meth:`PoseCorrection.to_dict` of each training photo, as in ``metrics.json``), or ``None`` when the poses
    were not refined."""
    if mode == "off" or not corrections:
        return None
    moved = [c for c in corrections if c["applied"]]
    against = {"input": "the input texture", "consensus": "the other photos' consensus"}.get(mode, mode)
    text = f"{len(moved)} of {len(corrections)} training photos aligned to {against}"
    if moved:
        rotation = float(np.median([c["rotation_deg"] for c in moved]))
        text += f" (median {rotation:.2f} deg, {float(np.median([c['translation_mm'] for c in moved])):.0f} mm)"
    if len(moved) < len(corrections):
        text += f", {len(corrections) - len(moved)} kept as recorded"
    return text + "; each correction in metrics.json (photos.pose_corrections)"


def perturbed_camera(camera: Camera, x: np.ndarray, depth_scale: float) -> Camera:
    """``camera`` with the correction ``x = (rotvec (3), translation / depth_scale (3), focal change)``
    applied: ``x_cam' = dR x_cam + dt``, ``f' = f (1 + df)`` (principal point kept)."""
    from scipy.spatial.transform import Rotation

    dR = Rotation.from_rotvec(x[:3]).as_matrix()
    w2c = camera.world_to_camera.copy()
    w2c[:3, :3] = dR @ camera.R
    w2c[:3, 3] = dR @ camera.t + x[3:6] * depth_scale
    K = camera.K.copy()
    K[0, 0] *= 1 + x[6]
    K[1, 1] *= 1 + x[6]
    K[0, 1] *= 1 + x[6]
    return Camera(K, w2c, camera.width, camera.height)


def refine_pose(scan: Scan, photos: PhotoSet, i: int, reference: Reference, caster,
                settings: PoseSettings = PoseSettings(), faces: np.ndarray | None = None) -> PoseCorrection:
    """Refine photo ``i``'s pose against ``reference`` (see the module docstring); only surface points on
    ``faces`` (``(F,) bool``, default all) are used."""
    return align_camera(scan, photos.cameras[i], photos.load_image(i), reference, caster, settings, faces, i)


def align_camera(scan: Scan, recorded: Camera, image: np.ndarray, reference: Reference, caster,
                 settings: PoseSettings = PoseSettings(), faces: np.ndarray | None = None,
                 index: int = 0) -> PoseCorrection:
    """The pose correction that makes ``image`` (``(H, W, 3)`` uint8, or float in [0, 1], at ``recorded``'s
    size) agree best with ``reference`` seen through the camera (see the module docstring); ``index``
    names the photo in the result and seeds its point sample."""
    from scipy import ndimage
    from scipy.optimize import least_squares

    from scantex.io.images import box_downscaled
    from scantex.photos.alignment import contour_map
    from scantex.photos.training import working_camera
    from scantex.views.raycast import cast_gbuffer

    cam = working_camera(recorded, settings.max_side)
    photo = np.asarray(image)
    if photo.dtype != np.uint8:
        photo = np.clip(np.round(photo * 255), 0, 255).astype(np.uint8)
    if (cam.width, cam.height) != (recorded.width, recorded.height):
        photo = box_downscaled(photo, cam.width, cam.height)
    photo = photo.astype(np.float32) / 255.0

    g = cast_gbuffer(caster, cam, scan.face_normals)
    mask = g.mask
    usable = ndimage.binary_erosion(mask, iterations=3) & ~ndimage.binary_dilation(
        contour_map(mask, g.depth), iterations=3)
    usable &= cam.ray_cosines(g.normal) > 0.3
    if faces is not None:
        usable &= faces[np.where(mask, g.face_id, 0)]
    ys, xs = np.nonzero(usable)
    identity = PoseCorrection(index, recorded, 0.0, 0.0, 1.0, float("nan"), float("nan"), False)
    if ys.size < 200:
        return identity
    fid, bary = g.face_id[ys, xs], g.bary[ys, xs]
    ref = np.asarray(reference(fid, bary), np.float32)
    seen = _rgb_to_grey_image(ref, ys, xs, mask.shape)  # the reference through the recorded camera
    # favour textured pixels (they carry the pose), keep some flat ones (they carry the exposure)
    grad = np.hypot(*np.gradient(ndimage.gaussian_filter(seen, 1.0)))
    strength = grad[ys, xs] + 1e-3
    rng = np.random.default_rng(index)
    n = min(settings.n_points, ys.size)
    pick = rng.choice(ys.size, n, replace=False, p=strength / strength.sum())
    points = g.points(scan.positions, scan.faces)[ys[pick], xs[pick]]
    ref = ref[pick]
    depth_scale = float(np.median(g.depth[ys, xs]))
    levels = {s: np.stack([ndimage.gaussian_filter(photo[..., c], s) for c in range(3)], -1) for s in (3.0, 1.0)}
    design = np.concatenate([ref, np.ones((n, 1), np.float32)], axis=1)  # [n, 4]

    last: dict = {}

    def observe(x, image, m):
        """The photo at the first ``m`` points through the camera ``x``: ``(camera-frame points (m, 3) of the
        perturbed camera, pixels (m, 2), colours (m, 3) NaN off the image, the colours' image gradients
        (m, 3, 2))``. The last call's answer is kept: the fit asks for the residuals and then the Jacobian
        at one ``x``."""
        key = (x.tobytes(), id(image), m)
        if last.get("key") != key:
            c = perturbed_camera(cam, x, depth_scale)
            last.update(key=key, value=_observe(points[:m], c.R, c.t, c.K, image))
        return last["value"]

    def exposure_fit(ok, values):
        """The least-squares coefficients of ``design``'s first rows for ``values (m, k)`` on the ``ok (m,)``
        rows (the normal equations of a 4-column design: several times faster than an SVD for each of the
        fit's hundreds of evaluations; ``lstsq`` where they are singular)."""
        d = design[:len(ok)][ok]
        try:
            return np.linalg.solve(d.T @ d, d.T @ values[ok])
        except np.linalg.LinAlgError:
            return np.linalg.lstsq(d, values[ok], rcond=None)[0]

    def residuals(x, image, m=n):
        _, _, observed, _ = observe(x, image, m)
        ok = np.isfinite(observed).all(axis=1)
        # exposure: the best affine map of the reference colours onto the observed ones, per channel
        r = observed - design[:m] @ exposure_fit(ok, observed)
        r[~ok] = 0.25  # a point leaving the image costs a fixed amount, no gradient
        return r.reshape(-1)

    def jacobian(x, image, m=n):
        """``(3m, 7)``: d residuals / d x, analytic (the finite differences took 8 evaluations a step).

        A residual is ``(I - H) observed`` with ``H`` the exposure fit's projection (variable projection:
        the exposure is solved for, not a parameter), so its derivative is ``(I - H)`` applied to the
        observed colours' derivative, ``grad I . d pixel / d x``. The rotation is differentiated at the
        current rotation (``d(dR p) = w x (dR p)``: exact at 0, a few per cent off at the 3-degree limit; the
        fit's steps are kept by the actual cost)."""
        local, pix, observed, grad = observe(x, image, m)
        ok = np.isfinite(observed).all(axis=1) & np.isfinite(pix).all(axis=1)
        dobs = _motion_gradients(local, pix, grad, ok, cam.K, x, depth_scale)
        # (I - H): the part the exposure fit cannot absorb (each channel's fit is the same projection)
        out = dobs - design[:m] @ exposure_fit(ok, dobs)
        out[~ok] = 0
        return out.reshape(3 * m, 7)

    def cost(x):
        r = residuals(x, levels[1.0]) / 0.05
        return float(np.mean(2 * (np.sqrt(1 + r * r) - 1)))

    def plausible(x) -> bool:
        """A correction within ``max_rotation_deg`` and ``max_translation`` of the depth."""
        moved = np.linalg.norm(perturbed_camera(cam, x, depth_scale).center - cam.center)
        return bool(np.degrees(np.linalg.norm(x[:3])) <= settings.max_rotation_deg
                    and moved <= settings.max_translation * depth_scale)

    n_params = 7 if settings.refine_focal else 6
    x = np.zeros(7)
    before = best = cost(x)
    if settings.search_px > 0:
        # a start from the best whole-image shift, where it agrees better: the photometric basin is a few
        # pixels wide, a recorded pose can be further off
        du, dv = image_shift(seen, usable, photo.mean(axis=2), settings.search_px)
        shifted = np.zeros(7)
        shifted[:2] = -dv / cam.K[1, 1], du / cam.K[0, 0]
        if (du or dv) and cost(shifted) < best:
            x, best = shifted, cost(shifted)
    # the coarse level (the photo blurred, its detail gone) needs fewer points than the fine one
    for sigma, m in ((3.0, min(n, settings.coarse_points)), (1.0, n)):
        # a weak prior towards the recorded pose: a rotation and a sideways move look alike through a narrow
        # lens, and the prior picks the smaller of the two (as strong against any number of points)
        prior = 0.01 * np.sqrt(m)

        def partial(y, sigma=sigma, m=m, prior=prior):
            full = x.copy()
            full[:n_params] = y
            return np.concatenate([residuals(full, levels[sigma], m), prior * y / PRIOR_SCALE[:n_params]])

        def partial_jacobian(y, sigma=sigma, m=m, prior=prior):
            full = x.copy()
            full[:n_params] = y
            return np.vstack([jacobian(full, levels[sigma], m)[:, :n_params],
                              np.diag(prior / PRIOR_SCALE[:n_params])])

        # the fit stops once a step moves the pose by under 1 % of the correction so far (xtol; scipy: 1e-8):
        # a few hundredths of a working pixel. At 1e-3 the bolster's 12 photos took 277 evaluations, at 1e-2 204,
        # 1.16 -> 0.97 s, each pose within 0.02 px of the tighter fit's (the façade's: 236 -> 112)
        fit = least_squares(partial, x[:n_params], jac=partial_jacobian, loss="soft_l1", f_scale=0.05,
                            x_scale=np.array([1e-3] * 3 + [1e-3] * 3 + [1e-3])[:n_params], max_nfev=20,
                            xtol=POSE_XTOL)
        trial = x.copy()
        trial[:n_params] = fit.x
        c = cost(trial)
        log.debug("photo %d sigma %.0f: cost %.4f -> %.4f x=%s (%s; %d evaluations)", index, sigma, best, c,
                  np.round(trial, 5), fit.message, fit.nfev)
        # a level's fit is kept only when it is plausible: a fine level that slides along a near-degenerate
        # direction (moving forward and zooming out alike, for a shallow subject) to an implausible pose
        # leaves the coarse level's correction, not none (a bolster photo: cost 2.43 recorded, 1.75 coarse,
        # 1.60 fine at 6.8 % of the depth forward and a 6.5 % wider lens)
        if c < best and plausible(trial):
            x, best = trial, c
    rotation = float(np.degrees(np.linalg.norm(x[:3])))
    refined_small = perturbed_camera(cam, x, depth_scale)
    moved = float(np.linalg.norm(refined_small.center - cam.center))
    shift = float(np.nanmean(np.linalg.norm(refined_small.project(points)[0] - cam.project(points)[0], axis=1)))
    applied = plausible(x) and best < before and shift >= settings.min_shift_px
    full = perturbed_camera(recorded, x, depth_scale) if applied else recorded
    return PoseCorrection(index, full, rotation if applied else 0.0, moved if applied else 0.0,
                          1 + x[6] if applied else 1.0, before, best if applied else before, applied, shift)


def refine_poses(scan: Scan, photos: PhotoSet, indices, reference: Reference, caster,
                 settings: PoseSettings = PoseSettings(),
                 update: Callable[[int, int], None] | None = None,
                 faces: np.ndarray | None = None, threads: int | None = None
                 ) -> tuple[PhotoSet, list[PoseCorrection]]:
    """``photos`` with the cameras at ``indices`` refined (the others as recorded), and the corrections.
    ``faces``: :func:`reference_faces` of ``scan``, when the caller has them (computed here otherwise, for a
    textured scan). ``threads``: photos refined at once (:func:`scantex.threads.side_by_side`; ``None``: one a
    core); each photo's fit is its own, so the corrections are the same whatever the number."""
    from scantex.threads import side_by_side

    cameras = list(photos.cameras)
    corrections = []
    if faces is None and scan.is_textured:
        faces = reference_faces(scan)
    fits = side_by_side(lambda i: refine_pose(scan, photos, int(i), reference, caster, settings, faces), indices,
                        threads)
    for k, c in enumerate(fits):
        cameras[c.index] = c.camera
        corrections.append(c)
        log.info("photo %d: pose corrected by %.2f deg, %.1f mm, focal x%.4f (error %.4f -> %.4f)%s", c.index,
                 c.rotation_deg, 1000 * c.translation_m, c.focal_scale, c.error_before, c.error_after,
                 "" if c.applied else " (kept as recorded)")
        if update:
            update(k + 1, len(indices))
    return dataclasses.replace(photos, cameras=tuple(cameras)), corrections


def consensus_poses(scan: Scan, photos: PhotoSet, views: list, canonicalise, caster, fallback,
                    iterations: int = 1, temperature: float = 5.0, settings: PoseSettings = PoseSettings(),
                    prepare: Callable[[PhotoSet], list] | None = None,
                    update: Callable[[int, int], None] | None = None, memory_mb: float = 0.0
                    ) -> tuple[PhotoSet, list, list[PoseCorrection]]:
    """Each training photo's pose aligned to the *consensus* of the others: the projective texture the other
    training photos make together (:func:`scantex.photos.texturing.projective_colour`, leave-one-out), so
    the photos come to agree with one another through the mesh, whatever the input texture's own errors.

    The input texture (``refine_poses`` input) is itself baked from misaligned photos, and aligning to it
    copies its errors; the consensus has no single photo's error. Repeated ``iterations`` times: each round
    aligns every photo, from its recorded pose, to the consensus of the previous round's poses (and
    G-buffers, remade by ``prepare(photos) -> views``).

    Args:
        views: the training photos' working G-buffers (:class:`~scantex.photos.training.PhotoView`).
        canonicalise: brings photo ``k``'s colours (``group`` k) to a common appearance (or ``None``).
        fallback: the colour where no other photo sees a point (a :data:`SurfaceColour`).
        memory_mb: the most the consensus's photo samples may hold (:class:`ProjectiveSettings`'s ``memory_mb``).

    Returns:
        ``(photos, views, corrections)``: the refined photo set, its training G-buffers, and the corrections
        (each photo's last round, against its recorded pose).
    """
    from scantex.threads import side_by_side

    recorded = {v.index: photos.cameras[v.index] for v in views}
    corrections: dict[int, PoseCorrection] = {}
    total, done = iterations * len(views), 0
    for _ in range(iterations):
        cameras = list(photos.cameras)
        consensus = consensus_reference(scan, photos, views, canonicalise, fallback, temperature, memory_mb)

        def align(k: int, consensus=consensus) -> PoseCorrection:
            # from the recorded pose every round (its prior stays the recorded pose): a photo that a first,
            # ghosted consensus pulled into a wrong minimum is not held there
            i = views[k].index
            return align_camera(scan, recorded[i], photos.load_image(i), lambda f, b: consensus(f, b, without=k),
                                caster, settings, None, i)

        # each photo against the same consensus: side by side, the same fits whatever the number of threads
        for c in side_by_side(align, range(len(views))):
            cameras[c.index] = c.camera
            corrections[c.index] = c
            done += 1
            if update:
                update(done, total)
        photos = dataclasses.replace(photos, cameras=tuple(cameras))
        if prepare is not None:
            views = prepare(photos)
    for c in corrections.values():
        log.info("photo %d: pose corrected by %.2f deg, %.1f mm, focal x%.4f (to the others' consensus)",
                 c.index, c.rotation_deg, 1000 * c.translation_m, c.focal_scale)
    return photos, views, [corrections[v.index] for v in views]


def consensus_reference(scan: Scan, photos: PhotoSet, views: list, canonicalise, fallback,
                        temperature: float = 5.0, memory_mb: float = 0.0) -> Callable[..., np.ndarray]:
    """``reference(face_ids, bary, without=None) -> (n, 3)``: the colour the photos of ``views`` give surface
    points together (:func:`scantex.photos.texturing.projective_colour`; ``without``: leave that one of the
    views out), a :data:`Reference` for :func:`align_camera`."""
    from scantex.photos.texturing import ProjectiveSettings, projective_colour
    from scantex.views.raycast import interpolate

    corners = scan.positions[scan.faces]
    colour, _ = projective_colour(photos, views, range(len(views)), canonicalise, fallback,
                                  ProjectiveSettings(temperature=temperature, memory_mb=memory_mb))

    def reference(face_ids, bary, without=None):
        return colour(interpolate(face_ids, bary, corners), scan.face_normals[face_ids], face_ids, bary,
                      without=without)
    return reference


def align_to_consensus(scan: Scan, photos: PhotoSet, indices, views: list, canonicalise, caster, fallback,
                       temperature: float = 5.0, settings: PoseSettings = PoseSettings(), memory_mb: float = 0.0
                       ) -> tuple[PhotoSet, list[PoseCorrection]]:
    """``photos`` with the cameras at ``indices`` (photos not among ``views``) aligned to the consensus of
    ``views``' photos, and the corrections: how photos held out of a consensus refinement join its frame."""
    consensus = consensus_reference(scan, photos, views, canonicalise, fallback, temperature, memory_mb)
    cameras = list(photos.cameras)
    corrections = []
    for i in indices:
        c = align_camera(scan, photos.cameras[int(i)], photos.load_image(int(i)), consensus, caster, settings,
                         None, int(i))
        cameras[int(i)] = c.camera
        corrections.append(c)
        log.info("photo %d: pose corrected by %.2f deg, %.1f mm, focal x%.4f (to the refined photos' consensus)",
                 c.index, c.rotation_deg, 1000 * c.translation_m, c.focal_scale)
    return dataclasses.replace(photos, cameras=tuple(cameras)), corrections


def reference_faces(scan: Scan) -> np.ndarray:
    """``(F,) bool`` faces whose input texture can serve as the photometric reference: not untextured
    (black holes) and not touching another UV chart (a capture app's atlas jumps in exposure there,
    an edge no photo has)."""
    from scantex.atlas.holes import untextured_faces
    from scantex.atlas.seams import uv_shells

    charts = uv_shells(scan)
    # on positions welded by value: a glTF or OpenMVS file repeats a position where its charts meet
    faces = scan.welded[scan.faces]
    n = int(faces.max()) + 1 if faces.size else 0
    lo = np.full(n, np.iinfo(np.int64).max)
    hi = np.full(n, -1)
    for k in range(3):
        np.minimum.at(lo, faces[:, k], charts)
        np.maximum.at(hi, faces[:, k], charts)
    border = (lo[faces] != hi[faces]).any(axis=1)
    return ~untextured_faces(scan) & ~border


def rotation_between(a: Camera, b: Camera) -> float:
    """The angle (degrees) of the rotation that turns camera ``b``'s axes into ``a``'s."""
    cos = (np.trace(a.R @ b.R.T) - 1.0) / 2.0
    return float(np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))))


def reprojection_error(scan: Scan, estimated: Camera, truth: Camera, caster, n: int = 5000) -> float:
    """Mean distance (pixels) between where ``estimated`` and ``truth`` project the surface points
    ``truth`` sees (a grid of its pixels' hits)."""
    from scantex.views.raycast import cast_gbuffer

    small = truth.scaled(min(1.0, 160 / max(truth.width, truth.height)))
    g = cast_gbuffer(caster, small)
    points = g.points(scan.positions, scan.faces)[g.mask]
    if len(points) > n:
        points = points[np.random.default_rng(0).choice(len(points), n, replace=False)]
    a, _ = estimated.project(points)
    b, _ = truth.project(points)
    return float(np.linalg.norm(a - b, axis=1).mean())


def image_shift(reference: np.ndarray, mask: np.ndarray, photo: np.ndarray, r: int) -> tuple[float, float]:
    """``(du, dv)``: the whole-pixel shift within ``+-r`` that best matches ``photo`` (grey) at ``p + d`` to
    ``reference`` (grey, known where ``mask``) at ``p``: the peak of their normalised cross-correlation
    after a band-pass (the detail that carries position, not the exposure), all shifts at once by FFT."""
    from scipy import fft, ndimage

    def band(image):
        return ndimage.gaussian_filter(image, 1.0) - ndimage.gaussian_filter(image, 4.0)

    m = mask.astype(np.float32)
    ref = band(np.where(mask, reference, np.float32(reference[mask].mean()) if mask.any() else 0)) * m
    img = band(photo)
    H, W = photo.shape
    size = [fft.next_fast_len(n + r, real=True) for n in (H, W)]
    spec = np.conj(fft.rfft2(ref, size))
    corr = fft.irfft2(fft.rfft2(img, size) * spec, size)          # sum_p ref(p) img(p + d), d mod size
    energy = fft.irfft2(fft.rfft2(img * img, size) * np.conj(fft.rfft2(m, size)), size)  # img's energy under the mask
    shifts = np.arange(-r, r + 1)
    corr = corr[np.ix_(shifts % size[0], shifts % size[1])]
    energy = energy[np.ix_(shifts % size[0], shifts % size[1])]
    score = corr / np.sqrt(np.maximum(energy, 1e-12))
    k = np.unravel_index(np.argmax(score), score.shape)
    return float(shifts[k[1]]), float(shifts[k[0]])


def _bilinear_rgb(image: np.ndarray, pix: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(colours (n, 3), gradients (n, 3, 2))``: bilinear samples of ``image (H, W, 3)`` at pixels ``pix (n, 2)``
    and their gradients (d/dx, d/dy); off the image (or NaN) the colours are NaN and the gradients 0. The
    three channels share one cell lookup (a third of the work of looking each channel up alone)."""
    from scantex.photos.alignment import _bilinear_cells

    off, x0, y0, fx, fy = _bilinear_cells(image.shape[:2], pix)
    fx, fy = fx[:, None], fy[:, None]
    a, b = image[y0, x0], image[y0, x0 + 1]
    c, d = image[y0 + 1, x0], image[y0 + 1, x0 + 1]
    top, bottom = a + fx * (b - a), c + fx * (d - c)
    colours = top + fy * (bottom - top)
    gradients = np.stack([(1 - fy) * (b - a) + fy * (d - c), bottom - top], axis=2)
    colours[off] = np.nan
    gradients[off] = 0
    return colours, gradients


def _rgb_to_grey_image(rgb: np.ndarray, ys: np.ndarray, xs: np.ndarray, shape) -> np.ndarray:
    out = np.zeros(shape, np.float32)
    out[ys, xs] = rgb @ np.array([0.299, 0.587, 0.114], np.float32)
    return out


def _observe(points: np.ndarray, rotation: np.ndarray, translation: np.ndarray, intrinsics: np.ndarray,
             image: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``points (m, 3)`` seen by the camera ``rotation``, ``translation``, ``intrinsics`` in ``image (H, W, 3)``:
    ``(camera-frame points (m, 3), pixels (m, 2) (NaN behind the camera), colours (m, 3) NaN off the image,
    their image gradients (m, 3, 2) 0 there)``; compiled (:mod:`scantex.jit`), or in numpy where numba is
    missing (:func:`_observe_numpy`, its twin)."""
    from scantex import jit

    kernel = jit.compiled(_observe_kernel)
    if kernel is None:
        return _observe_numpy(points, rotation, translation, intrinsics, image)
    m = len(points)
    local, pix, colours = np.empty((m, 3)), np.empty((m, 2)), np.empty((m, 3))
    gradients = np.empty((m, 3, 2))
    kernel(np.ascontiguousarray(points, np.float64), np.ascontiguousarray(rotation, np.float64),
           np.ascontiguousarray(translation, np.float64), np.ascontiguousarray(intrinsics, np.float64),
           np.ascontiguousarray(image, np.float32), local, pix, colours, gradients)
    return local, pix, colours, gradients


def _observe_numpy(points, rotation, translation, intrinsics, image):
    local = points @ np.ascontiguousarray(rotation.T) + translation  # contiguous: see Camera.project
    with np.errstate(divide="ignore", invalid="ignore"):
        pix = local @ np.ascontiguousarray(intrinsics.T)
        pix = pix[:, :2] / pix[:, 2:3]
    pix[local[:, 2] <= 0] = np.nan
    return (local, pix, *_bilinear_rgb(image, pix))


def _observe_kernel(points, rotation, translation, intrinsics, image, local, pix, colours, gradients):
    """:func:`_observe`'s kernel, point by point: its outputs filled in."""
    H, W = image.shape[0], image.shape[1]
    for i in range(points.shape[0]):
        p0, p1, p2 = points[i, 0], points[i, 1], points[i, 2]
        x = rotation[0, 0] * p0 + rotation[0, 1] * p1 + rotation[0, 2] * p2 + translation[0]
        y = rotation[1, 0] * p0 + rotation[1, 1] * p1 + rotation[1, 2] * p2 + translation[1]
        z = rotation[2, 0] * p0 + rotation[2, 1] * p1 + rotation[2, 2] * p2 + translation[2]
        local[i, 0], local[i, 1], local[i, 2] = x, y, z
        hz = intrinsics[2, 0] * x + intrinsics[2, 1] * y + intrinsics[2, 2] * z
        u = (intrinsics[0, 0] * x + intrinsics[0, 1] * y + intrinsics[0, 2] * z) / hz
        v = (intrinsics[1, 0] * x + intrinsics[1, 1] * y + intrinsics[1, 2] * z) / hz
        if not z > 0:
            u = v = np.nan
        pix[i, 0], pix[i, 1] = u, v
        if not (u >= 0 and u <= W - 1 and v >= 0 and v <= H - 1):  # off the image, or NaN
            for c in range(3):
                colours[i, c] = np.nan
                gradients[i, c, 0] = gradients[i, c, 1] = 0.0
            continue
        # the cell as _bilinear_cells takes it: its corner clamped inside the image
        cx, cy = min(u, W - 1.001), min(v, H - 1.001)
        x0, y0 = int(cx), int(cy)
        fx, fy = cx - x0, cy - y0
        for c in range(3):
            a, b = np.float64(image[y0, x0, c]), np.float64(image[y0, x0 + 1, c])
            e, d = np.float64(image[y0 + 1, x0, c]), np.float64(image[y0 + 1, x0 + 1, c])
            top, bottom = a + fx * (b - a), e + fx * (d - e)
            colours[i, c] = top + fy * (bottom - top)
            gradients[i, c, 0] = (1 - fy) * (b - a) + fy * (d - e)
            gradients[i, c, 1] = bottom - top


def _motion_gradients(local: np.ndarray, pix: np.ndarray, gradients: np.ndarray, ok: np.ndarray,
                      intrinsics: np.ndarray, x: np.ndarray, depth_scale: float) -> np.ndarray:
    """``(m, 21)``: d colour / d correction ``x`` (3 channels x 7 parameters; 0 where not ``ok``) of points seen
    at ``local (m, 3)`` (the perturbed camera's frame), ``pix (m, 2)`` with image gradients ``gradients (m, 3, 2)``
    (:func:`_observe`), for the recorded camera's ``intrinsics`` (see ``align_camera``'s Jacobian); compiled, or
    in numpy where numba is missing (:func:`_motion_gradients_numpy`, its twin)."""
    from scantex import jit

    kernel = jit.compiled(_motion_gradients_kernel)
    if kernel is None:
        return _motion_gradients_numpy(local, pix, gradients, ok, intrinsics, x, depth_scale)
    out = np.empty((len(local), 21))
    kernel(local, pix, gradients, np.ascontiguousarray(ok), np.ascontiguousarray(intrinsics, np.float64),
           np.ascontiguousarray(x, np.float64), float(depth_scale), out)
    return out


def _motion_gradients_numpy(local, pix, gradients, ok, intrinsics, x, depth_scale):
    m = len(local)
    K = intrinsics * np.array([[1 + x[6], 1 + x[6], 1], [1, 1 + x[6], 1], [1, 1, 1]])
    X, Y, Z = local[:, 0], local[:, 1], np.where(ok, local[:, 2], 1.0)
    # d pixel / d camera-frame point: u's row (a, b, c), v's (0, e, g)
    a, b, c = K[0, 0] / Z, K[0, 1] / Z, -(K[0, 0] * X + K[0, 1] * Y) / Z ** 2
    e, g = K[1, 1] / Z, -K[1, 1] * Y / Z ** 2
    # d camera-frame point / d (rotation vector, translation): e_k x p for the rotation (p the rotated
    # point before the translation), depth_scale e_k for the translation (in units of depth_scale)
    px, py, pz = (local - x[3:6] * depth_scale).T
    dpix = np.empty((m, 2, 7))
    dpix[:, 0, 0] = -b * pz + c * py
    dpix[:, 0, 1] = a * pz - c * px
    dpix[:, 0, 2] = -a * py + b * px
    dpix[:, 1, 0] = -e * pz + g * py
    dpix[:, 1, 1] = -g * px
    dpix[:, 1, 2] = e * px
    dpix[:, 0, 3:6] = depth_scale * np.stack([a, b, c], axis=1)
    dpix[:, 1, 3] = 0
    dpix[:, 1, 4:6] = depth_scale * np.stack([e, g], axis=1)
    centred = np.nan_to_num(pix) - intrinsics[:2, 2]
    dpix[:, :, 6] = centred / (1 + x[6])  # the focal scales the pixel's offset from the principal point
    # (m, 3 channels x 7 parameters): each channel's gradient along the pixel's motion
    dobs = (gradients[:, :, :1] * dpix[:, None, 0, :] + gradients[:, :, 1:] * dpix[:, None, 1, :]).reshape(m, 21)
    dobs[~ok] = 0
    return dobs


def _motion_gradients_kernel(local, pix, gradients, ok, intrinsics, x, depth_scale, out):
    """:func:`_motion_gradients`'s kernel, point by point: ``out`` filled in."""
    s = 1 + x[6]
    k00, k01, k11 = intrinsics[0, 0] * s, intrinsics[0, 1] * s, intrinsics[1, 1] * s
    d0 = np.empty(7)
    d1 = np.empty(7)
    for i in range(local.shape[0]):
        if not ok[i]:
            out[i, :] = 0.0
            continue
        X, Y, Z = local[i, 0], local[i, 1], local[i, 2]
        a, b, c = k00 / Z, k01 / Z, -(k00 * X + k01 * Y) / Z ** 2
        e, g = k11 / Z, -k11 * Y / Z ** 2
        px, py, pz = X - x[3] * depth_scale, Y - x[4] * depth_scale, Z - x[5] * depth_scale
        d0[0], d0[1], d0[2] = -b * pz + c * py, a * pz - c * px, -a * py + b * px
        d1[0], d1[1], d1[2] = -e * pz + g * py, -g * px, e * px
        d0[3], d0[4], d0[5] = depth_scale * a, depth_scale * b, depth_scale * c
        d1[3], d1[4], d1[5] = 0.0, depth_scale * e, depth_scale * g
        d0[6] = (pix[i, 0] - intrinsics[0, 2]) / s
        d1[6] = (pix[i, 1] - intrinsics[1, 2]) / s
        for ch in range(3):
            gx, gy = gradients[i, ch, 0], gradients[i, ch, 1]
            for k in range(7):
                out[i, 7 * ch + k] = gx * d0[k] + gy * d1[k]
