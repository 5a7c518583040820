"""RealityCapture's (RealityScan's) XMP sidecars: ``Alignment > Export > Registration > XMP``, one ``<photo>.xmp``
beside each photo, what RealityCapture reads back and what heritage and façade captures are aligned in.

Conventions (RealityCapture's support article "XMP camera math", its help's sample file, and the readers and writers
of camorph, EasyVolcap, AliceVision's importKnownPoses and Blender's camera projection painter, which agree on
them), and what scantex does with them:

- Each property (namespace ``http://www.capturingreality.com/ns/xcr/1.1#``) is an attribute of ``rdf:Description``
  or a child element of it: both forms are read. ``_common.xmp`` in the folder (any case) gives every photo's
  calibration defaults (a pose in it is not read).
- ``Rotation``: the world-to-camera rotation ``R``, row by row, the camera's axes OpenCV's (+x right, +y down, +z
  forward); ``Position``: the camera's centre ``C``, so ``x_cam = R (X - C)``. A file with neither is a
  calibration alone (skipped, with a count); one with one of the two is refused. ``Coordinates`` other than
  ``absolute`` (``relative``: the export's "exact" mode) are read as given, with a warning: their frame is the
  mesh's only if the mesh was exported in it. Positions over 100 km from the origin are taken for a georeferenced
  export (warned: the mesh must be exported in the same coordinate system, RealityCapture's "same as XMP").
- ``FocalLength35mm``: the focal length in a 36 mm frame over the image's longer side ``S = max(w, h)``: ``fx = f35 /
  36 * S``, ``fy = fx * AspectRatio``. ``PrincipalPointU``, ``PrincipalPointV``: the principal point's offset from
  the image's centre in units of ``S`` (``v`` down): ``cx = w / 2 + U S``, ``cy = h / 2 + V S`` with pixel centres at
  integers, as RealityCapture's own OpenCV export and EasyVolcap's and Meshroom's converters write it (whether its
  centre is half a pixel from there could not be checked here). A non-zero ``Skew`` (only its "K+" models fit one)
  is refused per photo, its unit being unknown.
- ``DistortionModel`` and the six ``DistortionCoeficients`` (RealityCapture's spelling; the dictionary's read too)
  ``k1 k2 k3 k4 t1 t2``: ``brown3`` (``k1``-``k3``), ``brown4`` (``k1``-``k4``), ``brown3t2`` and ``brown4t2`` (with
  the tangential pair), Brown's model of the normalised point, distorting it: ``x_d = x (1 + k1 r^2 + ... ) + t1
  (r^2 + 2 x^2) + 2 t2 x y``, ``y_d = y (...) + t2 (r^2 + 2 y^2) + 2 t1 x y``, OpenCV's with ``p1 = t2``, ``p2 =
  t1`` (the pair swapped). Undone as each photo is read where it moves pixels by more than ``max_distortion_px``
  (:mod:`scantex.photos.lens`). ``perspective`` (or ``none``, or coefficients all zero, whatever the model): no
  distortion. The ``division`` model and the rational ones with coefficients are not read (photos skipped, with
  the reason; RealityCapture's Bundler export writes undistorted photos), nor a Brown model without coefficients.
- The photo: the file beside its XMP of the same name and a photo's extension, any case (``IMG_1.xmp`` or
  ``IMG_1.JPG.xmp`` for ``IMG_1.JPG``), else in ``image_dir``. A photo with both gets ``IMG_1.xmp``, as
  RealityCapture reads it (a warning says so).
"""

from __future__ import annotations

import logging
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

from scantex.errors import ScanError
from scantex.photos.conventions import MAX_DISTORTION_PX, check_intrinsics, pinhole_camera, world_to_camera_from
from scantex.photos.files import check_sizes, converts, load_xml
from scantex.photos.photoset import Distortion, PhotoSet, image_size
from scantex.views.camera import Camera

log = logging.getLogger(__name__)

FORMAT = "realitycapture"
XCR = "http://www.capturingreality.com/ns/xcr/1.1#"
RDF = "http://www.w3.org/1999/02/22-rdf-syntax-ns#"
#: the sidecar every photo's properties default to
COMMON = "_common.xmp"
#: a sidecar is small; a larger file is no RealityCapture XMP
MAX_XMP_BYTES = 4 * 2**20
#: RealityCapture's Brown models: how many radial terms, and whether the tangential pair
BROWN = {"brown3": (3, False), "brown4": (4, False), "brown3t2": (3, True), "brown4t2": (4, True)}
#: models whose coefficients are not read: no distortion (``none``: what some converters write)
NO_LENS = ("perspective", "none", "")
#: the photo files looked for beside an XMP (any case)
PHOTO_SUFFIXES = (".jpg", ".jpeg", ".png", ".tif", ".tiff", ".webp")
#: ``Coordinates`` RealityCapture writes for an export in the frame it aligned in (any other: warned about)
ABSOLUTE = "absolute"
#: a camera this far from the frame's origin is taken for a georeferenced export (metres)
GEOREFERENCED_M = 1e5
#: the pose properties, a photo's own (``_common.xmp``'s are not read)
POSE = ("Rotation", "Position")


def is_xmp(path: Path) -> bool:
    """Whether ``path`` is a RealityCapture XMP (it declares the ``xcr`` namespace in its first 64 KiB)."""
    try:
        with open(path, "rb") as f:
            return XCR.encode() in f.read(65536)
    except OSError:
        return False


def sidecars(folder: Path) -> list[Path]:
    """The RealityCapture XMPs in ``folder``, by name (``_common.xmp`` left out)."""
    try:
        found = sorted(p for p in folder.glob("*.[xX][mM][pP]") if p.name.lower() != COMMON and p.is_file())
    except OSError:
        return []
    return [p for p in found if is_xmp(p)]


def xmp_folder(folder: Path) -> Path | None:
    """``folder`` when it holds RealityCapture XMPs, else ``None``."""
    return folder if sidecars(folder) else None


def load_realitycapture(path: str | Path, *, image_dir: str | Path | None = None,
                        max_distortion_px: float = MAX_DISTORTION_PX) -> PhotoSet:
    """Read RealityCapture's XMP sidecars (the folder holding them, or one of them: its folder's are read);
    conventions in the module docstring. ``image_dir``: where the photos are, by name, when not beside the XMPs.

    Raises:
        ScanError: no XMP, a malformed one, a photo not found, no photo with a pose and a lens scantex reads.
    """
    path = Path(path)
    folder = path.parent if path.is_file() else path
    files = sidecars(folder)
    if not files:
        raise ScanError(path, "no RealityCapture XMP (xcr) files in it")
    common_file = next((p for p in folder.glob("*.[xX][mM][pP]") if p.name.lower() == COMMON and p.is_file()), None)
    common = ({k: v for k, v in _properties(common_file).items() if k not in POSE} if common_file is not None
              else {})
    beside, elsewhere = _photo_files(folder), _photo_files(Path(image_dir)) if image_dir is not None else {}
    cameras, images, distortions, lenses = [], [], [], []
    unposed = ignored_coefficients = 0
    skipped: dict[str, int] = {}  # photos of a lens or camera scantex does not read, by why
    frames: set[str] = set()
    for xmp, image in _one_xmp_a_photo(files, beside, elsewhere, image_dir):
        what = f"photo {image.name!r}"
        props = {**common, **_properties(xmp)}
        has_rotation, has_position = "Rotation" in props, "Position" in props
        if not has_rotation and not has_position:
            unposed += 1
            continue
        if has_rotation != has_position:
            raise ScanError(xmp, f"it has a {'Rotation' if has_rotation else 'Position'} but no "
                                 f"{'Position' if has_rotation else 'Rotation'}")
        w, h = image_size(image)
        camera, why = _camera(props, w, h, xmp, what)
        coefficients = _coefficients(props, xmp, what)
        distortion, lens_why = _distortion(props, coefficients) if why is None else (None, None)
        why = why or lens_why
        if why is not None:
            skipped[why] = skipped.get(why, 0) + 1
            continue
        ignored_coefficients += distortion is None and coefficients is not None and coefficients.any()
        frames.add(props.get("Coordinates", ABSOLUTE).strip().lower())
        camera, lens = pinhole_camera(distortion, camera, max_distortion_px, xmp, what)
        cameras.append(camera)
        images.append(image)
        distortions.append(distortion)
        lenses.append(lens)
    if not cameras:
        if skipped:
            raise ScanError(folder, f"none of its photos can be read: {'; '.join(skipped)}")
        raise ScanError(folder, "none of its XMPs has a pose (Rotation and Position): export the registration "
                                "from RealityCapture after aligning the photos")
    for why, count in skipped.items():
        log.warning("%s: %d of its photos skipped: %s", folder, count, why)
    if unposed:
        log.warning("%s: %d of its XMPs hold no pose (a calibration alone): skipped", folder, unposed)
    if ignored_coefficients:
        log.warning("%s: %d of its photos have DistortionCoeficients but no lens model or a perspective one (no "
                    "distortion): the coefficients are not used", folder, ignored_coefficients)
    if frames - {ABSOLUTE}:
        log.warning("%s: its poses are in %s coordinates (RealityCapture's 'exact' export is relative): the mesh is "
                    "in their frame only if exported in it ('same as XMP')", folder,
                    ", ".join(sorted(frames - {ABSOLUTE})))
    far = max(np.linalg.norm(c.world_to_camera[:3, :3].T @ c.world_to_camera[:3, 3]) for c in cameras)
    if far > GEOREFERENCED_M:
        log.warning("%s: the cameras are %.0f km from the frame's origin: a georeferenced export; the mesh must be "
                    "exported in the same coordinate system (RealityCapture's 'same as XMP')", folder, far / 1000)
    check_sizes(cameras, images, folder)
    return PhotoSet(cameras=tuple(cameras), images=tuple(images), source=folder, format=FORMAT,
                    distortions=tuple(distortions), lenses=tuple(lenses))


def _photo_files(folder: Path) -> dict[str, Path]:
    """``folder``'s photo files by their lower-case names."""
    try:
        return {p.name.lower(): p for p in folder.iterdir() if p.suffix.lower() in PHOTO_SUFFIXES and p.is_file()}
    except OSError:
        return {}


def _one_xmp_a_photo(files: list[Path], beside: dict[str, Path], elsewhere: dict[str, Path],
                     image_dir: str | Path | None) -> list[tuple[Path, Path]]:
    """``(xmp, photo)`` pairs: the photo of each XMP's name (``IMG_1.xmp``, or ``IMG_1.JPG.xmp``) beside it, else in
    ``image_dir``. A photo with two XMPs gets RealityCapture's (``IMG_1.xmp``: it ignores ``IMG_1.JPG.xmp``), with a
    warning."""
    def photo_named(xmp: Path) -> bool:  # IMG_1.JPG.xmp
        return Path(xmp.stem).suffix.lower() in PHOTO_SUFFIXES

    pairs: dict[Path, Path] = {}
    for xmp in files:
        stem = xmp.stem.lower()
        names = [stem] if photo_named(xmp) else [stem + s for s in PHOTO_SUFFIXES]
        image = next((found[n] for found in (beside, elsewhere) for n in names if n in found), None)
        if image is None:
            raise ScanError(xmp, "no photo of its name beside it" + (
                f" or in {image_dir}" if image_dir is not None else " (name the photos' folder with --images DIR)"))
        other = pairs.get(image)
        if other is not None:
            kept, left = (other, xmp) if photo_named(xmp) or not photo_named(other) else (xmp, other)
            log.warning("%s: two XMPs for photo %s: %s read, %s not (RealityCapture reads the XMP named as the photo "
                        "less its extension)", xmp.parent, image.name, kept.name, left.name)
            xmp = kept
        pairs[image] = xmp
    return [(xmp, image) for image, xmp in pairs.items()]


def _properties(xmp: Path) -> dict[str, str]:
    """The ``xcr`` properties of an XMP's ``rdf:Description`` elements, attributes and child elements alike."""
    root = load_xml(xmp, MAX_XMP_BYTES, "a RealityCapture XMP")
    props: dict[str, str] = {}
    for description in root.iter(f"{{{RDF}}}Description"):
        for key, value in description.attrib.items():
            if key.startswith(f"{{{XCR}}}"):
                props.setdefault(key[len(XCR) + 2:], value)
        for child in description:
            if child.tag.startswith(f"{{{XCR}}}"):
                props.setdefault(child.tag[len(XCR) + 2:], (child.text or "").strip())
    return props


def _numbers(props: dict[str, str], key: str, n: int, xmp: Path, what: str) -> np.ndarray:
    try:
        values = np.array([float(v) for v in props[key].replace(",", " ").split()], np.float64)
    except ValueError:
        raise ScanError(xmp, f"{what}: its {key} is not numbers ({props[key][:40]!r})") from None
    if values.size != n:
        raise ScanError(xmp, f"{what}: its {key} is not {n} numbers (it has {values.size})")
    if not np.isfinite(values).all():
        raise ScanError(xmp, f"{what}: its {key} is not finite ({props[key][:40]!r})")
    return values


def _number(props: dict[str, str], key: str, default: float | None, xmp: Path, what: str) -> float:
    if key not in props:
        if default is None:
            raise ScanError(xmp, f"{what}: no {key}")
        return default
    return float(_numbers(props, key, 1, xmp, what)[0])


def _camera(props: dict[str, str], w: int, h: int, xmp: Path, what: str) -> tuple[Camera | None, str | None]:
    """``(camera, None)``, or ``(None, why)`` for a camera scantex does not read (a skew)."""
    if _number(props, "Skew", 0.0, xmp, what) != 0.0:
        return None, "a skewed camera (Skew), whose unit scantex does not know: export the cameras without it"
    focal, aspect = _number(props, "FocalLength35mm", None, xmp, what), _number(props, "AspectRatio", 1.0, xmp, what)
    for key, value in (("FocalLength35mm", focal), ("AspectRatio", aspect)):
        if not value > 0:
            raise ScanError(xmp, f"{what}: its {key} is {value:g}, not a positive number")
    side = max(w, h)
    fx = focal / 36.0 * side
    cx = w / 2.0 + _number(props, "PrincipalPointU", 0.0, xmp, what) * side
    cy = h / 2.0 + _number(props, "PrincipalPointV", 0.0, xmp, what) * side
    K = np.array([[fx, 0.0, cx], [0.0, fx * aspect, cy], [0.0, 0.0, 1.0]])
    check_intrinsics(K, w, h, xmp, what)
    R = _numbers(props, "Rotation", 9, xmp, what).reshape(3, 3)
    w2c = world_to_camera_from(R, _numbers(props, "Position", 3, xmp, what), xmp, what,
                               "its Rotation is no rotation")
    return Camera(K, w2c, w, h), None


def _coefficients(props: dict[str, str], xmp: Path, what: str) -> np.ndarray | None:
    """The six ``DistortionCoeficients`` (RealityCapture's spelling, or the dictionary's), ``None`` where there are
    none."""
    key = next((k for k in ("DistortionCoeficients", "DistortionCoefficients") if k in props), None)
    return None if key is None else _numbers(props, key, 6, xmp, what)


def _distortion(props: dict[str, str], coefficients: np.ndarray | None) -> tuple[Distortion | None, str | None]:
    """``(distortion or None, None)``, or ``(None, why)`` for a lens scantex does not read. Coefficients all zero
    are no distortion whatever the model (RealityCapture's help's sample: ``division`` with zeros)."""
    model = props.get("DistortionModel", "").strip()
    if model.lower() in NO_LENS or (coefficients is not None and not coefficients.any()):
        return None, None
    if model.lower() not in BROWN:
        return None, (f"a {model} lens model, which scantex does not read (Brown's: brown3, brown4, brown3t2, "
                      "brown4t2; RealityCapture's Bundler export writes undistorted photos)")
    if coefficients is None:
        return None, f"a {model} lens without its DistortionCoeficients"
    n_radial, tangential = BROWN[model.lower()]
    radial = [float(k) for k in coefficients[:n_radial]]
    while radial and radial[-1] == 0.0:
        radial.pop()
    t1, t2 = (float(coefficients[4]), float(coefficients[5])) if tangential else (0.0, 0.0)
    distortion = Distortion(f"RealityCapture {model}", tuple(radial), (t2, t1))
    return (None if distortion.is_zero else distortion), None


def write_realitycapture(photos: PhotoSet, out_dir: str | Path) -> Path:
    """Write each photo as ``out_dir/photo_000.<ext>`` with its XMP ``photo_000.xmp`` beside it; returns
    ``out_dir``. A photo undistorted when read is written as stored with its lens where Brown's model holds it
    (four radial terms, the tangential pair), else undistorted (a PNG).

    Raises:
        ValueError: a camera with a skew (RealityCapture's unit for it is not known here).
    """
    from scantex.io.atomic import atomic_files
    from scantex.photos.files import write_photo

    photos = photos.as_stored(_holds)
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    ET.register_namespace("x", "adobe:ns:meta/")
    ET.register_namespace("rdf", RDF)
    ET.register_namespace("xcr", XCR)
    with atomic_files() as files:
        for i, (cam, distortion) in enumerate(zip(photos.cameras, photos.distortions)):
            attributes = _attributes(cam, distortion, i)
            name = write_photo(files, photos, i, out_dir / f"photo_{i:03d}")
            meta = ET.Element("{adobe:ns:meta/}xmpmeta")
            description = ET.SubElement(ET.SubElement(meta, f"{{{RDF}}}RDF"), f"{{{RDF}}}Description",
                                        {f"{{{XCR}}}{k}": v for k, v in attributes.items()
                                         if k != "DistortionCoeficients"})
            centre = -cam.world_to_camera[:3, :3].T @ cam.world_to_camera[:3, 3]
            for key, values in (("Rotation", cam.world_to_camera[:3, :3].ravel()), ("Position", centre)):
                ET.SubElement(description, f"{{{XCR}}}{key}").text = " ".join(repr(float(v)) for v in values)
            ET.SubElement(description, f"{{{XCR}}}DistortionCoeficients").text = attributes["DistortionCoeficients"]
            ET.indent(meta)
            files.path(out_dir / f"{name.stem}.xmp").write_bytes(ET.tostring(meta, encoding="UTF-8"))
    return out_dir


def _holds(distortion: Distortion, cam: Camera) -> bool:
    return converts(lambda: _attributes(cam, distortion, 0))


def _attributes(cam: Camera, distortion: Distortion | None, i: int) -> dict[str, str]:
    """``cam``'s calibration as RealityCapture's XMP attributes (the inverse of :func:`_camera` and
    :func:`_distortion`)."""
    K = cam.K
    if K[0, 1] != 0:
        raise ValueError(f"photo {i}: a skewed camera (K {K.tolist()}): RealityCapture's skew is not written")
    side = max(cam.width, cam.height)
    model, coefficients = "perspective", [0.0] * 6
    if distortion is not None and not distortion.is_zero:
        if (distortion.is_fisheye or distortion.radial_denominator or distortion.inverse_radial
                or len(distortion.radial) > 4):
            raise ValueError(f"photo {i}: RealityCapture's Brown model cannot hold a {distortion.model} distortion")
        p1, p2 = distortion.tangential
        tangential = bool(p1 or p2)
        model = f"brown{4 if len(distortion.radial) > 3 else 3}{'t2' if tangential else ''}"
        coefficients = [*distortion.radial, *[0.0] * (4 - len(distortion.radial)), p2, p1]
    return {"Version": "3", "PosePrior": "locked", "Coordinates": "absolute", "DistortionModel": model,
            "FocalLength35mm": repr(float(K[0, 0]) * 36.0 / side), "Skew": "0",
            "AspectRatio": repr(float(K[1, 1] / K[0, 0])),
            "PrincipalPointU": repr((float(K[0, 2]) - cam.width / 2.0) / side),
            "PrincipalPointV": repr((float(K[1, 2]) - cam.height / 2.0) / side),
            "CalibrationPrior": "exact", "DistortionCoeficients": " ".join(repr(float(v)) for v in coefficients)}
