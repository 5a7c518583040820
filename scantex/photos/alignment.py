"""Does the mesh sit where the photos' cameras see it? A check before training on the photos.

A mesh and its photos come from one capture but often not in one frame: an app that re-centres or
re-orients the mesh on export, a nerfstudio file whose world was rotated to z-up, a COLMAP model in
its own arbitrary frame. Trained through such cameras, a texture would come out as a smear. The check
renders the mesh (by ray casting) from a few photos' cameras at a reduced size and compares *edges*,
keeping only render edges that can be an edge in the photo:

- occluding contours (silhouette and depth discontinuities), **except where the mesh simply ends**: a
  partial scan's ragged open border draws a silhouette where the real surface goes on (the wall
  continues, the façade's roof meets the sky at another place than the scan stopped), so contour
  pixels within ``BORDER_PX`` of a projected open boundary edge of the (position-welded) mesh are
  dropped;
- creases: visible mesh edges whose faces meet at more than ``CREASE_DEG`` (shading changes there), and
  whose faces' surroundings still meet at more than ``CREASE_SMOOTH_DEG`` (a scan's noise bends single
  faces, not their surroundings);
- texture edges of a textured mesh, after fitting the render's exposure to the photo (a per-channel
  gain and offset), inside the mesh's image, away from its open border, from untextured holes and from
  UV chart borders (where a capture app's atlas jumps in exposure: an edge no photo has);
- the photo's edges: Sobel gradient after a Gaussian blur, thinned by non-maximum suppression and
  thresholded (a light Canny without hysteresis).

Two measures follow:

- ``edge_distance_px``: the mean distance (working pixels) from a render edge pixel to the nearest
  photo edge, each capped at ``DISTANCE_CAP`` (5 %) of the image side (a one-sided truncated chamfer
  distance), and ``baseline_px``, the same for the render's edges moved by a tenth of the image in 8
  directions: what unrelated edges score. Their ratio says whether the edges match at all;
- **the rigid motion that best brings the mesh onto the photos**: the render edges' 3D surface points
  are moved by a rotation about their centroid and a translation, chosen by robust least squares on
  their distance to the photos' edges over all checked photos (Gauss-Newton steps of scipy's
  ``least_squares`` on the photos' edge distance transforms). It says by how much the mesh is off:
  ``offset_m`` and ``turn_deg``, and ``displacement``, the median image motion of the mesh's edge
  points that this correction makes, as a share of the photo's longer side.

The set is judged misaligned when the mesh covers less than 1 % of most checked photos; when even
after the best rigid correction the edges of the best third of the photos match no better than
``MAX_EDGE_RATIO`` (0.5) of unrelated edges (a mesh in another frame matches none; an aligned room may
show only a blurred atlas's smudges in its photos of bare walls), unless the capture's depth maps confirm
the mesh (below); or when the correction moves the mesh's
image by more than ``MAX_DISPLACEMENT`` of the image side (real captures' poses are off by 1-5 px, about
0.1-0.4 %, per photo; a correction shared by all photos averages those out). Four photos are checked;
when fewer than three of them show edges, or their edges miss, up to twelve. Measured values are in
``bench/RESULTS.md`` ("alignment").

**Depth maps**, where the capture has them (RGB-D: Kinect, a phone's LiDAR), are the most direct evidence
there is: ``depth_agreement`` is the share of the mesh's pixels (away from its contours) where the photo's
depth map reads the mesh's depth within ``DEPTH_AGREE`` (2 %). A mesh fused from those very depth maps
agrees almost everywhere (median over the checked photos: the bolster 100 %, a fused apartment of Kinect
frames 87 %), while the same meshes moved by 5 cm or turned by 5 degrees agree on at most 79 % (the bolster
turned, which its edges refuse by how much) and 53 % (the apartment). When the median over the checked
photos with depth reaches ``DEPTH_CONFIRMS`` (80 %), the edges' "miss" is not held against the mesh: a bare
fused mesh's edges are the noisy contours and creases of a depth fusion, which may match a room's photos
no better than random ones (the bare apartment: 0.55). Depth maps only confirm: one that disagrees may be a depth camera not registered
to the colour camera (photo mode then uses the photo without it), so it refuses nothing. A measured move
or turn (the rigid correction above) is refused whatever the depth maps say.
"""

from __future__ import annotations

import dataclasses
import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from scantex.arrays import unique_rows
from scantex.errors import ScanError
from scantex.photos.photoset import PhotoSet
from scantex.scan import Scan
from scantex.views.camera import Camera

log = logging.getLogger(__name__)

#: a photo the mesh covers less of than this does not count as seeing it
MIN_COVERAGE = 0.01
#: edge distance / random-offset distance above which the mesh is judged misaligned
MAX_EDGE_RATIO = 0.5
#: image motion (share of the longer image side) of the best rigid correction above which the mesh is
#: judged to be off, when the correction is also a real turn or shift (below)
MAX_DISPLACEMENT = 0.006
#: the correction must also turn the mesh by more than this, or shift it by more than ``MAX_SHIFT`` of the
#: scene's size, to refuse: the estimate's own wander on aligned synthetic captures moved their image by up
#: to 1 % (the demo room: 1.0 cm in a 5 m room, 0.0 degrees; four toy photos of a cube: 1.1 degrees)
MAX_TURN_DEG = 2.0
MAX_SHIFT = 0.02
#: fewest render edge pixels for a photo's edge distance to count
MIN_EDGE_PIXELS = 20
#: photos with edges to compare below which more photos are checked (up to ``check_alignment``'s
#: ``max_photos``)
MIN_JUDGED = 3
#: the edge ratio judged is this quantile of the photos' ratios (the best third): see :func:`_verdict`
MATCH_QUANTILE = 1 / 3
#: edge distances are capped at this share of the longer image side (a truncated chamfer distance:
#: one render edge with no counterpart in the photo, a cable or a shadow, must not dominate)
DISTANCE_CAP = 0.05
#: relative depth jump between neighbouring pixels that makes an occluding contour
DEPTH_JUMP = 0.1
#: dihedral angle (degrees) above which a mesh edge is a crease that shows in a photo
CREASE_DEG = 40.0
#: ... and the faces around its two faces, averaged, above this (a scan's noise bends single faces: creases
#: of a fused depth scan's noise made 60-70 % of an aligned room's render edges, matching nothing)
CREASE_SMOOTH_DEG = 20.0
#: contour pixels this close (working pixels) to a projected open boundary edge are the scan's end,
#: not an edge of the real surface
BORDER_PX = 3
#: typical size of the rigid correction's parameters (rotation vector: 3 degrees; translation: 5 % of the
#: edge points' spread), the unit of the weak prior towards no motion
PRIOR_SCALE = np.array([np.radians(3.0)] * 3 + [0.05] * 3)
#: most edge points per photo used to estimate the rigid correction
MAX_FIT_POINTS = 3000
#: relative difference between a depth map's reading and the mesh's depth within which a pixel agrees
DEPTH_AGREE = 0.02
#: median share of agreeing pixels (over the checked photos with depth maps) from which the depth maps
#: confirm the mesh is in the cameras' frame (see the module docstring)
DEPTH_CONFIRMS = 0.8
#: fewest mesh pixels with a depth reading for a photo's depth agreement to count
MIN_DEPTH_PIXELS = 100


@dataclass(frozen=True)
class PhotoAlignment:
    """How one photo agrees with the mesh rendered through its camera.

    Attributes:
        index: the photo's index in the :class:`PhotoSet`.
        image: its file.
        size: ``(width, height)`` the comparison ran at.
        coverage: share of the photo's pixels that see the mesh.
        edge_distance_px: mean distance (pixels at ``size``, each capped at ``DISTANCE_CAP`` of the
            longer side) from the render's edges to the photo's nearest edge; NaN when the render has fewer
            than ``MIN_EDGE_PIXELS`` edge pixels.
        baseline_px: the same for the render's edges moved by a tenth of the image (8 directions).
        n_edges: number of render edge pixels.
        corrected_distance_px: ``edge_distance_px`` with the mesh moved by the best rigid correction.
        n_border: contour pixels dropped because the mesh ends there (open border).
        depth_agreement: share of the mesh's pixels (away from contours, with a reading) where the photo's
            depth map agrees with the mesh's depth within ``DEPTH_AGREE``; NaN without a depth map.
    """

    index: int
    image: Path
    size: tuple[int, int]
    coverage: float
    edge_distance_px: float
    baseline_px: float
    n_edges: int
    corrected_distance_px: float = float("nan")
    n_border: int = 0
    depth_agreement: float = float("nan")

    @property
    def ratio(self) -> float:
        """``edge_distance_px / baseline_px``: about 0 aligned, about 1 unrelated."""
        return _ratio(self.edge_distance_px, self.baseline_px)

    @property
    def corrected_ratio(self) -> float:
        """The ratio after the best rigid correction."""
        return _ratio(self.corrected_distance_px, self.baseline_px)


@dataclass(frozen=True)
class AlignmentReport:
    """The verdict of :func:`check_alignment`.

    Attributes:
        photos: per checked photo.
        ok: False when the mesh is clearly not in the cameras' frame.
        problem: what is wrong when not ``ok`` (one clause), else ``None``.
        offset_m: length of the translation of the best rigid correction (scene units, metres).
        turn_deg: angle of its rotation (about the centroid of the mesh's edge points).
        displacement: median image motion of the edge points under that correction, as a share of the
            longer image side (multiply by a photo's longer side for pixels).
        scene_size_m: diagonal of the mesh's bounding box, for scale.
    """

    photos: tuple[PhotoAlignment, ...]
    ok: bool
    problem: str | None
    offset_m: float = float("nan")
    turn_deg: float = float("nan")
    displacement: float = float("nan")
    scene_size_m: float = float("nan")

    @property
    def edge_distance_px(self) -> float:
        """Median over photos of their edge distance (NaN when no photo has render edges)."""
        return _nanmedian([p.edge_distance_px for p in self.photos])

    @property
    def baseline_px(self) -> float:
        return _nanmedian([p.baseline_px for p in self.photos])

    @property
    def ratio(self) -> float:
        return _nanmedian([p.ratio for p in self.photos])

    @property
    def corrected_ratio(self) -> float:
        return _nanmedian([p.corrected_ratio for p in self.photos])

    @property
    def coverage(self) -> float:
        return float(np.median([p.coverage for p in self.photos]))

    @property
    def depth_agreement(self) -> float:
        """Median over the photos with depth maps of their depth agreement (NaN when none has one)."""
        return _nanmedian([p.depth_agreement for p in self.photos])

    def summary(self) -> str:
        size = max(self.photos[0].size) if self.photos else 0
        verdict = "aligned" if self.ok else f"NOT aligned: {self.problem}"
        depth = (f"; the depth maps agree with it on {100 * self.depth_agreement:.0f} % of its pixels"
                 if np.isfinite(self.depth_agreement) else "")
        return (f"mesh and photos {verdict}; median edge distance {self.edge_distance_px:.1f} px "
                f"(random offsets: {self.baseline_px:.1f} px, ratio {self.ratio:.2f}; "
                f"{self.corrected_ratio:.2f} after the best rigid correction: {_amount(self)}), mesh covers "
                f"{100 * self.coverage:.0f} % of the photo{depth}; {len(self.photos)} photos at {size} px")


@dataclass(frozen=True, eq=False)
class _EdgeSample:
    """Render edges of one checked photo, for fitting the rigid correction."""

    camera: Camera  # at the working size
    points: np.ndarray  # (n, 3) world points of the render's edge pixels
    distance: np.ndarray  # (h, w) float32 distance (px) to the photo's nearest edge


def check_alignment(scan: Scan, photos: PhotoSet, *, n_photos: int = 4, max_photos: int = 12, max_side: int = 480,
                    caster=None) -> AlignmentReport:
    """Reproject ``scan`` into evenly spread photos and measure how well its edges meet the photos'
    edges, and which rigid motion of the mesh would make them meet best (see the module docstring).

    ``n_photos`` are checked first. When fewer than ``MIN_JUDGED`` of them show edges to compare (a room's
    photos of bare walls), or when their edges miss the photos' edges, more photos are checked, spread among
    the others, up to ``max_photos`` in all, and the verdict is taken over all of them: a refusal for edges
    that miss rests on more than a few photos, and a pass costs no more than before. A mesh refused because
    it sits a measured amount away is refused from the first photos (the amount is measured well there).

    Args:
        scan: the mesh, in the frame it will be textured in.
        photos: the posed photos.
        n_photos: how many photos to check first.
        max_photos: how many photos to check at most.
        max_side: the longer image side the comparison runs at.
        caster: a prebuilt :class:`~scantex.views.raycast.RayCaster` of ``scan`` (built when ``None``).
    """
    from scantex.threads import one_blas_thread, side_by_side
    from scantex.views.raycast import RayCaster

    if len(photos) == 0:
        raise ValueError("no photos to check")
    caster = caster or RayCaster(scan.positions, scan.faces)
    edges = _MeshEdges.of(scan)
    first = min(n_photos, len(photos))
    order = _spread_order(len(photos), first, max(first, min(max_photos, len(photos))))

    def check(i) -> tuple:
        return _check_photo(scan, photos, int(i), max_side, caster, edges)

    # the photos side by side, and the rigid fit's small factorisations on one BLAS thread (where BLAS's
    # threads only spin: the façade's check 1.7 -> 1.0 s on 2 cores, the same report)
    with one_blas_thread():
        checked = list(side_by_side(check, order[:first]))
        report, edges_miss = _verdict(scan, checked)
        judged = sum(sample is not None for _, sample in checked)
        if (edges_miss or judged < MIN_JUDGED) and len(order) > first:
            more = order[first:]
            log.info("alignment: %s after %d photos; checking %d more", "edges miss" if edges_miss else
                     f"{judged} photos with edges", len(checked), len(more))
            checked += side_by_side(check, more)
            report, _ = _verdict(scan, checked)
    log.info("%s", report.summary())
    return report


def _spread_order(n: int, first: int, count: int) -> np.ndarray:
    """``count`` of ``0 .. n-1``: ``first`` evenly spread indices (the ends included), then others in an order
    that keeps every prefix spread out (each next index the farthest from those taken)."""
    picks = list(np.unique(np.linspace(0, n - 1, first).round().astype(int)))
    distance = np.min(np.abs(np.arange(n)[:, None] - np.asarray(picks)[None, :]), axis=1).astype(float)
    while len(picks) < count:
        i = int(np.argmax(distance))  # taken indices are at distance 0, below any other
        picks.append(i)
        distance = np.minimum(distance, np.abs(np.arange(n) - i))
    return np.asarray(picks, int)


def _verdict(scan: Scan, checked: list[tuple[PhotoAlignment, _EdgeSample | None]]) -> tuple[AlignmentReport, bool]:
    """The :class:`AlignmentReport` of the photos checked so far (see the module docstring), and whether it
    refuses the mesh because its edges miss the photos' (the verdict that more photos can overturn; the
    rigid correction's amount is measured well from a few photos)."""
    results = [c[0] for c in checked]
    covered = [k for k, p in enumerate(results) if p.coverage >= MIN_COVERAGE]
    size = float(np.linalg.norm(np.ptp(scan.positions, axis=0)))
    problem = None
    edges_miss = False
    agreements = [results[k].depth_agreement for k in covered if np.isfinite(results[k].depth_agreement)]
    depth_confirms = (len(agreements) >= min(MIN_JUDGED, len(covered)) > 0
                      and float(np.median(agreements)) >= DEPTH_CONFIRMS)
    offset = turn = displacement = float("nan")
    if 2 * len(covered) <= len(results):
        problem = (f"it projects outside {len(results) - len(covered)} of the {len(results)} photos "
                   f"checked (covers {100 * float(np.median([p.coverage for p in results])):.1f} % of "
                   "a photo on median)")
    else:
        samples = [checked[k][1] for k in covered if checked[k][1] is not None]
        if not samples or not np.isfinite(_nanmedian([results[k].ratio for k in covered])):
            if not depth_confirms:
                problem = "the rendered mesh shows no edges to compare with the photos"
        else:
            R, t, centre = fit_rigid_correction(samples)
            offset = float(np.linalg.norm(t))
            turn = float(np.degrees(np.arccos(np.clip((np.trace(R) - 1) / 2, -1, 1))))
            moves = []
            for k in covered:
                sample = checked[k][1]
                if sample is None:
                    continue
                moved = (sample.points - centre) @ R.T + centre + t
                p0, _ = sample.camera.project(sample.points)
                p1, _ = sample.camera.project(moved)
                side = max(sample.camera.width, sample.camera.height)
                moves.append(float(np.median(np.linalg.norm(p1 - p0, axis=1))) / side)
                w, h = results[k].size
                corrected = _chamfer(_lookup(sample.distance, p1), DISTANCE_CAP * max(w, h))
                results[k] = _replace(results[k], corrected_distance_px=corrected)
            displacement = float(np.median(moves))
            # per photo, the better of as-is and corrected (the fit minimises a robust cost, not this ratio);
            # over the photos, the best third: a mesh in another frame matches no photo's edges, while an
            # aligned one may show, in some photos, only edges a photo cannot have (a blurred atlas's
            # smudges on a bare wall), which match nothing wherever the mesh is
            best = [np.fmin(results[k].corrected_ratio, results[k].ratio) for k in covered]
            fitted = _nanquantile(best, MATCH_QUANTILE)
            if not fitted <= MAX_EDGE_RATIO and not depth_confirms:
                edges_miss = True
                problem = (f"its edges miss the photos' edges (distance ratio {fitted:.2f} to the same edges "
                           f"moved at random, even after the best small correction; aligned data gives "
                           f"< {MAX_EDGE_RATIO})")
            elif displacement > MAX_DISPLACEMENT and (turn > MAX_TURN_DEG or offset > MAX_SHIFT * size):
                problem = (f"it sits about {_length(offset)} and {turn:.1f} degrees away from where the "
                           f"photos see it (its image would move {100 * displacement:.1f} % of the photo "
                           f"side to match)")
    return AlignmentReport(tuple(results), problem is None, problem, offset, turn, displacement, size), edges_miss


#: image motion (share of the photo side) of a passing check's correction from which the mesh is also tried in other
#: units: aligned captures need 0-0.3 %, close-ups with realistic pose errors up to 24 %; a façade in centimetres 19 %
UNITS_PROBED_FROM = 0.05
#: how much closer to the photos' edges the mesh in other units must be, then (the façade in centimetres: 8.4 px as it
#: is, 1.0 px in metres; a close-up passed by its estimate's wander: 0.8 px, 3.3 px in feet)
UNITS_CLOSER = 0.5
#: what a refusal tells a capture of these formats first: the mesh exported in a frame of its own is their usual cause
EXPORT_ADVICE = {"realitycapture": "RealityCapture exports a mesh in the XMPs' frame with its coordinate system "
                                   "'same as XMP'; "}


def require_alignment(scan: Scan, photos: PhotoSet, **kwargs) -> AlignmentReport:
    """:func:`check_alignment`, raising when the mesh is clearly not in the cameras' frame.

    Raises:
        ScanError: naming ``photos.source``: "the mesh is not in the cameras' frame: ... (median edge
            distance N px ...)", and where the mesh lines up with the photos in other units (a mesh exported in
            millimetres, cameras in metres) or through poses read in another convention (camera-to-world, OpenGL's
            axes), which; also a mesh the check passes only by a large correction (over :data:`UNITS_PROBED_FROM`
            of the photo side) that lines up in other units as it is; ``--no-alignment-check``
            (``photos.check_alignment``) skips the check.
    """
    report = check_alignment(scan, photos, **kwargs)
    if report.ok and report.displacement > UNITS_PROBED_FROM:
        # a pass by a large correction (a small share of a mesh exported 100 times too large): the mesh in other
        # units fitting as it is, its edges far closer, says which it is (a close-up of a plain wall, passed by its
        # estimate's wander, fits a few other units too, none closer)
        units = other_units(scan, photos, within_px=UNITS_CLOSER * report.edge_distance_px, **kwargs)
        if units is not None:
            factor, mesh_unit, camera_unit = units
            raise ScanError(photos.source, f"the mesh is not in the cameras' frame: it fits the photos only after its "
                                           f"image moves {100 * report.displacement:.0f} % of the photo side, but it "
                                           f"lines up with the photos at {_fraction(factor)} its size: is the mesh in "
                                           f"{mesh_unit} and the cameras in {camera_unit}? Export the mesh in "
                                           f"{camera_unit}")
    if not report.ok:
        distance = report.edge_distance_px
        detail = (f"median edge distance {distance:.1f} px at {max(report.photos[0].size)} px"
                  if np.isfinite(distance) else "median edge distance: no mesh edges in the photos")
        units = other_units(scan, photos, **kwargs)
        if units is not None:
            factor, mesh_unit, camera_unit = units
            raise ScanError(photos.source, f"the mesh is not in the cameras' frame: {report.problem} ({detail}), but "
                                           f"it lines up with the photos at {_fraction(factor)} its size: is the mesh "
                                           f"in {mesh_unit} and the cameras in {camera_unit}? Export the mesh in "
                                           f"{camera_unit}")
        misread = other_convention(scan, photos, **kwargs)
        if misread is not None:
            raise ScanError(photos.source, f"the mesh is not in the cameras' frame: {report.problem} ({detail}), but "
                                           f"it lines up with the photos {misread}")
        # the same misfit comes of cameras described wrongly: intrinsics for another image size, camera-to-world
        # poses given as world-to-camera (an audit's K scaled by 2/3 read "39 cm and 44 degrees away")
        raise ScanError(photos.source, f"the mesh is not in the cameras' frame: {report.problem} ({detail}; "
                                       f"{EXPORT_ADVICE.get(photos.format, '')}if the mesh is where the capture left "
                                       "it, check the cameras: intrinsics for the photos' own size, poses "
                                       "world-to-camera; --no-alignment-check to go on anyway)")
    return report


#: mesh units per camera unit that an export in other units gives: (factor, the mesh's unit, the cameras')
UNITS = ((1000.0, "millimetres", "metres"), (100.0, "centimetres", "metres"), (0.001, "metres", "millimetres"),
         (0.01, "metres", "centimetres"), (1 / 0.0254, "inches", "metres"), (1 / 0.3048, "feet", "metres"),
         (0.0254, "metres", "inches"), (0.3048, "metres", "feet"))
#: the mesh's size over the spread of the cameras' positions (their median distance from their mean) for which a
#: unit change is tried on a refused mesh (a mesh in millimetres against cameras in metres gives a thousand times
#: an aligned capture's: the cube of the tests 0.7, the captures measured 1-10)
PLAUSIBLE_SIZE = (0.1, 30.0)


def other_units(scan: Scan, photos: PhotoSet, *, within_px: float = np.inf,
                **kwargs) -> tuple[float, str, str] | None:
    """``(factor, mesh unit, camera unit)`` where the cameras scaled by ``factor`` (positions and all: the mesh's
    units per the cameras') see the mesh line up with the photos (:func:`check_alignment` passes, its median edge
    distance within ``within_px``), among the unit changes of :data:`UNITS` that make the mesh's size plausible
    against the cameras' spread; ``None`` if none does. For a refused mesh, or one passed by a large correction:
    each candidate is a check of its own (a mesh moved by a few centimetres makes none plausible)."""
    size = float(np.linalg.norm(np.ptp(scan.positions, axis=0)))
    centres = np.array([c.center for c in photos.cameras])
    spread = float(np.median(np.linalg.norm(centres - centres.mean(axis=0), axis=1)))

    def plausible(factor: float) -> bool:
        return PLAUSIBLE_SIZE[0] * factor * spread <= size <= PLAUSIBLE_SIZE[1] * factor * spread

    if size <= 0 or spread <= 0:
        return None
    def in_mesh_units(factor: float):
        """A camera's pose with its position in the mesh's units: its translation times ``factor``."""
        def change(w2c: np.ndarray) -> np.ndarray:
            out = w2c.copy()
            out[:3, 3] *= factor
            return out
        return change

    for factor, mesh_unit, camera_unit in UNITS:
        if plausible(factor) and _passes(scan, photos, in_mesh_units(factor), kwargs, within_px):
            return factor, mesh_unit, camera_unit
    return None


#: the pose conventions a camera file written by hand gets wrong, as the change that undoes each and what it says:
#: a camera-to-world pose given for a world-to-camera one, OpenGL's camera axes (y up, looking down -z) for
#: OpenCV's (y down, looking down +z), and both
CONVENTIONS = (
    ("inverse", "with each camera's pose inverted: are the poses camera-to-world? scantex reads world-to-camera "
                "poses here (x_cam = R X + t)"),
    ("opengl", "with each camera's axes turned from OpenGL's to OpenCV's: are the poses in OpenGL's convention "
               "(y up, looking down -z)? scantex reads OpenCV's here (y down, looking down +z)"),
    ("both", "with each camera's pose inverted and its axes turned from OpenGL's to OpenCV's: are the poses "
             "OpenGL camera-to-world matrices (nerfstudio's transform_matrix)? scantex reads OpenCV world-to-camera "
             "poses here (x_cam = R X + t, y down, looking down +z)"),
)
#: OpenGL's camera axes in OpenCV's
GL_AXES = np.diag([1.0, -1.0, -1.0, 1.0])


def other_convention(scan: Scan, photos: PhotoSet, **kwargs) -> str | None:
    """Where the cameras read in another pose convention (:data:`CONVENTIONS`) see the mesh line up with the
    photos (:func:`check_alignment` passes), what that says; ``None`` if none does. For a refused mesh: each is a
    check of its own, of 4 photos. Only for scantex's own ``cameras.json``, which people write by hand: every other
    format has a convention of its own, which its importer follows (nerfstudio's is OpenGL's camera-to-world)."""
    if photos.format != "cameras.json":
        return None
    changes = {"inverse": np.linalg.inv, "opengl": lambda w2c: GL_AXES @ w2c,
               "both": lambda w2c: GL_AXES @ np.linalg.inv(w2c)}
    for change, said in CONVENTIONS:
        if _passes(scan, photos, changes[change], kwargs):
            return said
    return None


def _passes(scan: Scan, photos: PhotoSet, change, kwargs: dict, within_px: float = np.inf) -> bool:
    """Whether :func:`check_alignment` passes, on 4 photos and without their depth maps, a refused capture read
    another way (``change(world_to_camera) -> world_to_camera`` for each camera) with no correction to speak of (its
    image motion under :data:`MAX_DISPLACEMENT`: the reading fits as it is, not one a permissive check lets by) and
    its median edge distance within ``within_px``: a hint for the refusal's message, which a failure of its own (a
    camera placed inside the mesh, numbers that overflow) must not replace or add lines to."""
    cameras = tuple(dataclasses.replace(c, world_to_camera=change(c.world_to_camera)) for c in photos.cameras)
    photos = dataclasses.replace(photos, cameras=cameras, depths=(None,) * len(photos))
    kwargs = dict(kwargs, n_photos=4, max_photos=4)
    level = log.level
    log.setLevel(max(level, logging.WARNING))  # a probe's "mesh and photos aligned" is no verdict on the capture
    try:
        with np.errstate(all="ignore"):
            report = check_alignment(scan, photos, **kwargs)
            return report.ok and report.displacement <= MAX_DISPLACEMENT and report.edge_distance_px <= within_px
    except (ScanError, ValueError, ArithmeticError, np.linalg.LinAlgError) as e:
        log.debug("alignment: a changed reading could not be checked: %s", e)
        return False
    finally:
        log.setLevel(level)


def _fraction(factor: float) -> str:
    """The size the mesh lines up at, over its own, as a person says it (``factor``: the mesh's units per the
    cameras'): 1/1000 of, 1/39.37 of, 1000 times."""
    return f"1/{factor:.4g} of" if factor >= 1 else f"{1 / factor:.4g} times"


def fit_rigid_correction(samples: list[_EdgeSample]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The rigid motion ``X -> R (X - centre) + centre + t`` of the edge points that brings them closest
    to the photos' edges, over all ``samples`` (robust least squares, soft-L1 loss at 2 px).

    Returns:
        ``(R (3, 3), t (3,), centre (3,))``.
    """
    from scipy.optimize import least_squares
    from scipy.spatial.transform import Rotation

    centre = np.concatenate([s.points for s in samples]).mean(axis=0)
    spread = max(float(np.linalg.norm(np.concatenate([s.points for s in samples]).std(axis=0))), 1e-9)

    def sharp_cost(x):
        r = _edge_residuals(samples, centre, spread, x) / 2.0
        return float(np.mean(2 * (np.sqrt(1 + r * r) - 1)))

    # start from the translation that best explains each photo's own best image shift (an exhaustive
    # search, which repeated structure such as a façade's windows cannot trap the way it traps a local
    # fit), then settle the translation alone, then all six parameters, on sharper distance fields
    prior = 0.05 * np.sqrt(sum(len(s.points) for s in samples))
    x = np.zeros(6)
    start = x.copy()
    start[3:] = _translation_from_shifts(samples, centre) / spread
    if sharp_cost(start) < sharp_cost(x):
        x = start
    for sigma, free in ((3.0, slice(3, 6)), (3.0, slice(0, 6)), (1.0, slice(0, 6))):
        blurred = [_blur(s, sigma) for s in samples]

        def residuals(y, free=free, blurred=blurred):
            full = x.copy()
            full[free] = y
            # a weak prior towards no motion: with few edges (a small or flat mesh) a fit may otherwise
            # trade a turn against a shift that the edges hardly tell apart
            return np.concatenate([_edge_residuals(blurred, centre, spread, full), prior * full / PRIOR_SCALE])

        def jacobian(y, free=free, blurred=blurred):
            full = x.copy()
            full[free] = y
            return np.concatenate([_edge_jacobian(blurred, centre, spread, full),
                                   np.diag(prior / PRIOR_SCALE)])[:, free]

        # a tolerance of 1e-4 (scipy: 1e-8) stops where further steps move the mesh by far less than a pixel
        fit = least_squares(residuals, x[free], jac=jacobian, loss="soft_l1", f_scale=2.0, max_nfev=40,
                            ftol=1e-4, xtol=1e-4)
        trial = x.copy()
        trial[free] = fit.x
        # keep a step only when the sharp edges agree better: a blurred field can pull a sparse set of
        # edge points off a perfect fit
        if sharp_cost(trial) < 0.97 * sharp_cost(x):  # a real improvement, not noise
            x = trial
    return Rotation.from_rotvec(x[:3]).as_matrix(), x[3:] * spread, centre


def _edge_residuals(samples: list[_EdgeSample], centre: np.ndarray, spread: float, x: np.ndarray) -> np.ndarray:
    """``(n,)``: each sample's edge points moved by ``x`` (rotation vector about ``centre``, then translation
    ``x[3:] * spread``), their distance (px) to the photo's nearest edge; compiled (:mod:`scantex.jit`: the
    fit asks for it a hundred times and more), or :func:`_edge_residuals_numpy` where numba is missing."""
    return _edge_terms(samples, centre, spread, x, jacobian=False)


def _edge_jacobian(samples: list[_EdgeSample], centre: np.ndarray, spread: float, x: np.ndarray) -> np.ndarray:
    """``(n, 6)``: the derivatives of :func:`_edge_residuals` in ``x`` (the chain rule through the distance
    field's bilinear gradient, the projection and the rotation vector's left Jacobian); compiled, or
    :func:`_edge_jacobian_numpy` where numba is missing."""
    return _edge_terms(samples, centre, spread, x, jacobian=True)


def _edge_terms(samples: list[_EdgeSample], centre: np.ndarray, spread: float, x: np.ndarray,
                jacobian: bool) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    from scantex import jit

    kernel = jit.compiled(_edge_kernel)
    if kernel is None:
        return (_edge_jacobian_numpy if jacobian else _edge_residuals_numpy)(samples, centre, spread, x)
    R = Rotation.from_rotvec(x[:3]).as_matrix()
    turn = _left_jacobian(x[:3])
    shift = np.asarray(x[3:] * spread, np.float64)
    centre = np.asarray(centre, np.float64)
    out = []
    for s in samples:
        n = len(s.points)
        residuals, derivatives = np.empty(n), np.empty((n if jacobian else 0, 6))
        field = np.ascontiguousarray(s.distance)
        kernel(np.ascontiguousarray(s.points, np.float64), centre, R, shift, np.ascontiguousarray(s.camera.R),
               np.ascontiguousarray(s.camera.t, np.float64), np.ascontiguousarray(s.camera.K, np.float64), field,
               float(field.max()), float(spread), turn, residuals, derivatives, jacobian)
        out.append(derivatives if jacobian else residuals)
    return np.concatenate(out)


def _edge_kernel(points, centre, rotation, shift, cam_rotation, cam_translation, intrinsics, field, outside, spread,
                 turn, residuals, derivatives, jacobian):
    """The kernel of :func:`_edge_terms`, point by point: ``residuals (n,)`` filled in, and ``derivatives (n, 6)``
    where ``jacobian``, as :func:`_edge_residuals_numpy` and :func:`_edge_jacobian_numpy` make them."""
    H, W = field.shape
    KR = intrinsics @ cam_rotation
    moved = np.empty(3)
    world = np.empty(3)
    cam = np.empty(3)
    d_world = np.empty(3)
    for i in range(points.shape[0]):
        for k in range(3):  # R (X - centre), then the world point
            moved[k] = (rotation[k, 0] * (points[i, 0] - centre[0]) + rotation[k, 1] * (points[i, 1] - centre[1])
                        + rotation[k, 2] * (points[i, 2] - centre[2]))
            world[k] = moved[k] + centre[k] + shift[k]
        for k in range(3):
            cam[k] = (cam_rotation[k, 0] * world[0] + cam_rotation[k, 1] * world[1] + cam_rotation[k, 2] * world[2]
                      + cam_translation[k])
        hx = intrinsics[0, 0] * cam[0] + intrinsics[0, 1] * cam[1] + intrinsics[0, 2] * cam[2]
        hy = intrinsics[1, 0] * cam[0] + intrinsics[1, 1] * cam[1] + intrinsics[1, 2] * cam[2]
        hz = intrinsics[2, 0] * cam[0] + intrinsics[2, 1] * cam[1] + intrinsics[2, 2] * cam[2]
        u, v = hx / hz, hy / hz
        if not (cam[2] > 0 and u >= 0 and u <= W - 1 and v >= 0 and v <= H - 1):  # off the image (or behind)
            residuals[i] = outside
            if jacobian:
                derivatives[i, :] = 0.0
            continue
        cx, cy = min(u, W - 1.001), min(v, H - 1.001)  # the cell as _bilinear_cells takes it
        x0, y0 = int(cx), int(cy)
        fx, fy = cx - x0, cy - y0
        a, b = np.float64(field[y0, x0]), np.float64(field[y0, x0 + 1])
        c, d = np.float64(field[y0 + 1, x0]), np.float64(field[y0 + 1, x0 + 1])
        residuals[i] = (1 - fy) * ((1 - fx) * a + fx * b) + fy * ((1 - fx) * c + fx * d)
        if not jacobian:
            continue
        gx, gy = (1 - fy) * (b - a) + fy * (d - c), (1 - fx) * (c - a) + fx * (d - b)
        for k in range(3):  # d residual / d world point: grad . d pix / d world, d pix = ([I | -pix] / h_z) K R
            d_world[k] = (gx * (KR[0, k] - u * KR[2, k]) + gy * (KR[1, k] - v * KR[2, k])) / hz
        # d world / d rotation vector = -[R (X - centre)]x J_l: (moved x d_world) . J_l; d world / d x[3:] = spread I
        c0 = moved[1] * d_world[2] - moved[2] * d_world[1]
        c1 = moved[2] * d_world[0] - moved[0] * d_world[2]
        c2 = moved[0] * d_world[1] - moved[1] * d_world[0]
        for k in range(3):
            derivatives[i, k] = c0 * turn[0, k] + c1 * turn[1, k] + c2 * turn[2, k]
            derivatives[i, 3 + k] = spread * d_world[k]


def _edge_residuals_numpy(samples: list[_EdgeSample], centre: np.ndarray, spread: float,
                          x: np.ndarray) -> np.ndarray:
    """:func:`_edge_residuals` in numpy: its twin, and what runs where numba is missing."""
    from scipy.spatial.transform import Rotation

    R = Rotation.from_rotvec(x[:3]).as_matrix()
    t = x[3:] * spread
    out = []
    for s in samples:
        pix, z = s.camera.project((s.points - centre) @ R.T + centre + t)
        pix[z <= 0] = np.nan
        out.append(_lookup(s.distance, pix))
    return np.concatenate(out)


def _edge_jacobian_numpy(samples: list[_EdgeSample], centre: np.ndarray, spread: float,
                         x: np.ndarray) -> np.ndarray:
    """:func:`_edge_jacobian` in numpy: its twin, and what runs where numba is missing."""
    from scipy.spatial.transform import Rotation

    R = Rotation.from_rotvec(x[:3]).as_matrix()
    turn = _left_jacobian(x[:3])
    out = []
    for s in samples:
        moved = (s.points - centre) @ R.T  # R (X - centre)
        cam = (moved + centre + x[3:] * spread) @ s.camera.R.T + s.camera.t
        h = cam @ s.camera.K.T
        with np.errstate(divide="ignore", invalid="ignore"):
            pix = h[:, :2] / h[:, 2:3]
        pix[cam[:, 2] <= 0] = np.nan
        grad = _lookup_gradient(s.distance, pix)  # (n, 2); 0 off the image
        # d pix / d world = ([I | -pix] / h_z) K R_cam
        KR = s.camera.K @ s.camera.R
        with np.errstate(divide="ignore", invalid="ignore"):
            d_h = (grad[:, :, None] * (KR[None, :2] - np.nan_to_num(pix)[:, :, None] * KR[None, 2:3])).sum(1)
            d_world = np.nan_to_num(d_h / h[:, 2:3])  # (n, 3): d residual / d world point
        # d world / d rotation vector = -[R (X - centre)]x J_l, so g . that = (R (X - centre) x g) . J_l;
        # d world / d x[3:] = spread I
        out.append(np.concatenate([np.cross(moved, d_world) @ turn, spread * d_world], axis=1))
    return np.concatenate(out)


def _left_jacobian(rotvec: np.ndarray) -> np.ndarray:
    """``(3, 3)``: the left Jacobian of SO(3) at ``rotvec``: ``R(v + d) = exp(J d) R(v)`` to first order."""
    a = float(np.linalg.norm(rotvec))
    k = np.array([[0, -rotvec[2], rotvec[1]], [rotvec[2], 0, -rotvec[0]], [-rotvec[1], rotvec[0], 0]])
    if a < 1e-8:
        return np.eye(3) + 0.5 * k
    return np.eye(3) + (1 - np.cos(a)) / a ** 2 * k + (a - np.sin(a)) / a ** 3 * (k @ k)


def _translation_from_shifts(samples: list[_EdgeSample], centre: np.ndarray) -> np.ndarray:
    """``(3,)`` the translation whose image motion best matches (least squares over the photos) each
    photo's best integer shift of its edge points (searched over +-6 % of the image side)."""
    rows, rhs = [], []
    for s in samples:
        pix, _ = s.camera.project(s.points)
        H, W = s.distance.shape
        r = max(2, round(0.06 * max(H, W)))
        shift = _best_shift(_blur(s, 2.0).distance, pix, r, max(1, r // 12))
        # image motion of the centre under a small translation: d pix = J dt (finite differences)
        p0 = s.camera.project(centre[None])[0][0]
        h = 1e-4 * max(1.0, float(np.linalg.norm(centre - s.camera.center)))
        J = np.stack([(s.camera.project((centre + h * e)[None])[0][0] - p0) / h for e in np.eye(3)], axis=1)
        rows.append(J)
        rhs.append(shift)
    A, b = np.concatenate(rows), np.concatenate(rhs)
    # a little ridge: depth along the view is barely observed by near-parallel views
    lam = 1e-3 * float(np.trace(A.T @ A)) / 3
    return np.linalg.solve(A.T @ A + lam * np.eye(3), A.T @ b)


def _best_shift(field: np.ndarray, pix: np.ndarray, r: int, step: int) -> tuple[float, float]:
    """``(dx, dy)``: the whole-pixel shift of ``pix (n, 2)``, on a grid of ``step`` within ``+-r``, whose
    mean :func:`_lookup` of ``field`` is least (the smallest such shift on a tie).

    Every shift's cost at once, as a correlation: each point's four bilinear weights are spread over an image,
    whose correlation with ``field`` (padded ``r`` pixels with the value an off-image point reads) gives the
    summed lookups at every shift. The same as looking up every shift apart but within a pixel of the image
    border, where an off-image point read the padding's value a fraction of a pixel early before.
    """
    from scipy import fft

    H, W = field.shape
    outside = float(field.max())
    p = np.nan_to_num(pix, nan=-1e9, posinf=-1e9, neginf=-1e9)
    # points off the image at every shift read the padding's value whatever the shift
    near = (p[:, 0] >= -r) & (p[:, 0] <= W - 1 + r) & (p[:, 1] >= -r) & (p[:, 1] <= H - 1 + r)
    x, y = p[near, 0] + r, p[near, 1] + r  # in the padded frame
    x0, y0 = np.floor(x).astype(int), np.floor(y).astype(int)
    fx, fy = x - x0, y - y0
    shape = (H + 2 * r + 1, W + 2 * r + 1)
    weights = sum(np.bincount(np.ravel_multi_index((y0 + dy, x0 + dx), shape), w, shape[0] * shape[1])
                  for dy, dx, w in ((0, 0, (1 - fx) * (1 - fy)), (0, 1, fx * (1 - fy)), (1, 0, (1 - fx) * fy),
                                    (1, 1, fx * fy))).reshape(shape)
    # the field with room for every shift: a pixel q of ``weights`` shifted by d reads padded[q + d + r + 1]
    padded = np.pad(field.astype(np.float64), 2 * r + 1, constant_values=outside)
    # the correlation through the FFT (scipy.fft, not scipy.signal's fftconvolve, whose import pulls in
    # scipy.stats: 0.75 s of a 20 s run); a point at q + d stays inside ``padded`` for every shift, so the
    # circular correlation at a fast length no smaller than ``padded`` has no wrap-around
    size = [fft.next_fast_len(n, real=True) for n in padded.shape]
    spectrum = fft.rfft2(padded, size) * np.conj(fft.rfft2(weights, size))
    cost = fft.irfft2(spectrum, size)[:2 * r + 2, :2 * r + 2]  # cost[d + r + 1]: the correlation
    grid = np.arange(-r, r + 1, step)
    cost = cost[np.ix_(grid + r + 1, grid + r + 1)] + outside * float(np.count_nonzero(~near))
    dy, dx = np.meshgrid(grid, grid, indexing="ij")
    # the least cost, and on a tie (a flat field) the smallest shift
    order = np.lexsort(((dx ** 2 + dy ** 2).ravel(), np.round(cost.ravel() / max(len(p), 1), 9)))
    k = order[0]
    return float(dx.ravel()[k]), float(dy.ravel()[k])


def _blur(sample: _EdgeSample, sigma: float) -> _EdgeSample:
    from scipy import ndimage

    return _EdgeSample(sample.camera, sample.points, ndimage.gaussian_filter(sample.distance, sigma))


@dataclass(frozen=True, eq=False)
class _MeshEdges:
    """The mesh's open boundary edges and creases, on positions welded by value (an OBJ repeats a
    position at every UV seam; those are no borders)."""

    border: np.ndarray  # (B, 2, 3) end points of open boundary edges
    creases: np.ndarray  # (C, 2, 3) end points of crease edges
    holes: np.ndarray  # (F,) bool faces whose texture edges are no photo's: untextured, or touching another
    # UV chart (a capture app's atlas jumps in exposure there)

    @classmethod
    def of(cls, scan: Scan) -> _MeshEdges:
        P, faces = scan.welded_geometry()
        e = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
        owner = np.tile(np.arange(len(faces)), 3)
        key = np.sort(e, axis=1)
        keep = key[:, 0] != key[:, 1]
        key, owner = key[keep], owner[keep]
        _, inverse, counts = unique_rows(key, return_inverse=True, return_counts=True)
        inverse = inverse.reshape(-1)
        border = key[counts[inverse] == 1]
        # creases: edges with exactly two faces whose normals differ by more than CREASE_DEG
        two = np.flatnonzero(counts[inverse] == 2)
        order = two[np.argsort(inverse[two], kind="stable")]
        pairs = order.reshape(-1, 2)
        n = scan.face_normals
        a, b = owner[pairs[:, 0]], owner[pairs[:, 1]]
        cos = np.einsum("ij,ij->i", n[a], n[b])
        # and whose faces' neighbourhoods still meet at CREASE_SMOOTH_DEG: a scanned surface's noise bends
        # single faces (a fused depth scan of a room: most of its crease edges), not their surroundings
        m = _neighbourhood_normals(scan, faces)
        cos_smooth = np.einsum("ij,ij->i", m[a], m[b])
        sharp = (cos < np.cos(np.radians(CREASE_DEG))) & (cos_smooth < np.cos(np.radians(CREASE_SMOOTH_DEG)))
        crease = key[pairs[sharp, 0]]
        from scantex.photos.poses import reference_faces

        return cls(P[border], P[crease],
                   ~reference_faces(scan) if scan.is_textured else np.zeros(scan.n_faces, bool))


def _neighbourhood_normals(scan: Scan, faces: np.ndarray) -> np.ndarray:
    """``(F, 3)``: each face's normal averaged over the faces that share a vertex with it (area-weighted,
    through its welded vertices' normals)."""
    weighted = scan.face_normals * scan.face_areas[:, None]
    n = int(faces.max()) + 1 if faces.size else 0
    vertex = np.stack([np.bincount(faces.ravel(), np.repeat(weighted[:, c], 3), n) for c in range(3)], axis=1)
    out = vertex[faces].sum(axis=1)
    return out / np.maximum(np.linalg.norm(out, axis=1, keepdims=True), 1e-12)


def _edge_pixels(segments: np.ndarray, camera: Camera, depth: np.ndarray | None) -> np.ndarray:
    """``(H, W) bool`` pixels that ``segments (S, 2, 3)`` project to (sampled about every half pixel);
    with ``depth``, only the samples no nearer surface hides."""
    H, W = camera.height, camera.width
    out = np.zeros((H, W), bool)
    if len(segments) == 0:
        return out
    ends, z_ends = camera.project(segments.reshape(-1, 3))
    ends, z_ends = ends.reshape(-1, 2, 2), z_ends.reshape(-1, 2)
    # only segments that can reach the image: not wholly behind the camera, and (both ends in front) not
    # wholly beyond one of its sides, which a room's border mostly is (its samples cost 7 s in 4 photos)
    with np.errstate(invalid="ignore"):
        front = (z_ends > 0).all(axis=1)
        beyond = (((ends[..., 0] < -1).all(axis=1)) | ((ends[..., 0] > W).all(axis=1))
                  | ((ends[..., 1] < -1).all(axis=1)) | ((ends[..., 1] > H).all(axis=1)))
    keep = (z_ends > 0).any(axis=1) & ~(front & beyond)
    segments, ends = segments[keep], ends[keep]
    if len(segments) == 0:
        return out
    # an end at the camera's plane projects to infinity: such a segment is sampled as the longest that can show (one
    # whose ends both do, of no length to measure, in one step)
    length = np.nan_to_num(np.linalg.norm(ends[:, 1] - ends[:, 0], axis=1), nan=0.0, posinf=float(max(H, W)))
    steps = np.clip(np.ceil(2 * length), 1, 2 * max(H, W)).astype(int)
    seg = np.repeat(np.arange(len(segments)), steps + 1)
    # 0, 1/k, ..., 1 along each segment of k steps (as np.linspace makes them), all segments at once
    first = np.cumsum(steps + 1) - (steps + 1)
    frac = (np.arange(len(seg)) - first[seg]) * (1.0 / steps)[seg]
    frac[first + steps] = 1.0
    X = segments[seg, 0] + frac[:, None] * (segments[seg, 1] - segments[seg, 0])
    pix, z = camera.project(X)
    ok = np.isfinite(pix).all(axis=1) & (z > 0)
    x, y = np.round(pix[ok, 0]).astype(int), np.round(pix[ok, 1]).astype(int)
    z = z[ok]
    inside = (x >= 0) & (x < W) & (y >= 0) & (y < H)
    x, y, z = x[inside], y[inside], z[inside]
    if depth is not None:
        seen = z <= depth[y, x] * 1.01 + 1e-6
        x, y = x[seen], y[seen]
    out[y, x] = True
    return out


def _check_photo(scan: Scan, photos: PhotoSet, i: int, max_side: int, caster,
                 mesh_edges: _MeshEdges) -> tuple[PhotoAlignment, _EdgeSample | None]:
    from scipy import ndimage

    from scantex.io.images import box_downscaled
    from scantex.views.raycast import cast_gbuffer
    from scantex.views.render import render_gbuffer

    cam = photos.cameras[i]
    factor = min(1.0, max_side / max(cam.width, cam.height))
    w, h = max(1, round(cam.width * factor)), max(1, round(cam.height * factor))
    small = resized_camera(cam, w, h)
    photo = photos.load_image(i)
    if (w, h) != (cam.width, cam.height):
        photo = box_downscaled(photo, w, h)
    photo = photo.astype(np.float32) / 255.0
    photo_edges = edge_map(_gray(photo))

    g = cast_gbuffer(caster, small)
    mask = g.mask
    border = ndimage.binary_dilation(_edge_pixels(mesh_edges.border, small, None), iterations=BORDER_PX)
    contours = contour_map(mask, g.depth)
    n_border = int((contours & border).sum())
    render_edges = (contours & ~border) | (_edge_pixels(mesh_edges.creases, small, g.depth) & mask)
    inside = ndimage.binary_erosion(mask, iterations=2) & ~border
    if scan.is_textured:
        holes = mesh_edges.holes
        if holes.any():
            inside &= ~ndimage.binary_dilation(mask & holes[np.where(mask, g.face_id, 0)], iterations=2)
        colour = fit_exposure(render_gbuffer(scan, g), photo, inside)
        render_edges |= edge_map(_gray(colour)) & inside
    elif render_edges.sum() < MIN_EDGE_PIXELS:
        render_edges |= edge_map(_gray(render_gbuffer(scan, g))) & inside
    render_edges &= mask

    ys, xs = np.nonzero(render_edges)
    n = len(ys)
    sample = None
    if n < MIN_EDGE_PIXELS or not photo_edges.any():
        distance = baseline = float("nan")
    else:
        dt = ndimage.distance_transform_edt(~photo_edges).astype(np.float32)
        cap = DISTANCE_CAP * max(w, h)
        distance = _chamfer(dt[ys, xs], cap)
        r = max(2, round(0.1 * max(w, h)))
        shifted = []
        for angle in np.arange(8) * np.pi / 4:
            dy, dx = round(r * np.sin(angle)), round(r * np.cos(angle))
            y, x = ys + dy, xs + dx
            ok = (y >= 0) & (y < h) & (x >= 0) & (x < w)
            if ok.sum() >= MIN_EDGE_PIXELS:
                shifted.append(_chamfer(dt[y[ok], x[ok]], cap))
        baseline = float(np.median(shifted)) if shifted else float("nan")
        pick = np.random.default_rng(i).permutation(n)[:MAX_FIT_POINTS]
        points = g.points(scan.positions, scan.faces)[ys[pick], xs[pick]]
        sample = _EdgeSample(small, points, np.minimum(dt, cap))
    result = PhotoAlignment(i, photos.images[i], (w, h), float(mask.mean()), distance, baseline, n,
                            n_border=n_border, depth_agreement=_depth_agreement(
                                photos, i, g, mask & ~ndimage.binary_dilation(contours)))
    return result, sample


def _depth_agreement(photos: PhotoSet, i: int, g, mask: np.ndarray) -> float:
    """Share of ``mask``'s pixels with a reading in photo ``i``'s depth map (at the G-buffer's size) where it
    agrees with the mesh's depth ``g.depth`` within ``DEPTH_AGREE``; NaN without a depth map or readings."""
    from scantex.photos.training import resize_depth

    measured = photos.load_depth(i)
    if measured is None:
        return float("nan")
    h, w = mask.shape
    measured = resize_depth(measured, w, h)
    both = mask & np.isfinite(measured) & (measured > 0)
    if both.sum() < MIN_DEPTH_PIXELS:
        return float("nan")
    mesh = g.depth[both]
    return float((np.abs(measured[both] - mesh) <= DEPTH_AGREE * mesh).mean())


def fit_exposure(render: np.ndarray, photo: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """``render (H, W, 3)`` brought to ``photo``'s exposure over ``mask``: per channel, the gain and offset
    that give it the photo's mean and spread there, clipped to [0, 1]. Moments, not a regression: a
    regression's gain falls to zero when the render is misaligned, which would hide the very edges
    that show the misalignment."""
    out = render.copy()
    for c in range(3):
        x, y = render[..., c][mask], photo[..., c][mask]
        if x.size < 2 or np.std(x) < 1e-5:
            continue
        gain = np.std(y) / np.std(x)
        out[..., c] = gain * render[..., c] + (y.mean() - gain * x.mean())
    return np.clip(out, 0, 1)


def resized_camera(camera: Camera, width: int, height: int) -> Camera:
    """``camera`` for its image resized to ``width x height`` (corners kept: pixel centres move as in
    :meth:`Camera.scaled`, per axis)."""
    sx, sy = width / camera.width, height / camera.height
    K = camera.K.copy()
    K[0, 0] *= sx
    K[0, 1] *= sx
    K[0, 2] = (K[0, 2] + 0.5) * sx - 0.5
    K[1, 1] *= sy
    K[1, 2] = (K[1, 2] + 0.5) * sy - 0.5
    return Camera(K, camera.world_to_camera, width, height)


def edge_map(gray: np.ndarray, sigma: float = 1.0, min_gradient: float = 0.02) -> np.ndarray:
    """``(H, W) bool`` thin edges of ``gray (H, W)`` in [0, 1]: Gaussian blur, Sobel, non-maximum
    suppression across the edge, and the maxima above ``min_gradient`` (intensity change per pixel)."""
    from scipy import ndimage

    g = ndimage.gaussian_filter(gray.astype(np.float32), sigma)
    gx = ndimage.sobel(g, axis=1) / 8.0
    gy = ndimage.sobel(g, axis=0) / 8.0
    mag = np.hypot(gx, gy)
    # non-maximum suppression along the gradient, quantised to 0, 45, 90, 135 degrees
    angle = (np.round(np.arctan2(gy, gx) / (np.pi / 4)) % 4).astype(np.int8)
    padded = np.pad(mag, 1)
    H, W = mag.shape
    is_max = np.zeros_like(mag, dtype=bool)
    for k, (dy, dx) in enumerate(((0, 1), (1, 1), (1, 0), (1, -1))):
        ahead = padded[1 + dy:1 + dy + H, 1 + dx:1 + dx + W]
        behind = padded[1 - dy:1 - dy + H, 1 - dx:1 - dx + W]
        is_max |= (angle == k) & (mag >= ahead) & (mag >= behind)
    return is_max & (mag > min_gradient)


def contour_map(mask: np.ndarray, depth: np.ndarray) -> np.ndarray:
    """``(H, W) bool`` occluding contours of a render: pixels that see the mesh next to one that does
    not (the silhouette), or next to one more than ``DEPTH_JUMP`` (relative) farther away."""
    edges = np.zeros_like(mask)
    for axis in (0, 1):
        a = [slice(None), slice(None)]
        b = [slice(None), slice(None)]
        a[axis], b[axis] = slice(None, -1), slice(1, None)
        ma, mb = mask[tuple(a)], mask[tuple(b)]
        da, db = depth[tuple(a)], depth[tuple(b)]
        with np.errstate(invalid="ignore"):
            jump = ma & mb & (np.abs(da - db) > DEPTH_JUMP * np.minimum(da, db))
        # mark the nearer side: the contour belongs to the occluding surface
        edges[tuple(a)] |= (ma & ~mb) | (jump & (da < db))
        edges[tuple(b)] |= (mb & ~ma) | (jump & (db < da))
    return edges


def _chamfer(distances: np.ndarray, cap: float) -> float:
    return float(np.minimum(distances, cap).mean())


def _gray(rgb: np.ndarray) -> np.ndarray:
    return rgb[..., :3] @ np.array([0.299, 0.587, 0.114], dtype=np.float32)


def _nanmedian(values) -> float:
    return _nanquantile(values, 0.5)


def _nanquantile(values, q: float) -> float:
    values = np.asarray(values, dtype=np.float64)
    values = values[np.isfinite(values)]
    return float(np.quantile(values, q)) if values.size else float("nan")


def _ratio(distance: float, baseline: float) -> float:
    if not np.isfinite(distance) or not baseline > 0:
        return float("nan")
    return distance / baseline


def _bilinear_cells(shape: tuple[int, int], pix: np.ndarray):
    """``(off, x0, y0, fx, fy)`` for bilinear reads of an ``(H, W)`` field at pixels ``pix (n, 2)``: which
    pixels are off the image (or NaN), each one's cell corner (clamped inside) and its fractions there."""
    H, W = shape
    p = np.nan_to_num(pix, nan=-1e9, posinf=-1e9, neginf=-1e9)
    off = (p[:, 0] < 0) | (p[:, 0] > W - 1) | (p[:, 1] < 0) | (p[:, 1] > H - 1)
    x = np.clip(p[:, 0], 0, W - 1.001)
    y = np.clip(p[:, 1], 0, H - 1.001)
    x0, y0 = np.floor(x).astype(int), np.floor(y).astype(int)
    return off, x0, y0, x - x0, y - y0


def _lookup(field: np.ndarray, pix: np.ndarray, outside: float | None = None) -> np.ndarray:
    """Bilinear samples of ``field (H, W)`` at pixels ``pix (n, 2)``; pixels off the image (or NaN)
    read ``outside`` (default: the field's largest value), so that no fit gains by leaving the image."""
    off, x0, y0, fx, fy = _bilinear_cells(field.shape, pix)
    out = ((1 - fy) * ((1 - fx) * field[y0, x0] + fx * field[y0, x0 + 1])
           + fy * ((1 - fx) * field[y0 + 1, x0] + fx * field[y0 + 1, x0 + 1]))
    out[off] = float(field.max()) if outside is None else outside
    return out


def _lookup_gradient(field: np.ndarray, pix: np.ndarray) -> np.ndarray:
    """``(n, 2)``: the gradient (d/dx, d/dy) of :func:`_lookup`'s bilinear samples of ``field`` at ``pix
    (n, 2)``; 0 off the image (where the lookup reads a constant)."""
    off, x0, y0, fx, fy = _bilinear_cells(field.shape, pix)
    a, b = field[y0, x0], field[y0, x0 + 1]
    c, d = field[y0 + 1, x0], field[y0 + 1, x0 + 1]
    out = np.stack([(1 - fy) * (b - a) + fy * (d - c), (1 - fx) * (c - a) + fx * (d - b)], axis=1)
    out[off] = 0
    return out


def _replace(p: PhotoAlignment, **changes) -> PhotoAlignment:
    import dataclasses

    return dataclasses.replace(p, **changes)


def _length(metres: float) -> str:
    return f"{100 * metres:.1f} cm" if metres < 1 else f"{metres:.2f} m"


def _amount(report: AlignmentReport) -> str:
    if not np.isfinite(report.offset_m):
        return "none found"
    return (f"moved {_length(report.offset_m)} ({100 * report.offset_m / report.scene_size_m:.1f} % of the "
            f"mesh's size), turned {report.turn_deg:.1f} degrees, image motion "
            f"{100 * report.displacement:.2f} % of the photo side")
