"""Adam steps on hypotheses a second-order solve has placed, every step on fresh samples.

The Levenberg–Marquardt solve (fit.gauss_newton) compares its steps on one fixed sample set; a
few Adam steps on fresh samples afterwards average that set's draw out, as the Adam fit does
throughout (:func:`polish`). A longer Adam stage at the Adam fit's learning rates lets each
hypothesis leave the minimum of the code the solve went straight to (:func:`adam_stage`), on
every fit or only when two poses end within a few percent of each other (:func:`near_tie`). Adam is fit.adam's (no
``torch.optim``: no TorchDynamo import on the solver's path).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import torch

from jsrte.fit.adam import Adam
from jsrte.fit.optimize import hypothesis_losses
from jsrte.fit.params import HypothesisBatch
from jsrte.fit.quality import other_pose
from jsrte.model.decoder import Decoder
from jsrte.presets import FitSettings


def adam_steps(decoder: Decoder, batch: HypothesisBatch, draw: Callable[[int], object], settings: FitSettings, *,
               iterations: int, samples: int, lr: Callable[[int], float]) -> int:
    """``iterations`` Adam steps on ``batch``'s free parameters, step i at learning rate ``lr(i)``,
    each on ``samples`` fresh samples from ``draw(n)`` (a fit.gauss_newton.Problem: points, sdf,
    lower, clamp, penalty, scale_prior); s stays in its bounds. Returns the decoder evaluations."""
    params = [p for p in batch.parameters() if p.requires_grad]
    if not params or iterations <= 0:
        return 0
    optimizer = Adam(params, lr(0))
    evaluations = 0
    for i in range(iterations):
        problem = draw(samples)
        losses = hypothesis_losses(decoder, batch, problem.points, problem.sdf, clamp=problem.clamp,
                                   latent_penalty=problem.penalty, lower_bound=problem.lower,
                                   scale_prior=problem.scale_prior, bfloat16=problem.bfloat16)
        optimizer.zero_grad()
        losses.sum().backward()
        optimizer.lr = lr(i)
        optimizer.step()
        batch.clamp_scale(settings.scale_min, settings.scale_max)
        evaluations += len(batch) * len(problem.sdf)
    optimizer.zero_grad()
    return evaluations


def polish(decoder: Decoder, batch: HypothesisBatch, draw: Callable[[int], object], settings: FitSettings) -> int:
    """``settings.polish_iterations`` Adam steps (learning rate ``polish_lr``) on ``batch``, each on
    ``settings.polish_samples`` fresh samples (:func:`adam_steps`). Returns the decoder evaluations."""
    return adam_steps(decoder, batch, draw, settings, iterations=settings.polish_iterations,
                      samples=settings.polish_samples, lr=lambda _: settings.polish_lr)


def near_tie(batch: HypothesisBatch, objective: torch.Tensor, margin: float) -> bool:
    """Whether the best hypothesis at another pose than the best one (by ``objective`` (H,), lower
    is better; fit.quality's :func:`other_pose`) is within ``margin`` of it, relative:
    (theirs − best) / best < margin."""
    return len(contenders(batch, objective, margin)) > 1


def contenders(batch: HypothesisBatch, objective: torch.Tensor, margin: float) -> list[int]:
    """The rows of ``batch`` still in contention: the best by ``objective`` (H,), and the best at
    another pose (fit.quality's :func:`other_pose`) where it is within ``margin`` of the best,
    relative ((theirs − best) / best < margin)."""
    values = objective.detach().cpu().numpy().astype(np.float64)
    order = np.argsort(values)
    best = batch.transform(int(order[0]))
    if not np.isfinite(values[order[0]]) or values[order[0]] <= 0:
        return [int(order[0])]
    for h in order[1:]:
        if other_pose(batch.transform(int(h)), best):
            near = (values[h] - values[order[0]]) / values[order[0]] < margin
            return [int(order[0]), int(h)] if near else [int(order[0])]
    return [int(order[0])]


def adam_stage_due(batch: HypothesisBatch, objective: torch.Tensor, settings: FitSettings) -> bool:
    """Whether ``settings.adam_stage`` asks for the Adam stage after a solve that ended with
    ``objective`` (H,) on ``batch``."""
    if settings.adam_stage == "always":
        return True
    return settings.adam_stage == "near-tie" and near_tie(batch, objective, settings.adam_stage_margin)


def adam_stage(decoder: Decoder, batch: HypothesisBatch, draw: Callable[[int], object], settings: FitSettings) -> int:
    """``settings.adam_stage_iterations`` Adam steps on every hypothesis of ``batch``, on
    ``adam_stage_samples`` fresh samples each, at learning rate ``adam_stage_lr`` for the first
    ``adam_stage_decay_after`` steps and ``adam_stage_lr / lr_decay_factor`` after (the Adam fit's
    schedule once it has pruned to two hypotheses). Returns the decoder evaluations."""
    def lr(i: int) -> float:
        decayed = i >= settings.adam_stage_decay_after
        return settings.adam_stage_lr / (settings.lr_decay_factor if decayed else 1.0)

    return adam_steps(decoder, batch, draw, settings, iterations=settings.adam_stage_iterations,
                      samples=settings.adam_stage_samples, lr=lr)
