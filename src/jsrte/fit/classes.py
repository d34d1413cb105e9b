"""Deciding between classes that the screen leaves close, by their final fits.

The screen's quick fits (``jsrte.fit.screen``) leave bed, sofa and table close on many clean
scans: a few Levenberg–Marquardt iterations on a whole bed stop short of what the model can do.
Where other classes score within ``ScreenSettings.final_margin`` of the best
(:func:`jsrte.fit.screen.contending`), each contending class's object is fitted in full (the
preset's own fit), and the final fits are compared on the same points: each fit's **final
score** is the screen score's terms (:func:`jsrte.fit.screen.screen_terms`) measured on every
contending object's points and averaged, weighted as ``final_weights`` says:

- ``residual``: robust mean |SDF| of the fitted surface at the object's points, in units of the
  object's bounding-sphere radius (each point's distance capped), so that it compares models;
- ``freespace``: the share of the line-of-sight free-space samples the fitted shape fills;
- ``unexplained``: the share of the object's points left farther than a few hundredths of the
  radius from the fitted surface (a sofa fitted to a bed leaves the foot of the mattress there).

The lowest final score wins, and its fit is the result: only the other contenders' fits are extra.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from jsrte.fit.query import SdfQuery
from jsrte.fit.screen import ScreenSettings, screen_terms
from jsrte.model.checkpoint import DeepSdfModel
from jsrte.result import FitResult

FINAL_WEIGHTS = {"residual": 1.0, "freespace": 1.0, "unexplained": 0.0}
"""Weights of the final score's terms (chosen on the tuning scans: docs/fitting.md)."""


def final_terms(model: DeepSdfModel, result: FitResult, objects: dict[str, SdfQuery], settings: ScreenSettings,
                seed: int = 0) -> dict[str, float]:
    """The terms (``residual``, ``freespace``, ``unexplained``) of ``result`` (a fit of ``model``)
    on the points of every query in ``objects`` (class -> its object; the same points counted
    once), averaged over those queries."""
    seen: dict[tuple, dict[str, float]] = {}
    for query in objects.values():
        key = (len(query.surface), float(np.asarray(query.surface).sum()), query.n_refine_only)
        if key not in seen:
            seen[key] = screen_terms(model, query, result, settings, np.random.default_rng(seed))
    names = ("residual", "freespace", "unexplained")
    return {k: float(np.mean([t[k] for t in seen.values()])) for k in names}


def final_score(terms: dict[str, float], weights: dict[str, float] = FINAL_WEIGHTS) -> float:
    """The final score of a fit's ``terms`` (:func:`final_terms`): their sum under ``weights``."""
    return float(sum(weights[k] * terms[k] for k in weights))


def decide(terms: dict[str, dict[str, float]], weights: dict[str, float] = FINAL_WEIGHTS) -> tuple[str, dict]:
    """The class of lowest final score among ``terms`` (class -> its fit's :func:`final_terms`),
    and fit.json's record of the comparison: the classes compared, each one's score and terms,
    and the margin between the best two."""
    scores = {name: final_score(t, weights) for name, t in terms.items()}
    ranked = sorted(scores, key=scores.__getitem__)
    margin = scores[ranked[1]] - scores[ranked[0]] if len(ranked) > 1 else None
    record: dict[str, Any] = {
        "compared": list(terms), "scores": {k: round(v, 5) for k, v in scores.items()},
        "terms": {k: {n: round(v, 5) for n, v in t.items()} for k, t in terms.items()},
        "weights": dict(weights), "margin": None if margin is None else round(margin, 5)}
    return ranked[0], record


def fit_contenders(objects: dict[str, SdfQuery], models: dict[str, DeepSdfModel], options: object,
                   class_record: dict[str, Any], *, settings: ScreenSettings = ScreenSettings(),
                   progress: bool = False) -> FitResult:
    """Fit each contending class's object in full (``objects``: class -> its object, ``options``:
    the fit's ``FitOptions``) and keep the fit of lowest final score (:func:`decide`). Its
    fit.json ``class`` block is ``class_record`` (the screen's) with the final decision:
    ``chosen``, ``chosen_by: "final fit"`` and ``final`` (:func:`decide`'s record, plus each
    compared fit's decoder evaluations and seconds)."""
    from jsrte.fit import fit_recorded

    results: dict[str, FitResult] = {}
    terms: dict[str, dict[str, float]] = {}
    for name, query in objects.items():
        results[name] = fit_recorded(models[name], query, options, progress=progress)
        terms[name] = final_terms(models[name], results[name], objects, settings, seed=options.seed)
    winner, record = decide(terms)
    record["decoder_evaluations"] = {k: r.info.get("decoder_evaluations") for k, r in results.items()}
    record["seconds"] = {k: r.timing.get("total") for k, r in results.items()}
    result = results[winner]
    result.info["class"] = class_record | {"chosen": winner, "chosen_by": "final fit", "final": record}
    return result
