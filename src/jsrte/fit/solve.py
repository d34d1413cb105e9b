"""The JSRTE algorithm (paper Algorithm 1) on an SDF query: starts, minimization, and the winner."""

from __future__ import annotations

import time
from dataclasses import replace

import numpy as np
import torch

from jsrte.errors import JsrteError
from jsrte.fit.floor import with_below_floor_samples
from jsrte.fit.init import ClassGeometry, initial_hypotheses
from jsrte.fit.optimize import Optimized, loss_clamp, optimize
from jsrte.fit.params import Init, LatentPrior
from jsrte.fit.query import SdfQuery
from jsrte.metrics.surface import bounding_sphere, fscore
from jsrte.model.checkpoint import DeepSdfModel
from jsrte.model.decoder import Decoder, decoder_device, denormals_flushed, uses_bfloat16
from jsrte.model.meshing import decode_mesh
from jsrte.presets import FitSettings
from jsrte.result import FitResult, HypothesisReport
from jsrte.timing import stage, timed_stage

AXIS_PARAMETERS = frozenset({"psi", "rho"})
"""The rotation axis's spherical angles: held in the known-axis mode."""


def class_geometry(model: DeepSdfModel) -> ClassGeometry:
    """Canonical height and radius of the class: from the model metadata, else by decoding
    the mean training code (cached in ``model.meta``)."""
    meta = model.meta
    if "canonical_height" not in meta or "canonical_radius" not in meta:
        try:
            mesh = decode_mesh(model.decoder, model.mean_code(), resolution=64).mesh
        except JsrteError as exc:
            raise JsrteError(f"the fit diverged before it started: {exc}") from None
        if mesh is None:
            meta["canonical_height"], meta["canonical_radius"] = 1.0, 1.0
        else:
            meta["canonical_height"] = float(mesh.bounds[1, 1] - mesh.bounds[0, 1])
            meta["canonical_radius"] = bounding_sphere(mesh.vertices)[1]
    return ClassGeometry(height=float(meta["canonical_height"]), radius=float(meta["canonical_radius"]))


def sized(model: DeepSdfModel, settings: FitSettings) -> FitSettings:
    """``settings`` with the scale bounds narrowed to the model's class sizes widened by
    ``settings.size_margin`` (``jsrte.model.sizes``), where both are known."""
    from jsrte.model.sizes import model_sizes

    sizes = None if settings.size_margin is None else model_sizes(model.meta)
    if sizes is None:
        return settings
    lo, hi = sizes.bounds(settings.size_margin)
    return replace(settings, scale_min=max(settings.scale_min, lo), scale_max=min(settings.scale_max, hi))


def for_class(model: DeepSdfModel, settings: FitSettings) -> FitSettings:
    """``settings`` without the floor contact where ``settings.floor_contact_classes`` names
    classes and ``model``'s ``category`` is none of them."""
    classes = settings.floor_contact_classes
    if not settings.floor_contact or classes is None or model.meta.get("category") in classes:
        return settings
    return replace(settings, floor_contact=0.0)


def latent_prior(model: DeepSdfModel, settings: FitSettings) -> LatentPrior | None:
    """The training codes' Gaussian when ``settings.latent_space`` is "whitened", else None."""
    if settings.latent_space == "raw":
        return None
    if settings.latent_space != "whitened":
        raise ValueError(f"unknown latent_space {settings.latent_space!r}; known: raw, whitened")
    return LatentPrior.of_codes(model.codes.detach().cpu().numpy(), shrinkage=settings.latent_prior_shrinkage)


def search_decoder(model: DeepSdfModel, settings: FitSettings) -> DeepSdfModel:
    """The model whose decoder moves the hypotheses: ``model``'s distilled decoder with
    ``settings.distilled_search`` (JsrteError if it has none), else ``model``."""
    if not settings.distilled_search:
        return model
    from jsrte.model.registry import distilled_decoder

    return distilled_decoder(model)


def minimize(decoder: Decoder, query: SdfQuery, inits: list[Init], settings: FitSettings, *,
             fixed: frozenset[str], generator: torch.Generator, prior: LatentPrior | None,
             progress: bool = False, finisher: Decoder | None = None) -> Optimized:
    """Minimize every hypothesis's objective with ``settings.solver``: Adam (fit.optimize;
    ``finisher``, if given, takes the survivors of the last pruning and the final losses) or
    Levenberg–Marquardt (fit.gauss_newton; ``finisher``, if given, takes its refinement, polish
    and final losses)."""
    if settings.solver == "gauss-newton":
        from jsrte.fit.gauss_newton import solve

        return solve(decoder, query, inits, settings, fixed=fixed, generator=generator, prior=prior,
                     progress=progress, finisher=finisher)
    return optimize(decoder, query, inits, settings, fixed=fixed, generator=generator, prior=prior,
                    progress=progress, finisher=finisher)


@denormals_flushed()
def fit_query(model: DeepSdfModel, query: SdfQuery, settings: FitSettings, *,
              inits: list[Init] | None = None, n_hypotheses: int | None = None,
              fixed: frozenset[str] | None = None, seed: int = 0, progress: bool = False,
              assess: bool = True) -> FitResult:
    """Jointly estimate z and (s, R, t) for ``query``; returns the winning hypothesis.

    ``inits`` default to :func:`initial_hypotheses` (the θ grid). The winner is chosen by
    ``settings.selection``: F@5% of each surviving hypothesis's decoded surface against the
    query's surface points (the paper), or the final loss. ``fixed`` names the parameters held
    at their start (default: ψ and ρ when the query knows its up axis and ``settings.hold_axis``).
    ``assess``: fill the quality block and the flag (a quick fit that only ranks candidates and
    classes needs neither; its ``quality`` stays empty and its ``flag`` None). Denormal floats are
    flushed to zero on the calling thread while it runs (``jsrte.model.decoder.denormals_flushed``).
    """
    started = time.perf_counter()
    settings = for_class(model, sized(model, settings))
    if fixed is None:
        fixed = AXIS_PARAMETERS if settings.hold_axis and query.up is not None else frozenset()
    decoder = model.decoder
    generator = torch.Generator().manual_seed(seed)
    if inits is None:
        inits = initial_hypotheses(query, class_geometry(model), settings, n_hypotheses=n_hypotheses)
    n_query = len(query.sdf)
    observed = query
    clamp = loss_clamp(settings, inits)
    if settings.below_floor_samples and clamp is not None:
        query = with_below_floor_samples(query, settings.below_floor_samples, clamp=clamp,
                                         rng=np.random.default_rng(seed), depth=settings.below_floor_depth)
    searcher = search_decoder(model, settings)
    with stage("solve"):
        result = minimize(searcher.decoder, query, inits, settings, fixed=fixed, generator=generator,
                          prior=latent_prior(model, settings), progress=progress,
                          finisher=None if searcher is model else decoder)
    t_opt = time.perf_counter() - started
    _check_finite(result)
    reports = _reports(result, inits)
    winner, criterion = _select(model, query, result, reports, settings, seed)
    t_sel = time.perf_counter() - started - t_opt
    latent = result.batch.latent[winner].detach().to("cpu", torch.float32).numpy()
    with stage("meshing"):
        mesh = decode_mesh(decoder, latent, resolution=settings.extract_resolution).mesh
    timing = {"optimize": round(t_opt, 2), "select": round(t_sel, 2),
              "extract": round(time.perf_counter() - started - t_opt - t_sel, 2),
              "total": round(time.perf_counter() - started, 2)}
    fitted = FitResult(
        method="jsrte", transform=result.batch.transform(winner), latent=latent, mesh_canonical=mesh,
        loss=float(result.losses[winner]), criterion=criterion, angles=result.batch.angles(winner),
        hypotheses=reports, timing=timing,
        info={"decoder_evaluations": result.evaluations, "iterations": result.iterations,
              "fixed_parameters": sorted(fixed), "below_floor_samples": len(query.sdf) - n_query,
              "latent_space": settings.latent_space, "solver": settings.solver,
              "decoder_dtype": _dtype_used(settings, decoder), "search_decoder": searcher.name,
              "failed_hypotheses": {str(i): why for i, why in sorted(result.failed.items())},
              "winner_hypothesis": int(result.survivors[winner])},
    )
    if result.evaluation_parts:
        fitted.info["decoder_evaluations_by_part"] = dict(result.evaluation_parts)
    if assess:
        _assess(model, observed, fitted, seed)
    return fitted


def fit_with_retry(model: DeepSdfModel, query: SdfQuery, settings: FitSettings, *,
                   n_hypotheses: int | None = None, seed: int = 0, progress: bool = False) -> FitResult:
    """:func:`fit_query`, and where ``settings.float32_retry`` is set and the fit moved in
    bfloat16 and ends flagged "doubtful", the same fit again in float32; the better of the two is
    kept (:func:`_better`: the higher inlier share). fit.json's ``float32_retry`` records both
    fits' flags, inlier shares and losses and which was kept; the decoder evaluations and seconds
    are both fits' together."""
    first = fit_query(model, query, settings, n_hypotheses=n_hypotheses, seed=seed, progress=progress)
    if not (settings.float32_retry and first.flag == "doubtful" and first.info["decoder_dtype"] == "bfloat16"):
        return first
    again = fit_query(model, query, replace(settings, decoder_dtype="float32"), n_hypotheses=n_hypotheses,
                      seed=seed, progress=progress)
    kept = again if _better(again, first) else first
    kept.info["float32_retry"] = {"kept": kept.info["decoder_dtype"]} | {
        r.info["decoder_dtype"]: {"flag": r.flag, "inlier_share": r.quality.get("inlier_share"), "loss": r.loss}
        for r in (first, again)}
    kept.info["decoder_evaluations"] = first.info["decoder_evaluations"] + again.info["decoder_evaluations"]
    kept.timing["total"] = round(first.timing["total"] + again.timing["total"], 2)
    return kept


def _better(a: FitResult, b: FitResult) -> bool:
    """Whether fit ``a`` is to be kept over ``b``: a higher inlier share (the share of the
    query's points on the fitted surface, jsrte.fit.quality; a fit without one counts 0)."""
    def share(r: FitResult) -> float:
        return float(r.quality.get("inlier_share") or 0.0)

    return share(a) > share(b)


def _dtype_used(settings: FitSettings, decoder: Decoder) -> str:
    """The decoder arithmetic the fit moved its hypotheses with: "bfloat16" or "float32"."""
    return "bfloat16" if uses_bfloat16(settings.decoder_dtype, decoder_device(decoder)) else "float32"


def _assess(model: DeepSdfModel, query: SdfQuery, result: FitResult, seed: int) -> None:
    """Fill ``result.quality`` and ``result.flag`` (jsrte.fit.quality) from ``query``'s own samples."""
    from jsrte.fit.quality import assess, flag_of

    started = time.perf_counter()
    with stage("quality"):
        result.quality = assess(model.decoder, result, surface=query.surface, points=query.points, sdf=query.sdf,
                                codes=model.codes.detach().cpu().numpy(), seed=seed)
    result.flag = flag_of(result.quality)
    result.timing["quality"] = round(time.perf_counter() - started, 2)


def _check_finite(result: Optimized) -> None:
    """JsrteError if a surviving hypothesis ended with a non-finite loss, scale, pose or code."""
    batch = result.batch
    with torch.no_grad():
        values = [torch.as_tensor(np.asarray(result.losses, np.float64)).reshape(len(result.losses), -1)]
        values += [v.detach().cpu().reshape(len(result.losses), -1).to(torch.float64)
                   for v in (batch.scale, batch.psi, batch.rho, batch.theta, batch.translation, batch.latent)]
        finite = torch.cat(values, dim=1).isfinite().all(dim=1)
        scale_positive = (batch.scale.detach().cpu() > 0).reshape(-1)
    bad = (~(finite & scale_positive)).nonzero().reshape(-1).tolist()
    if bad:
        raise JsrteError(f"the fit diverged: hypothesis {int(result.survivors[bad[0]])} ended with a non-finite "
                         "loss, scale or pose (does the model give NaN or infinite values?)")


def _reports(result: Optimized, inits: list[Init]) -> list[HypothesisReport]:
    reports = []
    for i, init in enumerate(inits):
        init_json = {"scale": init.scale, "psi": init.psi, "rho": init.rho, "theta": init.theta,
                     "translation": np.asarray(init.translation, float).tolist()}
        if i in result.failed:
            reports.append(HypothesisReport(i, init_json, float("nan"), pruned=True, failed=result.failed[i]))
            continue
        if i in result.pruned_losses:
            reports.append(HypothesisReport(i, init_json, result.pruned_losses[i], pruned=True))
            continue
        h = int(np.nonzero(result.survivors == i)[0][0])
        reports.append(HypothesisReport(i, init_json, float(result.losses[h]),
                                        transform=result.batch.transform(h), angles=result.batch.angles(h)))
    return reports


@timed_stage("selection")
def _select(model: DeepSdfModel, query: SdfQuery, result: Optimized, reports: list[HypothesisReport],
            settings: FitSettings, seed: int) -> tuple[int, dict]:
    """Index (into the surviving batch) of the winner, and the criterion used."""
    by_loss = int(np.argmin(result.losses))
    if settings.selection == "loss" or len(result.losses) == 1:
        return by_loss, {"name": "loss", "value": float(result.losses[by_loss])}
    scores = []
    for h in range(len(result.losses)):
        latent = result.batch.latent[h].detach().to(torch.float32)
        mesh = decode_mesh(model.decoder, latent, resolution=settings.selection_resolution).mesh
        if mesh is not None:
            mesh.vertices = result.batch.transform(h).apply(mesh.vertices)
        f = fscore(mesh, query.surface, fraction=settings.fscore_fraction, n_points=settings.fscore_points,
                   rng=np.random.default_rng(seed)).fscore
        scores.append(f)
        reports[int(result.survivors[h])].fscore = f
    best = int(np.argmax(scores))
    return best, {"name": "fscore", "value": float(scores[best]), "agrees_with_loss": best == by_loss}
