"""A short Adam polish of hypotheses a second-order solve has placed: every step on fresh samples.

The Levenberg–Marquardt solve (fit.gauss_newton) compares its steps on one fixed sample set; a
few Adam steps on fresh samples afterwards average that set's draw out, as the Adam fit does
throughout. Adam is fit.adam's (no ``torch.optim``: no TorchDynamo import on the solver's path).
"""

from __future__ import annotations

from collections.abc import Callable

from jsrte.fit.adam import Adam
from jsrte.fit.optimize import hypothesis_losses
from jsrte.fit.params import HypothesisBatch
from jsrte.model.decoder import Decoder
from jsrte.presets import FitSettings


def polish(decoder: Decoder, batch: HypothesisBatch, draw: Callable[[int], object], settings: FitSettings) -> int:
    """``settings.polish_iterations`` Adam steps (learning rate ``polish_lr``) on ``batch``'s free
    parameters, each on ``settings.polish_samples`` fresh samples from ``draw(n)`` (a
    fit.gauss_newton.Problem: points, sdf, lower, clamp, penalty, scale_prior); s stays in its
    bounds. Returns the decoder evaluations."""
    params = [p for p in batch.parameters() if p.requires_grad]
    if not params:
        return 0
    optimizer = Adam(params, settings.polish_lr)
    evaluations = 0
    for _ in range(settings.polish_iterations):
        problem = draw(settings.polish_samples)
        losses = hypothesis_losses(decoder, batch, problem.points, problem.sdf, clamp=problem.clamp,
                                   latent_penalty=problem.penalty, lower_bound=problem.lower,
                                   scale_prior=problem.scale_prior)
        optimizer.zero_grad()
        losses.sum().backward()
        optimizer.step()
        batch.clamp_scale(settings.scale_min, settings.scale_max)
        evaluations += len(batch) * len(problem.sdf)
    optimizer.zero_grad()
    return evaluations
