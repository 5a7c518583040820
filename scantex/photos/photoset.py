"""The capture's own photos with their cameras, whatever format they came in.

Every importer in :mod:`scantex.photos` returns a :class:`PhotoSet`: pinhole cameras in scantex's one
convention (OpenCV, see :mod:`scantex.views.camera`: ``x_cam = R X + t``, +x right, +y down, +z
forward, pixel ``(0, 0)`` = the centre of the top-left pixel) in the *mesh's* world frame, and the
paths of the images (and, optionally, of depth maps). Images are read only when asked for.

Lens distortion, where a format stores it, is kept in :class:`Distortion`; the cameras themselves are
pinholes. A distortion that moves no pixel by more than ``max_distortion_px`` (default 1 px) is logged as a
warning and then ignored; a larger one is undone when a photo is read (:attr:`PhotoSet.lenses`,
:mod:`scantex.photos.lens`): a texture fitted to distorted photos through pinhole cameras would be smeared by
exactly that many pixels.
"""

from __future__ import annotations

import dataclasses
import threading
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from scantex.errors import ScanError
from scantex.io.images import open_image, rgb8
from scantex.views.camera import Camera

if TYPE_CHECKING:
    from scantex.photos.lens import Lens

#: metres per unit of an integer depth map in every format scantex reads: uint16 PNG in millimetres (a float map,
#: a 32-bit TIFF or a ``.npy``, is in metres)
DEPTH_SCALE_MM = 0.001

#: decoded photos kept in memory for the stages that read them again (the alignment check, pose refinement,
#: the working views and the texture each read every photo: a 1920x1080 JPEG costs ~30 ms to decode), when
#: all of a set's photos fit (the stages read them in turn: a cache holding a few of many would never be hit)
IMAGE_CACHE_MB = 256


class ImageCache:
    """The most recently decoded photos, up to ``budget_mb`` of pixels, shared by a :class:`PhotoSet` and
    the sets made from it (:meth:`PhotoSet.subset`, refined cameras): keyed by what the file is read as (a
    photo, a depth map: a frame whose depth map names a photo's file gets that file's pixels checked as a
    depth map, not the photo), the file, its size and its time of change (a file written again is read
    again), safe across threads. Its images are read-only."""

    def __init__(self, budget_mb: float = IMAGE_CACHE_MB):
        from collections import OrderedDict

        self.budget = int(budget_mb * 2**20)
        self._images: OrderedDict[tuple, np.ndarray] = OrderedDict()
        self._decoding: dict[tuple, threading.Event] = {}
        self._lock = threading.Lock()

    @staticmethod
    def _key(path: Path, kind: str) -> tuple | None:
        try:
            stat = path.stat()
        except OSError:
            return None
        return kind, path, stat.st_size, stat.st_mtime_ns

    def __getstate__(self) -> dict:
        # pickled (a photo set sent to another process) as an empty cache of the same budget: a lock does not
        # pickle, and the other process reads the photos it needs itself
        return {"budget": self.budget}

    def __setstate__(self, state: dict) -> None:
        self.__init__(state["budget"] / 2**20)

    def _used(self, key: tuple | None) -> np.ndarray | None:
        """The image kept under ``key``, now the most recently used (the caller holds the lock)."""
        image = self._images.get(key)
        if image is not None:
            self._images.move_to_end(key)
        return image

    def get(self, path: Path, kind: str = "photo") -> np.ndarray | None:
        key = self._key(path, kind)
        with self._lock:
            return self._used(key)

    def get_or_decode(self, path: Path, decode: Callable[[], np.ndarray], kind: str = "photo") -> np.ndarray:
        """The image of ``path`` read as ``kind``: the cache's, or ``decode()``'s, kept. A thread asking for a
        file another thread is decoding waits for that decode instead of repeating it (:meth:`PhotoSet.prefetch`
        decodes ahead of the stages)."""
        key = self._key(path, kind)
        with self._lock:
            image = self._used(key)
            if image is not None:
                return image
            pending = self._decoding.get(key)
            mine = pending is None and key is not None
            if mine:
                pending = self._decoding[key] = threading.Event()
        if not mine and pending is not None:
            pending.wait()
            image = self.get(path, kind)
            if image is not None:
                return image
            # the other decode failed: this one raises its error again, where the stage asked
        try:
            image = decode()  # also where the file cannot be keyed (missing): decode says so
            self.put(path, image, kind)
            return image
        finally:
            if mine:
                with self._lock:
                    del self._decoding[key]
                pending.set()

    def put(self, path: Path, image: np.ndarray, kind: str = "photo") -> None:
        key = self._key(path, kind)
        if key is None or image.nbytes > self.budget:
            return
        image.flags.writeable = False
        with self._lock:
            self._images[key] = image
            self._images.move_to_end(key)
            while sum(a.nbytes for a in self._images.values()) > self.budget:
                self._images.popitem(last=False)


#: how a lens maps a ray's angle from its axis before its distortion polynomial (:attr:`Distortion.projection`)
PROJECTIONS = ("perspective", "equidistant", "equisolid")


@dataclass(frozen=True)
class Distortion:
    """Lens distortion of normalised camera coordinates ``(x, y) = (X/Z, Y/Z)`` (OpenCV's model).

    ``r2 = x^2 + y^2``, ``radial = (1 + k1 r2 + k2 r2^2 + ...) / (1 + d1 r2 + d2 r2^2 + ...)``,
    ``x_d = x radial + 2 p1 x y + p2 (r2 + 2 x^2)``, ``y_d = y radial + p1 (r2 + 2 y^2) + 2 p2 x y``.
    A fisheye lens first takes ``(x, y)`` to its angle from the axis, ``theta = atan(r)``: ``(x, y) theta / r``
    (``projection`` ``"equidistant"``: OpenCV's and COLMAP's fisheye models, whose polynomial in ``theta^2`` is the
    radial one above) or ``(x, y) 2 sin(theta / 2) / r`` (``"equisolid"``).

    Attributes:
        model: the format's own name for it (``"OPENCV"``, ``"SIMPLE_RADIAL"``, ...).
        radial: ``(k1, k2, ...)`` polynomial radial coefficients.
        tangential: ``(p1, p2)``.
        radial_denominator: ``(k4, k5, k6)`` of OpenCV's rational model (COLMAP ``FULL_OPENCV``), else empty.
        inverse_radial: where the format's model maps distorted coordinates to undistorted ones (VisualSfM's
            ``x = x_d (1 + d0 r_d^2)``): its coefficients ``(d0, ...)``, solved exactly by :meth:`distort`;
            ``radial`` then holds its first-order forward twin (``k1 = -d0``) for the writers of OpenCV's model.
        projection: ``"perspective"`` (a pinhole's, distorted), or a fisheye's ``"equidistant"`` or ``"equisolid"``
            mapping of the ray's angle, before the polynomial.
    """

    model: str
    radial: tuple[float, ...] = ()
    tangential: tuple[float, float] = (0.0, 0.0)
    radial_denominator: tuple[float, ...] = ()
    inverse_radial: tuple[float, ...] = ()
    projection: str = "perspective"

    def __post_init__(self) -> None:
        if self.projection not in PROJECTIONS:
            raise ValueError(f"Distortion: projection {self.projection!r} is none of {', '.join(PROJECTIONS)}")

    @property
    def is_zero(self) -> bool:
        return (self.projection == "perspective" and not any(self.radial) and not any(self.tangential)
                and not any(self.radial_denominator) and not any(self.inverse_radial))

    @property
    def is_fisheye(self) -> bool:
        return self.projection != "perspective"

    def distort(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Distorted normalised coordinates of undistorted ``x, y`` (any shape)."""
        if any(self.inverse_radial):
            return self._solve_inverse(np.asarray(x, np.float64), np.asarray(y, np.float64))
        if self.is_fisheye:
            r = np.sqrt(x * x + y * y)
            theta = np.arctan(r)
            mapped = theta if self.projection == "equidistant" else 2.0 * np.sin(theta / 2.0)
            ratio = np.divide(mapped, r, out=np.ones_like(r, dtype=np.float64), where=r > 0)
            x, y = x * ratio, y * ratio
        r2 = x * x + y * y
        num = 1.0 + sum(k * r2 ** (i + 1) for i, k in enumerate(self.radial))
        den = 1.0 + sum(k * r2 ** (i + 1) for i, k in enumerate(self.radial_denominator))
        radial = num / den
        p1, p2 = self.tangential
        xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
        yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
        return xd, yd

    def _solve_inverse(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """:attr:`inverse_radial`'s model solved for the distorted radius ``s`` of each undistorted radius ``r``:
        ``s (1 + d0 s^2 + d1 s^4 + ...) = r``, by Newton's method from ``s = r`` (the model is monotonic where a
        lens is: a radius it cannot reach keeps its last iterate)."""
        r = np.sqrt(x * x + y * y)
        s = r.copy()
        for _ in range(20):
            s2 = s * s
            value = s * (1.0 + sum(d * s2 ** (i + 1) for i, d in enumerate(self.inverse_radial))) - r
            slope = 1.0 + sum((2 * i + 3) * d * s2 ** (i + 1) for i, d in enumerate(self.inverse_radial))
            s = s - value / np.where(np.abs(slope) > 1e-9, slope, 1e-9)
        ratio = np.divide(s, r, out=np.ones_like(r), where=r > 0)
        return x * ratio, y * ratio

    def max_shift_px(self, camera: Camera) -> float:
        """Largest distance in pixels that the distortion moves a pixel of ``camera``'s image
        (sampled on a 33 x 33 grid that includes the border and the corners)."""
        K = camera.K
        u, v = np.meshgrid(np.linspace(0, camera.width - 1, 33), np.linspace(0, camera.height - 1, 33))
        x = (u - K[0, 2] - K[0, 1] * (v - K[1, 2]) / K[1, 1]) / K[0, 0]
        y = (v - K[1, 2]) / K[1, 1]
        xd, yd = self.distort(x, y)
        du = K[0, 0] * (xd - x) + K[0, 1] * (yd - y)
        dv = K[1, 1] * (yd - y)
        return float(np.sqrt(du * du + dv * dv).max())


@dataclass(frozen=True, eq=False, kw_only=True)
class PhotoSet:
    """Posed photos of one capture.

    Attributes:
        cameras: one pinhole :class:`Camera` per photo, OpenCV convention, world frame = the mesh's.
        images: ``(N,)`` image files (any format Pillow reads); read by :meth:`load_image`.
        depths: ``(N,)`` depth maps (uint16 PNG, ``depth_scale`` metres per unit; or float, in metres: a 32-bit
            TIFF, a ``.npy``) or ``None`` per photo.
            A depth map may have another size than its photo (phones and the Kinect record depth at a
            lower resolution): :meth:`load_depth` returns it at its stored size and resizing it is the caller's
            business (it covers the photo's field of view, so its intrinsics are the photo's scaled by
            ``depth width / image width`` and ``depth height / image height``, pixel centres kept consistent
            as in :meth:`Camera.scaled`).
        depth_warps: ``(N,)`` per photo, ``None`` (its depth map covers the photo's view, as above) or the
            ``(3, 3)`` affine map from a point of the photo to the same point of its depth map, each in its image's
            share (``((u + 0.5) / width, (v + 0.5) / height)``), where the depth camera has a lens of its own (at the
            photo camera's centre, looking its way: a capture that registered depth to colour, as ScanNet's and the
            Structure Sensor's exports do; :func:`depth_warp` makes it from the two K): :meth:`load_depth` resamples
            the map into the photo's view. Fixed when the photos are read: a photo's pose or focal length refined
            later takes its map along, as it takes every map that covers its photo's view.
        depth_scale: metres per depth-map unit (0.001: millimetres).
        source: the file or folder the set was read from.
        format: the format it was read from (``"nerfstudio"``, ``"colmap-text"``, ``"colmap-binary"``,
            ``"3dscannerapp"``, ``"polycam"``, ``"cameras.json"``, ``"texrecon"``, ``"scannet"``,
            ``"rgbd-frames"``, ``"arkitscenes"``, ``"mve"``, ``"metashape"``, ``"meshroom"``,
            ``"openmvs"``, ``"openmvg"``, ``"bundler"``, ``"nvm"``, ``"realitycapture"``), or any label for sets made in
            code.
        distortions: ``(N,)`` lens distortion per photo as the format stored it, ``None`` for none. The
            cameras are pinholes: a distortion under the importer's limit is ignored, a larger one undone by
            :attr:`lenses`.
        lenses: ``(N,)`` per photo, ``None`` (the stored photo is its camera's pinhole image) or the
            :class:`~scantex.photos.lens.Lens` it was taken through: :meth:`load_image` and :meth:`load_depth`
            resample it into the camera's pinhole view. Fixed when the photos are read, as :attr:`depth_warps`.
        image_cache: the decoded photos :meth:`load_image` keeps when the set's photos all fit in it (a new
            set makes its own; the sets made from one by :func:`dataclasses.replace` share it).
        hidden: ``(N,)`` per photo, ``None`` or an ``(h, w) bool`` mask of the pixels where a surface that is
            not in the scan being textured hides it (a tile's neighbours, :mod:`scantex.scale.tiles`): the
            visibility test rejects them, whatever the scan's own ray cast says. Any size: it is resized
            (nearest) to the photo's working size.
        depth_factors: ``(N,)`` per photo, ``None`` (its depth map is judged against the scan when it is
            read: :func:`scantex.photos.training.depth_factor`) or the factor that judgement gave on the whole
            scan (a tile sees too little of a photo's view to judge its map) or at another pose, applied as
            it is (0: the map is not of the photo's view, and is not used).
        tones: ``(N,)`` per photo, ``None`` or its gamma (a float): :meth:`load_image` brings the photo to the
            capture's common tone curve (:mod:`scantex.photos.tones`).
        numbers: ``(N,)`` each photo's number in the capture it was taken from, as the messages name it (a tile's
            photos: :meth:`scantex.scale.tiles.TilePhotos.for_tile`; a subset of numbered photos keeps theirs);
            empty: its position here (:meth:`number`).
    """

    cameras: tuple[Camera, ...]
    images: tuple[Path, ...]
    depths: tuple[Path | None, ...] = ()
    depth_scale: float = DEPTH_SCALE_MM
    source: Path
    format: str
    distortions: tuple[Distortion | None, ...] = ()
    image_cache: ImageCache = dataclasses.field(default_factory=ImageCache, repr=False)
    hidden: tuple[np.ndarray | None, ...] = dataclasses.field(default=(), repr=False)
    depth_factors: tuple[float | None, ...] = ()
    tones: tuple[float | None, ...] = ()
    numbers: tuple[int, ...] = ()
    depth_warps: tuple[np.ndarray | None, ...] = dataclasses.field(default=(), repr=False)
    lenses: tuple[Lens | None, ...] = dataclasses.field(default=(), repr=False)

    def __post_init__(self) -> None:
        set_ = object.__setattr__
        n = len(self.cameras)
        set_(self, "cameras", tuple(self.cameras))
        set_(self, "images", tuple(Path(p) for p in self.images))
        set_(self, "depths", tuple(None if p is None else Path(p) for p in self.depths) or (None,) * n)
        set_(self, "distortions", tuple(self.distortions) or (None,) * n)
        set_(self, "hidden", tuple(self.hidden) or (None,) * n)
        set_(self, "depth_factors", tuple(self.depth_factors) or (None,) * n)
        set_(self, "tones", tuple(self.tones) or (None,) * n)
        set_(self, "depth_warps", tuple(None if a is None else np.array(a, np.float64).reshape(3, 3)
                                        for a in self.depth_warps) or (None,) * n)
        set_(self, "lenses", tuple(self.lenses) or (None,) * n)
        set_(self, "source", Path(self.source))
        set_(self, "numbers", tuple(int(i) for i in self.numbers))
        for name in ("images", "depths", "distortions", "hidden", "depth_factors", "tones", "depth_warps",
                     "lenses") + (
                ("numbers",) if self.numbers else ()):
            if len(getattr(self, name)) != n:
                raise ValueError(f"PhotoSet: {len(getattr(self, name))} {name} for {n} cameras")

    def __len__(self) -> int:
        return len(self.cameras)

    def number(self, i: int) -> int:
        """Photo ``i``'s number in its capture (see :attr:`numbers`)."""
        return self.numbers[i] if self.numbers else int(i)

    @property
    def has_depth(self) -> bool:
        return any(d is not None for d in self.depths)

    def subset(self, indices: Sequence[int]) -> PhotoSet:
        """The photos at ``indices``, in that order."""
        idx = [int(i) for i in indices]
        return dataclasses.replace(self, cameras=tuple(self.cameras[i] for i in idx),
                                   images=tuple(self.images[i] for i in idx),
                                   depths=tuple(self.depths[i] for i in idx),
                                   distortions=tuple(self.distortions[i] for i in idx),
                                   hidden=tuple(self.hidden[i] for i in idx),
                                   depth_factors=tuple(self.depth_factors[i] for i in idx),
                                   tones=tuple(self.tones[i] for i in idx),
                                   depth_warps=tuple(self.depth_warps[i] for i in idx),
                                   lenses=tuple(self.lenses[i] for i in idx),
                                   numbers=tuple(self.numbers[i] for i in idx) if self.numbers else ())

    def as_stored(self, holds: Callable[[Distortion, Camera], bool] | None = None) -> PhotoSet:
        """The set as a writer writes it. Each photo undistorted when read (:attr:`lenses`) whose lens the format
        ``holds`` (its distortion at the camera as stored; default: any) gets its camera as stored, the lens's
        intrinsics, which with :attr:`distortions` describe the photo file as it is (written as it is); one whose lens
        the format cannot hold keeps its pinhole camera and its lens, and loses its distortion
        (:func:`~scantex.photos.files.write_photo` writes its undistorted photo). A distortion ignored when read (under
        ``max_distortion_px``: the photo was taken for a pinhole one) that the format cannot hold is dropped. The
        intrinsics are those read: a focal length refined since is not carried over."""
        ignored = [i for i, (d, lens) in enumerate(zip(self.distortions, self.lenses))
                   if lens is None and d is not None and holds is not None and not holds(d, self.cameras[i])]
        if all(lens is None for lens in self.lenses) and not ignored:
            return self
        cameras, distortions, lenses = list(self.cameras), list(self.distortions), list(self.lenses)
        for i in ignored:
            distortions[i] = None
        for i, (c, lens) in enumerate(zip(self.cameras, self.lenses)):
            if lens is None:
                continue
            stored = Camera(lens.photo_K, c.world_to_camera, c.width, c.height)
            if holds is None or holds(lens.distortion, stored):
                cameras[i], lenses[i] = stored, None
            else:
                distortions[i] = None
        return dataclasses.replace(self, cameras=tuple(cameras), distortions=tuple(distortions), lenses=tuple(lenses))

    def load_image(self, i: int) -> np.ndarray:
        """``(H, W, 3) uint8`` RGB of photo ``i``, as stored (no EXIF rotation: the cameras describe the sensor's
        pixel grid) or undistorted where :attr:`lenses` gives its lens, and brought to the common tone curve where
        :attr:`tones` gives the photo's; read-only (it may be :attr:`image_cache`'s copy).

        Raises:
            ScanError: the file is missing, not an image, or not of its camera's size.
        """
        path = self.images[i]
        cam = self.cameras[i]

        def decode() -> np.ndarray:
            with open_image(path, "photo") as im:
                size = im.size
                if size != (cam.width, cam.height):
                    raise ScanError(path, f"photo is {size[0]}x{size[1]} but its camera is "
                                          f"{cam.width}x{cam.height}")
                image = rgb8(im)
            if lens is not None:
                from scantex.photos.lens import undistort_image

                image = undistort_image(image, lens)
            return image

        lens = self.lenses[i]
        image = (self.image_cache.get_or_decode(path, decode, "photo" if lens is None else "undistorted photo")
                 if self.all_cached else decode())
        if image.shape[:2] != (cam.height, cam.width):  # decoded for a set whose camera says another size
            raise ScanError(path, f"photo is {image.shape[1]}x{image.shape[0]} but its camera is "
                                  f"{cam.width}x{cam.height}")
        if self.tones[i] is not None:
            from scantex.photos.tones import toned

            image = toned(image, self.tones[i])
        image.flags.writeable = False
        return image

    @property
    def all_cached(self) -> bool:
        """Whether :attr:`image_cache` keeps the decoded photos and depth maps: only when they all fit (the
        stages read the photos in turn: a cache holding the last few would never be hit). A depth map is
        counted at its photo's size, 4 bytes a pixel: no larger than that in any capture scantex reads (16-bit
        maps at the photo's size or below)."""
        return sum(c.width * c.height * (3 + 4 * (d is not None))
                   for c, d in zip(self.cameras, self.depths)) <= self.image_cache.budget

    def prefetch(self) -> threading.Thread | None:
        """Decode the photos and depth maps into :attr:`image_cache` on a thread of their own, in order, while
        the caller does other work (Pillow decodes without the interpreter lock: the bolster's 12 photos of
        1920x1080 and their depth maps take 0.5 s, taken off the stages that read them); a stage asking for
        one being decoded waits for it. Returns the (daemon) thread, or ``None`` when they do not all fit in
        the cache. A file that cannot be read stops it quietly: the stage that reads it raises the error."""
        if not self.all_cached:
            return None

        def decode_all() -> None:
            for i in range(len(self)):
                try:
                    self.load_image(i)
                    self.stored_depth(i)  # what the cache keeps: no conversion to metres thrown away
                except Exception:  # noqa: BLE001 - the stage reading this photo says what is wrong with it
                    return

        thread = threading.Thread(target=decode_all, name="scantex-prefetch", daemon=True)
        thread.start()
        return thread

    def load_depth(self, i: int) -> np.ndarray | None:
        """``(h, w) float32`` depth in metres of photo ``i`` (NaN where the map has no measurement, stored
        as 0, or as NaN or a negative value in a float map), at the depth map's own size and covering the photo's
        view (a map of a lens of its own resampled: :attr:`depth_warps`); ``None`` when the photo has no
        depth map. An integer map is in ``depth_scale`` units, a float map (a 32-bit TIFF, a ``.npy``) in metres.
        The map as stored is what :attr:`image_cache` keeps (16-bit integers: half the size, and right for any
        ``depth_scale``)."""
        raw = self.stored_depth(i)
        if raw is None:
            return None
        if raw.dtype.kind == "f":
            depth = raw.astype(np.float32)
            depth[~(depth > 0) | ~np.isfinite(depth)] = np.nan
        else:
            depth = raw.astype(np.float32) * np.float32(self.depth_scale)
            depth[raw == 0] = np.nan
        if self.lenses[i] is not None:
            from scantex.photos.lens import undistort_depth

            depth = undistort_depth(depth, self.lenses[i], self.depth_warps[i])
        elif self.depth_warps[i] is not None:
            depth = into_photo_view(depth, self.depth_warps[i])
        return depth

    def stored_depth(self, i: int) -> np.ndarray | None:
        """Photo ``i``'s depth map as stored, ``(h, w)`` integers or floats (the cache's copy when the set
        fits it)."""
        path = self.depths[i]
        if path is None:
            return None

        def decode() -> np.ndarray:
            if path.suffix.lower() == ".npy":
                raw = _load_npy(path)
            else:
                with open_image(path, "depth map") as im:
                    im.load()  # decode inside the block: a truncated file becomes a clean error
                    raw = np.asarray(im)
            if raw.ndim != 2 or raw.dtype.kind not in "uif":
                raise ScanError(path, f"depth map is not a single-channel integer or float image "
                                      f"({raw.dtype} of shape {raw.shape})")
            return raw

        return self.image_cache.get_or_decode(path, decode, "depth") if self.all_cached else decode()


def depth_warp(K_depth: np.ndarray, depth_size: tuple[int, int], K_photo: np.ndarray,
               photo_size: tuple[int, int]) -> np.ndarray | None:
    """The :attr:`PhotoSet.depth_warps` entry of a depth camera (``K_depth`` for maps of ``depth_size``, ``(w,
    h)``) registered to a photo camera (``K_photo``, ``photo_size``): at the same centre, looking the same way, so
    a ray's pixel moves and its depth does not. ``None`` when the map covers the photo's view (the warp moves no
    point of the map by a twentieth of a pixel: ScanNet's depth K is its colour K scaled, to a hundredth)."""
    def share(size):  # pixel (u, v) -> ((u + 0.5) / w, (v + 0.5) / h)
        return np.array([[1.0 / size[0], 0, 0.5 / size[0]], [0, 1.0 / size[1], 0.5 / size[1]], [0, 0, 1]])

    warp = share(depth_size) @ np.asarray(K_depth, np.float64) @ np.linalg.inv(K_photo) @ np.linalg.inv(
        share(photo_size))
    warp[2] = (0.0, 0.0, 1.0)
    off = np.abs(warp[:2] - np.eye(3)[:2]) * np.array([[depth_size[0]], [depth_size[1]]])
    return None if off.max() < 0.05 else warp


def into_photo_view(depth: np.ndarray, warp: np.ndarray) -> np.ndarray:
    """A depth map of a lens of its own resampled, nearest (no depth averaged across an edge), into its photo's
    view at the map's size (``warp``: :attr:`PhotoSet.depth_warps`); NaN where the depth camera did not look."""
    h, w = depth.shape
    y, x = (np.arange(h) + 0.5) / h, (np.arange(w) + 0.5) / w
    qx = warp[0, 0] * x[None, :] + warp[0, 1] * y[:, None] + warp[0, 2]
    qy = np.broadcast_to(warp[1, 1] * y[:, None] + warp[1, 2], qx.shape)
    return nearest_at_shares(depth, qx, qy)


def nearest_at_shares(depth: np.ndarray, sx: np.ndarray, sy: np.ndarray) -> np.ndarray:
    """``depth`` sampled, nearest (no depth averaged across an edge), at shares of it (``(u + 0.5) / w``, ``(v + 0.5)
    / h``; ``sx``, ``sy`` of one shape): ``float32`` of that shape, NaN where a share falls outside the map."""
    h, w = depth.shape
    ud, vd = np.floor(sx * w), np.floor(sy * h)  # the pixel a share falls in
    inside = (ud >= 0) & (ud < w) & (vd >= 0) & (vd < h)
    out = np.full(np.shape(sx), np.nan, np.float32)
    out[inside] = depth[vd[inside].astype(np.intp), ud[inside].astype(np.intp)]
    return out


def _load_npy(path: Path) -> np.ndarray:
    """A depth map saved by ``numpy.save``; its header is checked against the size limit before its data is read."""
    from scantex.io.images import MAX_IMAGE_PIXELS

    if not path.is_file():
        raise ScanError(path, "depth map file not found")
    try:
        stored = np.load(path, mmap_mode="r", allow_pickle=False)
    except (OSError, ValueError, EOFError) as e:
        raise ScanError(path, f"cannot read the depth map ({str(e).splitlines()[0] if str(e) else type(e).__name__})"
                        ) from None
    if stored.size > MAX_IMAGE_PIXELS:
        raise ScanError(path, f"depth map has {stored.size:,} values, more than scantex reads")
    return np.array(stored)


def image_size(path: Path, what: str = "photo") -> tuple[int, int]:
    """``(width, height)`` of an image file, from its header (checked against the size limit); ``what`` it is, for
    the error."""
    with open_image(path, what) as im:
        return im.size
