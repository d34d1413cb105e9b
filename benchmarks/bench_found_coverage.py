"""How the coverage a found object needs (``jsrte.fit.scene_checks.COVERED_FOUND``), the share of it the
cameras may see through (``SEEN_THROUGH_FOUND_MAX``, with ``--seen-through``), or the share of its
points its fit must lie on (``FOUND_SHARE``, with ``--inlier``) trades objects found against false
detections, from ``jsrte experiment scenes`` rows.

``python benchmarks/bench_found_coverage.py OBJECTS.csv [...] [--bounds 0.15,0.2,0.23] [--seen-through | --inlier]``

Each CSV is the objects.csv of a scenes experiment (its ``outcome``, ``fscore`` and
``quality_surface_coverage``, ``quality_seen_through`` or ``quality_inlier_share`` columns). The
bound is replayed on the recorded fits: a fit whose candidate's points cover less than the bound
of its fitted surface (whose surface was seen through on more than it; which lies on less than it
of its points) is no object, so a hit beyond it becomes a miss and a false detection beyond it
goes. Only bounds no looser than the one the rows were made
with say anything (fits beyond that one are not in the rows). Printed per bound: the pieces of
furniture, those found, the false detections, detection recall and precision, and the mean
F@5% of the found objects (and with the misses counted as 0).
"""

from __future__ import annotations

import csv
from pathlib import Path

from replay_bounds import rows_and_bounds

from jsrte.fit.scene_checks import COVERED_FOUND, FOUND_SHARE, SEEN_THROUGH_FOUND_MAX

DEFAULT_BOUNDS = (0.15, 0.17, 0.19, 0.21, 0.22, 0.23, 0.24, 0.25, 0.28, 0.3)
SEEN_THROUGH_BOUNDS = (0.13, 0.15, 0.2, 0.25, 0.28, 0.3, 0.32, 0.35, 0.4)
INLIER_BOUNDS = (0.2, 0.4, 0.5, 0.55, 0.6, 0.62, 0.64, 0.66, 0.7)

SWITCHES = (("--seen-through", SEEN_THROUGH_BOUNDS, "replay the seen-through bound, not the coverage one"),
            ("--inlier", INLIER_BOUNDS, "replay the share of its points a found object's fit lies on"))
COLUMNS = {None: ("quality_surface_coverage", COVERED_FOUND, True),
           "--seen-through": ("quality_seen_through", SEEN_THROUGH_FOUND_MAX, False),
           "--inlier": ("quality_inlier_share", FOUND_SHARE, True)}
"""Per switch: the objects.csv column replayed, the shipped bound, and whether a value below the
bound is no object (else above it)."""


def read_rows(paths: list[Path], column: str) -> list[dict]:
    """The rows of every objects.csv in ``paths`` that are a piece of furniture (hit or missed) or
    a false detection, each with its ``value`` of ``column`` (None where not recorded) and
    ``fscore``."""
    rows = []
    for path in paths:
        with open(path, newline="") as f:
            for row in csv.DictReader(f):
                if row["outcome"] not in ("hit", "missed", "false positive"):
                    continue
                value = row.get(column)
                rows.append({"outcome": row["outcome"], "value": float(value) if value else None,
                             "fscore": float(row["fscore"]) if row.get("fscore") else 0.0})
    return rows


def replay(rows: list[dict], bound: float, *, lower: bool = True) -> dict[str, float | int]:
    """Counts and rates of ``rows`` if every fit whose value lies below ``bound`` (``lower``; else
    above it) were no object."""
    def kept(row: dict) -> bool:
        return row["value"] is None or (row["value"] >= bound if lower else row["value"] <= bound)

    furniture = sum(r["outcome"] in ("hit", "missed") for r in rows)
    hits = [r for r in rows if r["outcome"] == "hit" and kept(r)]
    false = sum(r["outcome"] == "false positive" and kept(r) for r in rows)
    scores = [r["fscore"] for r in hits]
    return {"furniture": furniture, "found": len(hits), "false": false,
            "recall": len(hits) / furniture if furniture else 0.0,
            "precision": len(hits) / (len(hits) + false) if hits or false else 0.0,
            "mean_f": sum(scores) / len(scores) if scores else 0.0,
            "mean_f_misses_0": sum(scores) / furniture if furniture else 0.0}


def main() -> None:
    paths, bounds, switch = rows_and_bounds(__doc__, DEFAULT_BOUNDS, SWITCHES)
    column, shipped, lower = COLUMNS[switch]
    rows = read_rows(paths, column)
    print(f"shipped bound: {shipped}")
    print("| bound | furniture | found | false detections | recall | precision | mean F@5% (misses 0) |")
    print("|---|---|---|---|---|---|---|")
    for bound in bounds:
        r = replay(rows, bound, lower=lower)
        print(f"| {bound:g} | {r['furniture']} | {r['found']} | {r['false']} | {r['recall']:.3f} | "
              f"{r['precision']:.3f} | {r['mean_f']:.3f} ({r['mean_f_misses_0']:.3f}) |")


if __name__ == "__main__":
    main()
