"""Samples under a known floor: where they go, and that they make a sunk pose cost more."""

import numpy as np
import pytest
import torch

from analytic import LShapeDecoder, SphereDecoder
from jsrte.fit.floor import with_below_floor_samples
from jsrte.fit.optimize import hypothesis_losses
from jsrte.fit.params import HypothesisBatch, Init
from jsrte.fit.query import SdfQuery
from jsrte.geometry.sim3 import rotation_between

UP = np.array([0.2, 0.95, -0.1]) / np.linalg.norm([0.2, 0.95, -0.1])


def floor_query(n_tail: int = 0) -> SdfQuery:
    rng = np.random.default_rng(0)
    surface = rng.uniform(-0.5, 0.5, size=(500, 3)) + 2.0 * UP  # an object 1.5-2.5 above the origin
    points = np.concatenate([surface, rng.normal(size=(n_tail, 3))])
    sdf = np.concatenate([np.zeros(len(surface)), np.full(n_tail, 7.0)])
    return SdfQuery(points, sdf, surface, up=UP, floor_offset=1.0, n_refine_only=n_tail)


def test_samples_lie_under_the_floor_below_the_object_before_the_refine_only_tail():
    query = floor_query(n_tail=30)
    out = with_below_floor_samples(query, 400, clamp=0.1, rng=np.random.default_rng(1))
    assert len(out.sdf) == len(query.sdf) + 400 and out.n_refine_only == 30
    np.testing.assert_array_equal(out.sdf[-30:], 7.0)  # the tail stays last
    added, depth = out.points[500:900], out.sdf[500:900]
    np.testing.assert_allclose(1.0 - added @ UP, depth, atol=1e-9)  # SDF = depth below the floor
    assert out.lower_bound is not None and out.lower_bound.sum() == 400 and out.lower_bound[500:900].all()
    assert depth.min() >= 0.15 - 1e-12 and depth.max() <= 0.4 + 1e-12
    flat = added - np.outer(added @ UP, UP)
    centre = (query.surface - np.outer(query.surface @ UP, UP)).mean(0)
    reach = np.linalg.norm(query.surface - np.outer(query.surface @ UP, UP) - centre, axis=1).max()
    assert np.linalg.norm(flat - centre, axis=1).max() <= 1.5 * reach + 1e-9


def test_without_a_floor_the_query_is_unchanged():
    query = floor_query()
    query.floor_offset = None
    assert with_below_floor_samples(query, 400, clamp=0.1, rng=np.random.default_rng(1)) is query


@pytest.mark.parametrize("sink", [0.0, 0.3])
def test_a_shape_sunk_through_the_floor_costs_more(sink):
    """The L-shape standing on the floor y = -0.85 (its lowest point) against one sunk by 0.3."""
    decoder = LShapeDecoder()
    surface = np.random.default_rng(2).uniform(-0.35, 0.35, size=(200, 3))
    query = SdfQuery(np.zeros((0, 3)), np.zeros(0), surface, up=np.array([0.0, 1.0, 0.0]), floor_offset=-0.85)
    query = with_below_floor_samples(query, 2000, clamp=0.1, rng=np.random.default_rng(3))
    init = Init(1.0, 0.0, 0.0, 0.0, np.array([0.0, -sink, 0.0]), base_rotation=rotation_between([0, 1, 0], [0, 1, 0]))
    batch = HypothesisBatch([init], 4, latent_init_std=0.0)
    loss = hypothesis_losses(decoder, batch, torch.as_tensor(query.points), torch.as_tensor(query.sdf),
                             clamp=0.1, latent_penalty=0.0)
    assert (float(loss[0].detach()) == pytest.approx(0.0, abs=1e-7)) == (sink == 0.0)
    if sink:
        assert float(loss[0].detach()) > 1e-3  # the leg pokes through: samples inside it


def test_the_depth_range_is_in_units_of_the_clamp():
    out = with_below_floor_samples(floor_query(), 400, clamp=0.1, rng=np.random.default_rng(1), depth=(0.1, 0.5))
    assert out.sdf[500:].min() >= 0.01 - 1e-12 and out.sdf[500:].max() <= 0.05 + 1e-12


@pytest.mark.parametrize("radius, cost", [(0.3, 0.0), (0.5, 0.0), (0.8, 0.3)])
def test_a_lower_bound_counts_only_a_prediction_that_falls_short(radius, cost):
    """A sample at (1, 0, 0) whose SDF is bounded below by 0.5; a sphere of radius r predicts
    1 − r there: it costs only where 1 − r < 0.5, by the shortfall (two-sided: |1 − r − 0.5|)."""
    batch = HypothesisBatch([Init(1.0, 0.0, 0.0, 0.0, np.zeros(3))], 2, latent_init_std=0.0)
    points = torch.tensor([[1.0, 0.0, 0.0]], dtype=torch.float64)
    bound = torch.tensor([0.5], dtype=torch.float64)
    decoder = SphereDecoder(r0=radius)
    one_sided = hypothesis_losses(decoder, batch, points, bound, clamp=None, latent_penalty=0.0,
                                  lower_bound=torch.tensor([True]))
    two_sided = hypothesis_losses(decoder, batch, points, bound, clamp=None, latent_penalty=0.0)
    assert float(one_sided[0].detach()) == pytest.approx(cost, abs=1e-6)
    assert float(two_sided[0].detach()) == pytest.approx(abs(0.5 - radius), abs=1e-6)
