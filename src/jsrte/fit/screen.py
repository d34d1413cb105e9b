"""Choosing the object, and its class, by a quick fit of each candidate.

Segmentation ranks a scan's candidate objects by their proportions alone (``class_score``): a
box, or the remnant of a wall, can look more like a chair than a half-hidden chair does. Here
the best few candidates by that rank are each fitted quickly (:data:`SCREEN_FIT`: the
Levenberg–Marquardt solver, few yaw starts, few iterations, few samples), and the candidate the
model explains best is the object. With several models (``--model auto`` or a list), every
model screens its own best candidates, each screen is scored on the whole cluster its candidate
was split from, the contended classes fit their wholes again, and the lowest class score wins
(:func:`class_scores`).

The **screen score** is scale-free and the same for every model, so that it compares
candidates of different sizes and classes of different models:

- the robust mean |SDF| of the fitted surface at the candidate's points, in units of the
  candidate's bounding-sphere radius (each point's distance capped at ``residual_cap`` radii:
  a few stray points do not decide);
- plus ``freespace_weight`` times the share of the line-of-sight free-space samples around the
  candidate (space the sensor saw empty) that the fitted shape fills: a chair fitted to a wall
  remnant or to the face of a box puts its seat or legs where the sensor saw through.

Both terms are measured on the candidate's own samples, whatever the model; neither depends on
the model's training loss scale or latent size.

A cluster that segmentation split in parts stays a candidate too (its ``parts``): one object
cut at a narrow place (a bed's headboard, a sofa's arm) and two objects side by side (a chair
beside a box) look alike to proportions, not to a fit. When a part is among the best
candidates, its whole and the whole's other parts are screened too, and the whole is weighed
against its parts (:func:`split_or_whole`): the parts' scores, weighted by their points, are
what the split explains of the whole's points; a chair model fitted to a chair beside a box
explains the box badly, a bed model fitted to a whole bed explains all of it. With one model,
a candidate the model explains badly that segmentation left whole at a weak neck (proportions
gave no reason to cut: a chair half hidden by the box beside it) is cut there, and its parts
are screened and judged the same way (:func:`cut_necks`). A chosen candidate that is a piece of
a bigger cluster (a cut through the chair left its legs with the box) grows over the cluster's
points that its fit passes through (:func:`grow`).
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
import torch

from jsrte.errors import JsrteError
from jsrte.fit.query import SdfQuery
from jsrte.model.checkpoint import DeepSdfModel
from jsrte.presets import FAST_GAUSS_NEWTON, FitSettings
from jsrte.result import FitResult
from jsrte.timing import stage

SCREEN_FIT = replace(FAST_GAUSS_NEWTON.fit, iterations=6, samples_per_iteration=1000, yaw_screen_keep=4,
                     yaw_screen_samples=400, prune_after=3, prune_keep=1, eval_samples=2000,
                     extract_resolution=24, translation_search=0.0, samples_after_pruning=None,
                     adam_stage="never", polish_iterations=0, polish_samples=1000, code_screen_samples=None,
                     code_starts_prune_after=None)
"""The quick fit of a candidate: 12 yaw starts screened by forward passes to the best 4, which
take 3 Levenberg–Marquardt iterations on 1000 samples, the best one goes on to at most 6."""

CLASS_FIT = replace(SCREEN_FIT, iterations=15, prune_keep=2, translation_search=0.3, samples_after_pruning=3000)
"""The fit of a whole whose class is in contention (:func:`class_scores`): as :data:`SCREEN_FIT`,
but the best two yaw starts go on, moved to the translation of lowest objective across the up
axis (±0.3 s0) and on 3000 fresh samples, to at most 15 iterations."""


@dataclass(frozen=True)
class ScreenSettings:
    """How candidates (and classes) are screened by a quick fit."""

    candidates: int = 3
    """The best this many candidates by class rank are screened."""
    fit: FitSettings = field(default_factory=lambda: SCREEN_FIT)
    surface_points: int = 2000
    """Candidate points at which the fitted surface's distance is measured."""
    freespace_points: int = 4000
    """Line-of-sight free-space samples at which the fitted shape's violation is measured."""
    residual_cap: float = 0.1
    """A point's |SDF| counts at most this many candidate radii."""
    unexplained_m: float = 0.05
    """A candidate point farther than this many candidate radii from the fitted surface is one
    the fit leaves unexplained (recorded, not scored: :func:`screen_terms`)."""
    freespace_weight: float = 1.0
    """Weight of the share of free-space samples inside the fitted shape."""
    rank_weight: float = 0.02
    """Weight of the candidate's class rank (segmentation's proportions score): it settles near
    ties of the fit (on the tuning rooms any weight from 0.005 to 0.05 chose the same)."""
    whole_margin: float = 0.01
    """A split's whole may be the object when its screen score is at most its parts' (weighted
    by their points) plus this (:func:`split_or_whole`)."""
    whole_explains: float = 1.3
    """... and when its fitted surface lies at most this many times as far from its best
    part's points as the part's own fitted surface (:func:`explained_ratio`)."""
    explained_floor: float = 0.0
    """... the part's own fitted surface counted at least this many part radii from its points
    (:func:`explained_ratio`): closer, two good fits differ by noise, not by what they explain."""
    class_fit: FitSettings = field(default_factory=lambda: CLASS_FIT)
    """The fit of a whole whose class is in contention (:func:`class_scores`)."""
    class_refit_margin: float = 0.02
    """Where two classes or more score on their wholes at most the best class's plus this, each
    is fitted again to its whole with ``class_fit`` (0: never)."""
    class_freespace_weight: float = 0.0
    """Weight of the free-space share in the class score (:func:`class_scores`)."""
    neck_score: float = 0.065
    """With one model, a screened candidate scoring worse than this that segmentation left
    whole at a weak neck (its ``neck``) is cut there, and its parts are screened and judged
    against it (:func:`split_or_whole`): on the tuning data a chair and a box 1-8 cm apart
    scored 0.074-0.1 as one candidate, a chair alone 0.01-0.035, a clean bed 0.009-0.072."""
    final_margin: float = 0.035
    """Where other classes score at most the best class's plus this after the screen (and the
    refits), the class is settled by full fits (``jsrte.fit.classes``; 0: never): the best
    class is fitted in full, and where its code is atypical the next best too."""
    final_classes: int = 2
    """At most this many classes are fitted in full (the best by class score first)."""
    final_code_max: float = 0.9
    """The best class's full fit settles the class when its code's ratio
    (``latent_mahalanobis_ratio``) is at most this; above it, the next best is fitted in full
    too (the confidence flag's own threshold for an atypical code)."""
    final_code_weight: float = 0.02
    """Weight of the code's ratio in the final score of a fully fitted class (its class score
    plus this times the ratio)."""
    final_size_margin: float | None = 1.3
    """A full fit whose radius lies outside its class's sizes (``jsrte.model.sizes``: its
    training shapes') widened by this below (and by ``final_size_margin_above`` above) is no
    evidence for the class (a sofa model stretched over a bed): the next contending class is
    fitted in full too, and a class whose fit lies within its sizes wins over one whose fit does
    not. None: sizes are not weighed (nor where a model records none)."""
    final_size_margin_above: float | None = 1.1
    """The widening of the largest size (None: ``final_size_margin``). A fit ends smaller than
    its object more often than larger (a partial view, a piece of it chosen), while a model of a
    smaller class stretched over a bigger object overshoots its own class: on the tuning scans
    (clean, indices 100-119 at their own sizes) every fit chosen with the right class lay at 0.97
    or less of its class's largest training size, and four beds went to tables fitted at 1.22-1.30
    times the largest training table (1.32 m), inside a margin of 1.3."""
    final_size_classes: int = 3
    """Where every class fitted in full lies outside its sizes (or needed a code beyond
    ``final_far_code``), the next contending classes (up to this many in all, each within
    ``final_margin`` of the best) are fitted in full on the best class's object, until one lies
    within its sizes (and needs a code within it)."""
    final_far_code: float | None = None
    """Where every class fitted in full needed a code's ratio above this, none is the object's
    class by its code, and the next contending classes are fitted too (``final_size_classes``);
    None: never."""
    slab_m: float = 0.08
    """A candidate thinner than this (m) across its thinnest direction (:func:`thickness`) is a
    slab: a wall's remnant or one face of a box, never an object of a class with volume. Slabs
    are screened only where fewer than ``candidates`` others are, and are chosen only where
    nothing else was screened (0: no slabs)."""
    boxes_last: bool = True
    """Boxes (``jsrte.scans.boxes``: an upright cuboid seen solid, clutter no model covers) are
    screened, as slabs are, only where fewer than ``candidates`` others are, and chosen only
    where nothing else was screened."""
    grow_within: float = 0.03
    """A chosen candidate that is a piece of a bigger cluster takes in that cluster's points
    within this many of its radii of its fitted surface (the rest of the object, which a cut
    through it left out), when the grown candidate's screen scores at most its own plus
    ``grow_margin`` (:func:`grow`; 0: never)."""
    grow_margin: float = 0.01
    grow_min_share: float = 0.05
    """... and when growing adds at least this share of its points."""

    def held_to_sizes(self, margin: float | None) -> ScreenSettings:
        """These settings with the quick fits held to each class's sizes as the full fits are (a
        preset's ``size_margin``, e.g. ``sized``); unchanged where the preset holds none."""
        return self._quick_fits(size_margin=margin)

    def in_arithmetic(self, dtype: str | None) -> ScreenSettings:
        """These settings with the quick fits in the decoder arithmetic ``dtype`` ("auto",
        "float32", "bfloat16": a fit's ``--dtype``, which every fit of the command follows);
        unchanged where None (the quick fits' own, "auto")."""
        return self._quick_fits(decoder_dtype=dtype)

    def searched_as(self, settings: FitSettings) -> ScreenSettings:
        """These settings with the quick fits searched by the model's distilled decoder where the
        full fit's ``settings`` say so (``FitSettings.distilled_screen``, ``express``); unchanged
        elsewhere."""
        return self._quick_fits(distilled_search=(settings.distilled_search and settings.distilled_screen) or None)

    def _quick_fits(self, **changes: object) -> ScreenSettings:
        """These settings with ``changes`` (``FitSettings`` fields) applied to both quick fits,
        ``fit`` and ``class_fit``; unchanged where every change is None."""
        changes = {name: value for name, value in changes.items() if value is not None}
        if not changes:
            return self
        return replace(self, fit=replace(self.fit, **changes), class_fit=replace(self.class_fit, **changes))


@dataclass
class Screened:
    """One candidate screened by one model.

    Attributes
    ----------
    model : the model's name
    candidate : position of the candidate in its segmentation (None: the whole query)
    query : the candidate's SDF query
    result : the quick fit
    score : the screen score (lower is better)
    parts : its terms (``residual``, ``freespace``, ``rank``), the candidate's radius (m) and the
        share of its points the fit leaves ``unexplained``
    """

    model: str
    candidate: int | None
    query: SdfQuery
    result: FitResult
    score: float
    parts: dict[str, float]

    def to_json(self) -> dict[str, Any]:
        """The screen's record in fit.json."""
        return {"model": self.model, "score": round(self.score, 5)} | {k: round(v, 5) for k, v in self.parts.items()}


def predicted_sdf(model: DeepSdfModel, result: FitResult, points: np.ndarray) -> np.ndarray:
    """SDF (n,) of the fitted shape of ``result`` at ``points`` (n, 3), in scan units."""
    from jsrte.model.decoder import decoder_device

    decoder = model.decoder
    canonical = result.transform.inverse().apply(points)
    device = decoder_device(decoder)
    dtype = next((p.dtype for p in decoder.parameters()), torch.float32)
    with torch.no_grad():
        f = decoder(torch.as_tensor(canonical, dtype=dtype, device=device),
                    torch.as_tensor(result.latent, dtype=dtype, device=device))
    return result.transform.s * f.detach().to("cpu", torch.float64).numpy()


def screen_terms(model: DeepSdfModel, query: SdfQuery, result: FitResult, settings: ScreenSettings,
                 rng: np.random.Generator) -> dict[str, float]:
    """The screen score's terms of ``result`` fitted to ``query``: ``residual`` (mean capped
    |SDF| at the query's surface points over their bounding-sphere radius), ``freespace`` (share
    of the line-of-sight samples inside the fitted shape) and ``radius`` (m); and, recorded
    beside them but not scored, ``unexplained``: the share of those points farther than
    ``unexplained_m`` radii from the fitted surface (a chair fitted to a chair and a table
    merged into one candidate leaves half or more of its points there, a chair alone a few
    percent)."""
    from jsrte.metrics.surface import bounding_sphere

    surface = query.surface
    radius = max(bounding_sphere(surface)[1], 1e-9)
    pick = rng.permutation(len(surface))[: settings.surface_points]
    distance = np.abs(predicted_sdf(model, result, surface[pick])) / radius
    residual = np.minimum(distance, settings.residual_cap)
    freespace = 0.0
    if query.n_refine_only:
        rays = query.points[len(query.points) - query.n_refine_only:]
        pick = rng.permutation(len(rays))[: settings.freespace_points]
        freespace = float((predicted_sdf(model, result, rays[pick]) < 0).mean())
    return {"residual": float(residual.mean()), "freespace": freespace, "radius": float(radius),
            "unexplained": float((distance > settings.unexplained_m).mean())}


def screen(model: DeepSdfModel, name: str, query: SdfQuery, candidate: int | None, settings: ScreenSettings,
           seed: int, rank: float = 0.0) -> Screened:
    """The quick fit of ``model`` to ``query`` and its screen score (``rank``: the candidate's
    class rank, 0 for a whole query)."""
    from jsrte.fit.solve import fit_query

    result = fit_query(model, query, settings.fit, seed=seed, assess=False)
    parts = screen_terms(model, query, result, settings, np.random.default_rng(seed))
    parts["rank"] = float(rank)
    return Screened(name, candidate, query, result, screen_score(parts, settings), parts)


def screen_score(parts: dict[str, float], settings: ScreenSettings, freespace_weight: float | None = None) -> float:
    """The screen score of ``parts`` (``residual``, ``freespace`` and ``rank``: :func:`screen`),
    the free-space share weighted by ``freespace_weight`` (default: the settings')."""
    weight = settings.freespace_weight if freespace_weight is None else freespace_weight
    return parts["residual"] + weight * parts["freespace"] + settings.rank_weight * parts["rank"]


@dataclass
class Choice:
    """The object and the class chosen by the screen.

    Attributes
    ----------
    query : the chosen candidate's SDF query
    model : the chosen model
    screened : every screen run
    classes : per model name, its class score (None when it had no candidate): its best screen
        score, with several models its best on a whole (:func:`class_scores`)
    refits : the contended wholes fitted again (:func:`class_scores`)
    objects : per contending class (:func:`contending`; the chosen first), the object its model
        chose; more than one: the classes' final fits decide (``jsrte.fit.classes``)
    """

    query: SdfQuery
    model: DeepSdfModel
    screened: list[Screened]
    classes: dict[str, float | None]
    refits: list[Screened] = field(default_factory=list)
    objects: dict[str, SdfQuery] = field(default_factory=dict)

    def class_json(self) -> dict[str, Any]:
        """fit.json's record of the class choice: every class's score and the margin."""
        scores = sorted(v for v in self.classes.values() if v is not None)
        margin = scores[1] - scores[0] if len(scores) > 1 else None
        return {"chosen": self.model.name, "chosen_by": "fit",
                "scores": {k: None if v is None else round(v, 5) for k, v in self.classes.items()},
                "margin": None if margin is None else round(margin, 5),
                "refitted": [r.model for r in self.refits]}


def choose_in_scan(path: object, models: dict[str, DeepSdfModel], *, segment: object,
                   settings: ScreenSettings = ScreenSettings(), seed: int = 0,
                   final_rng: np.random.Generator | None = None) -> Choice:
    """Screen the best candidates of a scan for each of ``models`` (name -> model) and keep the
    lowest screen score: the class is the model with the lowest class score (one model: its
    lowest screen score; several: :func:`class_scores`, judged on whole clusters), the object
    that model's best candidate once each split is judged (:func:`split_or_whole`: a whole or
    its parts; a whole's refit stands in for its quick fit where it scores lower).

    ``segment(model)`` segments the scan with that model's class shape and returns its
    ``ScanCandidates`` (``jsrte.fit.query.scan_candidates``). A single model with a single
    valid candidate is not screened: its query is built with ``final_rng`` as without a screen
    (and so it is when the screen agrees with the class rank).
    The winner's segmentation records every screened candidate's score and ``chosen_by: "fit"``.
    """
    per_model = {name: segment(model) for name, model in models.items()}
    if len(models) == 1:
        (name, cands), = per_model.items()
        valid = cands.valid()
        if len(valid) == 0 or (len(valid) == 1 and not cands.segmentation.candidates[valid[0]].neck):
            return Choice(cands.query(rng=final_rng), models[name], [], {name: None})
    queries: dict[str, SdfQuery] = {}
    screened: list[Screened] = []

    def run(name: str, cands: object, picks: list[int]) -> None:
        for k in picks:
            key = _points_key(cands, k)
            if key not in queries:
                with stage("screen queries"):
                    queries[key] = cands.query(k)
            with stage("screen"):
                rank = cands.segmentation.candidates[k].summary.get("rank", 0.0)
                screened.append(screen(models[name], name, queries[key], k, settings, seed, rank))

    box_tests: dict[str, object] = {}
    for name, cands in per_model.items():
        run(name, cands, screened_candidates(cands, settings.candidates, set_aside(cands, settings, box_tests)))
        if len(models) == 1:
            run(name, cands, cut_necks(cands.segmentation.candidates, screened, settings.neck_score))
    if not screened:
        raise JsrteError("no candidate object to screen", path)
    refits: list[Screened] = []
    if len(models) > 1:
        with stage("screen"):
            classes, refits = class_scores(per_model, screened, queries, models, settings, seed)
    else:
        classes = {name: min((s.score for s in screened if s.model == name), default=None) for name in models}
    ranked = sorted((name for name in models if classes[name] is not None), key=classes.__getitem__)
    contenders = contending(classes, settings) if len(models) > 1 else ranked[:1]
    objects = {name: _object_of(name, per_model[name], screened, refits, models[name], settings, seed,
                                final_rng if len(models) == 1 else None) for name in contenders}
    winner = ranked[0]
    return Choice(objects[winner], models[winner], screened, classes, refits, objects)


def contending(classes: dict[str, float | None], settings: ScreenSettings) -> list[str]:
    """The classes whose final fits decide (:data:`ScreenSettings.final_margin`): the best by class
    score first, then up to ``final_classes`` - 1 others scoring within ``final_margin`` of it."""
    ranked = sorted((name for name, v in classes.items() if v is not None), key=classes.__getitem__)
    if not ranked or settings.final_margin <= 0:
        return ranked[:1]
    best = classes[ranked[0]]
    return ranked[:1] + [n for n in ranked[1:settings.final_classes] if classes[n] <= best + settings.final_margin]


def _object_of(name: str, cands: object, screened: list[Screened], refits: list[Screened], model: DeepSdfModel,
               settings: ScreenSettings, seed: int, final_rng: np.random.Generator | None) -> SdfQuery:
    """The object model ``name`` chose in its segmentation ``cands``: its best candidate once each
    split is judged (:func:`split_or_whole`); its query records the segmentation with every
    screened candidate's score and ``chosen_by: "fit"`` (``final_rng``: with one model, the
    query of the class rank's own choice is drawn again with it, as without a screen)."""
    own = _with_refits([s for s in screened if s.model == name], [r for r in refits if r.model == name])
    covered = _covered(cands, own, model, settings, seed)
    scores = {s.candidate: s.score for s in own}
    thin = set_aside(cands, settings)
    eligible = [s for s in own if s.candidate not in covered]
    best = min([s for s in eligible if s.candidate not in thin] or eligible,
               key=lambda s: _best_within(cands.segmentation.candidates, scores, s.candidate))
    for s in own:
        record = s.to_json() | ({"covered": True} if s.candidate in covered else {})
        cands.segmentation.candidates[s.candidate].summary["screen"] = record
    seg = cands.segmentation
    by_class = seg.chosen
    best = grow(best, cands, model, settings, seed)
    seg.chosen, seg.index, seg.how = best.candidate, seg.candidates[best.candidate].index, "fit"
    query = replace(best.query, info=dict(best.query.info))  # another model may share the candidate's query
    if best.candidate == by_class and final_rng is not None:
        query = cands.query(best.candidate, rng=final_rng)  # the same samples as without a screen
    query.info["segmentation"] = seg.to_json()
    return query


def grow(best: Screened, cands: object, model: DeepSdfModel, settings: ScreenSettings, seed: int) -> Screened:
    """``best``, or its candidate grown over the top-most cluster it was split or joined from
    (``cands``: its ``ScanCandidates``): a cut through a chair beside a box leaves the chair's
    legs with the box, and the chair's fit, which completes the chair, passes through them. The
    cluster's points within ``grow_within`` candidate radii of the fitted surface join the
    candidate; the grown candidate (a new part of the cluster, its summary's ``grown_from`` the
    candidate) is screened, and chosen when it scores at most ``best``'s plus ``grow_margin``."""
    from jsrte.scans.segment import Candidate

    candidates = cands.segmentation.candidates
    root = _root(candidates, best.candidate)
    if settings.grow_within <= 0 or root == best.candidate:
        return best
    points = np.asarray(cands.segmented.cloud.points)[cands.segmented.index]
    own, pool = candidates[best.candidate].index, candidates[root].index
    near = np.abs(predicted_sdf(model, best.result, points[pool])) <= settings.grow_within * best.parts["radius"]
    grown = np.union1d(own, pool[near])
    if len(grown) < (1.0 + settings.grow_min_share) * len(own):
        return best
    box = points[grown].min(0), points[grown].max(0)
    summary = {"points": int(len(grown)), "centre": ((box[0] + box[1]) / 2.0).round(4).tolist(),
               "grown_from": best.candidate} | (
        {"rank": candidates[best.candidate].summary["rank"]} if "rank" in candidates[best.candidate].summary else {})
    candidates.append(Candidate(index=grown, summary=summary, parent=root))
    k = len(candidates) - 1
    with stage("screen"):
        grown_screen = screen(model, best.model, cands.query(k), k, settings, seed, best.parts["rank"])
    candidates[k].summary["screen"] = grown_screen.to_json()
    return grown_screen if grown_screen.score <= best.score + settings.grow_margin else best


def class_scores(per_model: dict[str, object], screened: list[Screened], queries: dict[str, SdfQuery],
                 models: dict[str, DeepSdfModel], settings: ScreenSettings,
                 seed: int) -> tuple[dict[str, float | None], list[Screened]]:
    """Each class's score, judged on whole objects, and the refits of the contended wholes.

    Every screen of a model (``screened``; ``per_model``: name -> ``ScanCandidates``;
    ``queries``: the screened candidates' queries by :func:`_points_key`) is scored on the
    whole of its candidate's split family (its top-most ``parent``; itself when not split):
    its fitted surface at the whole's points and its violation of the whole's free space
    (:func:`screen_terms`; weighted by ``class_freespace_weight``), plus its own rank term. A
    table fitted to the mattress of a bed pays for the headboard (those points' distances are
    capped, not dropped), and every class is judged on the whole cluster, not on the part it
    explains best. A class's score is its
    best screen's. Where another class is within ``class_refit_margin`` of the best, every
    class within it (the best included) is fitted again to its whole with ``class_fit`` (a
    six-iteration quick fit of a whole bed may stop in a poor minimum) and keeps the lower of
    the two scores.

    Returns per model name its class score (None without a candidate) and the refits."""
    scores: dict[str, float] = {}
    roots: dict[str, int] = {}
    for name, cands in per_model.items():
        candidates = cands.segmentation.candidates
        for s in (s for s in screened if s.model == name):
            root = _root(candidates, s.candidate)
            terms = s.parts
            if root != s.candidate:
                terms = screen_terms(models[name], queries[_points_key(cands, root)], s.result, settings,
                                     np.random.default_rng(seed)) | {"rank": s.parts["rank"]}
            score = screen_score(terms, settings, settings.class_freespace_weight)
            if name not in scores or score < scores[name]:
                scores[name], roots[name] = score, root
    refits = []
    if scores and settings.class_refit_margin > 0:
        best = min(scores.values())
        refit_settings = replace(settings, fit=settings.class_fit)
        contended = [n for n in scores if scores[n] <= best + settings.class_refit_margin]
        for name in contended if len(contended) > 1 else []:
            cands, root = per_model[name], roots[name]
            rank = cands.segmentation.candidates[root].summary.get("rank", 0.0)
            refit = screen(models[name], name, queries[_points_key(cands, root)], root, refit_settings, seed, rank)
            refits.append(refit)
            scores[name] = min(scores[name], screen_score(refit.parts, settings, settings.class_freespace_weight))
    return {name: scores.get(name) for name in models}, refits


def _root(candidates: list, k: int) -> int:
    """The top-most whole that candidate ``k`` was split from (``k`` when it was not split)."""
    while candidates[k].parent is not None:
        k = candidates[k].parent
    return k


def _with_refits(own: list[Screened], refits: list[Screened]) -> list[Screened]:
    """``own`` screens with each candidate's refit in its stead where the refit scores lower."""
    better = {r.candidate: r for r in refits}
    return [better[s.candidate] if s.candidate in better and better[s.candidate].score < s.score else s for s in own]


def screened_candidates(cands: object, n: int, thin: set[int] = frozenset()) -> list[int]:
    """Positions of the candidates of ``cands`` (``ScanCandidates``) to screen: the best ``n``
    by class rank among those not split (slabs, ``thin``, after all others), the wholes they
    were split from, and every part of those wholes (so that each whole can be weighed against
    all its parts)."""
    candidates = cands.segmentation.candidates
    valid = cands.valid()
    picks = ([k for k in valid if k not in thin] + [k for k in valid if k in thin])[:n]
    for k in list(picks):
        above = candidates[k].parent
        while above is not None:
            if above not in picks:
                picks.append(above)
            above = candidates[above].parent
    wholes = [k for k in picks if candidates[k].parts]
    while wholes:
        for part in candidates[wholes.pop()].parts:
            if part not in picks:
                picks.append(part)
                if candidates[part].parts:
                    wholes.append(part)
    return picks


def cut_necks(candidates: list, screened: list[Screened], worse_than: float) -> list[int]:
    """Cut each screened candidate scoring worse than ``worse_than`` at its weak neck (its
    ``neck``, which segmentation refused for want of class evidence): its two parts are appended
    to ``candidates`` (the segmentation's) as its ``parts``. Returns their positions, to be
    screened (a chair and the box beside it, one candidate the model explains badly, become the
    chair and the box; :func:`split_or_whole` keeps the whole where it explains its points as
    well as its parts)."""
    added: list[int] = []
    for s in screened:
        whole = candidates[s.candidate]
        if s.score <= worse_than or not whole.neck or whole.parts or any(p.rejected for p in whole.neck):
            continue
        whole.parts = list(range(len(candidates), len(candidates) + len(whole.neck)))
        for part in whole.neck:
            part.parent = s.candidate
            candidates.append(part)
        whole.neck = []
        added += whole.parts
    return added


def thickness(points: np.ndarray) -> float:
    """Extent (m) of ``points`` (n, 3) across their thinnest direction: the 5th to 95th
    percentile along their least principal axis (a wall's remnant: 3-6 cm; a chair: 10 cm or
    more, on the tuning rooms)."""
    if len(points) < 4:
        return 0.0
    centred = points - points.mean(axis=0)
    axis = np.linalg.eigh(np.cov(centred.T))[1][:, 0]
    return float(np.ptp(np.percentile(centred @ axis, [5, 95])))


def set_aside(cands: object, settings: ScreenSettings, box_tests: dict[str, object] | None = None) -> set[int]:
    """Positions of the valid candidates of ``cands`` screened and chosen last: slabs
    (:func:`slabs`) and, with ``boxes_last`` and more than one valid candidate, boxes
    (:func:`boxes`, with ``box_tests``; a lone candidate is chosen whatever it is, and its box
    test, which may look along every line of sight near it, is spared)."""
    several = settings.boxes_last and len(cands.valid()) > 1
    return slabs(cands, settings.slab_m) | (boxes(cands, box_tests) if several else set())


def boxes(cands: object, box_tests: dict[str, object] | None = None) -> set[int]:
    """Positions of the valid candidates of ``cands`` (``ScanCandidates``) that are boxes
    (``jsrte.scans.boxes.candidate_boxes``); each one's evidence goes to its summary (``box``:
    False where it is none). ``box_tests`` (points key -> evidence JSON or False) holds the
    tests already made on the same points (under another model's segmentation) and takes the new
    ones."""
    from jsrte.scans.boxes import candidate_boxes

    box_tests = {} if box_tests is None else box_tests
    candidates = cands.segmentation.candidates
    keys = {k: _points_key(cands, k) for k in cands.valid() if "box" not in candidates[k].summary}
    todo = [k for k, key in keys.items() if key not in box_tests]
    found = candidate_boxes(cands, todo)
    for k in todo:
        box_tests[keys[k]] = found[k].to_json() if k in found else False
    for k, key in keys.items():
        candidates[k].summary["box"] = box_tests[key]
    return {k for k in cands.valid() if candidates[k].summary["box"]}


def slabs(cands: object, slab_m: float) -> set[int]:
    """Positions of the valid candidates of ``cands`` (``ScanCandidates``) thinner than
    ``slab_m`` (:func:`thickness`); each candidate's ``thickness_m`` goes to its summary."""
    if slab_m <= 0:
        return set()
    segmented = cands.segmented
    points = np.asarray(segmented.cloud.points)[segmented.index]
    thin = set()
    for k in cands.valid():
        candidate = cands.segmentation.candidates[k]
        if "thickness_m" not in candidate.summary:
            candidate.summary["thickness_m"] = round(thickness(points[candidate.index]), 4)
        if candidate.summary["thickness_m"] < slab_m:
            thin.add(k)
    return thin


def split_or_whole(candidates: list, scores: dict[int, float], explains: object = None,
                   settings: ScreenSettings = ScreenSettings()) -> set[int]:
    """The screened candidates that are not objects of their own, as the screen ``scores``
    (position -> score) judge each split (``candidates``: the segmentation's, with their
    ``parent`` and ``parts``), smallest whole first. A whole covers its parts (they are pieces
    of one object) when

    - its score is at most its parts' (their scores weighted by their points, a part split
      again counting as it was judged) plus ``whole_margin``: the whole's fit explains its
      points as well as the parts' fits explain theirs; and
    - ``explains(whole, part, objects)`` (how much farther the whole's fitted surface lies
      from the part's points than the part's own, :func:`explained_ratio`) is at most
      ``whole_explains`` for the part that would be chosen in its stead (its best-scored
      part, or that part's best when covered by it): a chair beside a box fitted as one is
      a poor chair; a bed fitted whole is as good a bed at the mattress as the mattress alone.
      ``objects``: per part, the candidates it stands for as judged (itself, or the objects
      of a part judged to hold several), for a judgement that asks it of more than one part;

    else the whole is covered by its parts (it holds several objects)."""
    covered: set[int] = set()
    judged: dict[int, float] = {}
    best_of: dict[int, int] = {}
    held: dict[int, list[int]] = {}

    def covers(whole: int) -> None:
        for part in candidates[whole].parts:
            covered.add(part)
            if candidates[part].parts:
                covers(part)

    wholes = sorted((k for k in scores if candidates[k].parts), key=lambda k: len(candidates[k].index))
    for k in wholes:  # smallest first: a whole's parts are judged before it
        parts = candidates[k].parts
        if not all(p in scores for p in parts):
            covered.add(k)
            continue
        total = sum(len(candidates[p].index) for p in parts)
        split = sum(len(candidates[p].index) / total * judged.get(p, scores[p]) for p in parts)
        best = min((best_of.get(p, p) for p in parts), key=scores.__getitem__)
        objects = [held.get(p, [p]) for p in parts]
        whole = scores[k] <= split + settings.whole_margin and (
            explains is None or explains(k, best, objects) <= settings.whole_explains)
        if whole:
            judged[k], best_of[k], held[k] = scores[k], k, [k]
            covers(k)
        else:
            judged[k], best_of[k], held[k] = split, best, [o for held_by_part in objects for o in held_by_part]
            covered.add(k)
    return covered


def explained_ratio(model: DeepSdfModel, whole: Screened, part: Screened, settings: ScreenSettings,
                    seed: int = 0, part_model: DeepSdfModel | None = None) -> float:
    """How far the fitted surface of ``whole`` (a fit of ``model``) lies from the points of
    ``part``, over how far the part's own fitted surface lies (a fit of ``part_model``, default
    ``model``), that counted at least ``explained_floor`` part radii: mean |SDF| at up to
    ``surface_points`` of the part's points, each capped at ``residual_cap`` part radii."""
    own = part_distance(part_model or model, part, part, settings, seed)
    by_whole = part_distance(model, whole, part, settings, seed)
    return distance_ratio(by_whole, own, part.parts["radius"], settings)


def part_distance(model: DeepSdfModel, fitted: Screened, part: Screened, settings: ScreenSettings,
                  seed: int = 0) -> float:
    """Mean |SDF| (m) of the fitted surface of ``fitted`` (a fit of ``model``) at up to
    ``surface_points`` of the points of ``part`` (drawn with ``seed``), each capped at
    ``residual_cap`` part radii."""
    surface = part.query.surface
    pick = np.random.default_rng(seed).permutation(len(surface))[: settings.surface_points]
    cap = settings.residual_cap * part.parts["radius"]
    return float(np.minimum(np.abs(predicted_sdf(model, fitted.result, surface[pick])), cap).mean())


def distance_ratio(by_whole: float, own: float, radius: float, settings: ScreenSettings) -> float:
    """``by_whole`` over ``own`` (mean distances, m, of a whole's and a part's own fitted surface
    from the part's points), ``own`` counted at least ``explained_floor`` times the part's
    ``radius`` (m) (:func:`explained_ratio`)."""
    return by_whole / max(own, settings.explained_floor * radius, 1e-12)


def choose_class(query: SdfQuery, models: dict[str, DeepSdfModel], *,
                 settings: ScreenSettings = ScreenSettings(), seed: int = 0) -> Choice:
    """Screen ``query`` (a mesh or samples: one object) with each of ``models``; keep the lowest."""
    screened = [screen(model, name, query, None, settings, seed) for name, model in models.items()]
    best = min(screened, key=lambda s: s.score)
    return Choice(query, models[best.model], screened, {s.model: s.score for s in screened})


def _covered(cands: object, screened: list[Screened], model: DeepSdfModel, settings: ScreenSettings,
             seed: int) -> set[int]:
    """The candidates of ``cands`` screened by ``model`` that its splits' judgement covers
    (:func:`split_or_whole`)."""
    by_candidate = {s.candidate: s for s in screened}

    def explains(whole: int, part: int, objects: list[list[int]]) -> float:
        return explained_ratio(model, by_candidate[whole], by_candidate[part], settings, seed)

    return split_or_whole(cands.segmentation.candidates, {k: s.score for k, s in by_candidate.items()}, explains,
                          settings)


def _best_within(candidates: list, scores: dict[int, float], k: int) -> float:
    """The lowest of the screen ``scores`` of candidate ``k`` and of the parts it holds (a whole
    that covers its parts is as good an object as its best part: it is that part, completed)."""
    return min([scores[k]] + [_best_within(candidates, scores, p) for p in candidates[k].parts if p in scores])


def _points_key(cands: object, k: int) -> str:
    """A key of the candidate's points (the same points under two models' segmentations share a query)."""
    index = np.sort(cands.segmentation.candidates[k].index)
    return hashlib.sha1(index.tobytes()).hexdigest()
