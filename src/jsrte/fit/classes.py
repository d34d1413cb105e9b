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
far out among its training codes). A fit whose size is none of its class's (a sofa fitted to a
bed at 2 m, any training sofa being at most 1.46 m) also calls the runner-up's full fit, and a
class whose fit lies within its sizes wins over one whose fit does not (``final_size_margin``).

Each compared fit's data terms on the same points (:func:`final_terms`: the screen's robust
residual, free-space share and unexplained share, averaged over the compared objects) are
recorded beside the decision. On the tuning scans they did not tell the classes apart better
than the screen: a full fit of the wrong class often explains a bed or a sofa as closely as the
right one (docs/clutter.md).
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import numpy as np

from jsrte.fit.query import SdfQuery
from jsrte.fit.screen import ScreenSettings, contending, screen_terms
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
           settings: ScreenSettings = ScreenSettings(),
           admissible: dict[str, bool | None] | None = None) -> tuple[str, dict[str, float]]:
    """The class of lowest :func:`final_score` among the fully fitted ``codes`` (class -> its
    fit's code ratio; ``class_scores``: the screen's), and each one's final score. Where
    ``admissible`` (class -> whether its fit may be the object's class: False where it lies
    outside its class's sizes, or needed a code beyond ``final_far_code`` once every class first
    compared did; None: unknown) rules some fits out and not others, only the others can win."""
    scores = {name: final_score(class_scores[name], code, settings) for name, code in codes.items()}
    eligible = [name for name in scores if (admissible or {}).get(name) is not False] or list(scores)
    return min(eligible, key=scores.__getitem__), scores


def within_sizes(model: DeepSdfModel, result: FitResult, margin: float | None,
                 above: float | None = None) -> bool | None:
    """Whether ``result``'s radius (its scale s, metres) lies within ``model``'s class sizes
    widened by ``margin`` below and ``above`` above (None: ``margin`` both ways); None where the
    sizes or ``margin`` are unknown."""
    return radius_within_sizes(model, float(result.transform.s), margin, above)


def radius_within_sizes(model: DeepSdfModel, radius: float, margin: float | None,
                        above: float | None = None) -> bool | None:
    """Whether ``radius`` (metres) lies within ``model``'s class sizes widened as in
    :func:`within_sizes`; None where the sizes or ``margin`` are unknown."""
    from jsrte.model.sizes import model_sizes

    sizes = None if margin is None else model_sizes(model.meta)
    if sizes is None:
        return None
    lo, hi = sizes.bounds(margin, above)
    return bool(lo <= radius <= hi)


def fit_contenders(objects: dict[str, SdfQuery], models: dict[str, DeepSdfModel], options: object,
                   class_record: dict[str, Any], *, settings: ScreenSettings = ScreenSettings(),
                   progress: bool = False) -> FitResult:
    """Fit the best contending class's object in full (``objects``: class -> its object, the
    screen's best first; ``options``: the fit's ``FitOptions``); where its code is atypical
    (ratio above ``final_code_max``) or its size none of its class's (:func:`within_sizes`,
    ``final_size_margin``), fit the others too; where every fit lies outside its sizes, or every
    one needed a code beyond ``final_far_code``, the next contending classes
    (``final_size_classes``) too, on the best class's object, until one does not; where every fit
    still lies outside its sizes, the class of best screen score among the others whose sizes hold
    the first fit's radius (a bed fitted as a table larger than any table) too. The lowest
    final score among the fits within their sizes (and, after every class first compared needed
    a far code, among those that did not) wins (:func:`decide`).

    The kept fit's fit.json ``class`` block is ``class_record`` (the screen's: its ``scores`` are
    the class scores) with ``chosen``, ``chosen_by`` ("fit": the screen; "final fit": the final
    scores) and ``final``: the classes ``compared`` (fitted in full), each one's ``terms``
    (:func:`final_terms`), ``in_sizes`` and final ``scores``, the ``margin`` between the best
    two, ``far_code`` and ``first_all_far`` (whether every class first compared needed a code
    beyond it), and each compared fit's decoder evaluations and seconds."""
    compared = _Compared(models, objects, options, settings, progress)
    for name, query in objects.items():
        compared.fit(name, query)
        if len(compared.results) == 1 and compared.settles(name):
            break
    first = next(iter(objects.values()))
    if compared.none_fits():
        compared.all_far = compared.all_beyond_far_code()
        wider = contending(class_record["scores"], replace(settings, final_classes=settings.final_size_classes))
        for name in [n for n in wider if n not in compared.results and n in models]:
            compared.fit(name, first)
            if not compared.none_fits():
                break
    if compared.all_outside_sizes():
        compared.fit_class_holding(class_record["scores"], first)
    winner, scores = decide(class_record["scores"], {k: t["code"] for k, t in compared.terms.items()}, settings,
                            compared.admissible())
    result = compared.results[winner]
    result.info["class"] = class_record | {"chosen": winner,
                                           "chosen_by": "final fit" if len(compared.results) > 1 else "fit",
                                           "final": compared.record(scores)}
    return result


class _Compared:
    """The full fits of the classes compared so far, their terms and whether each lies within
    its class's sizes."""

    def __init__(self, models: dict[str, DeepSdfModel], objects: dict[str, SdfQuery], options: object,
                 settings: ScreenSettings, progress: bool) -> None:
        self.models, self.objects, self.options = models, objects, options
        self.settings, self.progress = settings, progress
        self.results: dict[str, FitResult] = {}
        self.terms: dict[str, dict[str, float | None]] = {}
        self.in_sizes: dict[str, bool | None] = {}
        self.all_far = False
        """Whether every class first compared needed a code beyond ``final_far_code``."""

    def fit(self, name: str, query: SdfQuery) -> None:
        """Fit class ``name`` to ``query`` in full, with its terms and whether it lies within its sizes."""
        from jsrte.fit import fit_recorded

        model = self.models[name]
        self.results[name] = fit_recorded(model, query, self.options, progress=self.progress)
        self.terms[name] = final_terms(model, self.results[name], self.objects, self.settings, seed=self.options.seed)
        self.in_sizes[name] = within_sizes(model, self.results[name], self.settings.final_size_margin,
                                           self.settings.final_size_margin_above)

    def beyond_far_code(self, name: str) -> bool:
        """Whether ``name``'s fit needed a code beyond ``final_far_code`` (never where it is None)."""
        far, code = self.settings.final_far_code, self.terms[name]["code"]
        return far is not None and code is not None and code > far

    def all_beyond_far_code(self) -> bool:
        """Whether every fit so far needed a code beyond ``final_far_code``."""
        return all(self.beyond_far_code(name) for name in self.terms)

    def all_outside_sizes(self) -> bool:
        """Whether every fit so far lies outside its class's sizes."""
        return all(inside is False for inside in self.in_sizes.values())

    def fit_class_holding(self, class_scores: dict[str, float | None], query: SdfQuery) -> None:
        """Fit to ``query``, of the classes not compared yet, the one of best screen score (in
        ``class_scores``) whose sizes hold the first fit's radius; none where no class's do."""
        radius = float(next(iter(self.results.values())).transform.s)
        scores = {n: np.inf if v is None else v for n, v in class_scores.items()}
        margins = (self.settings.final_size_margin, self.settings.final_size_margin_above)
        holding = [n for n in sorted(scores, key=scores.__getitem__) if n not in self.results and n in self.models
                   and radius_within_sizes(self.models[n], radius, *margins)]
        if holding:
            self.fit(holding[0], query)

    def none_fits(self) -> bool:
        """Whether every fit so far lies outside its class's sizes, or every one needed a code
        beyond ``final_far_code``: no compared class is the object's."""
        return self.all_outside_sizes() or self.all_beyond_far_code()

    def admissible(self) -> dict[str, bool | None]:
        """Class -> whether its fit may be the object's class (:func:`decide`): not where it lies
        outside its sizes, nor, where every class first compared needed a code beyond
        ``final_far_code``, where it needed one too; None where its sizes are unknown."""
        return {name: False if self.all_far and self.beyond_far_code(name) else inside
                for name, inside in self.in_sizes.items()}

    def settles(self, name: str) -> bool:
        """Whether ``name``'s fit alone settles the class: a typical code, a size of its class's."""
        code = self.terms[name]["code"]
        return (code is None or code <= self.settings.final_code_max) and self.in_sizes[name] is not False

    def record(self, scores: dict[str, float]) -> dict[str, Any]:
        """fit.json's ``final`` record of the comparison, with the final ``scores``."""
        ranked = sorted(scores.values())
        return {"compared": list(self.results), "code_max": self.settings.final_code_max,
                "far_code": self.settings.final_far_code, "first_all_far": self.all_far,
                "code_weight": self.settings.final_code_weight, "size_margin": self.settings.final_size_margin,
                "size_margin_above": self.settings.final_size_margin_above,
                "in_sizes": self.in_sizes, "scores": {k: round(v, 5) for k, v in scores.items()},
                "margin": round(ranked[1] - ranked[0], 5) if len(ranked) > 1 else None,
                "terms": {k: {n: None if v is None else round(v, 5) for n, v in t.items()}
                          for k, t in self.terms.items()},
                "decoder_evaluations": {k: r.info.get("decoder_evaluations") for k, r in self.results.items()},
                "seconds": {k: r.timing.get("total") for k, r in self.results.items()}}
