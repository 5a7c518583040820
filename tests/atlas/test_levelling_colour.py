"""Local seam levelling, noise estimation and the levelled-input colour source."""

from __future__ import annotations

import numpy as np

from scantex.atlas.bake import bake
from scantex.atlas.colour import estimate_noise, levelled_input_colour
from scantex.atlas.levelling import seam_offsets
from scantex.atlas.seams import seam_edges, seam_visibility
from scantex.metrics.patches import patch_score
from scantex.scan import Material, Scan
from scantex.views.camera import Camera
from scantex.views.render import render


def two_chart_wall(n: int = 16, size: int = 256, gain_right: float = 1.0, seed: int = 0) -> Scan:
    """A 2 m x 1 m wall (x-z plane, facing -y) cut into a left and a right chart at x = 0.

    Its texture is one world-space pattern (stripes), the right chart's texels multiplied by
    ``gain_right``: an exposure step along the seam when it is not 1.
    """
    xs = np.linspace(-1, 1, 2 * n + 1)
    zs = np.linspace(0, 1, n + 1)
    X, Z = np.meshgrid(xs, zs, indexing="ij")
    positions = np.stack([X.ravel(), np.zeros(X.size), Z.ravel()], 1)
    vid = np.arange(X.size).reshape(X.shape)
    faces, face_uvs, uvs = [], [], []
    uv_index = {}

    def uv_of(i, k, chart):
        key = (i, k, chart)
        if key not in uv_index:
            x0 = 0 if chart == 0 else n
            u = (0.04 if chart == 0 else 0.54) + 0.42 * (i - x0) / n
            uv_index[key] = len(uvs)
            uvs.append((u, 0.05 + 0.9 * k / n))
        return uv_index[key]

    for i in range(2 * n):
        chart = 0 if i < n else 1
        for k in range(n):
            a, b, c, d = vid[i, k], vid[i + 1, k], vid[i + 1, k + 1], vid[i, k + 1]
            ua, ub, uc, ud = (uv_of(i, k, chart), uv_of(i + 1, k, chart), uv_of(i + 1, k + 1, chart),
                              uv_of(i, k + 1, chart))
            faces += [[a, c, b], [a, d, c]]
            face_uvs += [[ua, uc, ub], [ua, ud, uc]]
    uvs = np.array(uvs)
    # the texture: every texel gets the world pattern at the point it maps to
    H = W = size
    yy, xx = np.mgrid[:H, :W]
    u, v = (xx + 0.5) / W, 1 - (yy + 0.5) / H
    right = u > 0.5
    x = np.where(right, (u - 0.54) / 0.42, -1 + (u - 0.04) / 0.42)
    z = (v - 0.05) / 0.9
    rng = np.random.default_rng(seed)
    phase = rng.uniform(0, 6, 3)
    # stripes along x (so the seam at x = 0 crosses them) and a slow variation across it
    pattern = 0.5 + 0.15 * np.sin(9 * z + phase[0]) + 0.05 * np.sin(40 * z + phase[1]) + 0.05 * np.sin(2 * x + phase[2])
    rgb = np.stack([pattern, 0.9 * pattern, 0.8 * pattern], -1)
    rgb = np.where(right[..., None], rgb * gain_right, rgb)
    image = (np.clip(rgb, 0, 1) * 255).round().astype(np.uint8)
    return Scan(positions, np.array(faces), uvs, np.array(face_uvs), None, (Material("wall", image),))


def front_camera(width: int = 200, height: int = 100) -> Camera:
    return Camera.look_at((0.0, -2.2, 0.5), (0.0, 0.0, 0.5), fov_deg=60.0, width=width, height=height)


def levelled(scan: Scan, **kwargs) -> Scan:
    fill = np.zeros(scan.n_faces, bool)
    offsets = seam_offsets(scan, **kwargs)
    colour = levelled_input_colour(scan, offsets, fill)
    (image,) = bake(scan, colour, size=scan.materials[0].image.shape[0])
    return scan.replace(materials=(Material("wall", image),))


def test_the_fixture_has_one_straight_seam_and_a_step():
    scan = two_chart_wall(gain_right=1.1)
    assert len(seam_edges(scan)) == 16
    assert seam_visibility(scan) > 8.0
    assert seam_visibility(two_chart_wall()) < 1.5


def test_levelling_removes_an_exposure_step_at_the_seam():
    scan = two_chart_wall(gain_right=1.1)
    out = levelled(scan)
    assert seam_visibility(out) < 0.25 * seam_visibility(scan)


def test_levelling_leaves_a_texture_without_steps_alone():
    scan = two_chart_wall()
    offsets = seam_offsets(scan)
    assert np.abs(offsets).max() < 0.01
    out = levelled(scan)
    diff = np.abs(out.materials[0].image.astype(int) - scan.materials[0].image.astype(int))
    assert np.median(diff) <= 1


def test_levelling_offsets_are_smooth_and_balanced():
    scan = two_chart_wall(gain_right=1.1)
    g = seam_offsets(scan)
    assert np.abs(g.mean(axis=0)).max() < 0.02  # the overall colour balance stays
    # the two charts move in opposite directions: the right one down, the left one up
    left = scan.uvs[:, 0] < 0.5
    assert g[left].mean() > 0 > g[~left].mean()
    # constant over a chart whose only seam has one step: no edge inside the charts
    assert g[left].std() < 0.5 * np.abs(g[left].mean()) + 1e-3


def corner_uvs(scan: Scan) -> Scan:
    """``scan`` with a UV index of its own for every face corner (same coordinates), as OpenMVS writes its
    OBJ, and with every position repeated per face, as a glTF file repeats them at seams."""
    F = scan.n_faces
    return Scan(scan.positions[scan.faces.reshape(-1)], np.arange(3 * F).reshape(F, 3),
                scan.uvs[scan.face_uvs.reshape(-1)], np.arange(3 * F).reshape(F, 3), None, scan.materials)


def test_charts_and_levelling_do_not_depend_on_how_the_file_indexes_its_corners():
    from scantex.atlas.seams import uv_shells

    scan = two_chart_wall(gain_right=1.1)
    split = corner_uvs(scan)
    assert np.array_equal(uv_shells(split), uv_shells(scan)) and uv_shells(scan).max() == 1
    assert len(seam_edges(split)) == len(seam_edges(scan)) == 16
    # the same offset at every face corner: a smooth field inside each chart, not a step at every face
    a = seam_offsets(scan)[scan.face_uvs]
    b = seam_offsets(split)[split.face_uvs]
    assert np.abs(a).max() > 0.02
    assert np.abs(a - b).max() < 1e-6
    out = levelled(split)
    assert seam_visibility(out) < 0.25 * seam_visibility(split)
    reference = levelled(scan).materials[0].image.astype(int)
    assert np.abs(out.materials[0].image.astype(int) - reference).max() <= 1


def test_levelled_output_has_no_patches_against_the_input():
    scan = two_chart_wall(gain_right=1.08)
    out = levelled(scan)
    cam = front_camera()
    a, mask = render(scan, cam, supersample=2)
    b, _ = render(out, cam, supersample=2)
    assert patch_score(b, a, mask > 0.5) < 0.002  # the step it removes never counts; nothing is added


def test_a_colour_edge_on_a_seam_is_not_levelled():
    """A seam whose sides disagree far beyond exposure (a real colour edge) moves nothing."""
    scan = two_chart_wall(gain_right=1.6)
    assert np.abs(seam_offsets(scan)).max() < 1e-3
    assert np.abs(seam_offsets(scan, max_step=1.0)).mean() > 0.05  # without the gate it would


def test_a_seam_on_a_crease_is_not_levelled():
    scan = two_chart_wall(gain_right=1.1)
    folded = scan.positions.copy()
    right = folded[:, 0] > 1e-9
    folded[right, 1] = folded[right, 0]  # fold the right half by 90 degrees about x = 0
    folded[right, 0] = 0
    bent = Scan(folded, scan.faces, scan.uvs, scan.face_uvs, None, scan.materials)
    assert np.abs(seam_offsets(bent)).max() < 1e-3
    assert np.abs(seam_offsets(bent, max_crease_deg=95)).mean() > 0.01


def test_noise_estimate_recovers_white_noise_on_a_smooth_image():
    rng = np.random.default_rng(0)
    yy, xx = np.mgrid[:256, :256]
    smooth = 0.5 + 0.2 * np.sin(xx / 40)[..., None] * np.ones(3)
    for sigma in (0.01, 0.03):
        noisy = smooth + rng.normal(0, sigma, (256, 256, 1))
        assert abs(estimate_noise(noisy) - sigma) < 0.25 * sigma
    assert estimate_noise(smooth) < 0.002


def test_denoising_against_a_perfect_field_removes_noise_and_keeps_strong_detail():
    """With a field that predicts the clean texture, noise within the threshold goes, a strong mark stays."""
    scan = two_chart_wall(size=128)
    clean = scan.materials[0].image.astype(np.float32) / 255
    rng = np.random.default_rng(1)
    noisy = clean + rng.normal(0, 0.02, clean.shape).astype(np.float32)
    noisy[60:68, 30:38] += 0.3  # a mark the field does not know: detail, not noise
    noisy_scan = scan.replace(materials=(Material("wall", (np.clip(noisy, 0, 1) * 255).round().astype(np.uint8)),))

    class PerfectField:
        appearance = None

        def surface_colour(self, points, normals, device):
            from scantex.views.raycast import RayCaster

            caster = RayCaster(scan.positions, scan.faces)
            hits = caster.intersect(points - 0.01 * normals, normals)
            from scantex.views.render import shade_hits

            return shade_hits(scan, hits.face_id, hits.bary)

    fill = np.zeros(scan.n_faces, bool)
    colour = levelled_input_colour(noisy_scan, np.zeros((len(scan.uvs), 3)), fill, fitted=PerfectField(),
                                   taught=np.ones(scan.n_faces, bool), charts=np.zeros(scan.n_faces, int),
                                   device="cpu", noise_threshold=0.05)
    (image,) = bake(noisy_scan, colour, size=128)
    out = image.astype(np.float32) / 255
    inside = np.zeros((128, 128), bool)
    inside[10:118, 8:52] = True
    inside[10:118, 72:118] = True
    inside[56:72, 26:42] = False
    err_in = np.abs(noisy - clean)[inside].mean()
    err_out = np.abs(out - clean)[inside].mean()
    assert err_out < 0.5 * err_in
    assert out[61:67, 31:37].mean() - clean[61:67, 31:37].mean() > 0.2  # the mark is kept


def reads_no_dark_texel(scan: Scan, f: np.ndarray, bary: np.ndarray) -> np.ndarray:
    """``(N,) bool``: the points whose bilinear lookup reads no texel of 30 levels or darker (6 + the dark ramp)."""
    from scantex.views.render import hit_uvs, sample_texture

    dark = (scan.materials[0].image.max(axis=2) <= 30).astype(np.float32)[..., None]
    return sample_texture(dark, hit_uvs(scan, f, bary))[:, 0] == 0


def test_the_ring_around_a_hole_keeps_its_own_texels():
    """A hole (one black face) and the ring of faces around it: the hole takes the harmonic fill, the ring
    keeps its own texels (a coarse mesh's ring is a large part of the surface); only black texels blend in."""
    from scantex.atlas.holes import untextured_faces
    from scantex.atlas.inpaint import grow_faces
    from scantex.views.raycast import interpolate

    scan = two_chart_wall(n=4)
    image = scan.materials[0].image.copy()
    hole = 10
    uv = scan.triangle_uvs[hole]  # paint the hole face's UV triangle black, a little beyond its edges
    H, W = image.shape[:2]
    ys, xs = np.mgrid[0:H, 0:W]
    u, v = (xs + 0.5) / W, 1 - (ys + 0.5) / H
    a, b, c = uv
    d = (b[1] - c[1]) * (a[0] - c[0]) + (c[0] - b[0]) * (a[1] - c[1])
    l1 = ((b[1] - c[1]) * (u - c[0]) + (c[0] - b[0]) * (v - c[1])) / d
    l2 = ((c[1] - a[1]) * (u - c[0]) + (a[0] - c[0]) * (v - c[1])) / d
    image[(l1 > -0.02) & (l2 > -0.02) & (1 - l1 - l2 > -0.02)] = 0
    scan = scan.replace(materials=(Material("wall", image),))
    holes = untextured_faces(scan)
    assert holes[hole] and holes.sum() == 1
    fill = grow_faces(scan, holes)
    ring = np.flatnonzero(fill & ~holes)
    colour = levelled_input_colour(scan, np.zeros((len(scan.uvs), 3)), fill)
    rng = np.random.default_rng(0)
    f = np.repeat(ring, 50)
    bary = rng.dirichlet([4, 4, 4], len(f))[:, 1:].astype(np.float32)  # inside the faces, off their edges
    from scantex.views.render import shade_hits

    own = shade_hits(scan, f, bary)
    got = colour(interpolate(f, bary, scan.triangles), scan.face_normals[f], f, bary)
    lit = reads_no_dark_texel(scan, f, bary)  # the ring's own texels, not the black ones nor lookups mixing them
    assert lit.mean() > 0.8
    np.testing.assert_allclose(got[lit], own[lit], atol=1e-5)
    assert got.max(axis=1).min() > 0.2  # and no dark rim where lookups mix a black texel with the ring's
    centre = np.full((1, 2), 1 / 3, np.float32)
    at = np.array([hole])
    filled = colour(interpolate(at, centre, scan.triangles), scan.face_normals[at], at, centre)
    assert filled.max() > 0.2  # the hole itself is filled from around it, not black


def test_an_apps_fade_into_its_black_around_a_hole_blends_into_the_fill():
    """Polycam fades its atlas into black over the texels around what it did not see. Kept as they were, those
    texels drew a dark, jagged rim along the hole's faces where the fill begins; now the ring's texels darker
    than ``FADE_SHARE`` of the fill, near the black, blend into it, and the ring's other texels are kept."""
    from scantex.atlas.colour import FADE_SHARE
    from scantex.atlas.holes import untextured_faces
    from scantex.atlas.inpaint import grow_faces
    from scantex.views.raycast import interpolate
    from scantex.views.render import shade_hits

    scan = two_chart_wall(n=4)
    image = scan.materials[0].image.astype(np.float64)
    hole = 10
    a, b, c = scan.triangle_uvs[hole]
    H, W = image.shape[:2]
    ys, xs = np.mgrid[0:H, 0:W]
    u, v = (xs + 0.5) / W, 1 - (ys + 0.5) / H
    d = (b[1] - c[1]) * (a[0] - c[0]) + (c[0] - b[0]) * (a[1] - c[1])
    l1 = ((b[1] - c[1]) * (u - c[0]) + (c[0] - b[0]) * (v - c[1])) / d
    l2 = ((c[1] - a[1]) * (u - c[0]) + (a[0] - c[0]) * (v - c[1])) / d
    inside = np.minimum(np.minimum(l1, l2), 1 - l1 - l2)  # > 0 inside the hole's UV triangle
    fade = np.clip(-inside / 0.4, 0, 1)  # black inside, the texture's own level 0.4 (barycentric) out
    scan = scan.replace(materials=(Material("wall", np.rint(image * fade[..., None]).astype(np.uint8)),))
    holes = untextured_faces(scan)
    assert holes[hole] and holes.sum() == 1
    fill = grow_faces(scan, holes)
    ring = np.flatnonzero(fill & ~holes)
    colour = levelled_input_colour(scan, np.zeros((len(scan.uvs), 3)), fill)
    f = np.repeat(ring, 200)
    bary = np.random.default_rng(0).dirichlet([1, 1, 1], len(f))[:, 1:].astype(np.float32)
    got = colour(interpolate(f, bary, scan.triangles), scan.face_normals[f], f, bary)
    own = shade_hits(scan, f, bary)
    wall = np.median(shade_hits(two_chart_wall(n=4), f, bary).max(axis=1))  # the texture's level, unfaded
    faded = own.max(axis=1) < 0.5 * wall
    assert faded.mean() > 0.05  # the fade reaches into the ring: its texels there were kept, dark, before
    # (without the rule 43 % of them come out above half the wall's level; the far end of the fade, lifted in
    # part, keeps the rest below)
    assert (got.max(axis=1)[faded] > 0.5 * wall).mean() > 0.7
    # the texels the fade leaves alone are kept (but a few of those below FADE_SHARE of a brighter fill there)
    bright = reads_no_dark_texel(scan, f, bary) & (own.max(axis=1) > 0.8 * wall)
    assert bright.mean() > 0.3
    moved = np.abs(got[bright] - own[bright]).max(axis=1)
    assert (moved < 1e-5).mean() > 0.97 and moved.max() < 0.01
    assert 0 < FADE_SHARE < 1


def test_black_specks_inside_faces_that_are_not_holes_are_filled():
    """An app's atlas is black where its photos did not reach; that border cuts faces in part. A face black
    only around its middle is no hole (its corners are coloured), yet its black texels must not reach the
    output: they take the fill there, the rest of the face keeps its own texels, and a dark texture that is not
    black (a dark stripe) is kept as it is. The real apartment's output showed such specks."""
    from scantex.atlas.holes import partly_untextured_faces, untextured_faces
    from scantex.views.raycast import interpolate
    from scantex.views.render import shade_hits, to_uint8
    from tests.conftest import grid_wall

    wall = grid_wall(n=21, size=2.0)  # 20 x 20 cells of 8 x 8 texels in a 160² atlas
    u, v = np.meshgrid(np.linspace(0, 1, 160), np.linspace(0, 1, 160))
    image = to_uint8(np.stack([0.45 + 0.3 * u, 0.5 + 0.2 * v, 0.6 - 0.2 * u], axis=2))
    image[:, 8 * 15 + 3:8 * 15 + 5] = 18  # a dark stripe two texels wide down column of cells 15: not black
    spots = [(4, 5), (10, 12), (16, 3)]  # (column, row) of cells whose middle 4 x 4 texels are black
    for i, j in spots:
        image[8 * j + 2:8 * j + 6, 8 * i + 2:8 * i + 6] = 0
    scan = wall.replace(materials=(Material("wall", image),))
    assert not untextured_faces(scan).any()  # no face is black at its centre and its corners
    partly = partly_untextured_faces(scan)
    centres = scan.triangle_uvs.mean(axis=1) * 20  # in cells
    spotted = np.zeros(scan.n_faces, bool)
    for i, j in spots:
        spotted |= (np.floor(centres[:, 0]) == i) & (np.floor(20 - centres[:, 1]) == j)
    assert spotted.sum() == 6 and (partly == spotted).all()  # the two triangles of each spotted cell, no other

    colour = levelled_input_colour(scan, np.zeros((len(scan.uvs), 3)), np.zeros(scan.n_faces, bool))
    rng = np.random.default_rng(0)
    f = np.repeat(np.arange(scan.n_faces), 40)
    bary = rng.dirichlet([2, 2, 2], len(f))[:, 1:].astype(np.float32)
    own = shade_hits(scan, f, bary)
    got = colour(interpolate(f, bary, scan.triangles), scan.face_normals[f], f, bary)
    stripe = (np.abs(own - 18 / 255) < 1e-3).all(axis=1)
    assert stripe.sum() > 100 and (np.abs(got[stripe] - own[stripe]) < 1e-5).all()  # the dark stripe is kept
    in_spot = spotted[f]
    assert (own[in_spot].max(axis=1) < 0.02).sum() > 20  # the input is black there ...
    assert got[in_spot].max(axis=1).min() > 0.4  # ... the output nowhere: the smooth wall is 0.45 or brighter
    np.testing.assert_allclose(got[~in_spot], own[~in_spot], atol=1e-5)  # every other face keeps its texels
    lit = reads_no_dark_texel(scan, f, bary)  # and so do the spotted faces' points away from the black
    assert lit[in_spot].mean() > 0.3
    np.testing.assert_allclose(got[lit], own[lit], atol=1e-5)


def test_black_amid_dark_texture_is_no_hole_and_keeps_its_texels():
    """A black tyre in shadow: its darkest texels are as dark as an app's untextured black, but they spread over
    the black levels where an app's black is pure, and the faces around them are dark too. Filled, they would
    turn into flat, lighter patches (a Polycam scan's tyres did). So: noisy black amid dark texture is no hole,
    noisy black specks in a lit face are no black specks, and both keep their texels; pure black is a hole in
    lit surroundings and in dark ones, and so is a noisy black face all over in lit surroundings (an app whose
    black is not pure); black specks of pure black are filled (the specks test above)."""
    from scantex.atlas.holes import partly_untextured_faces, untextured_faces
    from scantex.views.raycast import interpolate
    from scantex.views.render import shade_hits, to_uint8
    from tests.conftest import grid_wall

    rng = np.random.default_rng(0)
    wall = grid_wall(n=21, size=2.0)  # 20 x 20 cells of 8 x 8 texels in a 160² atlas
    u, v = np.meshgrid(np.linspace(0, 1, 160), np.linspace(0, 1, 160))
    image = to_uint8(np.stack([0.45 + 0.3 * u, 0.5 + 0.2 * v, 0.6 - 0.2 * u], axis=2))

    def cells(columns, rows):  # the atlas block of cells (column i, row j: image rows from the top)
        return slice(8 * rows[0], 8 * rows[1]), slice(8 * columns[0], 8 * columns[1])

    image[cells((2, 9), (2, 9))] = rng.integers(0, 25, (56, 56, 3))  # a dark object, 0-24 levels ...
    image[cells((4, 7), (4, 7))] = rng.integers(0, 7, (24, 24, 3))  # ... black at its heart, 0-6
    image[cells((12, 16), (12, 16))] = 0  # an app's hole: pure black, in the lit wall ...
    image[cells((2, 9), (13, 19))] = rng.integers(0, 25, (48, 56, 3))  # ... and one amid dark texture
    image[cells((4, 7), (15, 17))] = 0
    image[cells((12, 16), (2, 6))] = rng.integers(0, 7, (32, 32, 3))  # a hole in noisy black, in the lit wall
    for i, j in [(11, 9), (16, 9)]:  # noisy black specks in lit cells
        image[8 * j + 2:8 * j + 6, 8 * i + 2:8 * i + 6] = rng.integers(0, 7, (4, 4, 3))
    image[8 * 17 + 2:8 * 17 + 6, 8 * 8 + 2:8 * 8 + 6] = 0  # a pure black speck in a lit cell (column 8, row 17)
    scan = wall.replace(materials=(Material("wall", image),))

    centres = scan.triangle_uvs.mean(axis=1) * 20  # in cells
    column, row = np.floor(centres[:, 0]), np.floor(20 - centres[:, 1])

    def within(columns, rows):
        return (column >= columns[0]) & (column < columns[1]) & (row >= rows[0]) & (row < rows[1])

    holes, partly = untextured_faces(scan), partly_untextured_faces(scan)
    np.testing.assert_array_equal(holes, within((12, 16), (12, 16)) | within((12, 16), (2, 6)) | within((4, 7), (15, 17)))
    dark_object = within((2, 9), (2, 9))
    noisy_specks = within((11, 12), (9, 10)) | within((16, 17), (9, 10))
    assert not (holes | partly)[dark_object | noisy_specks].any()
    assert partly[within((8, 9), (17, 18))].all()

    colour = levelled_input_colour(scan, np.zeros((len(scan.uvs), 3)), np.zeros(scan.n_faces, bool))
    kept = np.flatnonzero(dark_object | noisy_specks)
    f = np.repeat(kept, 40)
    bary = rng.dirichlet([2, 2, 2], len(f))[:, 1:].astype(np.float32)
    got = colour(interpolate(f, bary, scan.triangles), scan.face_normals[f], f, bary)
    np.testing.assert_allclose(got, shade_hits(scan, f, bary), atol=1e-5)  # the input's own texels, all of them


def test_black_probes_are_the_same_compiled_and_in_numpy(monkeypatch):
    """The black and pure-black masks the faces' probes read: the compiled pass and its numpy twin agree."""
    from scantex import jit
    from scantex.atlas.holes import _black_probes
    from tests.conftest import grid_wall

    rng = np.random.default_rng(3)
    image = rng.integers(0, 9, (160, 160, 3)).astype(np.uint8)  # levels 0-8: black, pure black and neither
    image[40:80, 40:80] = 0
    scan = grid_wall(n=21).replace(materials=(Material("wall", image),))
    compiled = _black_probes(scan)
    monkeypatch.setattr(jit, "compiled", lambda function: None)
    twin = _black_probes(scan.replace(materials=(Material("wall", image.copy()),)))
    assert compiled[0].sum() > 0 and compiled[1].sum() > 0 and (compiled[1] < compiled[0]).any()
    np.testing.assert_array_equal(compiled[0], twin[0])
    np.testing.assert_array_equal(compiled[1], twin[1])


def test_faces_touching_another_chart_are_no_photometric_reference_however_the_file_indexes_them():
    from scantex.photos.poses import reference_faces

    scan = two_chart_wall(gain_right=1.1)
    split = corner_uvs(scan)
    reference = reference_faces(scan)
    # the two columns of faces along the seam at x = 0 touch the other chart (16 rows, 2 faces a cell)
    assert (~reference).sum() == 2 * 2 * 16
    assert np.array_equal(reference_faces(split), reference)



def test_a_holes_fill_is_seeded_by_the_colours_around_it_not_by_their_black():
    """A hole's fill is interpolated from the input's colours at the vertices around it, each read in the atlas
    at the vertex's UV corner, a bilinear lookup of the four texels about it. Where one of them is black (an
    app's atlas is black where its photos did not reach, and that border need not follow the faces), the seed
    is the colour of the others: on a uniform wall the fill is the wall's colour, not darker near that vertex
    (a real room's fill of its unseen upper walls had a dark drip below every vertex that read black)."""
    from scantex.atlas.holes import untextured_faces
    from scantex.atlas.inpaint import grow_faces
    from scantex.views.raycast import interpolate
    from scantex.views.render import to_uint8
    from tests.conftest import grid_wall

    wall = grid_wall(n=21, size=2.0)  # 20 x 20 cells of 8 x 8 texels in a 160² atlas, v up, rows down
    image = np.zeros((160, 160, 3), np.uint8)
    image[:] = to_uint8(np.array([0.6, 0.5, 0.4]))
    image[40:120, 48:80] = 0  # a hole of whole faces: cells 6-9 across, 5-14 down
    for row in range(48, 120, 8):  # single black texels at the corners just outside the hole's ring of faces
        image[row - 1, 39] = 0
    scan = wall.replace(materials=(Material("wall", image),))
    holes = untextured_faces(scan)
    fill = grow_faces(scan, holes, rings=1)  # as photo and mesh-only modes fill: the hole and its ring
    colour = levelled_input_colour(scan, np.zeros((len(scan.uvs), 3)), fill)
    f = np.flatnonzero(holes)
    centre = np.full((len(f), 2), 1 / 3, np.float32)
    got = colour(interpolate(f, centre, scan.triangles), scan.face_normals[f], f, centre)
    assert holes.sum() == 2 * 4 * 10
    np.testing.assert_allclose(got, np.broadcast_to([0.6, 0.5, 0.4], got.shape), atol=0.01)


def test_a_holes_fill_takes_the_levelling_offset_once_where_its_seeds_read_black():
    """The seam levelling's offset is added to every texel a seed's lookup reads, black ones too; the seed is
    renormalised by its non-black share, and the offset must not be (a real apartment's glass rim, its
    lookups 85 % black, took an offset of +0.1 as +0.7 and turned cyan). A hole in a wall whose seeds on
    one side read half black texels, with a uniform offset: the fill is the wall's colour plus the offset,
    as the wall's own texels are (before: up to 0.077 off, the offset doubled beside those seeds)."""
    from scantex.atlas.holes import untextured_faces
    from scantex.atlas.inpaint import grow_faces
    from scantex.views.raycast import interpolate
    from scantex.views.render import to_uint8
    from tests.conftest import grid_wall

    wall = grid_wall(n=21, size=2.0)
    image = np.zeros((160, 160, 3), np.uint8)
    image[:] = to_uint8(np.array([0.6, 0.5, 0.4]))
    image[40:120, 48:80] = 0  # a hole of whole faces
    image[32:128, 39] = 0  # black texels beside the vertices left of its ring: their lookups half black
    scan = wall.replace(materials=(Material("wall", image),))
    holes = untextured_faces(scan)
    fill = grow_faces(scan, holes, rings=1)
    offset = np.array([-0.07, 0.1, 0.1])
    colour = levelled_input_colour(scan, np.tile(offset, (len(scan.uvs), 1)), fill)
    f = np.flatnonzero(holes)
    centre = np.full((len(f), 2), 1 / 3, np.float32)
    got = colour(interpolate(f, centre, scan.triangles), scan.face_normals[f], f, centre)
    np.testing.assert_allclose(got, np.broadcast_to([0.53, 0.6, 0.5], got.shape), atol=0.02)


def test_a_loose_fragments_fill_takes_the_colour_of_the_surface_it_floats_on():
    """A fused scan's loose fragments (a TSDF's floaters a centimetre off a cabinet) are seen by no photo
    cleanly, so the input is black on them and their fill has no seed of its own: they take the colour of
    the nearest textured surface in space, not the mean colour of the whole scan (a real apartment's dark
    cabinets were dotted with light grey where their floaters were)."""
    from scantex.atlas.holes import untextured_faces
    from scantex.atlas.inpaint import grow_faces
    from scantex.views.render import to_uint8
    from tests.conftest import grid_wall

    wall = grid_wall(n=21, size=2.0)  # x-z plane, normals towards -y; u along x
    image = np.zeros((160, 160, 3), np.uint8)
    image[:, :80] = to_uint8(np.array([0.35, 0.25, 0.2]))  # dark wood on the left (x < 1)
    image[:, 80:] = to_uint8(np.array([0.9, 0.9, 0.85]))   # a white wall on the right
    image[:4, 150:] = 0  # black texels for the fragment's UVs (a corner of the atlas no wall face uses)
    # fragments of two triangles 1 cm in front of the wall, on UVs of that black corner: one over the dark
    # half, one straddling both halves
    squares = [np.array([[x0, -0.01, 0.8], [x1, -0.01, 0.8], [x1, -0.01, 1.0], [x0, -0.01, 1.0]])
               for x0, x1 in ((0.3, 0.5), (0.7, 1.3))]
    positions = np.concatenate([wall.positions, *squares])
    n, t = len(wall.positions), len(wall.uvs)
    quads = [[[n + o, n + o + 1, n + o + 2], [n + o, n + o + 2, n + o + 3]] for o in (0, 4)]
    faces = np.concatenate([wall.faces, *quads])
    corner_uvs = np.array([[0.95, 0.985], [0.99, 0.985], [0.99, 0.99], [0.95, 0.99]])
    uvs = np.concatenate([wall.uvs, corner_uvs])
    face_uvs = np.concatenate([wall.face_uvs, [[t, t + 1, t + 2], [t, t + 2, t + 3]] * 2])
    scan = Scan(positions, faces, uvs, face_uvs, None, (Material("wall", image),))
    holes = untextured_faces(scan)
    assert np.flatnonzero(holes).tolist() == list(range(len(wall.faces), len(faces)))
    colour = levelled_input_colour(scan, np.zeros((len(scan.uvs), 3)), grow_faces(scan, holes, rings=1))
    f = np.flatnonzero(holes)
    corners = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]], np.float32)
    got = np.stack([colour(scan.triangles[f, k], scan.face_normals[f], f, np.repeat(corners[k:k + 1], len(f), 0))
                    for k in range(3)], axis=1)  # [4 faces, 3 corners, RGB]
    np.testing.assert_allclose(got[:2], np.broadcast_to([0.35, 0.25, 0.2], got[:2].shape), atol=0.02)
    # the straddling one is one colour between the two, not dark at one end and white at the other
    assert np.ptp(got[2:].reshape(-1, 3), axis=0).max() < 1e-6
    assert np.all(got[2, 0] > [0.35, 0.25, 0.2]) and np.all(got[2, 0] < [0.9, 0.9, 0.85])


def test_levelling_gives_the_same_offsets_whatever_numpy_s_global_generator_holds():
    # the multigrid's spectral estimates start from a random vector of numpy's global generator
    scan = two_chart_wall(gain_right=1.3)
    np.random.seed(1)
    a = seam_offsets(scan)
    np.random.seed(2)
    b = seam_offsets(scan)
    assert np.abs(a).max() > 0.01
    np.testing.assert_array_equal(a, b)
    assert np.random.rand() == np.random.RandomState(2).rand()  # the caller's generator left where it was


def test_the_black_texels_tables_are_the_same_compiled_and_in_numpy(monkeypatch):
    """The black-texel tables of the hole fill (:func:`scantex.atlas.colour._dark_texels`: black, on the dark ramp,
    or neither; :func:`scantex.atlas.colour._near_black`: how near black) and of
    :func:`scantex.atlas.holes.partly_untextured_faces`, made in one compiled pass or in numpy: the same lookups
    and the same faces, on an atlas of every dark level and random colours."""
    from scantex import jit
    from scantex.atlas.colour import _dark_texels, _near_black
    from scantex.atlas.holes import partly_untextured_faces
    from tests.conftest import grid_wall

    wall = grid_wall(n=21, size=2.0)
    rng = np.random.default_rng(1)
    image = rng.integers(0, 40, (160, 160, 3)).astype(np.uint8)  # black, ramp and lit texels side by side
    image[::2] = rng.integers(0, 256, image[::2].shape).astype(np.uint8)
    image[40:60, 40:60] = 0
    scan = wall.replace(materials=(Material("wall", image),))
    f = np.repeat(np.arange(scan.n_faces), 30)
    bary = rng.dirichlet([2, 2, 2], len(f))[:, 1:].astype(np.float32)

    def tables():
        share, dark = _dark_texels(scan)(f, bary)
        return share, dark, partly_untextured_faces(scan), _near_black(scan)(f, bary)

    compiled = tables()
    monkeypatch.setattr(jit, "compiled", lambda function: None)
    in_numpy = tables()
    assert 0.05 < compiled[0].mean() < 0.9 and compiled[2].any() and 0 < compiled[3].mean() < 1
    for a, b in zip(compiled, in_numpy, strict=True):
        assert np.array_equal(a, b)
