"""How well the fit's flag ("ok" / "doubtful") catches bad fits, from ``jsrte experiment scans`` results.

``python benchmarks/bench_flag.py RESULTS.csv [RESULTS.csv ...] [--search]``

Each CSV is the results.csv of a scan experiment run with ``--methods jsrte`` (it has the
``truth_fscore`` and ``quality_*`` columns). A fit is bad when its F@5% against the complete true
shape is below 0.7 and good when it is at least 0.85; a failed fit counts as bad and flagged. The
flag is recomputed from the quality columns with the rule of ``jsrte.fit.quality.RULE`` (so older
CSVs are judged by the current rule). Printed, per file and for all together: fits, bad fits,
the share of bad fits flagged (recall; aim >= 0.80), the share of good fits flagged (aim <= 0.10),
and the share of flagged fits that are bad (precision).

``--search`` also lists the rules on a grid of thresholds that meet both aims on these files
(use it on a tuning set only, never on the set the figures are reported on).
"""

from __future__ import annotations

import argparse
import csv
import itertools
from pathlib import Path

from jsrte.fit.quality import RULE, flag_of

BAD, GOOD = 0.7, 0.85
"""F@5% below BAD: a fit the flag should catch; at least GOOD: a fit it should leave alone."""
MEASURES = ("inlier_share", "loss_margin_rel", "free_space_violation", "latent_mahalanobis_ratio", "surface_coverage")


def read_fits(path: Path) -> list[dict]:
    """The jsrte rows of a results.csv: truth F@5% (0 for a failed fit) and the quality measures."""
    fits = []
    with open(path, newline="") as f:
        for row in csv.DictReader(f):
            if row.get("method", "jsrte") != "jsrte":
                continue
            ok = row["status"] == "ok"
            quality = {m: _number(row.get(f"quality_{m}")) for m in MEASURES} if ok else {}
            fits.append({"scan": row["scan"], "fscore": _number(row.get("truth_fscore")) or 0.0 if ok else 0.0,
                         "quality": quality, "failed": not ok})
    return fits


def _number(text: str | None) -> float | None:
    return None if text in (None, "") else float(text)


def rates(fits: list[dict], rule: dict[str, float]) -> dict[str, float | int | None]:
    """Counts and the flag's recall on bad fits and false-alarm rate on good ones under ``rule``."""
    flagged = [f["failed"] or flag_of(f["quality"], rule) == "doubtful" for f in fits]
    bad = [g for f, g in zip(fits, flagged, strict=True) if f["fscore"] < BAD]
    good = [g for f, g in zip(fits, flagged, strict=True) if f["fscore"] >= GOOD]
    flagged_bad = sum(g and f["fscore"] < BAD for f, g in zip(fits, flagged, strict=True))
    return {"fits": len(fits), "bad": len(bad), "good": len(good), "flagged": sum(flagged),
            "bad_caught": sum(bad) / len(bad) if bad else None,
            "good_flagged": sum(good) / len(good) if good else None,
            "precision": flagged_bad / sum(flagged) if any(flagged) else None}


def _row(name: str, r: dict) -> str:
    def share(v: float | None) -> str:
        return "–" if v is None else f"{v:.2f}"
    return (f"| {name} | {r['fits']} | {r['bad']} | {r['good']} | {r['flagged']} | "
            f"{share(r['bad_caught'])} | {share(r['good_flagged'])} | {share(r['precision'])} |")


def search(fits: list[dict]) -> list[tuple[dict, dict]]:
    """Rules on a grid that meet both aims on ``fits``, best (most bad fits caught, fewest good
    flagged, then the loosest thresholds) first."""
    found = []
    for inliers, margin, violation, code, coverage in itertools.product(
            [x / 100 for x in range(0, 96, 5)], [0.0, 0.02, 0.05, 0.1, 0.15, 0.2, 0.3], [0.01, 0.02, 0.05, 1.0],
            [0.8, 0.9, 1.0, 1.1, 1.2, 1.5, 2.0, 1e9], [0.0, 0.2, 0.25, 0.3, 0.35, 0.4, 0.45]):
        rule = {"inlier_share_min": inliers, "loss_margin_min": margin, "free_space_violation_max": violation,
                "latent_mahalanobis_ratio_max": code, "surface_coverage_min": coverage}
        r = rates(fits, rule)
        if (r["bad_caught"] or 0) >= 0.8 and (r["good_flagged"] or 0) <= 0.1:
            found.append((rule, r))
    return sorted(found, key=lambda x: (-(x[1]["bad_caught"] or 0), x[1]["good_flagged"] or 0,
                                        x[0]["inlier_share_min"], x[0]["loss_margin_min"],
                                        -x[0]["free_space_violation_max"], -x[0]["latent_mahalanobis_ratio_max"],
                                        x[0]["surface_coverage_min"]))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("results", nargs="+", type=Path)
    parser.add_argument("--search", action="store_true", help="List the grid's rules that meet both aims.")
    args = parser.parse_args()
    every: list[dict] = []
    print(f"rule: {RULE}; bad: F@5% < {BAD}, good: F@5% >= {GOOD}; aims: bad caught >= 0.80, good flagged <= 0.10")
    print("| results | fits | bad | good | flagged | bad caught (recall) | good flagged | precision |")
    print("|---|---|---|---|---|---|---|---|")
    for path in args.results:
        fits = read_fits(path)
        every += fits
        print(_row(path.parent.name, rates(fits, RULE)))
    print(_row("all", rates(every, RULE)))
    if args.search:
        found = search(every)
        print(f"{len(found)} rules on the grid meet both aims" + (":" if found else ""))
        for rule, r in found[:15]:
            print(f"  {rule}: bad caught {r['bad_caught']:.2f}, good flagged {r['good_flagged']:.2f}")


if __name__ == "__main__":
    main()
