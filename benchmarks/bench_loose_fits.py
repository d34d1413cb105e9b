"""How the bound under which a found scene object's fit holds its points too loosely
(``jsrte.fit.scene_checks.LOOSE_SDF_REL_MAX``), alone or with a bound on the inlier share, trades bad
fits caught against good fits flagged, from ``jsrte experiment scenes`` rows.

``python benchmarks/bench_loose_fits.py OBJECTS.csv [OBJECTS.csv ...] [--distances inf,0.011] [--inliers 0,0.75]``

Each CSV is the objects.csv of a scenes experiment (its ``outcome``, ``fscore``, ``flag``,
``quality_mean_abs_sdf_rel`` and ``quality_inlier_share`` columns). Each pair of bounds is
replayed on the recorded fits of the found furniture (hits): a fit whose points lie at more
than the distance bound of its radius from it on average, or on fewer than the inlier bound of
which it lies, becomes ``doubtful``. The rows' own ``doubtful`` flags are kept, so only rows made
without the bound (or with a looser one) say how much each adds. Printed per pair: the bad fits
(F@5% < 0.7) and how many are flagged, the good ones (F@5% >= 0.85) and how many are flagged;
then the fits the shipped bound flags that the rows had ``ok`` (room, class, F@5%).
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

from replay_bounds import read_hits

from jsrte.fit.scene_checks import LOOSE_SDF_REL_MAX

BAD_BELOW, GOOD_FROM = 0.7, 0.85


def loose(hit: dict, distance_max: float, inliers_min: float = 0.0) -> bool:
    """Whether ``hit``'s fit holds its points more loosely than the bounds allow."""
    return ((hit["distance"] is not None and hit["distance"] > distance_max)
            or (hit["inliers"] is not None and hit["inliers"] < inliers_min))


def replay(hits: list[dict], distance_max: float, inliers_min: float) -> dict[str, int]:
    """Bad and good fits of ``hits``, and how many of each are doubtful with the two bounds."""
    def flagged(h: dict) -> bool:
        return h["doubtful"] or loose(h, distance_max, inliers_min)

    bad = [h for h in hits if h["fscore"] < BAD_BELOW]
    good = [h for h in hits if h["fscore"] >= GOOD_FROM]
    return {"bad": len(bad), "bad_caught": sum(map(flagged, bad)),
            "good": len(good), "good_flagged": sum(map(flagged, good))}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("objects", nargs="+", type=Path, help="objects.csv of a scenes experiment")
    parser.add_argument("--distances", default=f"inf,0.01,{LOOSE_SDF_REL_MAX},0.012",
                        help="bounds on the mean distance over the radius (inf: none)")
    parser.add_argument("--inliers", default="0,0.7,0.75,0.8", help="inlier-share bounds (0: none)")
    args = parser.parse_args()
    hits = read_hits(args.objects, {"distance": "quality_mean_abs_sdf_rel", "inliers": "quality_inlier_share"})
    print(f"shipped bound: mean distance {LOOSE_SDF_REL_MAX} of the radius, no inlier-share bound")
    print("| distance above | inlier share below | bad fits caught | good fits flagged |")
    print("|---|---|---|---|")
    for distance_max in (float(b) for b in args.distances.split(",")):
        for inliers_min in (float(b) for b in args.inliers.split(",")):
            r = replay(hits, distance_max, inliers_min)
            print(f"| {distance_max if math.isfinite(distance_max) else '–'} | {inliers_min or '–'} | "
                  f"{r['bad_caught']} of {r['bad']} ({r['bad_caught'] / max(r['bad'], 1):.2f}) | "
                  f"{r['good_flagged']} of {r['good']} ({r['good_flagged'] / max(r['good'], 1):.2f}) |")
    newly = [h for h in hits if not h["doubtful"] and loose(h, LOOSE_SDF_REL_MAX)]
    print("flagged by the shipped bound, ok in the rows:",
          ", ".join(f"room {h['room']} {h['class']} ({h['fscore']:.2f})" for h in newly) or "none")


if __name__ == "__main__":
    main()
