"""The compiled blend of projective texturing against its slow, plainly correct twin: the numpy path."""

from __future__ import annotations

import sys

import numpy as np
import pytest
from PIL import Image

from scantex import jit
from scantex.photos import compiled
from scantex.photos.texturing import ProjectiveSettings, inverse_transforms, projective_colour, recorded_transforms
from scantex.photos.training import VisibilitySettings, prepare_photos
from scantex.views.camera import Camera
from scantex.views.raycast import RayCaster
from tests.photos.test_alignment import photograph
from tests.photos.test_texturing import grey, smooth_wall, surface_points

pytest.importorskip("numba")

GAINS = (1.0, 1.8, 0.7, 1.2)


@pytest.fixture(scope="module")
def capture(tmp_path_factory):
    """Four photos of the wall, each its own exposure (the second over-exposed: its bright half clipped), one
    with an occluder the mesh does not hold; their transforms as a closed-form fit gives them."""
    tmp_path = tmp_path_factory.mktemp("capture")
    scan = smooth_wall()
    eyes = [(0.7, -2.2, 1.0), (1.3, -2.0, 1.1), (0.9, -2.4, 0.8), (1.1, -2.1, 1.2)]
    cams = [Camera.look_at(e, (1.0, 0.0, 1.0), fov_deg=55, width=640, height=480) for e in eyes]
    photos = photograph(scan, cams, tmp_path)
    for k, (path, gain) in enumerate(zip(photos.images, GAINS)):
        im = np.asarray(Image.open(path)).astype(np.float32) * gain
        if k == 2:
            im[180:300, 260:380] = (230, 20, 20)
        Image.fromarray(np.clip(im, 0, 255).astype(np.uint8)).save(path)
    caster = RayCaster(scan.positions, scan.faces)
    views = prepare_photos(scan, photos, range(4), caster, 160, VisibilitySettings(supersample=2))
    transforms = np.stack([np.vstack([np.eye(3) * g, np.zeros((1, 3))]) for g in GAINS])
    return scan, photos, views, transforms, surface_points(scan, 20000)


def both(capture, monkeypatch, canonicalise=None, **kwargs):
    """The compiled and the numpy colour functions of one setting, and their reports."""
    scan, photos, views, transforms, _ = capture
    fast, fast_report = projective_colour(photos, views, range(4), canonicalise, grey, **kwargs)
    with monkeypatch.context() as m:
        m.setattr(compiled, "available", lambda: False)
        slow, slow_report = projective_colour(photos, views, range(4), canonicalise, grey, **kwargs)
    assert fast_report["compiled"] and not slow_report["compiled"]
    return fast, slow, fast_report, slow_report


def assert_alike(got: np.ndarray, want: np.ndarray) -> None:
    """The same colours but at the odd point whose pixel lies on a rounding boundary (float64 against float32
    arithmetic): one in a thousand at most."""
    far = np.abs(got - want).max(axis=-1) > 1e-4
    assert far.mean() <= 1e-3, f"{far.sum()} of {far.size} points differ"


@pytest.mark.parametrize("settings", [ProjectiveSettings(), ProjectiveSettings(consistency=0.1),
                                      ProjectiveSettings(overshoot=0), ProjectiveSettings(temperature=0.15),
                                      ProjectiveSettings(detail_temperature=0.1),
                                      ProjectiveSettings(detail_temperature=0.1, detail_gain=0.5),
                                      ProjectiveSettings(soft_photos=(1,)),
                                      ProjectiveSettings(detail_temperature=0.1, soft_photos=(0, 2))],
                         ids=["default", "photo-consistency", "no-censoring", "best-view", "sharp-detail",
                              "balanced-detail", "a-soft-photo", "soft-photos-sharp-detail"])
def test_the_compiled_blend_is_the_numpy_blend(capture, monkeypatch, settings):
    scan, photos, views, transforms, (points, normals, f, b) = capture
    fast, slow, fast_report, slow_report = both(
        capture, monkeypatch, canonicalise=inverse_transforms(transforms), settings=settings, faces=scan.faces,
        recorded=recorded_transforms(transforms), transforms=transforms)
    assert_alike(fast(points, normals, f, b), slow(points, normals, f, b))
    for k in (0, 2):  # the leave-one-out blend pose refinement asks for
        assert_alike(fast(points, normals, f, b, without=k), slow(points, normals, f, b, without=k))
    (got, got_share), (want, want_share) = (c(points, normals, f, b, coverage=True) for c in (fast, slow))
    assert_alike(got, want)
    assert np.abs(got_share - want_share).max() < 1e-4
    for key in ("samples", "clipped", "gave_way"):
        assert fast_report["clipped"][key] == pytest.approx(slow_report["clipped"][key], rel=1e-3, abs=2)
    assert fast_report["clipped"]["clipped"] > 1000  # the over-exposed photo's clipped samples are there


def test_the_compiled_blend_without_transforms_or_culling(capture, monkeypatch):
    """The photos' colours as they are (no canonicalise), every photo asked about every point."""
    *_, (points, normals, f, b) = capture
    fast, slow, *_ = both(capture, monkeypatch)
    assert_alike(fast(points, normals, f, b), slow(points, normals, f, b))


def test_a_colour_transform_without_its_matrices_runs_in_numpy(capture):
    scan, photos, views, transforms, _ = capture
    _, report = projective_colour(photos, views, range(4), inverse_transforms(transforms), grey)
    assert not report["compiled"]


def test_the_points_split_across_threads_give_the_same_colours(capture):
    scan, photos, views, transforms, (points, normals, f, b) = capture
    kwargs = dict(faces=scan.faces, recorded=recorded_transforms(transforms), transforms=transforms)
    one, _ = projective_colour(photos, views, range(4), inverse_transforms(transforms), grey, threads=1, **kwargs)
    four, _ = projective_colour(photos, views, range(4), inverse_transforms(transforms), grey, threads=4, **kwargs)
    np.testing.assert_array_equal(four(points, normals, f, b), one(points, normals, f, b))


def test_without_numba_the_numpy_path_runs(capture, monkeypatch):
    scan, photos, views, transforms, (points, normals, f, b) = capture
    monkeypatch.setitem(sys.modules, "numba", None)  # as if it were not installed
    jit.compiled.cache_clear()
    try:
        assert not compiled.available()
        colour, report = projective_colour(photos, views, range(4), None, grey)
        assert not report["compiled"]
        assert np.isfinite(colour(points, normals, f, b)).all()
    finally:
        jit.compiled.cache_clear()


def test_where_numba_cannot_cache_the_blend_it_is_compiled_each_run(capture, monkeypatch, caplog):
    """A read-only install with no home folder: numba refuses ``cache=True``; the blend (and every other kernel)
    is compiled uncached, with one warning a run, not one a kernel."""
    import logging

    import numba

    from scantex.views.render import sample_texture, sample_texture_reference

    njit = numba.njit

    def refusing(*args, **kwargs):
        if kwargs.get("cache"):
            raise RuntimeError("cannot cache function '_blend': no locator available")
        return njit(*args, **kwargs)

    scan, photos, views, transforms, (points, normals, f, b) = capture
    monkeypatch.setattr(numba, "njit", refusing)
    jit.compiled.cache_clear()
    jit._uncached.cache_clear()
    image, uv = np.arange(48, dtype=np.uint8).reshape(4, 4, 3), np.linspace(0, 1, 10).reshape(5, 2)
    try:
        with caplog.at_level(logging.WARNING, logger="scantex.jit"):
            uncached, report = projective_colour(photos, views, range(4), None, grey)
            assert report["compiled"]
            got = uncached(points[:500], normals[:500], f[:500], b[:500])
            assert np.array_equal(sample_texture(image, uv), sample_texture_reference(image, uv))
    finally:
        jit.compiled.cache_clear()
    assert sum("cannot keep its cache" in r.getMessage() for r in caplog.records) == 1
    cached, _ = projective_colour(photos, views, range(4), None, grey)
    np.testing.assert_array_equal(got, cached(points[:500], normals[:500], f[:500], b[:500]))
