"""The floor's evidence: samples under it (where they go, and that they make a sunk pose cost
more), and the contact penalty (zero on the floor, the gap in the air, and legs the scan missed
made to reach it)."""

from dataclasses import replace

import numpy as np
import pytest
import torch

from analytic import LShapeDecoder, SphereDecoder
from jsrte.fit.floor import floor_contact, floor_grid, with_below_floor_samples
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


class LegLengthTableDecoder(torch.nn.Module):
    """f(x, z): :class:`analytic.TableDecoder`'s top (y 0.26..0.34) on four legs reaching down to
    y = −0.6 − z_0: the code sets how far the legs reach, which a scan of the top alone leaves open."""

    def __init__(self) -> None:
        super().__init__()
        from jsrte.model.decoder import DecoderConfig

        self.config = DecoderConfig(latent_size=2, hidden=8, depth=2, skip_layer=1)

    def forward(self, points: torch.Tensor, codes: torch.Tensor) -> torch.Tensor:
        from analytic import box_sdf

        sdf = box_sdf(points, (0.0, 0.3, 0.0), (0.8, 0.04, 0.45))
        bottom = -0.6 - codes[:, 0]

        def column(*values: torch.Tensor | float) -> torch.Tensor:
            return torch.stack([v if torch.is_tensor(v) else torch.full_like(bottom, v) for v in values], -1)

        for x in (-0.7, 0.7):
            for z in (-0.35, 0.35):
                centre, half = column(x, (0.26 + bottom) / 2, z), column(0.04, (0.26 - bottom) / 2, 0.04)
                q = (points - centre).abs() - half
                sdf = torch.minimum(sdf, q.clamp(min=0).norm(dim=-1) + q.max(dim=-1).values.clamp(max=0))
        return sdf


def table_top_query(floor: float) -> SdfQuery:
    """Samples of the table's top alone (on it and 2 cm above and below), floor at y = ``floor``."""
    from analytic import TableDecoder

    rng = np.random.default_rng(4)
    top = np.column_stack([rng.uniform(-0.8, 0.8, 3000), np.full(3000, 0.34), rng.uniform(-0.45, 0.45, 3000)])
    points = np.concatenate([top, top + [0, 0.02, 0], top - [0, 0.1, 0]])
    sdf = TableDecoder()(torch.as_tensor(points), torch.zeros(len(points), 4)).numpy()
    return SdfQuery(points, sdf, top, up=np.array([0.0, 1.0, 0.0]), floor_offset=floor)


def test_the_floor_grid_lies_on_the_floor_and_covers_the_disc_under_the_object():
    query = floor_query()
    points, spacing = floor_grid(query, 1000)
    assert 900 <= len(points) <= 1100
    np.testing.assert_allclose(points @ UP, 1.0, atol=1e-9)  # on the plane up·x = floor_offset
    flat = query.surface - np.outer(query.surface @ UP, UP)
    centre = flat.mean(0)
    reach = 1.5 * np.linalg.norm(flat - centre, axis=1).max()
    assert np.linalg.norm(points - np.outer(points @ UP, UP) - centre, axis=1).max() <= reach + 1e-9
    # every point of the disc lies within the half-diagonal of a grid point
    rng = np.random.default_rng(5)
    basis = np.linalg.svd(UP[None, :])[2][1:]
    r, a = 0.95 * reach * np.sqrt(rng.uniform(size=500)), rng.uniform(0, 2 * np.pi, 500)
    probes = centre + np.outer(r * np.cos(a), basis[0]) + np.outer(r * np.sin(a), basis[1]) + UP
    nearest = np.linalg.norm(probes[:, None] - points[None], axis=2).min(1)
    assert nearest.max() <= spacing / np.sqrt(2) + 1e-9
    assert floor_grid(replace(query, floor_offset=None), 1000) is None


@pytest.mark.parametrize("lift", [0.0, 0.25, -0.06])
def test_the_contact_penalty_is_zero_on_the_floor_and_the_gap_in_the_air_or_the_depth_sunk(lift):
    """The table's legs end at y = −0.6; the floor lies there, or the table floats ``lift`` above
    it (counted beyond 5 cm), or sinks 6 cm through it (the lowered grid 10 cm below the floor)."""
    query = table_top_query(floor=-0.6)
    contact = floor_contact(query, 2.0, 4000, depth=0.1, tolerance=0.05, device=torch.device("cpu"))
    batch = HypothesisBatch([Init(1.0, 0.0, 0.0, 0.0, np.array([0.0, lift, 0.0]))], 2, latent_init_std=0.0)
    assert contact.tolerance == 0.05
    gap = (lift - 0.05) if lift > 0 else -lift
    decoder = LegLengthTableDecoder()
    assert float(contact.final(decoder, batch)[0]) == pytest.approx(2.0 * gap, abs=1e-6)
    assert float(contact.penalty(decoder, batch, 0)[0].detach()) == pytest.approx(2.0 * gap, abs=1e-6)


@pytest.mark.parametrize("weight", [0.0, 0.5])
def test_a_table_seen_from_above_reaches_the_floor_only_with_the_contact_penalty(weight):
    """Only the top is seen and the floor lies 0.3 below where the code's legs start (z_0 = 0):
    the code is held by its penalty alone, the samples under the floor keep the legs from sinking,
    and only the contact term says they must reach it (z_0 = 0.3, up to the grid's tolerance)."""
    from jsrte.fit.optimize import optimize
    from jsrte.presets import FitSettings

    query = with_below_floor_samples(table_top_query(floor=-0.9), 2000, clamp=0.1, rng=np.random.default_rng(6),
                                     depth=(0.1, 4.0))  # as the fit adds them: nothing sinks
    settings = FitSettings(iterations=150, samples_per_iteration=2000, lr=0.02, lr_decay_every=100, clamp_canonical=0.1,
                           latent_penalty=1e-4, floor_contact=weight, floor_contact_points=4000,
                           floor_contact_tolerance=0.0)
    fixed = frozenset({"scale", "psi", "rho", "theta", "translation"})
    result = optimize(LegLengthTableDecoder(), query, [Init(1.0, 0.0, 0.0, 0.0, np.zeros(3), latent=np.zeros(2))],
                      settings, fixed=fixed, generator=torch.Generator().manual_seed(0))
    reach = float(result.batch.latent[0, 0].detach())
    data_evaluations = 150 * 2000 + min(settings.eval_samples, len(query.sdf))
    grid = len(floor_grid(query, 4000)[0])  # the contact's own evaluations are counted too
    assert result.evaluations >= data_evaluations + (2 * grid if weight else 0)
    assert result.evaluations == data_evaluations or weight
    if weight:
        tolerance = floor_grid(query, 4000)[1] / np.sqrt(2)
        assert 0.3 - tolerance - 0.02 <= reach <= 0.3 + 0.01
    else:
        assert abs(reach) < 0.02


def test_the_contact_penalty_is_refused_where_the_solver_has_none():
    from jsrte.presets import FitSettings

    with pytest.raises(ValueError, match="Adam fit only"):
        FitSettings(solver="gauss-newton", floor_contact=0.3)
    assert FitSettings(solver="gauss-newton").floor_contact == 0.0


@pytest.mark.parametrize("category, classes, kept", [("table", ("table",), True), ("chair", ("table",), False),
                                                     (None, ("table",), False), ("chair", None, True)])
def test_the_contact_acts_only_on_the_classes_it_names(category, classes, kept):
    from jsrte.fit.solve import for_class
    from jsrte.model.checkpoint import DeepSdfModel
    from jsrte.presets import FitSettings

    meta = {} if category is None else {"category": category}
    model = DeepSdfModel(decoder=LegLengthTableDecoder(), codes=torch.zeros(3, 2), meta=meta)
    settings = FitSettings(floor_contact=0.3, floor_contact_classes=classes)
    assert for_class(model, settings).floor_contact == (0.3 if kept else 0.0)
    assert for_class(model, settings).floor_contact_classes == classes


def test_fast_scales_floor_holds_tables_to_the_floor_and_nothing_else():
    from jsrte.fit.solve import for_class
    from jsrte.model.checkpoint import DeepSdfModel
    from jsrte.presets import default_preset, get_preset

    fit = get_preset("fast-scales-floor").fit
    weights = {name: for_class(DeepSdfModel(LegLengthTableDecoder(), torch.zeros(3, 2), {"category": name}),
                                fit).floor_contact for name in ("chair", "table", "sofa", "bed")}
    assert weights == {"chair": 0.0, "table": 0.3, "sofa": 0.0, "bed": 0.0}
    for scene in (False, True):
        assert get_preset(default_preset(scene=scene, class_unknown=True)).fit.floor_contact == 0.0
