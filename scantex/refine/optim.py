"""Adam / AdamW for the refiner and the denoiser, through torch's own fused update kernel.

The first ``torch.optim.Optimizer`` a process constructs imports ``torch._dynamo`` (its methods are
wrapped to keep the compiler out): 1.5-2 s on a 2-core machine, measured, out of a 30 s ``fast`` run that
trains the refiner once. The update itself is torch's maintained implementation, called as the
function ``torch.optim.adam.adam`` that ``torch.optim.Adam`` / ``AdamW`` call inside their ``step``; this class
only keeps the moments and step counts, as the ``Optimizer`` would. The learning rate is given to each
``step`` (the schedules here are plain functions of the step), so no ``LambdaLR`` is needed either.
"""

from __future__ import annotations

from collections.abc import Iterable


class Adam:
    """Adam (``weight_decay`` added to the gradient, as ``torch.optim.Adam``) or AdamW (``decoupled``: the
    weights decayed directly, as ``torch.optim.AdamW``), with the same results as those classes given the
    same learning rate at every step (tested)."""

    def __init__(self, params: Iterable, betas: tuple[float, float] = (0.9, 0.999), eps: float = 1e-8,
                 weight_decay: float = 0.0, decoupled: bool = False):
        import torch

        self.params = [p for p in params if p.requires_grad]
        self.betas, self.eps, self.weight_decay, self.decoupled = betas, eps, weight_decay, decoupled
        self.exp_avg = [torch.zeros_like(p, memory_format=torch.preserve_format) for p in self.params]
        self.exp_avg_sq = [torch.zeros_like(p, memory_format=torch.preserve_format) for p in self.params]
        # fused kernels keep the step count on the parameter's device, the single-tensor path on the CPU
        self.fused = all(p.device.type in ("cpu", "cuda") for p in self.params)
        self.steps = [torch.zeros((), dtype=torch.float32, device=p.device if self.fused else "cpu")
                      for p in self.params]

    def zero_grad(self) -> None:
        for p in self.params:
            p.grad = None

    def step(self, lr: float) -> None:
        """One update of every parameter that has a gradient, at learning rate ``lr``."""
        import torch
        from torch.optim.adam import adam

        live = [k for k, p in enumerate(self.params) if p.grad is not None]
        if not live:
            return
        with torch.no_grad():
            adam([self.params[k] for k in live], [self.params[k].grad for k in live],
                 [self.exp_avg[k] for k in live], [self.exp_avg_sq[k] for k in live], [],
                 [self.steps[k] for k in live], foreach=False, fused=self.fused, capturable=False,
                 differentiable=False, grad_scale=None, found_inf=None, has_complex=False, amsgrad=False,
                 beta1=self.betas[0], beta2=self.betas[1], lr=lr, weight_decay=self.weight_decay, eps=self.eps,
                 maximize=False, decoupled_weight_decay=self.decoupled)
