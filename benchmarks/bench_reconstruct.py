"""Latent-only reconstruction (``jsrte reconstruct``) by Adam (DeepSDF's recipe) and by
Levenberg–Marquardt, on held-out meshes of the evaluation seed set: F@5% against the
normalized input (as ``jsrte evaluate-model``), solver seconds, iterations, decoder evaluations,
with and without the training-code start (``--code-starts 0,1``)::

    .venv/bin/python benchmarks/bench_reconstruct.py --first 100 --meshes 5 --out runs/reconstruct.csv

Indices 0..19 are the model card's held-out shapes; choose settings on others (e.g. 100..).
"""

from __future__ import annotations

import argparse
import csv
import itertools
import statistics
from dataclasses import replace
from pathlib import Path


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--model", default="chair")
    parser.add_argument("--first", type=int, default=100, help="First held-out shape index.")
    parser.add_argument("--meshes", type=int, default=5)
    parser.add_argument("--solvers", default="gauss-newton,adam")
    parser.add_argument("--resolution", type=int, default=96)
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--code-starts", default="1",
                        help="Training-code starts beside the zero code; several, comma-separated, compared.")
    parser.add_argument("--prune-after", type=int, default=None,
                        help="Keep only the start with the lowest loss after this many iterations.")
    parser.add_argument("--samples", type=int, default=None, help="Samples per iteration (default: the recipe's).")
    parser.add_argument("--out", required=True, help="CSV of per-mesh rows.")
    args = parser.parse_args()

    import numpy as np
    import torch

    from jsrte.fit.reconstruct import LATENT_ONLY_ADAM, LATENT_ONLY_GAUSS_NEWTON, reconstruct_latent
    from jsrte.geometry.mesh import normalized
    from jsrte.metrics.surface import fscore
    from jsrte.model.meshing import decode_mesh
    from jsrte.model.registry import resolve_model
    from jsrte.shapes import EVAL_SET_SEED, generate_shape, shape_seed

    torch.set_num_threads(args.threads)
    model = resolve_model(args.model)
    category = model.meta.get("data", {}).get("category", args.model)
    recipes = {"adam": LATENT_ONLY_ADAM, "gauss-newton": LATENT_ONLY_GAUSS_NEWTON}
    if args.prune_after is not None:
        recipes = {name: replace(r, prune_after=args.prune_after, prune_keep=1) for name, r in recipes.items()}
    if args.samples is not None:
        recipes = {name: replace(r, samples_per_iteration=args.samples) for name, r in recipes.items()}
    code_starts = [int(v) for v in args.code_starts.split(",")]
    rows = []
    for i in range(args.first, args.first + args.meshes):
        canon = normalized(generate_shape(category, shape_seed(EVAL_SET_SEED, i)).mesh)
        for solver, starts in itertools.product(args.solvers.split(","), code_starts):
            report: dict = {}
            latent, _ = reconstruct_latent(model, canon, rng=np.random.default_rng(args.seed),
                                           settings=recipes[solver], code_starts=starts, report=report)
            pred = decode_mesh(model.decoder, latent, resolution=args.resolution).mesh
            score = fscore(pred, canon, rng=np.random.default_rng(args.seed)).fscore
            rows.append({"shape": i, "solver": solver, "code_starts": starts, "fscore": round(score, 4), **report})
            print(rows[-1], flush=True)
            with Path(args.out).open("w", newline="") as f:
                writer = csv.DictWriter(f, fieldnames=list(rows[0]))
                writer.writeheader()
                writer.writerows(rows)
    for solver, starts in itertools.product(args.solvers.split(","), code_starts):
        chosen = [r for r in rows if r["solver"] == solver and r["code_starts"] == starts]
        print(f"{solver}, {starts} code start(s): mean F@5% {statistics.mean(r['fscore'] for r in chosen):.3f}, "
              f"mean {statistics.mean(r['seconds'] for r in chosen):.1f} s, "
              f"mean evaluations {statistics.mean(r['decoder_evaluations'] for r in chosen):,.0f}")


if __name__ == "__main__":
    main()
