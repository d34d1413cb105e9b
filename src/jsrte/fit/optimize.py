"""The JSRTE optimization (paper eq. 6): min over s, ψ, ρ, θ, t, z of
Σ |s·f(R⁻¹(x − t)/s, z) − φ| + λ‖z‖², for H hypotheses at once, by Adam (beyond the paper,
plus the floor-contact penalty of ``FitSettings.floor_contact``: fit.floor).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
import torch
from tqdm import tqdm

from jsrte.fit.adam import Adam
from jsrte.fit.floor import FloorContact, floor_contact
from jsrte.fit.params import HypothesisBatch, Init, LatentPrior
from jsrte.fit.query import SdfQuery
from jsrte.model.decoder import Decoder, decoder_device, uses_bfloat16
from jsrte.presets import FitSettings


@dataclass
class Optimized:
    """The optimized batch and what happened on the way."""

    batch: HypothesisBatch
    losses: np.ndarray
    """(H,) final losses of the surviving hypotheses on a fixed evaluation subset."""
    survivors: np.ndarray
    """(H,) index of each surviving hypothesis among the initial ones."""
    pruned_losses: dict[int, float]
    """Loss of each pruned hypothesis (by initial index) when it was pruned."""
    iterations: int
    evaluations: int
    seconds: float
    failed: dict[int, str] = field(default_factory=dict)
    """Hypotheses (by initial index) dropped because their objective turned NaN or infinite, and why."""
    evaluation_parts: dict[str, int] = field(default_factory=dict)
    """``evaluations`` split by the part of the solve that spent them (Levenberg–Marquardt; Adam
    with a ``finisher``: "distilled" and "model"; else empty)."""


def new_batch(decoder: Decoder, inits: list[Init], settings: FitSettings, *, fixed: frozenset[str],
              generator: torch.Generator, prior: LatentPrior | None) -> HypothesisBatch:
    """The hypotheses of ``inits`` on the decoder's device, the decoder frozen in eval mode (both
    solvers optimize the hypotheses, never the decoder)."""
    decoder.eval()
    decoder.requires_grad_(False)
    return HypothesisBatch(inits, decoder.config.latent_size, latent_init_std=settings.latent_init_std,
                           fixed=fixed, generator=generator, prior=prior).to(decoder_device(decoder))


def learning_rate(settings: FitSettings, iteration: int) -> float:
    """The paper's schedule: lr divided by ``lr_decay_factor`` every ``lr_decay_every`` iterations."""
    return settings.lr / settings.lr_decay_factor ** (iteration // settings.lr_decay_every)


def pruning_stages(settings: FitSettings) -> dict[int, int]:
    """Iteration -> how many hypotheses (lowest running loss) to keep from it on."""
    stages = {settings.prune_after: settings.prune_keep, settings.prune_again_after: settings.prune_again_keep}
    return {it: keep for it, keep in stages.items() if it is not None}


def loss_clamp(settings: FitSettings, inits: list[Init]) -> float | None:
    """The loss's clamp in scan units: ``clamp_canonical`` times the median initial scale s0
    (fixed during the fit); None without a clamp."""
    if settings.clamp_canonical is None:
        return None
    return settings.clamp_canonical * float(np.median([i.scale for i in inits]))


def latent_penalty(settings: FitSettings, *, n_surface: int) -> float:
    """λ: ``latent_penalty``, times ``latent_penalty_points`` / ``n_surface`` (the query's
    surface points) when that is set."""
    if settings.latent_penalty_points is None:
        return settings.latent_penalty
    return settings.latent_penalty * settings.latent_penalty_points / max(n_surface, 1)


def hypothesis_losses(decoder: Decoder, batch: HypothesisBatch, points: torch.Tensor, sdf: torch.Tensor,
                      *, clamp: float | None, latent_penalty: float,
                      lower_bound: torch.Tensor | None = None,
                      scale_prior: tuple[float, float | None] = (0.0, 1.0), bfloat16: bool = False) -> torch.Tensor:
    """Per-hypothesis objective (H,): mean |clamp(s f(x_c, z)) − clamp(φ)| + λ‖code‖²
    [+ w s0 ln(s/s0)² with ``scale_prior`` = (w, s0); s0 None: each hypothesis's own initial
    scale, ``batch.start_scale``].

    ``points`` (K, 3) and ``sdf`` (K,) in scan units, shared by all hypotheses; the code is z
    (the paper) or the whitened w of a :class:`LatentPrior`. Where ``lower_bound`` (K,) bool is
    set, φ only bounds the true SDF from below: the term is max(0, clamp(φ) − clamp(s f)).
    ``bfloat16``: the decoder's matrix products in bfloat16 (``FitSettings.decoder_dtype``).
    """
    pred = batch.sdf(decoder, points, bfloat16=bfloat16)
    target = sdf.to(torch.float32)[None, :]
    if clamp is not None:
        pred, target = pred.clamp(-clamp, clamp), target.clamp(-clamp, clamp)
    error = (pred - target).abs()
    if lower_bound is not None:
        error = torch.where(lower_bound[None, :], (target - pred).clamp(min=0.0), error)
    data_term = error.mean(dim=1)
    loss = data_term + latent_penalty * batch.code.to(torch.float32).pow(2).sum(dim=1)
    weight, start = scale_prior
    if weight:
        start = batch.start_scale.to(torch.float32) if start is None else start
        loss = loss + weight * start * torch.log(batch.scale.to(torch.float32) / start).pow(2)
    return loss


def optimize(decoder: Decoder, query: SdfQuery, inits: list[Init], settings: FitSettings, *,
             fixed: frozenset[str] = frozenset(), generator: torch.Generator,
             prior: LatentPrior | None = None, progress: bool = False,
             finisher: Decoder | None = None) -> Optimized:
    """Run Adam on all hypotheses as one batch; prune to ``prune_keep`` after ``prune_after``
    (and to ``prune_again_keep`` after ``prune_again_after``).

    ``finisher`` (the model, where ``decoder`` is its distilled decoder): it takes the hypotheses
    over from :func:`handover_iteration` on, their Adam moments kept, and computes the final
    losses; ``evaluation_parts`` then splits the evaluations between the two.

    With a ``prior`` the whitened code is optimized and its penalty is λ s0 ‖w‖² (s0 the
    median initial scale: the data term is in scan units, so the balance does not depend on
    the object's size); without, λ‖z‖² as the paper.

    Runs on the decoder's device (``generator`` is a CPU generator: sample indices are drawn on
    the CPU, so a seed gives the same draws on every device).
    """
    start = time.perf_counter()
    batch = new_batch(decoder, inits, settings, fixed=fixed, generator=generator, prior=prior)
    device = decoder_device(decoder)
    clamp = loss_clamp(settings, inits)
    starts = [i.scale for i in inits]
    s0 = float(np.median(starts))
    penalty = latent_penalty(settings, n_surface=len(query.surface)) * (s0 if prior is not None else 1.0)
    # starting at two scales ("both"), each hypothesis is held near its own start scale
    own_start = settings.init_scale == "both" and len(set(starts)) > 1
    scale_prior = (settings.scale_prior, None if own_start else s0)
    points = torch.as_tensor(query.points, dtype=torch.float64, device=device)
    sdf = torch.as_tensor(query.sdf, dtype=torch.float64, device=device)
    lower = None if query.lower_bound is None else torch.as_tensor(query.lower_bound, device=device)
    reach = clamp if clamp is not None else 0.1 * s0  # the floor's distances in units of the clamp
    contact = floor_contact(query, settings.floor_contact, settings.floor_contact_points, device=device,
                            depth=0.5 * reach, tolerance=settings.floor_contact_tolerance * reach)
    survivors = np.arange(len(inits))
    pruned: dict[int, float] = {}
    bfloat16 = uses_bfloat16(settings.decoder_dtype, device)
    optimizer = _adam(batch, settings.lr)
    sampler = SampleDrawer(query.sdf, near_share=settings.near_sample_share, clamp=clamp, generator=generator)
    recent = torch.zeros(len(inits), dtype=torch.float64, device=device)  # running loss, kept on the device
    evaluations = 0
    parts = {"distilled": 0, "model": 0}
    stages = pruning_stages(settings)
    handover = handover_iteration(settings) if finisher is not None else None
    active = decoder
    for it in tqdm(range(settings.iterations), desc="fitting", disable=not progress):
        if it == handover:
            active = finisher
        if it in stages and len(batch) > stages[it]:
            ranking = recent
            if finisher is not None:  # the model judges what its distilled decoder moved
                ranking = _fixed_sample_losses(finisher, batch, points, sdf, lower, settings.judge_samples, clamp,
                                               penalty, scale_prior, generator, contact)
                judged = len(batch) * min(settings.judge_samples, len(sdf))
                evaluations, parts["model"] = evaluations + judged, parts["model"] + judged
            keep = torch.argsort(ranking.cpu())[: stages[it]]
            for i in range(len(batch)):
                if i not in keep.tolist():
                    pruned[int(survivors[i])] = float(recent[i])
            optimizer = _prune(batch, optimizer, keep)
            survivors = survivors[keep.numpy()]
            recent = recent[keep.to(device)]
        optimizer.lr = learning_rate(settings, it)
        idx = sampler.draw(_sample_pool(query, settings, it), settings.samples_per_iteration,
                           enriched=it >= settings.near_sample_from).to(device)
        losses = hypothesis_losses(active, batch, points[idx], sdf[idx], clamp=clamp, latent_penalty=penalty,
                                   lower_bound=None if lower is None else lower[idx], scale_prior=scale_prior,
                                   bfloat16=bfloat16)
        if contact is not None:
            losses = losses + contact.penalty(active, batch, it, bfloat16=bfloat16)
        optimizer.zero_grad()
        losses.sum().backward()
        optimizer.step()
        batch.clamp_scale(settings.scale_min, settings.scale_max)
        current = losses.detach().double()
        recent = 0.8 * recent + 0.2 * current if it else current
        evaluations += len(batch) * len(idx)
        parts["model" if active is finisher else "distilled"] += len(batch) * len(idx)
    final = _fixed_sample_losses(finisher or decoder, batch, points, sdf, lower, settings.eval_samples, clamp,
                                 penalty, scale_prior, generator, contact).cpu().numpy()
    evaluations += len(batch) * min(settings.eval_samples, len(sdf))
    parts["model"] += len(batch) * min(settings.eval_samples, len(sdf))
    evaluations += 0 if contact is None else contact.evaluations
    return Optimized(batch, final, survivors, pruned, settings.iterations, evaluations,
                     time.perf_counter() - start, evaluation_parts=parts if finisher is not None else {})


def handover_iteration(settings: FitSettings) -> int:
    """The iteration from which the model takes Adam's hypotheses over from its distilled decoder
    (``FitSettings.distilled_search``): ``distilled_iterations``, else the last pruning's (the
    survivors settled by the model alone), else the first."""
    if settings.distilled_iterations is not None:
        return settings.distilled_iterations
    stages = pruning_stages(settings)
    return max(stages) if stages else 0


class SampleDrawer:
    """Draws each iteration's sample indices: uniformly over the pool (the paper), or with at
    least ``near_share`` of them among the samples whose target is under the clamp.

    A scan's query is mostly freespace (25 000 samples beyond the clamp, which only say
    "outside"); the few thousand samples at ±1 cm along the normals are what place the surface.
    ``pool``: draw from the first this many samples (the refine-only tail waits for pruning).
    """

    def __init__(self, sdf: np.ndarray, *, near_share: float | None, clamp: float | None,
                 generator: torch.Generator) -> None:
        self.near = None if near_share is None or clamp is None else np.abs(np.asarray(sdf)) < clamp
        self.near_share = near_share
        self.generator = generator
        self._split: dict[int, tuple[torch.Tensor, torch.Tensor]] = {}

    def draw(self, pool: int, n: int, *, enriched: bool = True) -> torch.Tensor:
        """(min(n, pool),) int64 indices into the query's samples (CPU); uniform unless ``enriched``."""
        n = min(n, pool)
        if self.near is None or not enriched:
            return torch.randint(pool, (n,), generator=self.generator)
        if pool not in self._split:
            near = self.near[:pool]
            self._split[pool] = (torch.from_numpy(np.flatnonzero(near)), torch.from_numpy(np.flatnonzero(~near)))
        near, far = self._split[pool]
        if not len(near) or not len(far):
            return torch.randint(pool, (n,), generator=self.generator)
        n_near = round(n * max(self.near_share, len(near) / pool))
        pick = [group[torch.randint(len(group), (k,), generator=self.generator)]
                for group, k in ((near, n_near), (far, n - n_near))]
        return torch.cat(pick)


def _sample_pool(query: SdfQuery, settings: FitSettings, iteration: int) -> int:
    """How many of the query's samples (from the start) iteration ``iteration`` draws from."""
    pruning_ahead = settings.prune_after is not None and iteration < settings.prune_after
    if pruning_ahead and not settings.line_of_sight_before_pruning and query.n_refine_only < len(query.sdf):
        return len(query.sdf) - query.n_refine_only
    return len(query.sdf)


def _prune(batch: HypothesisBatch, optimizer: Adam, keep: torch.Tensor) -> Adam:
    """Keep hypotheses ``keep`` of ``batch``; returns an Adam over the kept parameters that goes
    on with their moment estimates (a fresh Adam's first steps move every parameter by ~lr)."""
    batch.keep(keep)
    return optimizer.kept([p for p in batch.parameters() if p.requires_grad], keep)


def _adam(batch: HypothesisBatch, lr: float) -> Adam:
    return Adam([p for p in batch.parameters() if p.requires_grad], lr)


def _fixed_sample_losses(decoder: Decoder, batch: HypothesisBatch, points: torch.Tensor, sdf: torch.Tensor,
                         lower: torch.Tensor | None, n: int, clamp: float | None, penalty: float,
                         scale_prior: tuple[float, float], generator: torch.Generator,
                         contact: FloorContact | None = None) -> torch.Tensor:
    """(H,) float64 objectives of every hypothesis by ``decoder`` (forward passes only, float32) on
    ``n`` samples of the query drawn once: the same samples for all, so the losses compare; with
    ``contact``, its penalty over the whole floor grid added."""
    n = min(n, len(sdf))
    idx = torch.randperm(len(sdf), generator=generator)[:n].to(sdf.device)
    with torch.no_grad():
        losses = hypothesis_losses(decoder, batch, points[idx], sdf[idx], clamp=clamp, latent_penalty=penalty,
                                   lower_bound=None if lower is None else lower[idx], scale_prior=scale_prior)
    if contact is not None:
        losses = losses + contact.final(decoder, batch)
    return losses.double()
