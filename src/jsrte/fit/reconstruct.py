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
                                   samples_per_iteration=4000, prune_after=5, prune_keep=1)
"""The same objective by Levenberg–Marquardt (fit.gauss_newton): at most 20 iterations on 4000
fixed samples, stopping once a step gains under ``tolerance``; of several starts
(:data:`CODE_STARTS`), the one with the lowest loss after 5 iterations goes on alone. On 20 tuning
tables, both against keeping both starts on 8000 samples: mean F@5% 0.969 against 0.971 at half
the decoder evaluations (docs/solver.md)."""

LATENT_ONLY = LATENT_ONLY_GAUSS_NEWTON
"""The recipe of ``jsrte reconstruct`` and ``jsrte evaluate-model``: Levenberg–Marquardt, at an eighth
of Adam's decoder evaluations or less, with a better held-out F@5% (docs/solver.md)."""

CODE_STARTS = 1
"""Besides the zero code, the solve starts from this many training codes (those whose surfaces
match the samples best, :func:`nearest_codes`), all at once; the start with the lowest loss goes
on (pruned as the recipe says). From the zero code alone, Levenberg–Marquardt ends in a poor
minimum on some shapes (F@5% 0.2 where another draw of samples gives 0.99; docs/models.md)."""

CODE_SCREEN_SAMPLES = 500
"""Samples on which every training code is scored for :data:`CODE_STARTS` (forward passes)."""


def reconstruct_latent(model: DeepSdfModel, mesh: trimesh.Trimesh, *, rng: np.random.Generator,
                       settings: FitSettings = LATENT_ONLY,
                       sampling: SdfSampling = SdfSampling(n_points=50_000), code_starts: int = CODE_STARTS,
                       progress: bool = False, report: dict | None = None) -> tuple[np.ndarray, Normalization]:
    """The latent code (d,) of ``mesh`` (canonical orientation), and its normalization.

    The solve starts from the zero code and from ``code_starts`` training codes
    (:func:`nearest_codes`) at once; the lowest loss wins. ``progress``: a bar over
    the solver's iterations; ``report``, if given, receives the solver's iterations, decoder
    evaluations, seconds and the winning start (0: the zero code)."""
    norm = unit_sphere_normalization(mesh)
    samples = sample_sdf(mesh, rng=rng, settings=sampling, normalization=norm)
    query = SdfQuery(samples.points.astype(np.float64), samples.sdf.astype(np.float64),
                     samples.points[:1000].astype(np.float64))
    starts = [np.zeros(model.latent_size, np.float32)]
    screened = 0
    if code_starts > 0 and len(model.codes):
        starts += list(nearest_codes(model, query, code_starts, clamp=settings.clamp_canonical))
        screened = len(model.codes) * min(CODE_SCREEN_SAMPLES, len(query.sdf))
    inits = [Init(scale=1.0, psi=0.0, rho=0.0, theta=0.0, translation=np.zeros(3), latent=code) for code in starts]
    fixed = frozenset(PARAMETER_NAMES) - {"latent"}
    out = minimize(model.decoder, query, inits, settings, fixed=fixed, prior=None,
                   generator=torch.Generator().manual_seed(int(rng.integers(2**31))), progress=progress)
    winner = int(np.argmin(np.nan_to_num(out.losses, nan=np.inf)))
    if report is not None:
        report.update(solver=settings.solver, iterations=out.iterations,
                      decoder_evaluations=out.evaluations + screened, seconds=round(out.seconds, 2),
                      start=int(out.survivors[winner]))
    return out.batch.latent[winner].detach().to("cpu", torch.float32).numpy(), norm


def nearest_codes(model: DeepSdfModel, query: SdfQuery, n: int, *, clamp: float | None = 0.1) -> np.ndarray:
    """The ``n`` training codes (n, d) whose decoded SDF is closest to ``query``'s (canonical
    units) in clamped L1, on its first :data:`CODE_SCREEN_SAMPLES` samples (forward passes only)."""
    decoder = model.decoder
    device = next((w.device for w in decoder.parameters()), torch.device("cpu"))
    codes = model.codes.detach().to(device, torch.float32)
    points = torch.as_tensor(query.points[:CODE_SCREEN_SAMPLES], dtype=torch.float32, device=device)
    target = torch.as_tensor(query.sdf[:CODE_SCREEN_SAMPLES], dtype=torch.float32, device=device)
    if clamp is not None:
        target = target.clamp(-clamp, clamp)
    with torch.no_grad():
        pred = decoder(points.repeat(len(codes), 1), codes.repeat_interleave(len(points), dim=0))
    if clamp is not None:
        pred = pred.clamp(-clamp, clamp)
    scores = (pred.reshape(len(codes), -1) - target).abs().mean(dim=1)
    return codes[torch.argsort(scores)[:n]].cpu().numpy()


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
                   settings: FitSettings = LATENT_ONLY, code_starts: int = CODE_STARTS) -> dict:
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
        latent, _ = reconstruct_latent(model, canon, rng=rng, settings=settings, code_starts=code_starts)
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
            "latent_only_settings": replace(settings).__dict__, "code_starts": code_starts}


def _score(pred: trimesh.Trimesh | None, truth: trimesh.Trimesh, rng: np.random.Generator) -> dict:
    f = fscore(pred, truth, rng=rng)
    return {"fscore": f.fscore, "precision": f.precision, "recall": f.recall, "chamfer": f.chamfer}
