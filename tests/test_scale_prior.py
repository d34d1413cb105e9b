"""The scale prior (beyond the paper): w s0 ln(s/s0)^2 holds the scale near its data-driven start."""

import math
from dataclasses import replace

import numpy as np
import pytest
import torch

from analytic import SphereDecoder
from jsrte.fit.optimize import hypothesis_losses, optimize
from jsrte.fit.params import HypothesisBatch, Init
from jsrte.fit.query import SdfQuery
from jsrte.presets import FAST


@pytest.mark.parametrize("scale", [0.5, 1.0, 2.0])
def test_the_penalty_is_w_s0_log_ratio_squared(scale):
    batch = HypothesisBatch([Init(scale, 0.0, 0.0, 0.0, np.zeros(3))], 2, latent_init_std=0.0)
    points = torch.tensor([[1.5, 0.0, 0.0], [0.0, -0.7, 0.2]], dtype=torch.float64)
    sdf = torch.tensor([0.3, -0.1], dtype=torch.float64)
    decoder = SphereDecoder(r0=0.6)
    plain = hypothesis_losses(decoder, batch, points, sdf, clamp=None, latent_penalty=0.0)
    held = hypothesis_losses(decoder, batch, points, sdf, clamp=None, latent_penalty=0.0, scale_prior=(0.2, 1.0))
    assert float((held - plain)[0].detach()) == pytest.approx(0.2 * 1.0 * math.log(scale) ** 2, abs=1e-6)


def unit_sphere_query() -> SdfQuery:
    """Exact SDF samples of the unit sphere: 2000 points at radii 0.7-1.3, surface points on it."""
    rng = np.random.default_rng(0)
    directions = rng.normal(size=(2000, 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    radii = rng.uniform(0.7, 1.3, size=2000)
    return SdfQuery(directions * radii[:, None], radii - 1.0, directions)


def test_the_final_losses_rank_an_equal_fit_nearer_the_start_first():
    """A sphere of radius 1 is s (|x|/s − r) for every s with s r = 1: two hypotheses fit it
    exactly at s = 1 and s = 3. The fit's final losses (what picks the winner) differ by the
    prior alone, about s0 = the median initial scale (2)."""
    query = unit_sphere_query()
    settings = replace(FAST.fit, iterations=0, prune_after=None, latent_space="raw", latent_penalty=0.0,
                       clamp_canonical=None, scale_prior=0.05)
    inits = [Init(s, 0.0, 0.0, 0.0, np.zeros(3), latent=np.array([1.0 / s, 0.0])) for s in (1.0, 3.0)]
    result = optimize(SphereDecoder(r0=0.0), query, inits, settings, generator=torch.Generator().manual_seed(0))
    expected = [0.05 * 2.0 * math.log(s / 2.0) ** 2 for s in (1.0, 3.0)]
    np.testing.assert_allclose(result.losses, expected, atol=1e-6)
    assert result.losses[1] < result.losses[0]  # 3 is nearer 2 than 1 is, on a log scale


def test_starting_at_two_scales_each_hypothesis_is_held_near_its_own():
    """With ``init_scale`` "both" the yaws start at two scales; the prior then holds each
    hypothesis near its own start, so the two exact fits at s = 1 and s = 3 pay no prior at all
    (about the median, 2, they would pay 0.05 · 2 · ln(s/2)² each)."""
    query = unit_sphere_query()
    settings = replace(FAST.fit, iterations=0, prune_after=None, latent_space="raw", latent_penalty=0.0,
                       clamp_canonical=None, scale_prior=0.05, init_scale="both")
    inits = [Init(s, 0.0, 0.0, 0.0, np.zeros(3), latent=np.array([1.0 / s, 0.0])) for s in (1.0, 3.0)]
    result = optimize(SphereDecoder(r0=0.0), query, inits, settings, generator=torch.Generator().manual_seed(0))
    np.testing.assert_allclose(result.losses, [0.0, 0.0], atol=1e-6)
