"""How the coverage under which a barely preferred class makes a scene object's fit doubtful
(``jsrte.fit.scene_checks.UNSURE_COVERED_MIN``, with ``UNSURE_CLASS_MARGIN``) trades bad fits caught
against good fits flagged, from ``jsrte experiment scenes`` rows.

``python benchmarks/bench_unsure_coverage.py OBJECTS.csv [OBJECTS.csv ...] [--bounds 0.35,0.39,0.43]``

Each CSV is the objects.csv of a scenes experiment (its ``outcome``, ``fscore``, ``flag``,
``class_margin`` and ``quality_surface_coverage`` columns). The bound is replayed on the
recorded fits of the found furniture (hits): a fit flagged ``ok`` whose class margin is below
``UNSURE_CLASS_MARGIN`` and whose candidate's points cover less than the bound of its fitted
surface becomes ``doubtful``. Only bounds at or above the one the rows were made with say
anything (the rows' ``doubtful`` flags are kept). Printed per bound: the bad fits (F@5% < 0.7)
and how many are flagged, the good ones (F@5% >= 0.85) and how many are flagged.
"""

from __future__ import annotations

from replay_bounds import read_hits, rows_and_bounds

from jsrte.fit.scene_checks import UNSURE_CLASS_MARGIN, UNSURE_COVERED_MIN

DEFAULT_BOUNDS = (0.35, 0.37, 0.39, 0.41, 0.42, 0.43, 0.44, 0.45, 0.47)
BAD_BELOW, GOOD_FROM = 0.7, 0.85


def flagged(hit: dict, bound: float) -> bool:
    """Whether ``hit`` is doubtful with ``bound`` in place of the rows' class-margin coverage bound."""
    unsure = hit["margin"] is not None and hit["margin"] < UNSURE_CLASS_MARGIN
    return hit["doubtful"] or (unsure and hit["coverage"] is not None and hit["coverage"] < bound)


def replay(hits: list[dict], bound: float) -> dict[str, int]:
    """Bad and good fits of ``hits``, and how many of each ``bound`` flags."""
    bad = [h for h in hits if h["fscore"] < BAD_BELOW]
    good = [h for h in hits if h["fscore"] >= GOOD_FROM]
    return {"bad": len(bad), "bad_caught": sum(flagged(h, bound) for h in bad),
            "good": len(good), "good_flagged": sum(flagged(h, bound) for h in good)}


def main() -> None:
    paths, bounds, _ = rows_and_bounds(__doc__, DEFAULT_BOUNDS)
    hits = read_hits(paths, {"margin": "class_margin", "coverage": "quality_surface_coverage"})
    print(f"shipped bound: {UNSURE_COVERED_MIN} (class margin below {UNSURE_CLASS_MARGIN})")
    print("| bound | bad fits caught | good fits flagged |")
    print("|---|---|---|")
    for bound in bounds:
        r = replay(hits, bound)
        print(f"| {bound:g} | {r['bad_caught']} of {r['bad']} ({r['bad_caught'] / max(r['bad'], 1):.2f}) | "
              f"{r['good_flagged']} of {r['good']} ({r['good_flagged'] / max(r['good'], 1):.2f}) |")


if __name__ == "__main__":
    main()
