"""Fit settings variants on prepared scans: F@5% against the complete true shape, time, evaluations.

How the defaults of `fast` are chosen (docs/presets.md). First make the query files with
``bench_presets.py prepare`` (held-out chairs; the tuning set is shapes 100..119, scan seed 5,
which Table 2 (shapes 0..29) does not use), then run variants of the ``fast`` fit settings::

    .venv/bin/python benchmarks/bench_presets.py prepare --first-shape 100 --scans 20 --seed 5 --out runs/tune
    .venv/bin/python benchmarks/bench_fit_variants.py runs/tune --out runs/tune/raw.csv latent_space=raw

Each ``KEY=VALUE`` replaces a field of the fit settings of ``--preset`` (default ``fast``; numbers
and booleans as JSON).
Rows are written as they finish (with the fit's flag and the quality measures the flag reads); the
mean is printed at the end.
"""

from __future__ import annotations

import argparse
import csv
import json
import pickle
import statistics
import time
from dataclasses import replace
from pathlib import Path

PARTS = ("yaw screening", "retrieval", "starts", "translation search", "code scoring", "survivors", "adam stage",
         "refine", "polish", "final losses")
"""The parts of a Levenberg–Marquardt solve whose decoder evaluations are reported apart."""
FLAG_MEASURES = ("inlier_share", "loss_margin_rel", "free_space_violation", "latent_mahalanobis_ratio",
                 "surface_coverage")
"""The quality measures the flag reads (jsrte.fit.quality.RULE), one column each."""


def settings_from(pairs: list[str], preset: str = "fast"):
    from jsrte.presets import get_preset

    changes = {}
    for pair in pairs:
        key, _, value = pair.partition("=")
        try:
            changes[key] = json.loads(value)
        except json.JSONDecodeError:
            changes[key] = value
    return replace(get_preset(preset).fit, **changes)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("folder", help="A bench_presets.py prepare folder.")
    parser.add_argument("--out", required=True, help="CSV of per-scan rows.")
    parser.add_argument("--model", default="chair")
    parser.add_argument("--preset", default="fast", help="Whose fit settings the KEY=VALUE changes start from.")
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--scans", default=None, help="Comma-separated scan names (default: every scan).")
    parser.add_argument("changes", nargs="*", help="KEY=VALUE fields of FitSettings.")
    args = parser.parse_intermixed_args()

    import numpy as np
    import torch

    from jsrte.experiments.truth import score_against_truth
    from jsrte.fit.query import read_query_file
    from jsrte.fit.solve import fit_query
    from jsrte.model.registry import resolve_model
    from jsrte.timing import profiling

    torch.set_num_threads(args.threads)
    settings = settings_from(args.changes, args.preset)
    folder = Path(args.folder)
    truths = pickle.loads((folder / "truths.pkl").read_bytes())
    model = resolve_model(args.model)
    rows = []
    only = None if args.scans is None else set(args.scans.split(","))
    for name, truth in sorted(truths.items()):
        if only is not None and name not in only:
            continue
        if not (folder / f"{name}.npz").exists():
            print(f"no query file for {name}: skipped", flush=True)
            continue
        query = read_query_file(folder / f"{name}.npz")
        started = time.perf_counter()
        with profiling() as profile:
            result = fit_query(model, query, settings, seed=args.seed)
        seconds = time.perf_counter() - started
        score = score_against_truth(result, truth, rng=np.random.default_rng(args.seed))
        rows.append({"scan": name, "fscore": round(score["fscore"], 4),
                     "rotation_error_deg": round(score["rotation_error_deg"], 2),
                     "scale_error_rel": round(score["scale_error_rel"], 4),
                     "translation_error": round(score["translation_error"], 4), "seconds": round(seconds, 1),
                     "optimize_s": result.timing["optimize"], "iterations": result.info["iterations"],
                     "decoder_evaluations": result.info["decoder_evaluations"],
                     "criterion": round(result.criterion["value"], 4),
                     **{f"ev_{part.replace(' ', '_')}": result.info.get("decoder_evaluations_by_part", {}).get(part, 0)
                        for part in PARTS},
                     "ev_meshing": profile.evaluations.get("meshing", 0),
                     "ev_quality": profile.evaluations.get("quality", 0),
                     "flag": result.flag,
                     **{f"q_{k}": (result.quality or {}).get(k) for k in FLAG_MEASURES}})
        print(rows[-1], flush=True)
        with open(args.out, "w", newline="") as f:
            writer = csv.DictWriter(f, fieldnames=list(rows[0]))
            writer.writeheader()
            writer.writerows(rows)
    scores = [r["fscore"] for r in rows]
    parts = {part: statistics.mean(r[f"ev_{part.replace(' ', '_')}"] for r in rows)
             for part in (*PARTS, "meshing", "quality")}
    if any(parts.values()):
        print("mean evaluations by part: " + ", ".join(f"{k} {v:,.0f}" for k, v in parts.items()))
    print(f"{len(rows)} scans: mean F@5% {statistics.mean(scores):.3f}, median {statistics.median(scores):.3f}, "
          f"mean evaluations {statistics.mean(r['decoder_evaluations'] for r in rows):,.0f}, "
          f"mean optimize {statistics.mean(r['optimize_s'] for r in rows):.1f} s; "
          f"preset {args.preset}, settings changed: {args.changes or 'none'}")


if __name__ == "__main__":
    main()
