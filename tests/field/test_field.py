"""Radiance field: encodings against their references, volume rendering against a loop, fitting."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
import torch

from scantex.field import (
    BoxNormaliser,
    FieldConfig,
    FrequencyEncoding,
    HashGridEncoding,
    RadianceField,
    band_samples,
    evaluate_colour,
    hash_grid_encode,
    hash_grid_layout,
    hash_grid_reference,
    render_rays,
    volume_render,
    volume_render_reference,
)

DEVICES = ["cpu", pytest.param("cuda", marks=pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA"))]

TINY_HASH = {"n_levels": 6, "log2_table_size": 10, "base_resolution": 2, "max_resolution": 64}


def tiny_grid(seed: int = 0, **overrides) -> HashGridEncoding:
    torch.manual_seed(seed)
    enc = HashGridEncoding(**{**TINY_HASH, **overrides})
    with torch.no_grad():
        enc.table.uniform_(-1.0, 1.0)  # large values so that any indexing mistake shows
    return enc


# --- smoke and bad input -------------------------------------------------------------------------


def test_field_smoke_and_shapes():
    field = RadianceField(FieldConfig(**TINY_HASH, hidden=16, colour_hidden=16))
    sigma, rgb = field(torch.rand(37, 3))
    assert sigma.shape == (37,) and rgb.shape == (37, 3)
    assert sigma.dtype == rgb.dtype == torch.float32
    assert (sigma >= 0).all() and (rgb > 0).all() and (rgb < 1).all()
    assert field.colour(torch.rand(5, 3)).shape == (5, 3)


def test_viewdir_field_shapes_and_needs_directions():
    field = RadianceField(FieldConfig(encoding="frequency", n_freqs=4, use_viewdirs=True, hidden=16))
    d = torch.nn.functional.normalize(torch.randn(11, 3), dim=1)
    sigma, rgb = field(torch.rand(11, 3), d)
    assert sigma.shape == (11,) and rgb.shape == (11, 3)
    with pytest.raises(ValueError, match="view directions"):
        field(torch.rand(11, 3))


@pytest.mark.parametrize(
    "bad",
    [{"encoding": "grid"}, {"density_activation": "relu"}, {"skip_at": 4, "n_layers": 4}, {"hidden": 0}],
)
def test_bad_config_raises(bad):
    with pytest.raises(ValueError):
        FieldConfig(**bad)


def test_bad_inputs_raise():
    with pytest.raises(ValueError, match=r"\(N, 3\)"):
        RadianceField(FieldConfig(**TINY_HASH))(torch.rand(4, 2))
    with pytest.raises(ValueError):
        hash_grid_layout(4, 40, 16, 512)
    with pytest.raises(ValueError):
        band_samples(torch.ones(3), 0, 0.1, stratified=False)
    with pytest.raises(ValueError):
        BoxNormaliser((0.0, 0.0, 0.0), (1.0, 0.0, 1.0))


# --- encodings -----------------------------------------------------------------------------------


def test_out_dims():
    assert FrequencyEncoding(10).out_dim == 63  # NeRF's 3 + 3 * 2 * 10
    assert FrequencyEncoding(4, include_input=False).out_dim == 24
    assert HashGridEncoding(**TINY_HASH).out_dim == 12
    assert HashGridEncoding(n_levels=16, features_per_level=2).out_dim == 32
    for enc in (FrequencyEncoding(3), HashGridEncoding(**TINY_HASH)):
        assert enc(torch.rand(9, 3)).shape == (9, enc.out_dim)


def test_frequency_encoding_known_values():
    x = torch.tensor([[0.0, 0.25, 0.5]])
    out = FrequencyEncoding(2)(x)[0]
    # [x | sin(pi x), sin(2 pi x) | cos(pi x), cos(2 pi x)], axis-minor within each frequency
    expected = [0.0, 0.25, 0.5]
    expected += [math.sin(math.pi * v) for v in (0.0, 0.25, 0.5)] + [
        math.sin(2 * math.pi * v) for v in (0.0, 0.25, 0.5)
    ]
    expected += [math.cos(math.pi * v) for v in (0.0, 0.25, 0.5)] + [
        math.cos(2 * math.pi * v) for v in (0.0, 0.25, 0.5)
    ]
    torch.testing.assert_close(out, torch.tensor(expected), atol=1e-6, rtol=0)


def test_hash_grid_layout():
    layout = hash_grid_layout(16, 19, 16, 2048)
    assert layout.resolutions[0] == 16 and layout.resolutions[-1] == 2048
    growth = [b / a for a, b in zip(layout.resolutions, layout.resolutions[1:])]
    assert all(1.3 < g < 1.45 for g in growth)  # geometric, b = exp(ln(128) / 15) = 1.38
    assert layout.n_dense == 5  # 59^3 fits 2^19 rows, 81^3 does not
    sizes = sorted(
        (off, (r + 1) ** 3 if lvl < layout.n_dense else layout.table_size)
        for lvl, (off, r) in enumerate(zip(layout.offsets, layout.resolutions))
    )
    assert all(a + s == b for (a, s), (b, _) in itertools.pairwise(sizes))  # levels tile the table
    assert sizes[-1][0] + sizes[-1][1] == layout.rows
    assert all(layout.offsets[lvl] % layout.table_size == 0 for lvl in range(layout.n_dense, 16))


def test_hash_grid_params_initialised_small():
    enc = HashGridEncoding(**TINY_HASH)
    assert enc.table.abs().max() <= 1e-4 and enc.table.abs().max() > 0


@pytest.mark.parametrize("device", DEVICES)
def test_hash_grid_matches_reference_forward_and_gradients(device):
    enc = tiny_grid().to(device)
    assert 0 < enc.layout.n_dense < enc.layout.n_levels  # both dense and hashed levels are exercised
    g = torch.Generator().manual_seed(1)
    x = torch.rand(500, 3, generator=g)
    x[:4] = torch.tensor([[0.0, 0.0, 0.0], [1.0, 1.0, 1.0], [1.0, 0.0, 0.5], [0.5, 0.5, 0.5]])  # grid edges
    x = x.to(device).requires_grad_(True)
    fast = enc(x)
    slow = hash_grid_reference(enc, x)
    torch.testing.assert_close(fast, slow, atol=1e-6, rtol=1e-5)
    upstream = torch.randn(fast.shape, generator=g).to(device)
    g_table_fast, g_x_fast = torch.autograd.grad(fast, [enc.table, x], upstream)
    g_table_slow, g_x_slow = torch.autograd.grad(slow, [enc.table, x], upstream)
    torch.testing.assert_close(g_table_fast, g_table_slow, atol=1e-5, rtol=1e-5)
    torch.testing.assert_close(g_x_fast, g_x_slow, atol=1e-3, rtol=1e-4)  # magnitudes ~ resolution (64)


def test_hash_grid_naive_backward_matches_fused():
    enc = tiny_grid()
    x = torch.rand(300, 3, generator=torch.Generator().manual_seed(2))
    grads = []
    for fused in (True, False):
        enc.table.grad = None
        out = hash_grid_encode(x, enc.table, enc.layout, fused_backward=fused)
        (out * torch.arange(out.shape[1])).sum().backward()
        grads.append(enc.table.grad.clone())
    torch.testing.assert_close(grads[0], grads[1], atol=1e-5, rtol=1e-5)


def test_hash_grid_interpolates_vertices_exactly():
    # at a grid vertex of the coarsest level, that level's feature is the vertex's table row
    enc = tiny_grid()
    res = enc.layout.resolutions[0]
    vertex = torch.tensor([[1, 2, 0]])
    out = enc(vertex.float() / res)
    row = enc.layout.offsets[0] + 1 + 2 * (res + 1)  # dense index x + y (R+1) + z (R+1)^2
    torch.testing.assert_close(out[0, :2], enc.table[row].detach())


# --- volume rendering ----------------------------------------------------------------------------


def test_band_samples():
    depth = torch.tensor([1.0, 2.5])
    t = band_samples(depth, 4, 0.2, stratified=False)
    torch.testing.assert_close(t[0], torch.tensor([0.925, 0.975, 1.025, 1.075]))
    g = torch.Generator().manual_seed(0)
    ts = band_samples(depth.repeat(500), 4, 0.2, stratified=True, generator=g)
    assert (ts >= depth.repeat(500)[:, None] - 0.1).all() and (ts <= depth.repeat(500)[:, None] + 0.1).all()
    assert (ts[:, 1:] > ts[:, :-1]).all()
    assert ts.std(dim=0).min() > 0.01  # jittered
    torch.testing.assert_close(band_samples(depth, 1, 0.2, stratified=True), depth[:, None])


@pytest.mark.parametrize("S", [1, 2, 5])
def test_volume_render_matches_reference(S):
    g = torch.Generator().manual_seed(S)
    R = 7
    sigma = torch.rand(R, S, generator=g) * 30
    rgb = torch.rand(R, S, 3, generator=g)
    t = band_samples(torch.rand(R, generator=g) + 1, S, 0.1, stratified=True, generator=g)
    bg = torch.tensor([0.2, 0.4, 0.9])
    fast = volume_render(sigma, rgb, t, background=bg)
    slow = volume_render_reference(sigma, rgb, t, background=bg)
    for a, b in zip(fast, slow):
        torch.testing.assert_close(a, b, atol=1e-5, rtol=1e-5)
    if S == 1:
        torch.testing.assert_close(fast[0], rgb[:, 0])


def test_all_density_at_one_sample_returns_its_colour():
    R, S = 3, 6
    sigma = torch.zeros(R, S)
    sigma[:, 2] = 1e4  # opaque third sample
    rgb = torch.rand(R, S, 3, generator=torch.Generator().manual_seed(0))
    t = band_samples(torch.ones(R), S, 0.06, stratified=False)
    colour, weights, opacity = volume_render(sigma, rgb, t, background=torch.ones(3))
    torch.testing.assert_close(colour, rgb[:, 2])
    torch.testing.assert_close(weights[:, 2], torch.ones(R))
    torch.testing.assert_close(opacity, torch.ones(R))


def test_empty_band_shows_background():
    sigma = torch.zeros(2, 4)
    colour, _, opacity = volume_render(
        sigma,
        torch.rand(2, 4, 3),
        band_samples(torch.ones(2), 4, 0.1, stratified=False),
        background=torch.tensor([0.1, 0.2, 0.3]),
    )
    torch.testing.assert_close(colour, torch.tensor([[0.1, 0.2, 0.3]] * 2))
    assert (opacity == 0).all()


def test_box_normaliser():
    pts = np.array([[0.0, 0.0, 0.0], [4.0, 0.02, 3.0]])
    box = BoxNormaliser.from_points(pts, margin=0.05)
    n = box.apply(torch.tensor(pts, dtype=torch.float32))
    assert (n > 0).all() and (n < 1).all()
    assert box.scale == pytest.approx(4.4)
    sides = [h - l for l, h in zip(box.lo, box.hi)]
    assert max(sides) == pytest.approx(min(sides))  # cubic: cells are cubes in metres
    torch.testing.assert_close(box.apply(torch.tensor([box.lo, box.hi])), torch.tensor([[0.0] * 3, [1.0] * 3]))


def test_render_rays_non_unit_directions_hit_the_surface_point():
    # a surface colour field (S = 1) must be evaluated exactly at origin + depth * direction
    field = RadianceField(FieldConfig(**TINY_HASH, hidden=16))
    box = BoxNormaliser((-1.0, -1.0, -1.0), (3.0, 3.0, 3.0))
    origin = torch.tensor([0.5, -0.5, 0.5])
    directions = torch.tensor([[0.1, 1.0, 0.2], [-0.3, 1.0, 0.0]])  # unit camera-z, not unit length
    depth = torch.tensor([1.5, 0.7])
    rgb, weights = render_rays(field, origin, directions, depth, 1, 0.05, box, stratified=True)
    expected = field.colour(box.apply(origin + depth[:, None] * directions))
    torch.testing.assert_close(rgb, expected)
    assert weights.shape == (2, 1)
    rgb, weights = render_rays(field, origin, directions, depth, 4, 0.05, box, stratified=False)
    assert rgb.shape == (2, 3) and weights.shape == (2, 4)


# --- gradients and fitting -----------------------------------------------------------------------


@pytest.mark.parametrize("encoding", ["hash", "frequency"])
@pytest.mark.parametrize("bf16", [False, True])
def test_gradients_reach_every_parameter(encoding, bf16):
    torch.manual_seed(0)
    field = RadianceField(
        FieldConfig(encoding=encoding, n_freqs=4, use_viewdirs=True, hidden=16, bf16=bf16, **TINY_HASH)
    )
    box = BoxNormaliser((0.0, 0.0, 0.0), (2.0, 2.0, 2.0))
    R = 64
    origins = torch.tensor([1.0, -1.0, 1.0])
    directions = torch.nn.functional.normalize(torch.randn(R, 3) * 0.2 + torch.tensor([0.0, 1.0, 0.0]), dim=1)
    rgb, _ = render_rays(field, origins, directions, torch.full((R,), 2.0), 4, 0.1, box, stratified=True)
    rgb.sum().backward()
    for name, p in field.named_parameters():
        assert p.grad is not None and p.grad.abs().sum() > 0, name


def wall_colour(x: torch.Tensor) -> torch.Tensor:
    """A smooth 'texture' over [0, 1]^3: ``(N, 3)`` in [0.1, 0.9]."""
    s = torch.sin(2 * math.pi * x)
    return torch.stack([0.5 + 0.4 * s[:, 0] * s[:, 1], 0.5 + 0.4 * s[:, 2], 0.5 + 0.4 * s[:, 0] * s[:, 2]], dim=1)


@pytest.mark.parametrize("encoding", ["hash", "frequency"])
def test_tiny_field_fits_a_smooth_colour_function(encoding):
    torch.manual_seed(0)
    config = FieldConfig(
        encoding=encoding,
        n_freqs=4,
        hidden=32,
        n_layers=3,
        skip_at=1,
        colour_hidden=32,
        n_levels=8,
        log2_table_size=14,
        base_resolution=4,
        max_resolution=64,
    )
    field = RadianceField(config)
    opt = torch.optim.Adam(field.parameters(), lr=1e-2, eps=1e-15)
    g = torch.Generator().manual_seed(0)
    for _ in range(300):
        x = torch.rand(1024, 3, generator=g)
        loss = (field.colour(x) - wall_colour(x)).square().mean()
        opt.zero_grad()
        loss.backward()
        opt.step()
    x = torch.rand(4096, 3, generator=g)  # held-out points
    mse = float((evaluate_colour(field, x, chunk=1000) - wall_colour(x)).square().mean())
    variance = float(wall_colour(x).var(dim=0).mean())  # the MSE of predicting the mean colour, ~0.04
    assert mse < 2e-3 < variance / 10, mse


def test_evaluate_colour_matches_colour_and_needs_no_grad():
    field = RadianceField(FieldConfig(**TINY_HASH, hidden=16))
    x = torch.rand(1000, 3)
    out = evaluate_colour(field, x, chunk=300)
    assert not out.requires_grad
    torch.testing.assert_close(out, field.colour(x).detach())
