"""Deciding between classes that the screen leaves close, by their full fits.

The screen's quick fits (``jsrte.fit.screen``) leave bed, sofa and table close on many clean
scans. Where another class scores within ``ScreenSettings.final_margin`` of the best
(:func:`jsrte.fit.screen.contending`), the best class is fitted in full first (the preset's own
fit, which the scan needs anyway). Only when that fit needed an atypical code (its
``latent_mahalanobis_ratio``, the code's Mahalanobis distance under the class's training codes
over their median one, above ``final_code_max``) is the runner-up fitted in full too, and the
two are compared by their **final score**: the class score of the screen plus
``final_code_weight`` times the code's ratio. The class score says how well each model explains
the whole cluster; the code's ratio says how typical a shape of its class the model had to
become to do so (a sofa model stretched over a bed, or a bed model over a sofa, needs a code
far out among its training codes).

Each compared fit's data terms on the same points (:func:`final_terms`: the screen's robust
residual, free-space share and unexplained share, averaged over the compared objects) are
recorded beside the decision. On the tuning scans they did not tell the classes apart better
than the screen: a full fit of the wrong class often explains a bed or a sofa as closely as the
right one (docs/clutter.md).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from jsrte.fit.query import SdfQuery
from jsrte.fit.screen import ScreenSettings, screen_terms
from jsrte.model.checkpoint import DeepSdfModel
from jsrte.result import FitResult


def final_terms(model: DeepSdfModel, result: FitResult, objects: dict[str, SdfQuery], settings: ScreenSettings,
                seed: int = 0) -> dict[str, float]:
    """The data terms (``residual``, ``freespace``, ``unexplained``: :func:`screen_terms`) of
    ``result`` (a fit of ``model``) on the points of every query in ``objects`` (class -> its
    object; the same points counted once), averaged over those queries, and the fit's ``code``
    ratio (``latent_mahalanobis_ratio`` of its quality block; None without one)."""
    seen: dict[tuple, dict[str, float]] = {}
    for query in objects.values():
        key = (len(query.surface), float(np.asarray(query.surface).sum()), query.n_refine_only)
        if key not in seen:
            seen[key] = screen_terms(model, query, result, settings, np.random.default_rng(seed))
    terms: dict[str, float | None] = {k: float(np.mean([t[k] for t in seen.values()]))
                                      for k in ("residual", "freespace", "unexplained")}
    terms["code"] = result.quality.get("latent_mahalanobis_ratio")
    return terms


def final_score(class_score: float, code: float | None, settings: ScreenSettings) -> float:
    """The final score of a fully fitted class: its screen ``class_score`` plus
    ``final_code_weight`` times its fit's ``code`` ratio (0 where unknown)."""
    return class_score + settings.final_code_weight * (code or 0.0)


def decide(class_scores: dict[str, float], codes: dict[str, float | None],
           settings: ScreenSettings = ScreenSettings()) -> tuple[str, dict[str, float]]:
    """The class of lowest :func:`final_score` among the fully fitted ``codes`` (class -> its
    fit's code ratio; ``class_scores``: the screen's), and each one's final score."""
    scores = {name: final_score(class_scores[name], code, settings) for name, code in codes.items()}
    return min(scores, key=scores.__getitem__), scores


def fit_contenders(objects: dict[str, SdfQuery], models: dict[str, DeepSdfModel], options: object,
                   class_record: dict[str, Any], *, settings: ScreenSettings = ScreenSettings(),
                   progress: bool = False) -> FitResult:
    """Fit the best contending class's object in full (``objects``: class -> its object, the
    screen's best first; ``options``: the fit's ``FitOptions``); where its code is atypical
    (ratio above ``final_code_max``), fit the others too and keep the lowest final score
    (:func:`decide`). The kept fit's fit.json ``class`` block is ``class_record`` (the
    screen's: its ``scores`` are the class scores) with ``chosen``, ``chosen_by`` ("fit": the
    screen; "final fit": the final scores) and ``final``: the classes ``compared`` (fitted in
    full), each one's ``terms`` (:func:`final_terms`) and final ``scores``, the ``margin``
    between the best two, and each compared fit's decoder evaluations and seconds."""
    from jsrte.fit import fit_recorded

    results: dict[str, FitResult] = {}
    terms: dict[str, dict[str, float | None]] = {}
    for name, query in objects.items():
        results[name] = fit_recorded(models[name], query, options, progress=progress)
        terms[name] = final_terms(models[name], results[name], objects, settings, seed=options.seed)
        code = terms[name]["code"]
        if len(results) == 1 and (code is None or code <= settings.final_code_max):
            break
    winner, scores = decide(class_record["scores"], {k: t["code"] for k, t in terms.items()}, settings)
    ranked = sorted(scores.values())
    record = {"compared": list(results), "code_max": settings.final_code_max,
              "code_weight": settings.final_code_weight,
              "scores": {k: round(v, 5) for k, v in scores.items()},
              "margin": round(ranked[1] - ranked[0], 5) if len(ranked) > 1 else None,
              "terms": {k: {n: None if v is None else round(v, 5) for n, v in t.items()} for k, t in terms.items()},
              "decoder_evaluations": {k: r.info.get("decoder_evaluations") for k, r in results.items()},
              "seconds": {k: r.timing.get("total") for k, r in results.items()}}
    result = results[winner]
    result.info["class"] = class_record | {"chosen": winner, "chosen_by": "final fit" if len(results) > 1 else "fit",
                                           "final": record}
    return result
