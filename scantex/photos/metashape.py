"""Agisoft Metashape's (PhotoScan's) cameras: the XML of ``File > Export > Export Cameras`` beside the photos.

Photogrammetry of façades and heritage sites is mostly made in Metashape; its mesh export and its cameras share one
frame. Conventions, and what scantex does with them:

- ``<document><chunk>``: the first chunk is read (a file of several is warned about). Its ``<sensors>`` hold each
  camera model's ``<calibration>`` (``class="adjusted"`` preferred to ``"initial"``) at a ``<resolution>``:
  ``f`` (``fx``, ``fy`` in PhotoScan's files), ``cx``, ``cy`` (the principal point's offset from the image's centre;
  PhotoScan's ``fx`` files give it from the corner), ``b1``, ``b2`` (affinity and skew), ``k1``-``k4``, ``p1``,
  ``p2``. Metashape's model (its manual's appendix): ``x' = x (1 + k1 r^2 + ... + k4 r^8) + p1 (r^2 + 2 x^2) + 2 p2
  x y``, ``y' = y (...) + p2 (r^2 + 2 y^2) + 2 p1 x y``, ``u = w / 2 + cx + x' (f + b1) + y' b2``, ``v = h / 2 + cy
  + y' f``, pixel centres at half pixels (the top-left pixel's centre at ``(0.5, 0.5)``): scantex's ``K = [[f + b1,
  b2, w / 2 + cx - 0.5], [0, f, h / 2 + cy - 0.5]]``, OpenCV's tangential terms ``(p2, p1)`` (the two are swapped
  against OpenCV's). A distortion over ``max_distortion_px`` is undone as each photo is read
  (:mod:`scantex.photos.lens`). ``frame``, ``fisheye`` (equidistant: ``x = x0 atan(r0) / r0`` before the model
  above, its manual's fisheye) and ``equisolid_fisheye`` sensors are read; the cameras of spherical and
  cylindrical ones, or of one with ``p3``/``p4`` terms, are skipped with a warning (refused when no other is left).
- ``<camera label transform sensor_id component_id enabled>``: ``transform`` is the 4x4 camera-to-chunk matrix (row
  by row; the camera's axes are OpenCV's: +x right, +y down, +z forward). The chunk's frame is carried to the
  world by the camera's component's ``<transform>`` (Metashape 2) and the chunk's (``rotation``, ``translation``,
  ``scale``: ``X = s R x + t``): the frame the mesh is exported in. A georeferenced chunk's world is geocentric
  (its translation millions of metres): said in a warning, as a mesh exported in a projected or local frame is not
  in it. Cameras without a transform (not aligned) or disabled are skipped, with a count.
- ``label``: the photo's file name, with or without its extension, or a path; looked for beside the XML, in its
  ``images/`` or ``photos/`` folder, or in ``image_dir``.
"""

from __future__ import annotations

import logging
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from scantex.errors import ScanError
from scantex.photos.conventions import MAX_DISTORTION_PX, check_intrinsics, pinhole_camera, world_to_camera_from
from scantex.photos.files import check_sizes, converts, load_xml, located
from scantex.photos.photoset import Distortion, PhotoSet
from scantex.views.camera import Camera

log = logging.getLogger(__name__)

FORMAT = "metashape"
#: the photo file types looked for when a camera's label has no extension
IMAGE_SUFFIXES = (".jpg", ".JPG", ".jpeg", ".JPEG", ".png", ".PNG", ".tif", ".TIF", ".tiff", ".TIFF")
#: a larger XML is refused before it is parsed (a cameras file of 10,000 photos is a few MB)
MAX_XML_BYTES = 256 * 2**20
#: Metashape's sensor types scantex reads, and their projection before the distortion polynomial
PROJECTIONS = {"frame": "perspective", "fisheye": "equidistant", "equisolid_fisheye": "equisolid"}
#: a world frame this far from its origin is taken for geocentric coordinates (metres)
GEOCENTRIC_M = 1e5


@dataclass(frozen=True)
class _Sensor:
    K: np.ndarray
    size: tuple[int, int]
    distortion: Distortion | None
    refused: str | None  # why its cameras cannot be read (a fisheye), or None


def is_cameras_xml(path: Path) -> bool:
    """Whether ``path`` is a Metashape cameras XML (its opening names a ``document`` and a ``chunk``)."""
    try:
        with open(path, "rb") as f:
            head = f.read(4096).lower()
    except OSError:
        return False
    return b"<document" in head and b"<chunk" in head


def cameras_file(folder: Path) -> Path | None:
    """The Metashape cameras XML in ``folder`` (the first by name), else ``None``."""
    try:
        candidates = sorted(p for p in folder.iterdir() if p.suffix.lower() == ".xml" and p.is_file())
    except OSError:
        return None
    return next((p for p in candidates if is_cameras_xml(p)), None)


def load_metashape(path: str | Path, *, image_dir: str | Path | None = None,
                   max_distortion_px: float = MAX_DISTORTION_PX) -> PhotoSet:
    """Read a Metashape cameras XML (the file, or a folder holding one); conventions in the module docstring.

    Raises:
        ScanError: not a Metashape XML, no aligned camera, an unsupported sensor, a photo not found or of another
            size than its sensor's calibration.
    """
    path = Path(path)
    xml = located(path, cameras_file, "no Metashape cameras XML in it")
    chunk = _chunk(xml)
    sensors = {s.get("id"): _sensor(s, xml) for s in chunk.iterfind("sensors/sensor")}
    to_world = _transform(chunk.find("transform"), xml, "the chunk's transform")
    components = {c.get("id"): _transform(c.find("transform"), xml, f"component {c.get('id')}'s transform")
                  for c in chunk.iterfind("components/component")}
    folders = [Path(image_dir)] if image_dir is not None else [xml.parent, xml.parent / "images",
                                                               xml.parent / "photos"]
    cameras, images, distortions, lenses = [], [], [], []
    unaligned = disabled = 0
    unread: dict[str, int] = {}  # cameras of sensors scantex does not read, by why
    for element in chunk.iterfind("cameras//camera"):
        label = element.get("label") or element.get("id") or "?"
        what = f"camera {label!r}"
        if element.get("enabled", "true").lower() in ("false", "0"):
            disabled += 1
            continue
        if element.find("transform") is None:
            unaligned += 1
            continue
        sensor = sensors.get(element.get("sensor_id"))
        if sensor is None:
            raise ScanError(xml, f"{what}: its sensor {element.get('sensor_id')!r} has no calibration in the file")
        if sensor.refused:
            unread[sensor.refused] = unread.get(sensor.refused, 0) + 1
            continue
        component_id = element.get("component_id")
        if components and component_id is not None and component_id not in components:
            raise ScanError(xml, f"{what}: its component {component_id!r} is not in the file (<components>): "
                                 "export the cameras again with the chunk's components")
        component = components.get(component_id, np.eye(4))
        c2w = to_world @ component @ _matrix(element.find("transform").text, 16, xml, f"{what}'s transform")
        camera = Camera(sensor.K, _world_to_camera(c2w, xml, what), *sensor.size)
        camera, lens = pinhole_camera(sensor.distortion, camera, max_distortion_px, xml, what)
        cameras.append(camera)
        distortions.append(sensor.distortion)
        lenses.append(lens)
        images.append(_photo(label, folders, xml, what))
    if not cameras:
        if unread:
            raise ScanError(xml, f"none of its cameras can be read: {'; '.join(unread)}")
        raise ScanError(xml, "none of its cameras is aligned (no camera has a transform)" if unaligned else
                        "lists no cameras")
    for why, count in unread.items():
        log.warning("%s: %d of its cameras skipped: %s", xml, count, why)
    for count, why in ((unaligned, "not aligned (no transform)"), (disabled, "disabled")):
        if count:
            log.warning("%s: %d of its cameras are %s: skipped", xml, count, why)
    far = max(np.linalg.norm(c.world_to_camera[:3, :3].T @ c.world_to_camera[:3, 3]) for c in cameras)
    if far > GEOCENTRIC_M:
        log.warning("%s: the cameras are %.0f km from the frame's origin: a georeferenced chunk's geocentric "
                    "coordinates; the mesh must be exported in that frame (EPSG::4978), not a projected or local "
                    "one", xml, far / 1000)
    check_sizes(cameras, images, xml)
    return PhotoSet(cameras=tuple(cameras), images=tuple(images), source=xml, format=FORMAT,
                    distortions=tuple(distortions), lenses=tuple(lenses))


def _chunk(xml: Path) -> ET.Element:
    root = load_xml(xml, MAX_XML_BYTES, "a cameras file scantex reads")
    chunks = root.findall("chunk") if root.tag == "document" else []
    if not chunks:
        raise ScanError(xml, "not a Metashape cameras file: no <document><chunk>")
    if len(chunks) > 1:
        log.warning("%s holds %d chunks: reading the first (%s)", xml, len(chunks), chunks[0].get("label", "?"))
    return chunks[0]


def _number(element: ET.Element, tag: str, xml: Path, what: str, default: float | None = 0.0) -> float:
    child = element.find(tag)
    if child is None or child.text is None:
        if default is None:
            raise ScanError(xml, f"{what}: no <{tag}>")
        return default
    try:
        value = float(child.text)
    except ValueError:
        raise ScanError(xml, f"{what}: <{tag}> is not a number ({child.text.strip()[:20]!r})") from None
    if not np.isfinite(value):
        raise ScanError(xml, f"{what}: <{tag}> is not finite")
    return value


def _sensor(element: ET.Element, xml: Path) -> _Sensor | None:
    what = f"sensor {element.get('label') or element.get('id')!r}"
    kind = element.get("type", "frame")
    calibrations = element.findall("calibration")
    calib = next((c for c in calibrations if c.get("class") == "adjusted"), calibrations[0] if calibrations else None)
    if calib is None:
        return None
    kind = calib.get("type", kind)
    if kind not in PROJECTIONS:
        return _Sensor(np.eye(3), (0, 0), None, f"{what} is a {kind} camera; scantex reads frame and fisheye "
                                                f"cameras")
    resolution = calib.find("resolution")
    if resolution is None:
        resolution = element.find("resolution")
    try:
        w, h = int(resolution.get("width")), int(resolution.get("height"))
    except (AttributeError, TypeError, ValueError):
        raise ScanError(xml, f"{what}: no <resolution width height>") from None
    if calib.find("f") is not None:  # Metashape: f, the principal point's offset from the centre
        f = _number(calib, "f", xml, what, None)
        fx, fy = f + _number(calib, "b1", xml, what), f
        cx, cy = w / 2 + _number(calib, "cx", xml, what), h / 2 + _number(calib, "cy", xml, what)
    else:  # PhotoScan: fx, fy, the principal point from the corner
        fx, fy = _number(calib, "fx", xml, what, None), _number(calib, "fy", xml, what, None)
        cx, cy = _number(calib, "cx", xml, what, w / 2), _number(calib, "cy", xml, what, h / 2)
    K = np.array([[fx, _number(calib, "b2", xml, what), cx - 0.5], [0.0, fy, cy - 0.5], [0.0, 0.0, 1.0]])
    check_intrinsics(K, w, h, xml, what)
    if _number(calib, "p3", xml, what) or _number(calib, "p4", xml, what):
        return _Sensor(K, (w, h), None, f"{what} has p3/p4 tangential terms, which scantex does not model "
                                        f"(undistort its photos in Metashape: Export > Undistort Photos)")
    radial = [_number(calib, f"k{i}", xml, what) for i in range(1, 5)]
    while radial and radial[-1] == 0.0:
        radial.pop()
    p1, p2 = _number(calib, "p1", xml, what), _number(calib, "p2", xml, what)
    projection = PROJECTIONS[kind]
    distortion = (Distortion("Metashape" if kind == "frame" else f"Metashape {kind}", tuple(radial), (p2, p1),
                             projection=projection) if radial or p1 or p2 or kind != "frame" else None)
    return _Sensor(K, (w, h), distortion, None)


def _matrix(text: str | None, n: int, xml: Path, what: str) -> np.ndarray:
    try:
        values = np.array([float(v) for v in (text or "").split()])
    except ValueError:
        raise ScanError(xml, f"{what} is not {n} numbers") from None
    if values.size != n or not np.isfinite(values).all():
        raise ScanError(xml, f"{what} is not {n} finite numbers (got {values.size})")
    return values.reshape(4, 4) if n == 16 else values


def _transform(element: ET.Element | None, xml: Path, what: str) -> np.ndarray:
    """``(4, 4)`` similarity of a chunk's or component's ``<transform>`` (rotation, translation, scale; or a
    ``<matrix>``); the identity where there is none."""
    out = np.eye(4)
    if element is None:
        return out
    if element.find("matrix") is not None:
        return _matrix(element.find("matrix").text, 16, xml, what)
    rotation = element.find("rotation")
    if rotation is not None:
        out[:3, :3] = _matrix(rotation.text, 9, xml, f"{what}'s rotation").reshape(3, 3)
    translation = element.find("translation")
    if translation is not None:
        out[:3, 3] = _matrix(translation.text, 3, xml, f"{what}'s translation")
    out[:3, :3] *= _number(element, "scale", xml, what, 1.0)
    return out


def _world_to_camera(c2w: np.ndarray, xml: Path, what: str) -> np.ndarray:
    """OpenCV world-to-camera of a camera-to-world similarity (the chunk's scale taken out of its rotation)."""
    scale = np.cbrt(np.linalg.det(c2w[:3, :3]))
    if not scale > 0:
        raise ScanError(xml, f"{what}: its transform is no rigid motion (determinant {scale ** 3:.3g})")
    return world_to_camera_from((c2w[:3, :3] / scale).T, c2w[:3, 3], xml, what,
                                "its transform's rotation is not orthonormal")


def _photo(label: str, folders: list[Path], xml: Path, what: str) -> Path:
    """The photo file a camera's label names (with or without its extension, or a path), in ``folders``."""
    named = Path(label)
    if named.is_absolute() and named.is_file():
        return named
    for folder in folders:
        for name in (label, named.name):
            candidate = folder / name
            if candidate.is_file():
                return candidate
            for suffix in IMAGE_SUFFIXES:
                if candidate.with_name(candidate.name + suffix).is_file():
                    return candidate.with_name(candidate.name + suffix)
    raise ScanError(xml, f"{what}: its photo is not in {', '.join(str(f) for f in folders)} (with or without "
                         f"{', '.join(IMAGE_SUFFIXES[::2])}; name the photos' folder with --images DIR)")


def write_metashape(photos: PhotoSet, out_dir: str | Path) -> Path:
    """Write ``out_dir/cameras.xml`` (one chunk, its frame the world's; a sensor per distinct camera model) with
    the photos copied beside it as ``photo_000.<ext>``; returns the XML's path. A photo undistorted when read is
    written as stored, with its lens, where Metashape's model holds it, else undistorted (a PNG); a small distortion
    ignored when read that Metashape's model cannot hold (a rational one) raises ``ValueError``."""
    from scantex.io.atomic import atomic_files
    from scantex.photos.files import write_photo

    photos = photos.as_stored(_holds)  # an undistorted photo as stored with its lens, where Metashape's model holds it
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    document = ET.Element("document", version="2.0.0")
    chunk = ET.SubElement(document, "chunk", label="scantex", enabled="true")
    sensors = ET.SubElement(chunk, "sensors")
    cameras = ET.SubElement(chunk, "cameras")
    models: dict[tuple, str] = {}
    with atomic_files() as files:
        for i, (cam, image, distortion) in enumerate(zip(photos.cameras, photos.images, photos.distortions)):
            model = _calibration(cam, distortion, i)
            if model not in models:
                models[model] = str(len(models))
                kind = model[2]
                sensor = ET.SubElement(sensors, "sensor", id=models[model], label=f"camera {models[model]}",
                                       type=kind)
                ET.SubElement(sensor, "resolution", width=str(cam.width), height=str(cam.height))
                calib = ET.SubElement(sensor, "calibration", type=kind, **{"class": "adjusted"})
                ET.SubElement(calib, "resolution", width=str(cam.width), height=str(cam.height))
                for tag, value in model[3:]:
                    ET.SubElement(calib, tag).text = repr(value)
            name = write_photo(files, photos, i, out_dir / f"photo_{i:03d}").name
            element = ET.SubElement(cameras, "camera", id=str(i), sensor_id=models[model], label=name)
            c2w = np.linalg.inv(cam.world_to_camera)
            ET.SubElement(element, "transform").text = " ".join(repr(float(v)) for v in c2w.ravel())
        ET.indent(document)
        files.path(out_dir / "cameras.xml").write_bytes(ET.tostring(document, encoding="UTF-8", xml_declaration=True))
    return out_dir / "cameras.xml"


def _holds(distortion: Distortion, cam: Camera) -> bool:
    return converts(lambda: _calibration(cam, distortion, 0))


def _calibration(cam: Camera, distortion: Distortion | None, i: int) -> tuple:
    """``(width, height, sensor type, (tag, value), ...)``: ``cam``'s model in Metashape's terms (the inverse of
    :func:`_sensor`)."""
    (fx, b2, cx), (_, f, cy) = cam.K[0], cam.K[1]
    tags = [("f", float(f)), ("cx", float(cx + 0.5 - cam.width / 2)), ("cy", float(cy + 0.5 - cam.height / 2))]
    tags += [(t, float(v)) for t, v in (("b1", fx - f), ("b2", b2)) if v]
    if distortion is not None and not distortion.is_zero:
        if distortion.radial_denominator or distortion.inverse_radial or len(distortion.radial) > 4:
            raise ValueError(f"photo {i}: Metashape's model cannot hold a {distortion.model} distortion")
        tags += [(f"k{n + 1}", float(k)) for n, k in enumerate(distortion.radial)]
        p1, p2 = distortion.tangential
        tags += [("p1", float(p2)), ("p2", float(p1))]
    kind = next(k for k, p in PROJECTIONS.items() if p == (distortion.projection if distortion else "perspective"))
    return (cam.width, cam.height, kind, *tags)
