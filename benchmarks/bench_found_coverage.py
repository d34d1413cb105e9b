"""How the coverage a found object needs (``jsrte.fit.scene.COVERED_FOUND``) trades objects found
against false detections, from ``jsrte experiment scenes`` rows.

``python benchmarks/bench_found_coverage.py OBJECTS.csv [OBJECTS.csv ...] [--bounds 0.15,0.2,0.23]``

Each CSV is the objects.csv of a scenes experiment (its ``outcome``, ``fscore`` and
``quality_surface_coverage`` columns). The bound is replayed on the recorded fits: a fit whose
candidate's points cover less than the bound of its fitted surface is no object, so a hit below
it becomes a miss and a false detection below it goes. Only bounds at or above the one the rows
were made with say anything (fits below that one are not in the rows). Printed per bound: the
pieces of furniture, those found, the false detections, detection recall and precision, and the
mean F@5% of the found objects (and with the misses counted as 0).
"""

from __future__ import annotations

import csv
from pathlib import Path

from replay_bounds import rows_and_bounds

from jsrte.fit.scene import COVERED_FOUND

DEFAULT_BOUNDS = (0.15, 0.17, 0.19, 0.21, 0.22, 0.23, 0.24, 0.25, 0.28, 0.3)


def read_rows(paths: list[Path]) -> list[dict]:
    """The rows of every objects.csv in ``paths`` that are a piece of furniture (hit or missed) or
    a false detection, each with its ``coverage`` (None where not recorded) and ``fscore``."""
    rows = []
    for path in paths:
        with open(path, newline="") as f:
            for row in csv.DictReader(f):
                if row["outcome"] not in ("hit", "missed", "false positive"):
                    continue
                coverage = row.get("quality_surface_coverage")
                rows.append({"outcome": row["outcome"], "coverage": float(coverage) if coverage else None,
                             "fscore": float(row["fscore"]) if row.get("fscore") else 0.0})
    return rows


def replay(rows: list[dict], bound: float) -> dict[str, float | int]:
    """Counts and rates of ``rows`` if every fit covered less than ``bound`` were no object."""
    def kept(row: dict) -> bool:
        return row["coverage"] is None or row["coverage"] >= bound

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
    paths, bounds = rows_and_bounds(__doc__, DEFAULT_BOUNDS)
    rows = read_rows(paths)
    print(f"shipped bound: {COVERED_FOUND}")
    print("| bound | furniture | found | false detections | recall | precision | mean F@5% (misses 0) |")
    print("|---|---|---|---|---|---|---|")
    for bound in bounds:
        r = replay(rows, bound)
        print(f"| {bound:g} | {r['furniture']} | {r['found']} | {r['false']} | {r['recall']:.3f} | "
              f"{r['precision']:.3f} | {r['mean_f']:.3f} ({r['mean_f_misses_0']:.3f}) |")


if __name__ == "__main__":
    main()
