"""Is a bad fit the search's fault or the objective's? The fit's mean clamped SDF residual on its
own samples, against the truth's: the true pose with the code that reconstructs the true shape
(latent-only, as ``jsrte reconstruct``), each split by kind of sample::

    jsrte experiment scans --category table --model table --scans 10 --first 100 --methods jsrte --out DIR
    jsrte fit DIR/scans/table_106.ply --model table --out FIT
    .venv/bin/python benchmarks/bench_truth_residual.py DIR/scans/table_106.ply FIT --model table

The scan's sidecar JSON gives the true pose (``scan_from_mesh``); the shape is the held-out
shape of the scan's name (``CLASS_NNN``: evaluation set, index NNN). A truth that explains the
samples better than the fit means the fit stopped in a worse minimum of the same objective.
"""

from __future__ import annotations

import argparse
import importlib
import json
from pathlib import Path

import numpy as np
import torch


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("scan", type=Path, help="A scan written by `jsrte experiment scans` (CLASS_NNN.ply).")
    parser.add_argument("fit", type=Path, help="The folder `jsrte fit` wrote for it (fit.json).")
    parser.add_argument("--model", default="chair")
    args = parser.parse_args()

    from jsrte.experiments.truth import truth_of
    from jsrte.fit.reconstruct import reconstruct_latent
    from jsrte.geometry.sim3 import Sim3
    from jsrte.model.registry import resolve_model
    from jsrte.options import FitOptions
    from jsrte.shapes import EVAL_SET_SEED, generate_shape, shape_seed

    fitting = importlib.import_module("jsrte.fit")  # the package (jsrte.fit is the function)
    model = resolve_model(args.model)
    query = fitting.fit_query_of(args.scan, FitOptions(), model=model)
    category, index = args.scan.stem.rsplit("_", 1)
    mesh = generate_shape(category, shape_seed(EVAL_SET_SEED, int(index))).mesh
    pose = json.loads(args.scan.with_suffix(".json").read_text())["scan_from_mesh"]
    truth = truth_of(mesh, Sim3(pose["scale"], np.array(pose["rotation"]), np.array(pose["translation"])))
    true_code, _ = reconstruct_latent(model, mesh, rng=np.random.default_rng(0))
    fit = json.loads((args.fit / "fit.json").read_text())
    fitted = Sim3(fit["scale"], np.array(fit["rotation"]), np.array(fit["translation"]))

    n, rays, near = len(query.sdf), query.n_refine_only, 2 * len(query.surface)
    kinds = {"surface (±offset)": slice(0, near), "normal free space": slice(near, n - rays),
             "line of sight": slice(n - rays, n), "all": slice(0, n)}
    clamp = 0.1 * fit["scale"]
    print(f"samples: {', '.join(f'{k} {s.stop - s.start}' for k, s in kinds.items())}; clamp {clamp:.4f}")
    for name, pose_, code in (("fit", fitted, fit["latent"]), ("truth", truth.scan_from_canonical, true_code)):
        residual = clamped_residual(model, query, pose_, np.asarray(code, float), clamp)
        cells = ", ".join(f"{k} {residual[s].mean():.5f}" for k, s in kinds.items())
        print(f"{name:5s} scale {pose_.s:.3f}: {cells}")


def clamped_residual(model: object, query: object, pose: object, code: np.ndarray, clamp: float) -> np.ndarray:
    """|clamp(s f(T⁻¹x, z)) − clamp(φ)| (K,) at the query's samples (scan units)."""
    canonical = torch.as_tensor(pose.inverse().apply(query.points), dtype=torch.float32)
    codes = torch.as_tensor(code, dtype=torch.float32)[None].expand(len(canonical), -1)
    with torch.no_grad():
        sdf = pose.s * model.decoder(canonical, codes).numpy().ravel()
    return np.abs(np.clip(sdf, -clamp, clamp) - np.clip(query.sdf, -clamp, clamp))


if __name__ == "__main__":
    main()
