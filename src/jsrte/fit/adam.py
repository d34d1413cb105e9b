"""Adam (Kingma & Ba) over a hypothesis batch's parameters, written out.

The same update as ``torch.optim.Adam`` with its defaults (β = 0.9, 0.999, ε = 1e-8), so that a
fit never imports ``torch.optim``: its constructor imports TorchDynamo, a second of a fit's
start-up. Pruning keeps the moments of the kept hypotheses (:meth:`Adam.kept`).
"""

from __future__ import annotations

import torch

BETAS = (0.9, 0.999)
EPSILON = 1e-8


def adam_step(params: list[torch.Tensor], state: list[tuple[torch.Tensor, torch.Tensor]], step: int,
              lr: float) -> None:
    """One Adam update of ``params`` in place from their ``.grad`` (a parameter without one is
    left alone); ``state`` holds each parameter's (first, second) moments, ``step`` counts from 1."""
    b1, b2 = BETAS
    with torch.no_grad():
        for p, (m, v) in zip(params, state, strict=True):
            if p.grad is None:
                continue
            m.mul_(b1).add_(p.grad, alpha=1.0 - b1)
            v.mul_(b2).addcmul_(p.grad, p.grad, value=1.0 - b2)
            denominator = (v.sqrt() / (1.0 - b2**step) ** 0.5).add_(EPSILON)
            p.addcdiv_(m, denominator, value=-lr / (1.0 - b1**step))


class Adam:
    """Adam over ``params`` (tensors whose first dimension is the hypothesis), learning rate ``lr``."""

    def __init__(self, params: list[torch.Tensor], lr: float) -> None:
        if not params:
            raise ValueError("every parameter is fixed: nothing to optimize")
        self.params = list(params)
        self.lr = lr
        self.steps = 0
        self.moments = [(torch.zeros_like(p), torch.zeros_like(p)) for p in self.params]

    def zero_grad(self) -> None:
        """Forget every parameter's gradient."""
        for p in self.params:
            p.grad = None

    def step(self) -> None:
        """One update from the parameters' gradients."""
        self.steps += 1
        adam_step(self.params, self.moments, self.steps, self.lr)

    def kept(self, params: list[torch.Tensor], rows: torch.Tensor) -> Adam:
        """An Adam over ``params`` (the same parameters, hypotheses ``rows`` (k,) kept) that goes on
        with their moments and step count (a fresh Adam's first steps move every parameter by ~lr)."""
        pruned = Adam(params, self.lr)
        pruned.steps = self.steps
        pruned.moments = [(m[rows.to(m.device)].clone(), v[rows.to(v.device)].clone()) for m, v in self.moments]
        return pruned
