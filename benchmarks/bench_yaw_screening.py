"""How often the right yaw survives: forward-only screening of many yaw starts against the
``fast`` preset's pruning (12 starts, Adam, the best 4 kept after 20 iterations).

On query files made from held-out chairs with their truths (``bench_solver.py prepare``; the
tuning set: shapes 100..119, scan seed 5, never Table 2's 0..29)::

    .venv/bin/python benchmarks/bench_yaw_screening.py runs/tune --starts 36,48,72 --keep 2,3,4 \\
        --samples 200,400

A start "survives right" when a kept start lies within ``--within`` degrees (rotation angle,
tilt included) of the true rotation; the table also gives the nearest kept start's angle, and
the decoder evaluations each way spends (screening: forward passes only).
"""

from __future__ import annotations

import argparse
import pickle
import statistics
from dataclasses import replace
from pathlib import Path


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("folder")
    parser.add_argument("--model", default="chair")
    parser.add_argument("--starts", default="36,72")
    parser.add_argument("--keep", default="2,3,4")
    parser.add_argument("--samples", default="400")
    parser.add_argument("--within", type=float, default=30.0)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--threads", type=int, default=1)
    args = parser.parse_args()

    import numpy as np
    import torch

    from jsrte.fit.floor import with_below_floor_samples
    from jsrte.fit.gauss_newton import ProblemDrawer, pack, screen_yaws
    from jsrte.fit.init import initial_hypotheses
    from jsrte.fit.optimize import loss_clamp, optimize
    from jsrte.fit.params import HypothesisBatch
    from jsrte.fit.query import read_query_file
    from jsrte.fit.solve import AXIS_PARAMETERS, class_geometry, latent_prior
    from jsrte.geometry.sim3 import rotation_angle_deg
    from jsrte.model.registry import resolve_model
    from jsrte.presets import FAST

    torch.set_num_threads(args.threads)
    folder = Path(args.folder)
    truths = pickle.loads((folder / "truths.pkl").read_bytes())
    model = resolve_model(args.model)
    geometry = class_geometry(model)
    settings = FAST.fit
    prior = latent_prior(model, settings)
    variants = [(n, k, m) for n in map(int, args.starts.split(",")) for k in map(int, args.keep.split(","))
                for m in map(int, args.samples.split(","))]
    nearest: dict[str, list[float]] = {"adam-12": []} | {f"screen-{n}-keep{k}-{m}": [] for n, k, m in variants}
    evaluations: dict[str, int] = {}
    for name, truth in sorted(truths.items()):
        query = read_query_file(folder / f"{name}.npz")
        inits12 = initial_hypotheses(query, geometry, settings)
        query = with_below_floor_samples(query, settings.below_floor_samples, clamp=loss_clamp(settings, inits12),
                                         rng=np.random.default_rng(args.seed), depth=settings.below_floor_depth)
        true_r = truth.scan_from_canonical.R

        def angle_of(inits: list, kept: list[int], true_r: np.ndarray = true_r) -> float:
            """Rotation angle (degrees) from the truth to the nearest kept start."""
            batch = HypothesisBatch([inits[i] for i in kept], model.decoder.config.latent_size, latent_init_std=0)
            return min(rotation_angle_deg(r, true_r) for r in batch.rotation().detach().numpy())

        adam = optimize(model.decoder, query, inits12, replace(settings, iterations=settings.prune_after + 1),
                        fixed=AXIS_PARAMETERS, generator=torch.Generator().manual_seed(args.seed), prior=prior)
        nearest["adam-12"].append(angle_of(inits12, list(adam.survivors)))
        evaluations["adam-12"] = settings.prune_after * 12 * settings.samples_per_iteration
        row = [f"{name}: adam-12 {nearest['adam-12'][-1]:.0f}"]
        for n, k, m in variants:
            inits = initial_hypotheses(query, geometry, settings, n_hypotheses=n)
            generator = torch.Generator().manual_seed(args.seed)
            batch = HypothesisBatch(inits, model.decoder.config.latent_size,
                                    latent_init_std=settings.latent_init_std, generator=generator, prior=prior)
            problem = ProblemDrawer(query, inits, settings, generator=generator, whitened=prior is not None,
                                    device=torch.device("cpu"))(m)
            whitening = None if prior is None else (batch.prior_mean, batch.prior_factor)
            _, keep = screen_yaws(model.decoder, pack(batch), batch.base_rotation, problem, whitening, k)
            key = f"screen-{n}-keep{k}-{m}"
            nearest[key].append(angle_of(inits, keep.tolist()))
            evaluations[key] = n * m
            row.append(f"{key} {nearest[key][-1]:.0f}")
        print("; ".join(row), flush=True)
    print(f"\n| way | right yaw kept (within {args.within:.0f} deg) | median nearest kept (deg) | evaluations |")
    print("|---|---|---|---|")
    for key, angles in nearest.items():
        kept = sum(a <= args.within for a in angles)
        print(f"| {key} | {kept}/{len(angles)} | {statistics.median(angles):.1f} | {evaluations[key]:,} |")


if __name__ == "__main__":
    main()
