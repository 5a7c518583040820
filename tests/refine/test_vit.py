"""The ViT refiner: shapes, identity at start, bad input, the overlap-add head, gradients, tiling."""

from __future__ import annotations

import pytest
import torch
import torch.nn.functional as F

from scantex.refine.vit import PRESETS, ViTRefiner, hann_window, overlap_add, refine_tiled


def small_model(**kwargs) -> ViTRefiner:
    torch.manual_seed(0)
    return ViTRefiner(width=32, depth=2, heads=2, patch=8, grid=(4, 4), **kwargs)


def test_presets_build_and_map_rgb_plus_mask_to_rgb():
    for name in PRESETS:
        model = ViTRefiner.preset(name, patch=16, grid=(2, 2))
        assert model(torch.rand(1, 4, 32, 48)).shape == (1, 3, 32, 48)
    with pytest.raises(ValueError, match="unknown refiner size"):
        ViTRefiner.preset("huge")


def test_an_untrained_refiner_is_the_identity():
    model = small_model()
    x = torch.rand(2, 4, 32, 40)
    assert torch.equal(model(x), x[:, :3])


def test_bad_input_raises():
    model = small_model()
    with pytest.raises(ValueError, match="input channels"):
        model(torch.rand(1, 3, 32, 32))
    with pytest.raises(ValueError, match="multiple of the patch"):
        model(torch.rand(1, 4, 30, 32))
    with pytest.raises(ValueError, match="even"):
        ViTRefiner(patch=7)


def test_overlap_add_matches_fold_and_the_window_is_a_partition_of_unity():
    p = 4
    windows = torch.rand(2, 3, 5, 3, 2 * p, 2 * p)
    # slow twin: torch's fold over columns ordered (C, 2p, 2p) x tokens
    cols = windows.permute(0, 3, 4, 5, 1, 2).reshape(2, 3 * 4 * p * p, 15)
    reference = F.fold(cols, output_size=(4 * p, 6 * p), kernel_size=2 * p, stride=p)
    assert torch.allclose(overlap_add(windows, p), reference)
    w = hann_window(2 * p).expand(1, 4, 4, 1, 2 * p, 2 * p)
    inner = overlap_add(w, p)[0, 0, p:-p, p:-p]
    assert torch.allclose(inner, torch.ones_like(inner), atol=1e-6)


def test_positional_embedding_interpolates_to_other_grids():
    model = small_model()
    assert model.positional(4, 4).shape == (1, 16, 32)
    assert model.positional(3, 7).shape == (1, 21, 32)


def test_gradients_reach_every_parameter():
    model = small_model()
    opt = torch.optim.SGD(model.parameters(), lr=0.1)
    x, target = torch.rand(2, 4, 32, 32), torch.rand(2, 3, 32, 32)
    for _ in range(2):  # the zero head blocks gradients to the rest until it has moved once
        opt.zero_grad()
        F.mse_loss(model(x), target).backward()
        opt.step()
    for name, p in model.named_parameters():
        assert p.grad is not None and p.grad.abs().sum() > 0, name


def test_the_residual_is_smooth_across_patch_borders():
    model = small_model()
    torch.nn.init.normal_(model.head.weight, 0, 0.05)
    x = torch.rand(1, 4, 32, 32)
    residual = (model(x) - x[:, :3])[0].detach()
    # rows across a patch border (7 | 8) step no more than rows inside a patch (3 | 4)
    border = (residual[:, 8] - residual[:, 7]).abs().mean()
    inside = (residual[:, 4] - residual[:, 3]).abs().mean()
    assert border < 2 * inside


def test_tiled_refinement_keeps_size_and_identity():
    model = small_model()
    x = torch.rand(2, 4, 45, 70)
    assert torch.allclose(refine_tiled(model, x, 32), x[:, :3], atol=1e-6)
    torch.nn.init.normal_(model.head.weight, 0, 0.05)
    out = refine_tiled(model, x, 32, batch=3)
    assert out.shape == (2, 3, 45, 70)
    assert torch.allclose(out, refine_tiled(model, x, 32, batch=64), atol=1e-5)
