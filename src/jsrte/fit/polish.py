"""A short Adam polish of hypotheses a second-order solve has placed: every step on fresh samples.

The Levenberg–Marquardt solve (fit.gauss_newton) compares its steps on one fixed sample set; a
few Adam steps on fresh samples afterwards average that set's draw out, as the Adam fit does
throughout. The update is written out here (the standard Adam), so that the solver's path never
imports ``torch.optim``, whose constructor imports TorchDynamo (a second of start-up).
"""

from __future__ import annotations

from collections.abc import Callable

import torch

from jsrte.fit.optimize import hypothesis_losses
from jsrte.fit.params import HypothesisBatch
from jsrte.model.decoder import Decoder
from jsrte.presets import FitSettings

BETAS = (0.9, 0.999)
EPSILON = 1e-8


def adam_step(params: list[torch.Tensor], state: list[tuple[torch.Tensor, torch.Tensor]], step: int,
              lr: float) -> None:
    """One Adam update (Kingma & Ba, as ``torch.optim.Adam`` with its defaults) of ``params`` in
    place from their ``.grad``; ``state`` holds each parameter's (first, second) moments and
    ``step`` counts from 1."""
    b1, b2 = BETAS
    with torch.no_grad():
        for p, (m, v) in zip(params, state, strict=True):
            if p.grad is None:
                continue
            m.mul_(b1).add_(p.grad, alpha=1.0 - b1)
            v.mul_(b2).addcmul_(p.grad, p.grad, value=1.0 - b2)
            denominator = (v / (1.0 - b2**step)).sqrt_().add_(EPSILON)
            p.addcdiv_(m, denominator, value=-lr / (1.0 - b1**step))


def polish(decoder: Decoder, batch: HypothesisBatch, draw: Callable[[int], object], settings: FitSettings) -> int:
    """``settings.polish_iterations`` Adam steps (learning rate ``polish_lr``) on ``batch``'s free
    parameters, each on ``settings.polish_samples`` fresh samples from ``draw(n)`` (a
    fit.gauss_newton.Problem: points, sdf, lower, clamp, penalty, scale_prior); s stays in its
    bounds. Returns the decoder evaluations."""
    params = [p for p in batch.parameters() if p.requires_grad]
    if not params:
        return 0
    state = [(torch.zeros_like(p), torch.zeros_like(p)) for p in params]
    evaluations = 0
    for step in range(1, settings.polish_iterations + 1):
        problem = draw(settings.polish_samples)
        losses = hypothesis_losses(decoder, batch, problem.points, problem.sdf, clamp=problem.clamp,
                                   latent_penalty=problem.penalty, lower_bound=problem.lower,
                                   scale_prior=problem.scale_prior)
        for p in params:
            p.grad = None
        losses.sum().backward()
        adam_step(params, state, step, settings.polish_lr)
        batch.clamp_scale(settings.scale_min, settings.scale_max)
        evaluations += len(batch) * len(problem.sdf)
    for p in params:
        p.grad = None
    return evaluations
