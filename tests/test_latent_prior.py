"""The whitened latent space: the training codes' Gaussian, and a fit that stays on it."""

from dataclasses import replace

import numpy as np
import pytest
import torch

from analytic import SphereDecoder
from jsrte.fit.optimize import latent_penalty, optimize
from jsrte.fit.params import HypothesisBatch, Init, LatentPrior
from jsrte.fit.query import SdfQuery
from jsrte.fit.solve import latent_prior
from jsrte.model.checkpoint import DeepSdfModel
from jsrte.presets import FAST

COV = np.array([[0.04, 0.01, 0.0], [0.01, 0.02, 0.0], [0.0, 0.0, 0.001]])


def test_prior_matches_the_codes_gaussian_and_whitening_inverts_it():
    rng = np.random.default_rng(0)
    codes = rng.multivariate_normal([0.3, -0.1, 0.05], COV, size=20000)
    prior = LatentPrior.of_codes(codes, shrinkage=0.0)
    np.testing.assert_allclose(prior.mean, [0.3, -0.1, 0.05], atol=0.005)
    np.testing.assert_allclose(prior.factor @ prior.factor.T, COV, atol=0.001)
    z = np.array([1.0, -2.0, 0.5])
    np.testing.assert_allclose(prior.mean + prior.factor @ prior.whiten(z), z, atol=1e-12)
    shrunk = LatentPrior.of_codes(codes, shrinkage=0.5)
    added = np.diag(shrunk.factor @ shrunk.factor.T - prior.factor @ prior.factor.T)
    np.testing.assert_allclose(added, 0.5 * np.trace(COV) / 3, rtol=0.02)
    assert np.all(np.isfinite(LatentPrior.of_codes(codes[:1], shrinkage=0.01).factor))  # one code


def test_batch_latent_is_mean_plus_factor_times_code():
    prior = LatentPrior(np.array([0.5, -0.5]), np.array([[0.2, 0.0], [0.1, 0.3]]))
    given = np.array([0.7, 0.1])
    inits = [Init(1.0, 0.0, 0.0, 0.0, np.zeros(3)), Init(1.0, 0.0, 0.0, 0.0, np.zeros(3), latent=given)]
    batch = HypothesisBatch(inits, 2, latent_init_std=0.01, generator=torch.Generator().manual_seed(0),
                            prior=prior)
    w = batch.code.detach().numpy()
    np.testing.assert_allclose(batch.latent.detach().numpy()[0], prior.mean + prior.factor @ w[0])
    np.testing.assert_allclose(batch.latent.detach().numpy()[1], given, atol=1e-12)


def sphere_fit(space: str) -> np.ndarray:
    """Fit the radius of a sphere of radius 0.7 (pose known); the training codes vary along z_0
    only (std 0.1), z_1 is ~0 in all of them. Returns the fitted z (2,)."""
    rng = np.random.default_rng(1)
    codes = np.stack([rng.normal(0, 0.1, 200), rng.normal(0, 1e-3, 200)], axis=1)
    model = DeepSdfModel(SphereDecoder(), torch.as_tensor(codes, dtype=torch.float32), {"name": "sphere"})
    points = rng.uniform(-1, 1, size=(4000, 3))
    query = SdfQuery(points, np.linalg.norm(points, axis=1) - 0.7, points[:10])
    settings = replace(FAST.fit, iterations=300, prune_after=None, latent_space=space, latent_penalty=1e-5,
                       latent_penalty_points=None)
    out = optimize(model.decoder, query, [Init(1.0, 0.0, 0.0, 0.0, np.zeros(3))], settings,
                   fixed=frozenset({"scale", "psi", "rho", "theta", "translation"}),
                   generator=torch.Generator().manual_seed(0), prior=latent_prior(model, settings))
    return out.batch.latent[0].detach().numpy()


def test_whitened_fit_moves_along_the_codes_spread_and_raw_fit_does_not():
    whitened, raw = sphere_fit("whitened"), sphere_fit("raw")
    assert abs(whitened.sum() - 0.2) < 0.01 and abs(raw.sum() - 0.2) < 0.01  # both fit the radius
    assert abs(whitened[1]) < 0.02  # stays where the training codes are
    assert abs(raw[1]) > 0.05  # the paper's raw z drifts off them


def test_latent_penalty_scales_with_the_evidence():
    settings = replace(FAST.fit, latent_penalty=1e-5, latent_penalty_points=3000)
    assert latent_penalty(settings, n_surface=1000) == pytest.approx(3e-5)
    assert latent_penalty(settings, n_surface=6000) == pytest.approx(5e-6)
    assert latent_penalty(replace(settings, latent_penalty_points=None), n_surface=1000) == 1e-5


def test_sparse_evidence_leans_on_the_prior_and_dense_evidence_does_not():
    """The same SDF samples, told they come from 10 or from 10 000 surface points: with the
    penalty scaled by the evidence the sparse fit stays near the training codes' mean radius
    (0.5) and the dense one fits the sphere (0.7)."""
    rng = np.random.default_rng(1)
    codes = rng.normal(0, 0.1, (200, 2))
    model = DeepSdfModel(SphereDecoder(), torch.as_tensor(codes, dtype=torch.float32), {"name": "sphere"})
    points = rng.uniform(-1, 1, size=(4000, 3))
    settings = replace(FAST.fit, iterations=300, prune_after=None, prune_again_after=None, latent_space="raw",
                       latent_penalty=1.0, latent_penalty_points=100)
    sums = []
    for n_surface in (10, 10_000):
        query = SdfQuery(points, np.linalg.norm(points, axis=1) - 0.7, np.zeros((n_surface, 3)))
        out = optimize(model.decoder, query, [Init(1.0, 0.0, 0.0, 0.0, np.zeros(3))], settings,
                       fixed=frozenset({"scale", "psi", "rho", "theta", "translation"}),
                       generator=torch.Generator().manual_seed(0))
        sums.append(float(out.batch.latent[0].detach().sum()))
    assert abs(sums[0]) < 0.05 and abs(sums[1] - 0.2) < 0.01
