"""The refiner's and the denoiser's optimiser: torch's Adam / AdamW update, without torch.optim.Optimizer."""

import sys

import pytest
import torch

from scantex.refine.optim import Adam


def _train(make, steps=6):
    torch.manual_seed(0)
    model = torch.nn.Sequential(torch.nn.Linear(5, 7), torch.nn.GELU(), torch.nn.Linear(7, 3))
    x, y = torch.randn(16, 5), torch.randn(16, 3)
    step = make(model)
    for k in range(steps):
        loss = ((model(x) - y) ** 2).mean()
        loss.backward()
        step(k)
    return [p.detach().clone() for p in model.parameters()]


@pytest.mark.parametrize("decoupled", [False, True])
def test_same_weights_as_torch_optimizers(decoupled):
    """Given the same learning rate at every step, the weights after a few steps are torch's, bitwise."""

    def lr(k):
        return 0.01 * (k + 1) / 3

    def ours(model):
        opt = Adam(model.parameters(), weight_decay=0.05, decoupled=decoupled)

        def step(k):
            opt.step(lr(k))
            opt.zero_grad()
        return step

    def theirs(model):
        cls = torch.optim.AdamW if decoupled else torch.optim.Adam
        opt = cls(model.parameters(), lr=lr(0), weight_decay=0.05, fused=True)

        def step(k):
            for group in opt.param_groups:
                group["lr"] = lr(k)
            opt.step()
            opt.zero_grad()
        return step

    for a, b in zip(_train(ours), _train(theirs)):
        assert torch.equal(a, b)


def test_parameters_without_gradient_are_left_alone():
    used, unused = torch.nn.Parameter(torch.ones(3)), torch.nn.Parameter(torch.ones(3))
    frozen = torch.nn.Parameter(torch.ones(3), requires_grad=False)
    opt = Adam([used, unused, frozen])
    (used * 2).sum().backward()
    opt.step(0.1)
    assert not torch.equal(used, torch.ones(3))
    assert torch.equal(unused, torch.ones(3)) and torch.equal(frozen, torch.ones(3))
    assert opt.steps[0].item() == 1 and opt.steps[1].item() == 0


def test_does_not_import_the_compiler():
    """The reason the class exists: torch.optim.Optimizer imports torch._dynamo (seconds at start-up)."""
    import subprocess

    code = ("import sys, torch; from scantex.refine.optim import Adam; p = torch.nn.Parameter(torch.ones(4)); "
            "o = Adam([p], weight_decay=0.1, decoupled=True); p.sum().backward(); o.step(0.1); "
            "print('torch._dynamo' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"
