"""Class sizes: the shipped record, and a fit held to its class's sizes."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import torch

from analytic import LShapeDecoder, make_query, tilted_truth
from jsrte.fit.solve import fit_query
from jsrte.model.checkpoint import DeepSdfModel
from jsrte.model.meshing import decode_mesh
from jsrte.model.registry import resolve_model
from jsrte.model.sizes import ClassSizes, model_sizes, procedural_sizes
from jsrte.presets import FAST


def test_the_shipped_record_holds_the_sizes_of_each_models_training_shapes():
    chair = resolve_model("chair")
    recorded = model_sizes(chair.meta)
    measured = procedural_sizes("chair", chair.meta["data"]["n_shapes"], chair.meta["data"]["set_seed"])
    assert recorded.shapes == measured.shapes == 200
    assert (recorded.smallest, recorded.largest) == pytest.approx((measured.smallest, measured.largest), abs=1e-4)
    for name in ("bed", "sofa", "table"):
        sizes = model_sizes(resolve_model(name).meta)
        assert 0.3 < sizes.smallest < sizes.median < sizes.largest < 2.5
    altered = dict(chair.meta, sha256="0" * 64)  # another model called "chair" has no sizes
    assert model_sizes(altered) is None


def test_a_fit_held_to_its_class_sizes_stays_within_them():
    """The L-shape scanned at scale 1.7: a fit free to take any size recovers it; a class whose
    shapes are 0.8-1.0 m (margin 1.2) ends at most at 1.2 m, and its start too."""
    mesh = decode_mesh(LShapeDecoder(), torch.zeros(4), resolution=48).mesh
    truth, up = tilted_truth(theta=1.0)
    query = make_query(mesh, truth, up, np.random.default_rng(3))
    sizes = ClassSizes(smallest=0.8, median=0.9, largest=1.0, shapes=10)
    height = float(np.ptp(mesh.vertices[:, 1]))
    meta = {"name": "lshape", "canonical_height": height, "canonical_radius": 1.0,
            "sizes_m": sizes.__dict__}
    model = DeepSdfModel(LShapeDecoder(), torch.zeros(1, 4), meta)
    settings = replace(FAST.fit, iterations=60, lr_decay_every=40, prune_again_after=None, latent_space="raw",
                       below_floor_samples=0)
    free = fit_query(model, query, settings, seed=0)
    assert free.transform.s == pytest.approx(truth.s, rel=0.05)
    held = fit_query(model, query, replace(settings, size_margin=1.2), seed=0)
    assert held.transform.s <= 1.2 + 1e-6 and held.loss > free.loss
    assert all(h.init["scale"] <= 1.2 + 1e-6 for h in held.hypotheses)


def test_models_lists_each_class_sizes_and_its_distilled_decoder(monkeypatch, capsys):
    from cli_runner import run_cli

    code, out, err = run_cli(monkeypatch, capsys, "models")
    assert code == 0, err
    line = next(row for row in out.splitlines() if row.startswith("chair"))
    assert "radius 0.49-0.76 m" in line and "distilled (tiny, 25" in line
