"""The JSRTE objective (paper eq. 6, with the ``fast`` terms) minimized by a batched
Levenberg–Marquardt (damped Gauss–Newton) solver, as DSP-SLAM fits a DeepSDF code and a Sim(3).

Same parameters as the Adam fit (fit.optimize): per hypothesis a vector
p = (s, ψ, ρ, θ, t (3), code (d)), the code raw z or whitened w (z = μ + L w); any of them held.
Same terms: the clamped data term (two-sided, or one-sided where the sample only bounds the SDF
from below), line-of-sight samples (ordinary samples of the query), the latent penalty and the
scale prior (as extra residual rows).

The L1 data term is minimized by iteratively reweighted least squares: a sample with residual
r gets the weight 1 / (2 max(|r|, δ)), the quadratic that touches |r| from above at the current
r (Huber below δ). The step solves, for all hypotheses at once ((H, P, P) batch),

    (JᵀWJ + Λ + μ diag(JᵀWJ + Λ)) Δp = −(JᵀWr + λ-and-prior gradient)

where Λ holds the penalty and prior rows, and μ is each hypothesis's own damping: a step that
does not lower that hypothesis's (Huber-smoothed) objective is rejected and μ grows; an accepted
one shrinks it. The Jacobian costs one backward pass: every sample's SDF depends only on its
own input, so the gradient of the sum of outputs with respect to a per-sample input tensor
(x_c, z) is every sample's own ∂f/∂(x_c, z); it is chained analytically to (s, t, code) and
through ∂R/∂(ψ, ρ, θ) to the angles.

Before the solve, many yaw starts can be screened by forward passes only
(``FitSettings.yaw_screen_keep``): each start's objective on a few hundred samples at its
initial pose and code; the best few go on.

At the first pruning, by forward passes too: every survivor can move to the translation of
lowest objective on a grid across its up axis (``translation_search``; the damped steps do not
cross a start a quarter metre off, the code bends to reach the points instead), and restart
from the training codes that fit best there (``code_starts``); the survivors can then go on
on a fresh, larger sample set (``samples_after_pruning``).

After the solve, every survivor can take a longer Adam stage (``adam_stage``,
fit.polish.adam_stage) before the comparison, always or when two poses end within a few
percent of each other: the solve goes straight to the nearest minimum of the code, and which
of two near-equal poses wins then depends on which code got stuck.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
import torch
from tqdm import tqdm

from jsrte.errors import JsrteError
from jsrte.fit.optimize import (
    Optimized,
    SampleDrawer,
    SdfQuery,
    _fixed_sample_losses,
    latent_penalty,
    loss_clamp,
    new_batch,
    pruning_stages,
)
from jsrte.fit.params import HypothesisBatch, Init, LatentPrior
from jsrte.fit.polish import adam_stage, adam_stage_due, contenders, polish
from jsrte.geometry.sim3 import rotation_from_paper
from jsrte.model.decoder import Decoder, decoder_device, uses_bfloat16
from jsrte.presets import FitSettings

POSE_COLUMNS = {"scale": [0], "psi": [1], "rho": [2], "theta": [3], "translation": [4, 5, 6]}
"""Columns of each pose parameter in the vector p (H, 7 + d); the code takes 7 onwards."""
N_POSE = 7
MAX_DAMPING = 1e10
"""A hypothesis whose damping passes this has stopped moving: converged."""


@dataclass(frozen=True)
class Problem:
    """What the objective of every hypothesis shares (scan units).

    Attributes
    ----------
    points : (K, 3) float64 sample points; sdf : (K,) float64 targets
    lower : (K,) bool or None: samples that only bound the SDF from below
    clamp : the loss's clamp (scan units) or None
    huber : δ (scan units): residuals under it are weighted as a quadratic
    penalty : λ of ‖code‖²
    scale_prior : (w, s0) of w s0 ln(s/s0)²
    """

    points: torch.Tensor
    sdf: torch.Tensor
    lower: torch.Tensor | None
    clamp: float | None
    huber: float
    penalty: float
    scale_prior: tuple[float, float]
    bfloat16: bool = False
    """The decoder's matrix products in bfloat16 (``FitSettings.decoder_dtype``)."""


@dataclass
class Linearization:
    """The objective (H,) at p, and for the free columns its half Gauss–Newton Hessian
    ``hessian`` (H, F, F) and half gradient ``gradient`` (H, F); None without the Jacobian."""

    objective: torch.Tensor
    hessian: torch.Tensor | None = None
    gradient: torch.Tensor | None = None


def pack(batch: HypothesisBatch) -> torch.Tensor:
    """p (H, 7 + d) float64: s, ψ, ρ, θ, t, code of every hypothesis."""
    with torch.no_grad():
        return torch.cat([batch.scale[:, None], batch.psi[:, None], batch.rho[:, None], batch.theta[:, None],
                          batch.translation, batch.code], dim=1).to(torch.float64).clone()


def unpack_into(batch: HypothesisBatch, p: torch.Tensor) -> None:
    """Write p (H, 7 + d) into ``batch``'s parameters (same H)."""
    with torch.no_grad():
        batch.scale.copy_(p[:, 0])
        batch.psi.copy_(p[:, 1])
        batch.rho.copy_(p[:, 2])
        batch.theta.copy_(p[:, 3])
        batch.translation.copy_(p[:, 4:7])
        batch.code.copy_(p[:, N_POSE:])


def free_columns(fixed: frozenset[str], latent_size: int) -> torch.Tensor:
    """Indices (F,) of the optimized columns of p."""
    cols = [c for name, idx in POSE_COLUMNS.items() if name not in fixed for c in idx]
    if "latent" not in fixed:
        cols += list(range(N_POSE, N_POSE + latent_size))
    if not cols:
        raise ValueError("every parameter is fixed: nothing to optimize")
    return torch.tensor(cols)


def _rotations(angles: torch.Tensor, base: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """R (H, 3, 3) = R(ψ, ρ, θ) @ base and ∂R/∂(ψ, ρ, θ) (H, 3, 3, 3) (last index: the angle).

    The derivative comes from nine reverse-mode passes over the tiny rotation graph (one per
    entry of R, every hypothesis at once): ``torch.func`` would import TorchDynamo, a second
    of start-up, for this alone."""
    with torch.enable_grad():
        a = angles.detach().clone().requires_grad_(True)
        r = rotation_from_paper(a[:, 0], a[:, 1], a[:, 2]) @ base
        rows = [torch.autograd.grad(r[:, i, j].sum(), a, retain_graph=True)[0] for i in range(3) for j in range(3)]
    return r.detach(), torch.stack(rows, dim=1).reshape(len(angles), 3, 3, 3)


def _latent(p: torch.Tensor, prior: tuple[torch.Tensor, torch.Tensor] | None) -> torch.Tensor:
    code = p[:, N_POSE:]
    return code if prior is None else prior[0] + code @ prior[1].T


def _robust(r: torch.Tensor, delta: float) -> tuple[torch.Tensor, torch.Tensor]:
    """Huber-smoothed |r| (same shape) and the IRLS weight 1 / (2 max(|r|, δ))."""
    a = r.abs()
    rho = torch.where(a >= delta, a, r * r / (2.0 * delta) + delta / 2.0)
    return rho, 0.5 / a.clamp(min=delta)


def linearize(decoder: Decoder, p: torch.Tensor, base: torch.Tensor, problem: Problem,
              prior: tuple[torch.Tensor, torch.Tensor] | None, free: torch.Tensor | None) -> Linearization:
    """The objective of every hypothesis at p (H, 7 + d) on ``problem``'s samples, in one decoder
    pass; with ``free`` (F,) columns also its Gauss–Newton system (one backward pass more)."""
    h, k = p.shape[0], problem.points.shape[0]
    s = p[:, 0]
    rot, d_rot = _rotations(p[:, 1:4], base)
    y = problem.points[None, :, :] - p[:, None, 4:7]  # (H, K, 3)
    dtype = next((t.dtype for t in decoder.parameters()), torch.float32)
    canonical = (y @ rot / s[:, None, None]).to(dtype)
    z = _latent(p, prior).to(dtype)
    need = free is not None
    x_in = canonical.reshape(h * k, 3).requires_grad_(need)
    z_in = z[:, None, :].expand(h, k, -1).reshape(h * k, -1)
    z_in = z_in.contiguous().requires_grad_(need) if need else z_in
    with torch.set_grad_enabled(need), torch.autocast(x_in.device.type, dtype=torch.bfloat16,
                                                      enabled=problem.bfloat16):
        f = decoder(x_in, z_in)
        if need:
            gx, gz = torch.autograd.grad(f.sum(), [x_in, z_in], allow_unused=True)
            gx = torch.zeros_like(x_in) if gx is None else gx  # a model that ignores x or z
            gz = torch.zeros_like(z_in) if gz is None else gz
    f = f.detach().to(torch.float64).reshape(h, k)
    pred = s[:, None] * f
    target = problem.sdf[None, :]
    active = torch.ones_like(pred, dtype=torch.bool)
    if problem.clamp is not None:
        active = pred.abs() < problem.clamp
        pred, target = pred.clamp(-problem.clamp, problem.clamp), target.clamp(-problem.clamp, problem.clamp)
    r = pred - target
    if problem.lower is not None:  # one-sided: only a prediction under the bound counts
        short = r < 0
        r = torch.where(problem.lower[None, :], torch.where(short, r, torch.zeros_like(r)), r)
        active = active & (~problem.lower[None, :] | short)
    rho, weight = _robust(r, problem.huber)
    code = p[:, N_POSE:]
    objective = rho.mean(dim=1) + problem.penalty * code.pow(2).sum(dim=1)
    w_prior, s0 = problem.scale_prior
    if w_prior:
        objective = objective + w_prior * s0 * torch.log(s / s0).pow(2)
    if not need:
        return Linearization(objective)
    gx = gx.to(torch.float64).reshape(h, k, 3)
    gz = gz.to(torch.float64).reshape(h, k, -1)
    cols = [
        f - (gx * canonical.to(torch.float64)).sum(-1),  # ∂(s f)/∂s: x_c = Rᵀ(x − t)/s
        *torch.einsum("hki,hjia,hkj->ahk", gx, d_rot, y),  # ∂/∂(ψ, ρ, θ) = g · ∂Rᵀ/∂a (x − t)
        *(-(gx @ rot.transpose(1, 2))).permute(2, 0, 1),  # ∂/∂t = −R g
    ]
    d_code = s[:, None, None] * (gz if prior is None else gz @ prior[1])
    jac = torch.cat([torch.stack(cols, dim=-1), d_code], dim=-1)[:, :, free]  # (H, K, F)
    jac = jac * active[..., None]
    wk = weight / k
    hessian = torch.einsum("hkf,hk,hkg->hfg", jac, wk, jac)
    gradient = torch.einsum("hkf,hk->hf", jac, wk * r)
    extra_h = torch.zeros(h, p.shape[1], dtype=torch.float64, device=p.device)
    extra_g = torch.zeros_like(extra_h)
    extra_h[:, N_POSE:] = problem.penalty
    extra_g[:, N_POSE:] = problem.penalty * code
    if w_prior:
        extra_h[:, 0] = w_prior * s0 / s**2
        extra_g[:, 0] = w_prior * s0 * torch.log(s / s0) / s
    hessian = hessian + torch.diag_embed(extra_h[:, free])
    return Linearization(objective, hessian, gradient + extra_g[:, free])


def damped_step(lin: Linearization, damping: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Δp (H, F) solving (A + μ diag(A)) Δp = −g for each hypothesis, and (H,) bool: solved."""
    a = lin.hessian
    diag = torch.diagonal(a, dim1=1, dim2=2)
    floor = 1e-9 * diag.abs().amax(dim=1, keepdim=True).clamp(min=1e-12)
    damped = a + torch.diag_embed(damping[:, None] * diag.clamp(min=0) + floor)
    step, info = torch.linalg.solve_ex(damped, -lin.gradient[..., None])
    step = step[..., 0]
    ok = (info == 0) & torch.isfinite(step).all(dim=1)
    return torch.where(ok[:, None], step, torch.zeros_like(step)), ok


class ProblemDrawer:
    """Draws the fixed sample sets (:class:`Problem`) of a query's objective, the terms set as the
    Adam fit sets them (fit.optimize): clamp and scale prior from the median initial scale s0,
    the latent penalty times s0 for a whitened code."""

    def __init__(self, query: SdfQuery, inits: list[Init], settings: FitSettings, *, generator: torch.Generator,
                 whitened: bool, device: torch.device) -> None:
        self.clamp = loss_clamp(settings, inits)
        self.s0 = float(np.median([i.scale for i in inits]))
        self.penalty = latent_penalty(settings, n_surface=len(query.surface)) * (self.s0 if whitened else 1.0)
        self.points = torch.as_tensor(query.points, dtype=torch.float64, device=device)
        self.sdf = torch.as_tensor(query.sdf, dtype=torch.float64, device=device)
        self.lower = None if query.lower_bound is None else torch.as_tensor(query.lower_bound, device=device)
        self.sampler = SampleDrawer(query.sdf, near_share=settings.near_sample_share, clamp=self.clamp,
                                    generator=generator)
        self.settings = settings
        self.device = device
        self.bfloat16 = uses_bfloat16(settings.decoder_dtype, device)

    def __call__(self, n: int) -> Problem:
        """``n`` samples drawn from all of the query's (with the near share, if any)."""
        idx = self.sampler.draw(len(self.sdf), n).to(self.device)
        return Problem(self.points[idx], self.sdf[idx], None if self.lower is None else self.lower[idx],
                       self.clamp, self.settings.huber_canonical * self.s0, self.penalty,
                       (self.settings.scale_prior, self.s0), self.bfloat16)


def screen_yaws(decoder: Decoder, p: torch.Tensor, base: torch.Tensor, problem: Problem,
                prior: tuple[torch.Tensor, torch.Tensor] | None, keep: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Forward passes only: the objective (H,) of every start on ``problem``'s samples, and the
    indices (keep,) of the lowest, best first."""
    with torch.no_grad():
        scores = linearize(decoder, p, base, problem, prior, None).objective
    scores = torch.where(torch.isfinite(scores), scores, torch.full_like(scores, float("inf")))
    return scores, torch.argsort(scores)[:keep]


def solve(decoder: Decoder, query: SdfQuery, inits: list[Init], settings: FitSettings, *,
          fixed: frozenset[str] = frozenset(), generator: torch.Generator,
          prior: LatentPrior | None = None, progress: bool = False,
          trace: list[dict[int, float]] | None = None, finisher: Decoder | None = None) -> Optimized:
    """Minimize every hypothesis's objective by Levenberg–Marquardt, as one batch.

    ``settings.iterations`` bounds the iterations (each one decoder pass with its backward over
    the hypotheses still moving); ``settings.samples_per_iteration`` samples are drawn once and
    kept (a fixed objective, so steps can be compared). ``prune_after``/``prune_again_after``
    count these iterations. With ``yaw_screen_keep`` set, the starts are first screened by
    forward passes on ``yaw_screen_samples`` samples and only the best that many solved.
    A hypothesis whose objective or system turns NaN/inf is dropped (``Optimized.failed``);
    if all are, a JsrteError. ``trace``, if given, receives each iteration's objective of every
    hypothesis still in the batch (by initial index), for studying pruning schedules.
    ``finisher`` (default ``decoder``) takes the refinement after the Adam stage, the polish and
    the final losses: the model itself where ``decoder`` is its distilled decoder
    (``FitSettings.distilled_search``).
    """
    start = time.perf_counter()
    batch = new_batch(decoder, inits, settings, fixed=fixed, generator=generator, prior=prior)
    device = decoder_device(decoder)
    whitening = None if prior is None else (batch.prior_mean, batch.prior_factor)
    problem_of = ProblemDrawer(query, inits, settings, generator=generator, whitened=prior is not None,
                               device=device)
    clamp, penalty, s0 = problem_of.clamp, problem_of.penalty, problem_of.s0
    points, sdf, lower = problem_of.points, problem_of.sdf, problem_of.lower

    p = pack(batch)
    survivors = np.arange(len(inits))
    pruned: dict[int, float] = {}
    failed: dict[int, str] = {}
    parts: dict[str, int] = {}

    def count(part: str, n: int) -> None:
        parts[part] = parts.get(part, 0) + n

    if settings.yaw_screen_keep is not None and len(inits) > settings.yaw_screen_keep:
        screen = problem_of(settings.yaw_screen_samples)
        scores, keep = screen_yaws(decoder, p, batch.base_rotation, screen, whitening, settings.yaw_screen_keep)
        count("yaw screening", len(p) * len(screen.sdf))
        kept = set(keep.tolist())
        pruned.update({int(survivors[i]): float(scores[i]) for i in range(len(p)) if i not in kept})
        batch.keep(keep.cpu())
        p, survivors = p[keep], survivors[keep.cpu().numpy()]
    if settings.retrieval_start and prior is not None and prior.codes is not None and "latent" not in fixed:
        p, n = retrieval_start(decoder, p, batch.base_rotation, problem_of(settings.retrieval_samples), batch,
                               prior, settings.retrieval_start)
        count("retrieval", n)
    problem = problem_of(settings.samples_per_iteration)
    free = free_columns(fixed, decoder.config.latent_size).to(device)
    base = batch.base_rotation
    lin = linearize(decoder, p, base, problem, whitening, free)
    count("starts", len(p) * len(problem.sdf))
    damping = torch.full((len(p),), settings.damping, dtype=torch.float64, device=device)
    moving = torch.ones(len(p), dtype=torch.bool, device=device)
    stages = pruning_stages(settings)
    iterations = 0
    searched = False  # the translation search and the code restarts, once
    restarted_at: int | None = None  # the iteration of the code restarts
    for it in tqdm(range(settings.iterations), desc="fitting", disable=not progress):
        p, base, lin, damping, moving, survivors = _drop_failed(p, base, lin, damping, moving, survivors,
                                                                failed, batch)
        if it in stages and len(p) > stages[it]:
            keep = torch.argsort(lin.objective)[: stages[it]]
            pruned.update({int(survivors[i]): float(lin.objective[i]) for i in range(len(p))
                           if i not in set(keep.tolist())})
            p, base, lin, damping, moving, survivors = _subset(keep, p, base, lin, damping, moving, survivors, batch)
        after = settings.code_starts_prune_after
        if after is not None and restarted_at is not None and it == restarted_at + after \
                and len(set(survivors.tolist())) < len(survivors):  # only the best copy of each start goes on
            keep = torch.as_tensor(_best_copy_rows(survivors, lin.objective), device=p.device)
            p, base, lin, damping, moving, survivors = _subset(keep, p, base, lin, damping, moving, survivors, batch)
        if not searched and (it == min(stages, default=0) or not bool(moving.any())):
            searched = True
            if settings.samples_after_pruning is not None:
                problem = problem_of(settings.samples_after_pruning)
                lin = None
            if settings.translation_search and "translation" not in fixed:
                p, n = _translation_search(decoder, p, base, problem_of, whitening, settings)
                count("translation search", n)
                lin = None
            if settings.code_starts and prior is not None and prior.codes is not None and "latent" not in fixed:
                p, base, survivors, n = _code_restarts(decoder, p, base, survivors, batch, problem_of, prior,
                                                       settings)
                count("code scoring", n)
                restarted_at = it
                lin = None
        if lin is None:  # new hypotheses: linearize afresh, every one moving
            lin = linearize(decoder, p, base, problem, whitening, free)
            count("survivors" if searched else "starts", len(p) * len(problem.sdf))
            damping = torch.full((len(p),), settings.damping, dtype=torch.float64, device=device)
            moving = torch.ones(len(p), dtype=torch.bool, device=device)
        if trace is not None:
            trace.append({int(i): float(v) for i, v in zip(survivors, lin.objective.tolist(), strict=True)})
        if not bool(moving.any()):
            break
        iterations = it + 1
        count("survivors" if searched else "starts",
              lm_iteration(decoder, p, base, lin, damping, moving, problem, whitening, free, settings))
    p, base, lin, damping, moving, survivors = _drop_failed(p, base, lin, damping, moving, survivors, failed,
                                                            batch)
    unpack_into(batch, p)
    objective = lin.objective
    if len(set(survivors.tolist())) < len(survivors):
        survivors, objective = _best_copies(batch, survivors, objective)
    finisher = decoder if finisher is None else finisher
    if adam_stage_due(batch, objective, settings):
        if settings.adam_stage_contenders_only:
            survivors, objective = _contenders_only(batch, survivors, objective, pruned, settings.adam_stage_margin)
        count("adam stage", adam_stage(decoder, batch, problem_of, settings))
        if settings.refine_iterations:
            count("refine", _refine(finisher, batch, problem, whitening, free, settings))
    if settings.polish_iterations:
        count("polish", polish(finisher, batch, problem_of, settings))
    final = _fixed_sample_losses(finisher, batch, points, sdf, lower, settings.eval_samples, clamp, penalty,
                                 (settings.scale_prior, s0), generator).cpu().numpy()
    count("final losses", len(batch) * min(settings.eval_samples, len(sdf)))
    return Optimized(batch, final, survivors, pruned, iterations, sum(parts.values()), time.perf_counter() - start,
                     failed=failed, evaluation_parts=parts)


def lm_iteration(decoder: Decoder, p: torch.Tensor, base: torch.Tensor, lin: Linearization, damping: torch.Tensor,
                 moving: torch.Tensor, problem: Problem, whitening: tuple[torch.Tensor, torch.Tensor] | None,
                 free: torch.Tensor, settings: FitSettings) -> int:
    """One damped step of every ``moving`` hypothesis, in place: p (H, 7 + d), ``lin`` and
    ``damping`` (H,) take an accepted step's values; a rejected step raises the damping; a
    hypothesis that gains under ``settings.tolerance`` or whose damping passes MAX_DAMPING stops
    (``moving`` False). Returns the decoder evaluations."""
    rows = torch.nonzero(moving)[:, 0]
    step, solved = damped_step(Linearization(lin.objective[rows], lin.hessian[rows], lin.gradient[rows]),
                               damping[rows])
    trial = p[rows].clone()
    trial[:, free] += step
    trial[:, 0] = trial[:, 0].clamp(settings.scale_min, settings.scale_max)
    new = linearize(decoder, trial, base[rows], problem, whitening, free)
    finite = torch.isfinite(new.objective) & torch.isfinite(new.hessian).flatten(1).all(1) & \
        torch.isfinite(new.gradient).all(1)
    better = solved & finite & (new.objective < lin.objective[rows])
    gain = (lin.objective[rows] - new.objective) / lin.objective[rows].abs().clamp(min=1e-12)
    accepted = rows[better]
    p[accepted] = trial[better]
    lin.objective[accepted] = new.objective[better]
    lin.hessian[accepted] = new.hessian[better]
    lin.gradient[accepted] = new.gradient[better]
    damping[rows] = torch.where(better, damping[rows] / 3.0, damping[rows] * 4.0)
    done = (better & (gain < settings.tolerance)) | (damping[rows] > MAX_DAMPING)
    moving[rows] = moving[rows] & ~done
    return len(rows) * len(problem.sdf)


def _refine(decoder: Decoder, batch: HypothesisBatch, problem: Problem,
            whitening: tuple[torch.Tensor, torch.Tensor] | None, free: torch.Tensor, settings: FitSettings) -> int:
    """At most ``settings.refine_iterations`` Levenberg–Marquardt iterations on ``batch`` (in
    place) on ``problem``'s samples, after the Adam stage; a hypothesis whose system turns
    non-finite keeps the Adam stage's parameters. Returns the decoder evaluations."""
    p, base = pack(batch), batch.base_rotation
    lin = linearize(decoder, p, base, problem, whitening, free)
    evaluations = len(p) * len(problem.sdf)
    finite = torch.isfinite(lin.objective) & torch.isfinite(lin.hessian).flatten(1).all(1) & \
        torch.isfinite(lin.gradient).all(1)
    damping = torch.full((len(p),), settings.damping, dtype=torch.float64, device=p.device)
    moving = finite.clone()
    for _ in range(settings.refine_iterations):
        if not bool(moving.any()):
            break
        evaluations += lm_iteration(decoder, p, base, lin, damping, moving, problem, whitening, free, settings)
    unpack_into(batch, p)
    return evaluations


def _contenders_only(batch: HypothesisBatch, survivors: np.ndarray, objective: torch.Tensor, pruned: dict[int, float],
                     margin: float) -> tuple[np.ndarray, torch.Tensor]:
    """Keep only the hypotheses of ``batch`` still in contention (fit.polish's :func:`contenders`):
    the best, and the best at another pose within ``margin`` of it; the others go to ``pruned``
    with their objective. Returns the kept start indices and objectives."""
    keep = contenders(batch, objective, margin)
    pruned.update({int(survivors[h]): float(objective[h]) for h in range(len(survivors)) if h not in keep})
    batch.keep(torch.as_tensor(keep))
    return survivors[keep], objective[torch.as_tensor(keep, device=objective.device)]


def _drop_failed(p: torch.Tensor, base: torch.Tensor, lin: Linearization, damping: torch.Tensor,
                 moving: torch.Tensor, survivors: np.ndarray, failed: dict[int, str],
                 batch: HypothesisBatch) -> tuple:
    """Drop the hypotheses whose parameters or system are not finite; record them in ``failed``."""
    ok = torch.isfinite(p).all(1) & torch.isfinite(lin.objective) & torch.isfinite(lin.hessian).flatten(1).all(1) \
        & torch.isfinite(lin.gradient).all(1)
    if bool(ok.all()):
        return p, base, lin, damping, moving, survivors
    for i in torch.nonzero(~ok)[:, 0].tolist():
        failed[int(survivors[i])] = "the objective or its derivatives became NaN or infinite"
    if not bool(ok.any()):
        raise JsrteError(f"the fit diverged: every hypothesis ({len(failed)}) became NaN or infinite")
    keep = torch.nonzero(ok)[:, 0]
    batch.keep(keep.cpu())
    lin = Linearization(lin.objective[keep], lin.hessian[keep], lin.gradient[keep])
    return p[keep], base[keep], lin, damping[keep], moving[keep], survivors[keep.cpu().numpy()]


def translation_offsets(settings: FitSettings) -> torch.Tensor:
    """(N, 2) offsets (units of s0) of the translation search: a square grid of step
    ``translation_search_step`` reaching ``translation_search`` each way, (0, 0) first."""
    if settings.translation_search_step <= 0:
        raise ValueError(f"translation_search_step must be positive, got {settings.translation_search_step}")
    n = int(round(settings.translation_search / settings.translation_search_step))
    ticks = torch.arange(-n, n + 1, dtype=torch.float64) * settings.translation_search_step
    grid = torch.cartesian_prod(ticks, ticks)
    return grid[torch.argsort(grid.norm(dim=1), stable=True)]


def _translation_search(decoder: Decoder, p: torch.Tensor, base: torch.Tensor, problem_of: ProblemDrawer,
                        whitening: tuple[torch.Tensor, torch.Tensor] | None,
                        settings: FitSettings) -> tuple[torch.Tensor, int]:
    """Move every hypothesis of p (H, 7 + d) to the translation of lowest objective among
    :func:`translation_offsets` (times s0) across its own up axis (the second column of its
    rotation), its code and the rest of its pose held; forward passes on
    ``translation_search_samples`` samples (unset: ``yaw_screen_samples``). Returns p and the
    evaluations spent."""
    screen = problem_of(settings.yaw_screen_samples if settings.translation_search_samples is None
                        else settings.translation_search_samples)
    offsets = translation_offsets(settings).to(p.device) * problem_of.s0
    rot, _ = _rotations(p[:, 1:4], base)
    up = rot[:, :, 1]
    helper = torch.where(up[:, :1].abs() < 0.9, p.new_tensor([1.0, 0.0, 0.0]), p.new_tensor([0.0, 0.0, 1.0]))
    side = torch.linalg.cross(up, helper, dim=1)
    side = side / side.norm(dim=1, keepdim=True)
    other = torch.linalg.cross(up, side, dim=1)
    out = p.clone()
    for h in range(len(p)):
        trial = p[h].repeat(len(offsets), 1)
        trial[:, 4:7] += offsets[:, :1] * side[h] + offsets[:, 1:] * other[h]
        with torch.no_grad():
            scores = linearize(decoder, trial, base[h].expand(len(trial), 3, 3), screen, whitening, None).objective
        scores = torch.where(torch.isfinite(scores), scores, torch.full_like(scores, float("inf")))
        out[h] = trial[int(torch.argmin(scores))]  # ties (argmin: first) keep the start
    return out, len(p) * len(offsets) * len(screen.sdf)


def whitened_codes(batch: HypothesisBatch, prior: LatentPrior, device: torch.device) -> torch.Tensor:
    """The model's training codes (n, d) in ``batch``'s whitened space: w = L⁻¹(z − μ)."""
    codes = torch.as_tensor(prior.codes, dtype=torch.float64, device=device)
    return torch.linalg.solve_triangular(batch.prior_factor, (codes - batch.prior_mean).T, upper=False).T


def score_codes(decoder: Decoder, p_row: torch.Tensor, base_row: torch.Tensor, codes: torch.Tensor,
                screen: Problem, whitening: tuple[torch.Tensor, torch.Tensor]) -> torch.Tensor:
    """Forward passes only: the objective (n,) of the hypothesis p_row (7 + d,) (base rotation
    base_row (3, 3)) with its code replaced by each of ``codes`` (n, d), on ``screen``'s samples;
    a non-finite objective scores inf."""
    trial = p_row.repeat(len(codes), 1)
    trial[:, N_POSE:] = codes
    with torch.no_grad():
        scores = linearize(decoder, trial, base_row.expand(len(codes), 3, 3), screen, whitening, None).objective
    return torch.where(torch.isfinite(scores), scores, torch.full_like(scores, float("inf")))


def retrieval_start(decoder: Decoder, p: torch.Tensor, base: torch.Tensor, screen: Problem,
                    batch: HypothesisBatch, prior: LatentPrior, k: int) -> tuple[torch.Tensor, int]:
    """Start every hypothesis of p (H, 7 + d) from the retrieved code: the mean (whitened) of the
    ``k`` training codes with the lowest objective at its start pose on ``screen``'s samples
    (forward passes only; ``k`` = 1: the best training code itself). Returns p and the
    evaluations spent."""
    codes = whitened_codes(batch, prior, p.device)
    whitening = (batch.prior_mean, batch.prior_factor)
    out = p.clone()
    for h in range(len(p)):
        scores = score_codes(decoder, p[h], base[h], codes, screen, whitening)
        out[h, N_POSE:] = codes[torch.argsort(scores)[: min(k, len(codes))]].mean(dim=0)
    return out, len(p) * len(codes) * len(screen.sdf)


def _code_restarts(decoder: Decoder, p: torch.Tensor, base: torch.Tensor, survivors: np.ndarray,
                   batch: HypothesisBatch, problem_of: ProblemDrawer, prior: LatentPrior,
                   settings: FitSettings) -> tuple[torch.Tensor, torch.Tensor, np.ndarray, int]:
    """Every hypothesis of p (H, 7 + d) followed by ``settings.code_starts`` copies at its pose
    whose whitened codes are the training codes with the lowest objective there (forward passes
    on ``yaw_screen_samples`` samples); returns p, base, survivors and the evaluations spent."""
    whitened = whitened_codes(batch, prior, p.device)
    screen = problem_of(settings.yaw_screen_samples if settings.code_screen_samples is None
                        else settings.code_screen_samples)
    n, k = len(whitened), min(settings.code_starts, len(whitened))
    rows, bases = [], []
    for h in range(len(p)):
        scores = score_codes(decoder, p[h], base[h], whitened, screen, (batch.prior_mean, batch.prior_factor))
        trial = p[h].repeat(k, 1)
        trial[:, N_POSE:] = whitened[torch.argsort(scores)[:k]]
        rows += [p[h][None], trial]
        bases += [base[h][None]] * (1 + k)
    index = torch.arange(len(p)).repeat_interleave(1 + k)
    batch.keep(index)
    return (torch.cat(rows), torch.cat(bases), survivors[index.numpy()],
            len(p) * n * len(screen.sdf))


def _subset(keep: torch.Tensor, p: torch.Tensor, base: torch.Tensor, lin: Linearization, damping: torch.Tensor,
            moving: torch.Tensor, survivors: np.ndarray, batch: HypothesisBatch) -> tuple:
    """Only the hypotheses ``keep`` (indices, in that order) of every per-hypothesis state go on."""
    batch.keep(keep.cpu())
    lin = Linearization(lin.objective[keep], lin.hessian[keep], lin.gradient[keep])
    return p[keep], base[keep], lin, damping[keep], moving[keep], survivors[keep.cpu().numpy()]


def _best_copy_rows(survivors: np.ndarray, objective: torch.Tensor) -> list[int]:
    """Of the hypotheses that share a start (code restarts), the row with the lowest ``objective``
    (H,), start by start in first-seen order."""
    values = objective.cpu().numpy()
    return [int(min(np.flatnonzero(survivors == s), key=lambda h: values[h]))
            for s in dict.fromkeys(survivors.tolist())]


def _best_copies(batch: HypothesisBatch, survivors: np.ndarray,
                 objective: torch.Tensor) -> tuple[np.ndarray, torch.Tensor]:
    """Keep, of the hypotheses that share a start (code restarts), the one with the lowest
    ``objective`` (H,); returns the kept hypotheses' start indices and objectives."""
    keep = _best_copy_rows(survivors, objective)
    batch.keep(torch.as_tensor(keep))
    return survivors[keep], objective[torch.as_tensor(keep, device=objective.device)]
