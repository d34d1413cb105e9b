"""Scoring a fitted scene against its truth: which found object is which true one, and the tallies.

A found object *matches* a true one when its centre lies within ``MATCH_FRACTION`` of the true
object's bounding-sphere radius of the true centre (centres: bounding-box centres, scan units);
each true object takes at most one found object and each found one at most one true object
(the pairing that makes the most matches, then the smallest summed relative distance: Hungarian
assignment).

Only furniture (the shipped classes, ``FURNITURE``) is to be found. A box is clutter no model
covers: a found object on a box is neither a hit nor a false positive, it is counted apart (and
should be flagged doubtful); a box nobody found is no miss. A scene also reports boxes (class
``BOX``, not fitted): one on a true box is a box found, one on furniture leaves that furniture
missed, one on nothing is a false box; none counts as a hit or a false positive.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from jsrte.shapes import CATEGORIES

MATCH_FRACTION = 0.3
"""A found centre within this fraction of the true object's bounding-sphere radius matches."""
BAD_FSCORE = 0.7
"""A fit with F@5% below this is bad: the flag should call it doubtful."""
GOOD_FSCORE = 0.85
"""A fit with F@5% at least this is good: the flag should leave it ok."""
FURNITURE = CATEGORIES
"""The classes to be found (those the shipped models cover)."""
MISSED = "missed"
"""The confusion matrix's column of true objects nobody found."""

BOX = "box"
"""The class of a box, true or reported by a scene."""

HIT, MISS, FALSE_POSITIVE, ON_BOX, BOX_UNFOUND = "hit", "missed", "false positive", "on box", "box not found"
BOX_FOUND, FALSE_BOX = "box found", "false box"
"""Outcomes of an object row: a true furniture object found (hit) or not (missed, also where a
reported box stands on it); a found object matching nothing (false positive) or a box (on box);
a box no object matched, or one a reported box matched (box found); a reported box matching
nothing (false box)."""


@dataclass(frozen=True)
class TrueObject:
    """One true object of a room: its index in the room, class ("box" for clutter), bounding-box
    centre (3,) and bounding-sphere radius about it (scan units)."""

    index: int
    kind: str
    centre: np.ndarray
    radius: float


@dataclass(frozen=True)
class FoundObject:
    """One fitted object of a scene: its index in the scene, class, centre (3,) (bounding-box
    centre of the retrieved mesh, scan units) and flag ("ok" / "doubtful")."""

    index: int
    kind: str
    centre: np.ndarray
    flag: str | None = None


def match_objects(true: list[TrueObject], found: list[FoundObject],
                  fraction: float = MATCH_FRACTION) -> dict[int, int]:
    """One-to-one matches {position in ``found``: position in ``true``}: a pair may match when
    the found centre lies within ``fraction`` × the true radius of the true centre; among the
    pairings, the most matches, then the smallest summed distance over radius."""
    from scipy.optimize import linear_sum_assignment

    if not true or not found:
        return {}
    distance = np.array([[np.linalg.norm(np.asarray(f.centre, float) - np.asarray(t.centre, float)) / t.radius
                          for t in true] for f in found])
    allowed = distance < fraction
    cost = np.where(allowed, distance, fraction * (len(found) + len(true)) + 1.0)
    rows, cols = linear_sum_assignment(cost)
    return {int(r): int(c) for r, c in zip(rows, cols, strict=True) if allowed[r, c]}


def object_rows(true: list[TrueObject], found: list[FoundObject],
                fraction: float = MATCH_FRACTION) -> list[dict]:
    """One row per true object (with the found object matched to it, if any), then one per found
    object that matched none: ``true_index``, ``true_class``, ``found_index``, ``found_class``,
    ``flag``, ``distance_rel`` (found centre to true centre over the true radius) and ``outcome``
    (``HIT``, ``MISS``, ``ON_BOX``, ``BOX_UNFOUND``, ``BOX_FOUND``, ``FALSE_POSITIVE`` or
    ``FALSE_BOX``). Found objects of class :data:`BOX` are the boxes a scene reported."""
    matches = match_objects(true, found, fraction)
    by_true = {t: f for f, t in matches.items()}
    rows = []
    for k, t in enumerate(true):
        furniture = t.kind in FURNITURE
        row = {"true_index": t.index, "true_class": t.kind, "found_index": None, "found_class": None,
               "flag": None, "distance_rel": None}
        if k in by_true:
            f = found[by_true[k]]
            row.update(found_index=f.index, found_class=f.kind, flag=f.flag,
                       distance_rel=float(np.linalg.norm(np.asarray(f.centre) - t.centre) / t.radius),
                       outcome=_matched_outcome(furniture, f.kind == BOX))
        else:
            row["outcome"] = MISS if furniture else BOX_UNFOUND
        rows.append(row)
    for k, f in enumerate(found):
        if k not in matches:
            rows.append({"true_index": None, "true_class": None, "found_index": f.index, "found_class": f.kind,
                         "flag": f.flag, "distance_rel": None,
                         "outcome": FALSE_BOX if f.kind == BOX else FALSE_POSITIVE})
    return rows


def _matched_outcome(furniture: bool, box_found: bool) -> str:
    """The outcome of a true object (furniture or a box) matched by a found one (a fitted object
    or a reported box)."""
    if furniture:
        return MISS if box_found else HIT
    return BOX_FOUND if box_found else ON_BOX


def detection(rows: list[dict]) -> dict[str, float | int | None]:
    """Detection tallies of object rows (any number of rooms): recall = hits / true furniture,
    precision = hits / (hits + false positives) (found objects on boxes left out of both), class
    accuracy over the hits, the found objects on boxes with the share flagged doubtful, and the
    reported boxes: on true boxes, on furniture, on nothing."""
    outcomes = (HIT, MISS, FALSE_POSITIVE, ON_BOX, BOX_UNFOUND, BOX_FOUND, FALSE_BOX)
    count = {o: sum(r["outcome"] == o for r in rows) for o in outcomes}
    hits = [r for r in rows if r["outcome"] == HIT]
    on_box = [r for r in rows if r["outcome"] == ON_BOX]
    return {
        "true_furniture": count[HIT] + count[MISS], "found": count[HIT] + count[FALSE_POSITIVE] + count[ON_BOX],
        "hits": count[HIT], "missed": count[MISS], "false_positives": count[FALSE_POSITIVE],
        "found_on_boxes": count[ON_BOX], "boxes": count[ON_BOX] + count[BOX_UNFOUND] + count[BOX_FOUND],
        "boxes_found": count[BOX_FOUND], "false_boxes": count[FALSE_BOX],
        "furniture_as_boxes": sum(r["outcome"] == MISS and r["found_class"] == BOX for r in rows),
        "recall": _share(count[HIT], count[HIT] + count[MISS]),
        "precision": _share(count[HIT], count[HIT] + count[FALSE_POSITIVE]),
        "class_accuracy": _share(sum(r["found_class"] == r["true_class"] for r in hits), len(hits)),
        "boxes_flagged_doubtful": _share(sum(r["flag"] == "doubtful" for r in on_box), len(on_box)),
    }


def fit_quality(rows: list[dict]) -> dict[str, float | int | None]:
    """Over the hits that carry ``fscore`` (F@5% against the complete true shape): its mean and
    median, the mean with every missed furniture object as 0; over hits given their true class,
    the median ``rotation_error_deg`` and ``scale_error_rel``; and the flag as a detector of bad
    fits (F < ``BAD_FSCORE``): precision, recall, and the share of good fits (F ≥ ``GOOD_FSCORE``)
    it flags."""
    scored = [r for r in rows if r["outcome"] == HIT and r.get("fscore") is not None]
    f = np.array([r["fscore"] for r in scored], float)
    missed = sum(r["outcome"] == MISS for r in rows)
    right = [r for r in scored if r["found_class"] == r["true_class"]]
    bad = f < BAD_FSCORE
    doubtful = np.array([r["flag"] == "doubtful" for r in scored], bool)
    good = f >= GOOD_FSCORE
    return {
        "scored": len(scored), "fscore_mean": _mean(f), "fscore_median": _median(f),
        "fscore_mean_misses_zero": _mean(np.concatenate([f, np.zeros(missed)])),
        "fits_below_0.7": int(bad.sum()), "fits_at_least_0.85": int(good.sum()),
        "rotation_error_deg_median": _median([r["rotation_error_deg"] for r in right
                                              if r.get("rotation_error_deg") is not None]),
        "scale_error_rel_median": _median([r["scale_error_rel"] for r in right
                                           if r.get("scale_error_rel") is not None]),
        "flag_precision": _share(int((bad & doubtful).sum()), int(doubtful.sum())),
        "flag_recall": _share(int((bad & doubtful).sum()), int(bad.sum())),
        "good_fits_flagged": _share(int((good & doubtful).sum()), int(good.sum())),
    }


def confusion(rows: list[dict]) -> dict[str, dict[str, int]]:
    """{true class: {found class or ``MISSED``: count}} over the true objects (furniture, then
    boxes when there are any); columns: every shipped class, any other class found, ``MISSED``."""
    found_classes = sorted({r["found_class"] for r in rows if r["true_class"] and r["found_class"]} - set(FURNITURE))
    columns = list(FURNITURE) + found_classes + [MISSED]
    kinds = list(FURNITURE) + sorted({r["true_class"] for r in rows if r["true_class"]} - set(FURNITURE))
    table = {k: dict.fromkeys(columns, 0) for k in kinds}
    for r in rows:
        if r["true_class"]:
            table[r["true_class"]][r["found_class"] or MISSED] += 1
    return table


def _share(part: int, whole: int) -> float | None:
    return None if whole == 0 else round(part / whole, 4)


def _mean(values: object) -> float | None:
    values = np.asarray(values, float)
    return None if not len(values) else round(float(values.mean()), 4)


def _median(values: object) -> float | None:
    values = np.asarray(values, float)
    return None if not len(values) else round(float(np.median(values)), 4)
