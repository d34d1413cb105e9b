"""Latent-only reconstruction (DeepSDF): a shape already in canonical orientation, any position
and scale, normalized first; only z is optimized. Also the model-quality evaluation."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import torch
import trimesh

from jsrte.fit.params import PARAMETER_NAMES, Init
from jsrte.fit.query import SdfQuery
from jsrte.fit.solve import minimize
from jsrte.geometry.mesh import Normalization, normalized, unit_sphere_normalization
from jsrte.metrics.surface import fscore
from jsrte.model.checkpoint import DeepSdfModel
from jsrte.model.meshing import decode_mesh
from jsrte.presets import FitSettings, SdfSampling
from jsrte.sdf.mesh_sdf import sample_sdf

LATENT_ONLY_ADAM = FitSettings(iterations=400, samples_per_iteration=4000, lr=5e-3, lr_decay_every=200,
                               lr_decay_factor=5.0, clamp_canonical=0.1, selection="loss")
"""DeepSDF's reconstruction recipe (Adam on z, lr 5e-3, clamp 0.1, code penalty), halved in length."""

LATENT_ONLY_GAUSS_NEWTON = replace(LATENT_ONLY_ADAM, solver="gauss-newton", iterations=20,
                                   samples_per_iteration=8000)
"""The same objective by Levenberg–Marquardt (fit.gauss_newton): at most 20 iterations on 8000
fixed samples, stopping once a step gains under ``tolerance``."""

LATENT_ONLY = LATENT_ONLY_GAUSS_NEWTON
"""The recipe of ``jsrte reconstruct`` and ``jsrte evaluate-model``: Levenberg–Marquardt, at about a
tenth of Adam's decoder evaluations with the same held-out F@5% (docs/solver.md)."""


def reconstruct_latent(model: DeepSdfModel, mesh: trimesh.Trimesh, *, rng: np.random.Generator,
                       settings: FitSettings = LATENT_ONLY,
                       sampling: SdfSampling = SdfSampling(n_points=50_000),
                       progress: bool = False, report: dict | None = None) -> tuple[np.ndarray, Normalization]:
    """The latent code (d,) of ``mesh`` (canonical orientation), and its normalization.

    ``progress``: a bar over the solver's iterations; ``report``, if given, receives the solver's
    iterations, decoder evaluations and seconds."""
    norm = unit_sphere_normalization(mesh)
    samples = sample_sdf(mesh, rng=rng, settings=sampling, normalization=norm)
    query = SdfQuery(samples.points.astype(np.float64), samples.sdf.astype(np.float64),
                     samples.points[:1000].astype(np.float64))
    init = Init(scale=1.0, psi=0.0, rho=0.0, theta=0.0, translation=np.zeros(3),
                latent=model.mean_code().numpy() * 0.0)
    fixed = frozenset(PARAMETER_NAMES) - {"latent"}
    out = minimize(model.decoder, query, [init], settings, fixed=fixed, prior=None,
                   generator=torch.Generator().manual_seed(int(rng.integers(2**31))), progress=progress)
    if report is not None:
        report.update(solver=settings.solver, iterations=out.iterations, decoder_evaluations=out.evaluations,
                      seconds=round(out.seconds, 2))
    return out.batch.latent[0].detach().to("cpu", torch.float32).numpy(), norm


def reconstruct_mesh(model: DeepSdfModel, mesh: trimesh.Trimesh, *, rng: np.random.Generator, resolution: int = 128,
                     settings: FitSettings = LATENT_ONLY,
                     progress: bool = False) -> tuple[trimesh.Trimesh | None, np.ndarray]:
    """Reconstructed surface in the input's own frame (or None), and the latent code."""
    latent, norm = reconstruct_latent(model, mesh, rng=rng, settings=settings, progress=progress)
    out = decode_mesh(model.decoder, latent, resolution=resolution).mesh
    if out is not None:
        out.vertices = norm.to_mesh(out.vertices)
    return out, latent


def evaluate_model(model: DeepSdfModel, train_meshes: list[trimesh.Trimesh], heldout_meshes: list[trimesh.Trimesh],
                   *, resolution: int = 96, seed: int = 0,
                   settings: FitSettings = LATENT_ONLY) -> dict:
    """Mean F@5% and Chamfer (canonical units) of training shapes decoded from their learned
    codes (``train_meshes[i]`` is training shape i), and of held-out shapes reconstructed
    latent-only. Returns per-shape rows and means."""
    rng = np.random.default_rng(seed)
    rows = []
    for i, mesh in enumerate(train_meshes):
        pred = decode_mesh(model.decoder, model.codes[i], resolution=resolution).mesh
        rows.append({"set": "train", "index": i, **_score(pred, normalized(mesh), rng)})
    for i, mesh in enumerate(heldout_meshes):
        canon = normalized(mesh)
        latent, _ = reconstruct_latent(model, canon, rng=rng, settings=settings)
        pred = decode_mesh(model.decoder, latent, resolution=resolution).mesh
        rows.append({"set": "heldout", "index": i, **_score(pred, canon, rng)})
    summary = {}
    for name in ("train", "heldout"):
        chosen = [r for r in rows if r["set"] == name]
        if chosen:
            for key in ("fscore", "precision", "recall", "chamfer"):
                summary[f"{name}_{key}_mean"] = round(float(np.mean([r[key] for r in chosen])), 4)
            summary[f"{name}_count"] = len(chosen)
    return {"summary": summary, "rows": rows, "resolution": resolution,
            "latent_only_settings": replace(settings).__dict__}


def _score(pred: trimesh.Trimesh | None, truth: trimesh.Trimesh, rng: np.random.Generator) -> dict:
    f = fscore(pred, truth, rng=rng)
    return {"fscore": f.fscore, "precision": f.precision, "recall": f.recall, "chamfer": f.chamfer}
