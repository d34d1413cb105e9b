"""The JSRTE fit: recover known similarity transforms; initialization; scale bounds; the CLI."""

from dataclasses import replace

import numpy as np
import pytest
import torch

from analytic import LShapeDecoder, make_query, tall_class_case, tilted_truth
from jsrte.fit.init import ClassGeometry, initial_hypotheses, theta_grid
from jsrte.fit.optimize import SampleDrawer, _adam, _prune, hypothesis_losses, optimize
from jsrte.fit.params import HypothesisBatch, Init
from jsrte.fit.solve import fit_query
from jsrte.geometry.sim3 import Sim3, axis_angle_matrix, rotation_angle_deg, rotation_between, spherical_from_axis
from jsrte.model.checkpoint import DeepSdfModel
from jsrte.model.meshing import decode_mesh
from jsrte.presets import FAST

SETTINGS = replace(FAST.fit, iterations=150, samples_per_iteration=1500, lr_decay_every=100, prune_after=20,
                   prune_keep=2, selection="loss", extract_resolution=48)


@pytest.fixture(scope="module")
def lshape():
    decoder = LShapeDecoder()
    return DeepSdfModel(decoder, torch.zeros(1, 4), {"name": "lshape", "canonical_height": 1.5,
                                                     "canonical_radius": 0.95})


@pytest.fixture(scope="module")
def lshape_mesh(lshape):
    return decode_mesh(lshape.decoder, torch.zeros(4), resolution=48).mesh


def test_known_axis_recovers_transform_from_theta_grid(lshape, lshape_mesh):
    truth, up = tilted_truth(theta=2.2)
    query = make_query(lshape_mesh, truth, up, np.random.default_rng(0))
    result = fit_query(lshape, query, SETTINGS, seed=0)
    assert result.transform.s == pytest.approx(truth.s, rel=0.03)
    assert rotation_angle_deg(result.transform.R, truth.R) < 3.0
    assert np.linalg.norm(result.transform.t - truth.t) < 0.05
    assert sum(not h.pruned for h in result.hypotheses) == SETTINGS.prune_keep
    assert len(result.hypotheses) == 12


def test_a_fit_not_assessed_is_the_same_fit_without_a_quality_block(lshape, lshape_mesh):
    """A quick fit that only ranks (``assess=False``) skips the quality block, nothing else."""
    truth, up = tilted_truth(theta=2.2)
    query = make_query(lshape_mesh, truth, up, np.random.default_rng(0))
    quick = replace(SETTINGS, iterations=30, prune_after=10)
    assessed = fit_query(lshape, query, quick, seed=0)
    bare = fit_query(lshape, query, quick, seed=0, assess=False)
    assert assessed.quality["inlier_share"] > 0.5 and assessed.flag in ("ok", "doubtful")
    assert bare.quality == {} and bare.flag is None and "quality" not in bare.to_json()
    np.testing.assert_array_equal(bare.transform.matrix(), assessed.transform.matrix())
    np.testing.assert_array_equal(bare.latent, assessed.latent)


def test_unknown_axis_recovers_transform_from_nearby_start(lshape, lshape_mesh):
    rng = np.random.default_rng(1)
    # the paper's synthetic setting: R = R(psi, rho, theta), axis unknown, start near the truth
    psi, rho = spherical_from_axis(np.array([0.2, 0.7, 0.68]))
    true_r = axis_angle_matrix(np.array([np.sin(psi) * np.cos(rho), np.sin(psi) * np.sin(rho), np.cos(psi)]), 0.9)
    truth = Sim3(1.3, true_r, np.array([0.5, 1.0, -2.0]))
    query = make_query(lshape_mesh, truth, None, rng)
    start = Init(scale=1.3 * 1.2, psi=psi + 0.05, rho=rho - 0.05, theta=0.9 + 0.25,
                 translation=truth.t + np.array([0.08, -0.05, 0.05]))
    result = fit_query(lshape, query, replace(SETTINGS, iterations=250), inits=[start], seed=0)
    assert result.transform.s == pytest.approx(truth.s, rel=0.03)
    assert rotation_angle_deg(result.transform.R, truth.R) < 3.0
    assert np.linalg.norm(result.transform.t - truth.t) < 0.05


def test_fixed_parameters_do_not_move_and_scale_stays_in_bounds(lshape, lshape_mesh):
    truth, up = tilted_truth(theta=0.3)
    query = make_query(lshape_mesh, truth, up, np.random.default_rng(2))
    psi, rho = spherical_from_axis(up)
    inits = [Init(scale=0.02, psi=psi, rho=rho, theta=0.3, translation=truth.t,
                  base_rotation=rotation_between([0, 1, 0], up))]
    settings = replace(SETTINGS, iterations=30, prune_after=None, scale_min=0.01, scale_max=0.05)
    out = optimize(lshape.decoder, query, inits, settings, fixed=frozenset({"psi", "rho", "translation"}),
                   generator=torch.Generator().manual_seed(0))
    batch = out.batch
    assert float(batch.psi[0]) == psi and float(batch.rho[0]) == rho
    np.testing.assert_array_equal(batch.translation[0].detach().numpy(), truth.t)
    assert 0.01 <= float(batch.scale[0].detach()) <= 0.05


def test_initialization_from_floor_and_height(lshape_mesh):
    truth, up = tilted_truth(theta=1.0)
    query = make_query(lshape_mesh, truth, up, np.random.default_rng(3))
    geometry = ClassGeometry(height=float(np.ptp(lshape_mesh.vertices[:, 1])), radius=0.9)
    inits = initial_hypotheses(query, geometry, replace(SETTINGS, init_scale="height"))
    assert len(inits) == 12
    np.testing.assert_allclose([i.theta for i in inits], theta_grid(30.0))
    assert inits[0].scale == pytest.approx(truth.s, rel=0.02)
    # the base rotation takes canonical +y to the floor normal, so theta turns about up
    batch = HypothesisBatch(inits, 4, latent_init_std=0.01)
    rotations = batch.rotation().detach().numpy()
    np.testing.assert_allclose(rotations @ np.array([0, 1, 0]), np.tile(up, (12, 1)), atol=1e-9)
    # one of the 30-degree starts lies within 15 degrees of the true rotation
    assert min(rotation_angle_deg(r, truth.R) for r in rotations) <= 15.0 + 1e-6


def test_both_start_scales_where_height_and_sphere_disagree(lshape_mesh):
    """An object 2.5 times taller, in its own units, than its class's mean shape: its height puts
    the start at 1/2.5 of its scale, and a short fit from there stays far off. "both" adds the yaw
    starts at the scale of the points' bounding sphere (here the whole surface: the true scale),
    and the same fit recovers it; where the two scales agree it starts as "height" does."""
    query, truth, tall_class, height, radius = tall_class_case(lshape_mesh, factor=2.5)
    short = replace(SETTINGS, iterations=60, lr_decay_every=40, prune_again_after=None)
    both = replace(short, init_scale="both")
    inits = initial_hypotheses(query, ClassGeometry(height=2.5 * height, radius=radius), both)
    assert len(inits) == 24
    assert inits[0].scale == pytest.approx(truth.s / 2.5, rel=0.03)
    assert inits[12].scale == pytest.approx(truth.s, rel=0.03)
    agreeing = initial_hypotheses(query, ClassGeometry(height=height, radius=radius), both)
    by_height = initial_hypotheses(query, ClassGeometry(height=height, radius=radius),
                                   replace(short, init_scale="height"))
    assert [(i.scale, i.theta) for i in agreeing] == [(i.scale, i.theta) for i in by_height]

    from_height = fit_query(tall_class, query, replace(short, init_scale="height"), seed=0)
    assert abs(from_height.transform.s / truth.s - 1.0) > 0.1
    result = fit_query(tall_class, query, both, seed=0)
    assert len(result.hypotheses) == 24
    assert result.transform.s == pytest.approx(truth.s, rel=0.03)
    assert rotation_angle_deg(result.transform.R, truth.R) < 3.0


def test_hypotheses_are_one_batch_not_a_loop(lshape):
    inits = [Init(1.0, 0.0, 0.0, t, np.zeros(3)) for t in theta_grid(30.0)]
    batch = HypothesisBatch(inits, 4, latent_init_std=0.01)
    assert batch.to_canonical(torch.zeros(5, 3, dtype=torch.float64)).shape == (12, 5, 3)
    assert batch.latent.shape == (12, 4)


@pytest.mark.parametrize("from_start", [False, True])
def test_refine_only_samples_wait_until_the_hypotheses_are_pruned(lshape, lshape_mesh, from_start):
    """Line-of-sight samples (the query's last ``n_refine_only``) take no part in deciding which
    yaw hypotheses survive: up to the pruning, a fit with them is the fit without them, unless
    ``line_of_sight_before_pruning`` draws them from the start."""
    truth, up = tilted_truth(0.8)
    query = make_query(lshape_mesh, truth, up, np.random.default_rng(4))
    extra = truth.apply(np.random.default_rng(5).uniform(-0.4, 0.4, size=(3000, 3)))
    misleading = np.full(len(extra), -1.0)  # "inside" everywhere: would change every hypothesis
    settings = replace(SETTINGS, iterations=SETTINGS.prune_after, line_of_sight_before_pruning=from_start)
    inits = initial_hypotheses(query, ClassGeometry(1.5, 0.95), settings, n_hypotheses=4)

    def run(n_refine_only: int) -> np.ndarray:
        with_extra = replace(query, points=np.concatenate([query.points, extra]),
                             sdf=np.concatenate([query.sdf, misleading]), n_refine_only=n_refine_only)
        result = optimize(lshape.decoder, with_extra if n_refine_only >= 0 else query, inits, settings,
                          generator=torch.Generator().manual_seed(0))
        return torch.cat([p.detach().flatten() for p in result.batch.parameters()]).numpy()

    without = run(-1)
    assert np.array_equal(run(len(extra)), without) != from_start
    assert not np.allclose(run(0), without)  # in the main pool, they do change the fit


def test_known_up_axis_is_held_unless_freed(lshape, lshape_mesh):
    truth, up = tilted_truth(theta=1.0)
    query = make_query(lshape_mesh, truth, up, np.random.default_rng(4))
    tilted_up = up + np.array([0.0, 0.0, 0.15])  # a floor normal a few degrees off the truth
    query.up = tilted_up / np.linalg.norm(tilted_up)
    short = replace(SETTINGS, iterations=60, prune_after=None)
    held = fit_query(lshape, query, short, n_hypotheses=2, seed=0)
    free = fit_query(lshape, query, replace(short, hold_axis=False), n_hypotheses=2, seed=0)
    assert held.info["fixed_parameters"] == ["psi", "rho"] and free.info["fixed_parameters"] == []
    np.testing.assert_allclose(held.transform.R @ [0.0, 1.0, 0.0], query.up, atol=1e-9)
    moved = np.degrees(np.arccos(np.clip(free.transform.R @ [0.0, 1.0, 0.0] @ query.up, -1.0, 1.0)))
    assert moved > 0.5  # free, the axis leaves the wrong floor normal towards the truth


def test_two_stage_pruning_keeps_the_lowest_running_losses(lshape, lshape_mesh):
    """12 θ starts, 4 kept after 10 iterations, 2 after 25: the right yaw survives both, and the
    decoder evaluations count 12, then 4, then 2 hypotheses."""
    truth, up = tilted_truth(theta=-1.3)
    query = make_query(lshape_mesh, truth, up, np.random.default_rng(2))
    settings = replace(SETTINGS, iterations=60, prune_after=10, prune_keep=4, prune_again_after=25,
                       prune_again_keep=2)
    result = fit_query(lshape, query, settings, seed=0)
    pruned = [h for h in result.hypotheses if h.pruned]
    assert len(pruned) == 10 and sum(not h.pruned for h in result.hypotheses) == 2
    assert rotation_angle_deg(result.transform.R, truth.R) < 5.0
    assert result.info["decoder_evaluations"] == (10 * 12 + 15 * 4 + 35 * 2) * 1500 + 2 * min(
        settings.eval_samples, len(query.sdf) + result.info["below_floor_samples"])


def test_sample_drawer_enriches_the_samples_under_the_clamp():
    """With a near share of 0.5, half of each draw has |φ| under the clamp (10% of the pool);
    uniform draws (no share, or before ``near_sample_from``) keep the pool's 10%; the
    refine-only tail beyond ``pool`` is never drawn."""
    sdf = np.where(np.arange(10_000) % 10 == 0, 0.01, 0.5)
    sdf[9_000:] = -0.001  # the tail: all under the clamp, outside the pool below

    def near_share(share: float | None, *, enriched: bool = True) -> float:
        drawer = SampleDrawer(sdf, near_share=share, clamp=0.1, generator=torch.Generator().manual_seed(0))
        idx = drawer.draw(9_000, 20_000, enriched=enriched).numpy()
        assert len(idx) == 9_000 and idx.max() < 9_000
        return float(np.mean(np.abs(sdf[idx]) < 0.1))

    assert near_share(0.5) == pytest.approx(0.5, abs=1e-3)
    assert near_share(None) == pytest.approx(0.1, abs=0.02)
    assert near_share(0.5, enriched=False) == pytest.approx(0.1, abs=0.02)
    assert near_share(0.05) == pytest.approx(0.1, abs=0.02)  # never below the pool's own share


def test_pruning_carries_the_kept_hypotheses_adam_moments(lshape):
    """After pruning, Adam goes on with the kept rows' moment estimates and step count, so the
    survivors' next step is the one they would have taken without the pruning."""
    import copy

    inits = [Init(1.0 + 0.1 * i, 0.0, 0.0, t, np.zeros(3)) for i, t in enumerate(theta_grid(90.0))]
    batch = HypothesisBatch(inits, 4, latent_init_std=0.01, generator=torch.Generator().manual_seed(0))
    optimizer = _adam(batch, 0.05)
    points = torch.randn(64, 3, dtype=torch.float64)

    def step(b: HypothesisBatch, opt) -> None:  # noqa: ANN001
        opt.zero_grad()
        hypothesis_losses(lshape.decoder, b, points, torch.zeros(64, dtype=torch.float64), clamp=None,
                          latent_penalty=1e-4).sum().backward()
        opt.step()

    for _ in range(3):
        step(batch, optimizer)
    whole = copy.deepcopy(batch)
    whole_optimizer = optimizer.kept([p for p in whole.parameters() if p.requires_grad], torch.arange(len(inits)))
    keep = torch.tensor([3, 1])
    pruned = _prune(batch, optimizer, keep)
    assert pruned.steps == 3
    for (m, v), (m0, v0) in zip(pruned.moments, optimizer.moments, strict=True):
        torch.testing.assert_close(m, m0[keep])
        torch.testing.assert_close(v, v0[keep])
    step(batch, pruned)
    step(whole, whole_optimizer)
    for (name, p), (_, q) in zip(batch.named_parameters(), whole.named_parameters(), strict=True):
        torch.testing.assert_close(p.detach(), q.detach()[keep], msg=name)


@pytest.fixture(scope="module")
def octahedron_case():
    """The hand-set octahedron MLP, a query of its shape under a known transform, the transform."""
    from analytic import octahedron_model

    model = octahedron_model()
    model.meta.update(canonical_height=1.0, canonical_radius=0.5)
    mesh = decode_mesh(model.decoder, torch.zeros(8), resolution=48).mesh
    truth, up = tilted_truth(theta=0.3)
    return model, make_query(mesh, truth, up, np.random.default_rng(2)), truth


def test_bfloat16_decoder_arithmetic_in_the_adam_steps_still_recovers_a_known_transform(octahedron_case):
    """``decoder_dtype="bfloat16"``: the losses of a real MLP decoder (the hand-set octahedron)
    are computed with bfloat16 matrix products (they differ from float32's, by under 1%), and an
    Adam fit with them recovers the scale and translation of a known similarity transform."""
    model, query, truth = octahedron_case
    batch = HypothesisBatch([Init(truth.s, 0.0, 0.0, 0.0, truth.t)], 8, latent_init_std=0.0)
    points, sdf = torch.as_tensor(query.points[:2000]), torch.as_tensor(query.sdf[:2000])
    with torch.no_grad():
        exact, rounded = (hypothesis_losses(model.decoder, batch, points, sdf, clamp=0.1, latent_penalty=0.0,
                                            bfloat16=bf) for bf in (False, True))
    assert rounded.dtype == torch.float32 and float(rounded) != float(exact)
    assert float(rounded) == pytest.approx(float(exact), rel=0.01)

    result = fit_query(model, query, replace(SETTINGS, decoder_dtype="bfloat16", extract_resolution=32), seed=0)
    assert result.transform.s == pytest.approx(truth.s, rel=0.03)
    assert np.linalg.norm(result.transform.t - truth.t) < 0.05


@pytest.mark.parametrize("float32_flag, float32_inliers, kept", [("ok", 0.5, "float32"),
                                                                  ("doubtful", 0.5, "float32"),
                                                                  ("ok", 0.2, "bfloat16")])
def test_a_doubtful_bfloat16_fit_is_fitted_again_in_float32_and_the_better_kept(monkeypatch, octahedron_case,
                                                                                 float32_flag, float32_inliers, kept):
    """``float32_retry``: a bfloat16 fit flagged doubtful (here: made so, inlier share 0.3) is
    fitted again in float32; the float32 fit is kept when its inlier share is higher, flagged
    "ok" or not; fit.json records both, and the evaluations are both fits'."""
    from jsrte.fit import solve
    model, query, truth = octahedron_case
    real, dtypes = solve.fit_query, []

    def judged(*args, **kwargs):
        result = real(*args, **kwargs)
        dtypes.append(result.info["decoder_dtype"])
        made = ("doubtful", 0.3) if dtypes[-1] == "bfloat16" else (float32_flag, float32_inliers)
        result.flag, result.quality["inlier_share"] = made
        return result

    monkeypatch.setattr(solve, "fit_query", judged)
    settings = replace(SETTINGS, iterations=40, decoder_dtype="bfloat16", extract_resolution=24, float32_retry=True)
    result = solve.fit_with_retry(model, query, settings, seed=0)
    assert dtypes == ["bfloat16", "float32"]
    record = result.info["float32_retry"]
    assert record["kept"] == kept == result.info["decoder_dtype"]
    assert record["bfloat16"]["inlier_share"] == 0.3 and record["float32"]["flag"] == float32_flag
    assert result.info["decoder_evaluations"] > real(model, query, settings, seed=0).info["decoder_evaluations"]
    assert result.transform.s == pytest.approx(truth.s, rel=0.05)

    dtypes.clear()
    solve.fit_with_retry(model, query, replace(settings, float32_retry=False), seed=0)
    assert dtypes == ["bfloat16"]


def test_an_ok_bfloat16_fit_is_not_fitted_again(monkeypatch, octahedron_case):
    """Only a doubtful bfloat16 fit is fitted again: an "ok" one is kept as it is."""
    from jsrte.fit import solve
    model, query, truth = octahedron_case
    real, calls = solve.fit_query, []

    def judged(*args, **kwargs):
        result = real(*args, **kwargs)
        calls.append(result.info["decoder_dtype"])
        result.flag = "ok"
        return result

    monkeypatch.setattr(solve, "fit_query", judged)
    settings = replace(SETTINGS, iterations=40, decoder_dtype="bfloat16", extract_resolution=24, float32_retry=True)
    result = solve.fit_with_retry(model, query, settings, seed=0)
    assert calls == ["bfloat16"] and "float32_retry" not in result.info
