"""The Levenberg–Marquardt solver: its step is the finite-difference Gauss–Newton step; it
recovers a known transform and code in both axis modes; yaw screening; divergence handling."""

from dataclasses import replace

import numpy as np
import pytest
import torch

from analytic import LShapeDecoder, WideningLShapeDecoder, make_query, tilted_truth
from jsrte.errors import JsrteError
from jsrte.fit.gauss_newton import (
    Linearization,
    Problem,
    damped_step,
    free_columns,
    linearize,
    pack,
    solve,
    translation_offsets,
)
from jsrte.fit.init import ClassGeometry, initial_hypotheses
from jsrte.fit.optimize import hypothesis_losses
from jsrte.fit.params import HypothesisBatch, Init, LatentPrior
from jsrte.fit.query import SdfQuery
from jsrte.fit.solve import fit_query
from jsrte.geometry.sim3 import Sim3, axis_angle_matrix, rotation_angle_deg, rotation_between, spherical_from_axis
from jsrte.model.checkpoint import DeepSdfModel
from jsrte.model.decoder import Decoder, DecoderConfig
from jsrte.model.meshing import decode_mesh
from jsrte.presets import FAST

SETTINGS = replace(FAST.fit, solver="gauss-newton", iterations=40, samples_per_iteration=2000, prune_after=3,
                   prune_keep=2, prune_again_after=None, selection="loss", extract_resolution=48,
                   below_floor_samples=0, latent_space="raw", latent_penalty=1e-6, latent_penalty_points=None,
                   scale_prior=0.0)
TRUE_CODE = np.array([0.3, 0.0, 0.0])


@pytest.fixture(scope="module")
def widening():
    return DeepSdfModel(WideningLShapeDecoder(), torch.zeros(1, 3), {"name": "widening", "canonical_height": 1.5,
                                                                     "canonical_radius": 0.95})


@pytest.fixture(scope="module")
def widened_mesh(widening):
    return decode_mesh(widening.decoder, torch.tensor(TRUE_CODE, dtype=torch.float32), resolution=64).mesh


def test_known_axis_recovers_transform_and_code_from_the_theta_grid(widening, widened_mesh):
    truth, up = tilted_truth(theta=2.2)
    query = make_query(widened_mesh, truth, up, np.random.default_rng(0))
    result = fit_query(widening, query, SETTINGS, seed=0)
    assert result.info["fixed_parameters"] == ["psi", "rho"] and result.info["solver"] == "gauss-newton"
    assert result.transform.s == pytest.approx(truth.s, rel=0.02)
    assert rotation_angle_deg(result.transform.R, truth.R) < 2.0
    assert np.linalg.norm(result.transform.t - truth.t) < 0.03
    assert result.latent[0] == pytest.approx(TRUE_CODE[0], abs=0.03)
    assert result.info["iterations"] < SETTINGS.iterations  # converged: stopped early


def test_unknown_axis_recovers_transform_and_code_from_a_nearby_start(widening, widened_mesh):
    psi, rho = spherical_from_axis(np.array([0.2, 0.7, 0.68]))
    axis = np.array([np.sin(psi) * np.cos(rho), np.sin(psi) * np.sin(rho), np.cos(psi)])
    truth = Sim3(1.3, axis_angle_matrix(axis, 0.9), np.array([0.5, 1.0, -2.0]))
    query = make_query(widened_mesh, truth, None, np.random.default_rng(1))
    start = Init(scale=1.3 * 1.2, psi=psi + 0.08, rho=rho - 0.08, theta=0.9 + 0.3,
                 translation=truth.t + np.array([0.1, -0.05, 0.05]), latent=np.zeros(3))
    result = fit_query(widening, query, SETTINGS, inits=[start], seed=0)
    assert result.info["fixed_parameters"] == []
    assert result.transform.s == pytest.approx(truth.s, rel=0.02)
    assert rotation_angle_deg(result.transform.R, truth.R) < 2.0
    assert np.linalg.norm(result.transform.t - truth.t) < 0.03
    assert result.latent[0] == pytest.approx(TRUE_CODE[0], abs=0.03)


def _small_problem(rng: np.random.Generator, *, whitened: bool) -> tuple:
    """A random double-precision decoder, two hypotheses and 300 samples (a third only lower bounds)."""
    torch.manual_seed(0)
    decoder = Decoder(DecoderConfig(latent_size=4, hidden=32, depth=3, skip_layer=2, weight_norm=False)).double()
    decoder.requires_grad_(False)
    prior = LatentPrior.of_codes(rng.normal(size=(10, 4)), shrinkage=0.1) if whitened else None
    inits = [Init(1.0 + 0.2 * h, 0.4 + 0.1 * h, 0.3, 0.5 + 0.5 * h, rng.normal(size=3) * 0.1,
                  latent=rng.normal(size=4) * 0.3, base_rotation=rotation_between([0, 1, 0], [0.2, 1.0, 0.1]))
             for h in range(2)]
    batch = HypothesisBatch(inits, 4, latent_init_std=0.0, prior=prior)
    points = torch.as_tensor(rng.normal(size=(300, 3)) * 0.6)
    sdf = torch.as_tensor(rng.normal(size=300) * 0.05)
    lower = torch.as_tensor(np.arange(300) % 3 == 0)
    problem = Problem(points, sdf, lower, clamp=0.2, huber=0.01, penalty=1e-3, scale_prior=(0.05, 1.1))
    whitening = None if prior is None else (batch.prior_mean, batch.prior_factor)
    return decoder, batch, problem, whitening


def _residuals(decoder: Decoder, batch: HypothesisBatch, problem: Problem) -> torch.Tensor:
    """The data residuals (H, K) by the Adam loss's own path: clamp(s f(x_c, z)) − clamp(φ), one-sided
    where ``lower``."""
    canonical = batch.to_canonical(problem.points)
    h, k = canonical.shape[:2]
    z = batch.latent[:, None, :].expand(h, k, -1)
    pred = batch.scale[:, None] * decoder(canonical.reshape(h * k, 3), z.reshape(h * k, -1)).reshape(h, k)
    r = pred.clamp(-problem.clamp, problem.clamp) - problem.sdf.clamp(-problem.clamp, problem.clamp)[None]
    return torch.where(problem.lower[None] & (r > 0), torch.zeros_like(r), r)


@pytest.mark.parametrize(("whitened", "fixed"), [(False, frozenset()), (True, frozenset({"psi", "rho"}))])
def test_step_equals_the_finite_difference_gauss_newton_step(whitened, fixed):
    decoder, batch, problem, whitening = _small_problem(np.random.default_rng(0), whitened=whitened)
    p0 = pack(batch)
    free = free_columns(fixed, 4)
    lin = linearize(decoder, p0, batch.base_rotation, problem, whitening, free)
    step, solved = damped_step(lin, torch.zeros(2, dtype=torch.float64))
    assert solved.all()

    def residuals(p: torch.Tensor) -> torch.Tensor:
        probe = HypothesisBatch([Init(1.0, 0.0, 0.0, 0.0, np.zeros(3))] * 2, 4, latent_init_std=0.0,
                                prior=None if whitening is None else LatentPrior(whitening[0].numpy(),
                                                                                 whitening[1].numpy()))
        probe.base_rotation = batch.base_rotation
        with torch.no_grad():
            for name, value in zip(("scale", "psi", "rho", "theta"), p[:, :4].T, strict=True):
                getattr(probe, name).copy_(value)
            probe.translation.copy_(p[:, 4:7])
            probe.code.copy_(p[:, 7:])
            return _residuals(decoder, probe, problem)

    r0 = residuals(p0)
    eps = 1e-6
    jac = torch.zeros(2, 300, len(free), dtype=torch.float64)
    for j, col in enumerate(free.tolist()):
        plus, minus = p0.clone(), p0.clone()
        plus[:, col] += eps
        minus[:, col] -= eps
        jac[:, :, j] = (residuals(plus) - residuals(minus)) / (2 * eps)
    weight = 0.5 / r0.abs().clamp(min=problem.huber) / 300  # IRLS: the quadratic touching |r| at r0
    hessian = torch.einsum("hkf,hk,hkg->hfg", jac, weight, jac)
    gradient = torch.einsum("hkf,hk->hf", jac, weight * r0)
    code_cols = [j for j, c in enumerate(free.tolist()) if c >= 7]
    hessian[:, code_cols, code_cols] += problem.penalty  # rows sqrt(λ) code
    gradient[:, code_cols] += problem.penalty * p0[:, 7:]
    w, s0 = problem.scale_prior  # a row sqrt(w s0) ln(s/s0)
    s = p0[:, 0]
    hessian[:, 0, 0] += w * s0 / s**2
    gradient[:, 0] += w * s0 * torch.log(s / s0) / s
    expected = torch.linalg.solve(hessian, -gradient[..., None])[..., 0]
    torch.testing.assert_close(step, expected, rtol=1e-4, atol=1e-7)
    torch.testing.assert_close(lin.gradient, gradient, rtol=1e-5, atol=1e-9)


def test_yaw_screening_keeps_the_right_yaw_by_forward_passes(widening, widened_mesh):
    truth, up = tilted_truth(theta=-1.3)
    query = make_query(widened_mesh, truth, up, np.random.default_rng(2))
    settings = replace(SETTINGS, theta_grid_deg=10.0, yaw_screen_keep=3, yaw_screen_samples=300, prune_after=None)
    inits = initial_hypotheses(query, ClassGeometry(1.5, 0.95), settings)
    out = solve(widening.decoder, query, inits, settings, fixed=frozenset({"psi", "rho"}),
                generator=torch.Generator().manual_seed(0))
    assert len(inits) == 36 and len(out.survivors) == 3 and len(out.pruned_losses) == 33
    start_errors = [rotation_angle_deg(HypothesisBatch([inits[i]], 3, latent_init_std=0).transform(0).R, truth.R)
                    for i in out.survivors]
    assert min(start_errors) <= 5.0 + 1e-6  # the start nearest the truth (10-degree grid) went on
    assert out.evaluations >= 36 * 300


def test_fixed_parameters_do_not_move_and_scale_stays_in_bounds(widening, widened_mesh):
    truth, up = tilted_truth(theta=0.3)
    query = make_query(widened_mesh, truth, up, np.random.default_rng(3))
    psi, rho = spherical_from_axis(up)
    inits = [Init(scale=0.02, psi=psi, rho=rho, theta=0.3, translation=truth.t,
                  base_rotation=rotation_between([0, 1, 0], up))]
    settings = replace(SETTINGS, iterations=10, prune_after=None, scale_min=0.01, scale_max=0.05)
    out = solve(widening.decoder, query, inits, settings, fixed=frozenset({"psi", "rho", "translation"}),
                generator=torch.Generator().manual_seed(0))
    assert float(out.batch.psi[0]) == psi and float(out.batch.rho[0]) == rho
    np.testing.assert_array_equal(out.batch.translation[0].detach().numpy(), truth.t)
    assert 0.01 <= float(out.batch.scale[0].detach()) <= 0.05


class _BlowsUpFarAway(LShapeDecoder):
    """The L-shape, NaN wherever a canonical point lies beyond radius 20 (a broken model)."""

    def forward(self, points: torch.Tensor, codes: torch.Tensor) -> torch.Tensor:
        f = super().forward(points, codes)
        return torch.where(points.norm(dim=-1) > 20.0, torch.full_like(f, float("nan")), f)


def test_a_diverging_hypothesis_is_dropped_and_recorded_and_all_failing_is_an_error(widened_mesh):
    model = DeepSdfModel(_BlowsUpFarAway(), torch.zeros(1, 4), {"name": "broken", "canonical_height": 1.5,
                                                                "canonical_radius": 0.95})
    truth, up = tilted_truth(theta=0.0)
    query = make_query(widened_mesh, truth, up, np.random.default_rng(4))
    psi, rho = spherical_from_axis(up)
    base = rotation_between([0, 1, 0], up)
    good = Init(truth.s, psi, rho, 0.0, truth.t, base_rotation=base)
    tiny = replace(good, scale=0.011)  # the scan's points fall far outside the canonical sphere
    result = fit_query(model, query, replace(SETTINGS, iterations=5), inits=[tiny, good], seed=0)
    assert list(result.info["failed_hypotheses"]) == ["0"]
    assert result.hypotheses[0].failed and result.hypotheses[0].to_json()["loss"] is None
    assert result.info["winner_hypothesis"] == 1 and np.isfinite(result.loss)
    with pytest.raises(JsrteError, match="every hypothesis"):
        fit_query(model, query, replace(SETTINGS, iterations=5), inits=[tiny, tiny], seed=0)


def test_an_unknown_solver_is_refused():
    with pytest.raises(ValueError, match="solver must be one of adam, gauss-newton, got 'newton'"):
        replace(SETTINGS, solver="newton")


def test_linearization_objective_is_the_adam_loss_up_to_the_huber_smoothing():
    decoder, batch, problem, _ = _small_problem(np.random.default_rng(1), whitened=False)
    decoder = decoder.float()  # as the Adam loss evaluates it

    lin = linearize(decoder, pack(batch), batch.base_rotation, problem, None, None)
    assert isinstance(lin, Linearization) and lin.hessian is None
    adam = hypothesis_losses(decoder, batch, problem.points, problem.sdf, clamp=problem.clamp,
                             latent_penalty=problem.penalty, lower_bound=problem.lower,
                             scale_prior=problem.scale_prior).double()
    # Huber differs from |r| by at most δ/2 per sample
    assert torch.all((lin.objective - adam).abs() <= problem.huber / 2 + 1e-6)


def test_latent_only_reconstruction_by_gauss_newton_recovers_a_sphere():
    """``jsrte reconstruct``'s latent-only fit by Levenberg–Marquardt: a sphere of radius 2 at
    (1, −2, 3), normalized to radius 1/1.03, is the analytic sphere model with z_0 + z_1 = 1/1.03 − 0.5,
    shared equally by the code penalty; its surface comes back in the input's own frame."""
    import trimesh

    from analytic import SphereDecoder
    from jsrte.fit.reconstruct import LATENT_ONLY_GAUSS_NEWTON, reconstruct_latent, reconstruct_mesh

    model = DeepSdfModel(SphereDecoder(), torch.zeros(1, 2), {"name": "sphere"})
    mesh = trimesh.creation.icosphere(subdivisions=4, radius=2.0)
    mesh.apply_translation([1.0, -2.0, 3.0])
    latent, _ = reconstruct_latent(model, mesh, rng=np.random.default_rng(0), settings=LATENT_ONLY_GAUSS_NEWTON)
    assert latent.sum() == pytest.approx(1 / 1.03 - 0.5, abs=0.01)
    assert latent[0] == pytest.approx(latent[1], abs=1e-3)
    out, _ = reconstruct_mesh(model, mesh, rng=np.random.default_rng(0), resolution=32,
                              settings=LATENT_ONLY_GAUSS_NEWTON)
    np.testing.assert_allclose(out.bounds, mesh.bounds, atol=0.02)


def test_the_fast_gn_preset_as_shipped_recovers_a_known_transform(widening, widened_mesh):
    """``fast-gn``: whitened code, depth bounds under the floor, scale prior, 12 starts pruned
    to 2 after 4 iterations."""
    from jsrte.presets import get_preset

    settings = replace(get_preset("fast-gn").fit, extract_resolution=32)
    truth, up = tilted_truth(theta=-2.0)
    query = make_query(widened_mesh, truth, up, np.random.default_rng(6))
    result = fit_query(widening, query, settings, seed=0)
    assert result.info["below_floor_samples"] == settings.below_floor_samples > 0
    assert sum(not h.pruned for h in result.hypotheses) == 2 and len(result.hypotheses) == 12
    assert result.transform.s == pytest.approx(truth.s, rel=0.03)
    assert rotation_angle_deg(result.transform.R, truth.R) < 3.0
    assert np.linalg.norm(result.transform.t - truth.t) < 0.05


class _TwoBasinSphereDecoder(torch.nn.Module):
    """f(x, z) = |x| − k r(z_0), r(c) = 0.5 + 0.1 c² − 0.01 c⁴: radius 0.5 k at c = 0 (a local
    minimum of r), rising to 0.75 k at |c| = √5 and falling to 0.3 k at |c| ≈ 3.42 (k = 1 unless given)."""

    def __init__(self, k: float = 1.0) -> None:
        super().__init__()
        self.k = k
        self.config = DecoderConfig(latent_size=1, hidden=8, depth=2, skip_layer=1)

    def forward(self, points: torch.Tensor, codes: torch.Tensor) -> torch.Tensor:
        if codes.dim() == 1:
            codes = codes.expand(len(points), -1)
        c = codes[:, 0]
        return points.norm(dim=-1) - self.k * (0.5 + 0.1 * c**2 - 0.01 * c**4)


def test_latent_only_reconstruction_also_starts_from_the_nearest_training_code():
    """A sphere, normalized to radius 1/1.03, seen by the two-basin model scaled by k = 2.5: from
    the zero code Levenberg–Marquardt stays at radius 1.25 (a local minimum); the training code
    whose surface is nearest the samples (3.5: radius 0.56, nearer than ±1 or −2) starts in the
    basin of the true radius (c ≈ 3.32), and its start ends with the lower loss and wins."""
    import trimesh

    from jsrte.fit.reconstruct import LATENT_ONLY_GAUSS_NEWTON, nearest_codes, reconstruct_latent

    model = DeepSdfModel(_TwoBasinSphereDecoder(k=2.5), torch.tensor([[-2.0], [-1.0], [1.0], [3.5]]),
                         {"name": "two-basin"})
    mesh = trimesh.creation.icosphere(subdivisions=4, radius=2.0)
    settings = replace(LATENT_ONLY_GAUSS_NEWTON, clamp_canonical=None, iterations=30)

    def radius(code_starts: int) -> tuple[float, dict]:
        report: dict = {}
        latent, _ = reconstruct_latent(model, mesh, rng=np.random.default_rng(0), settings=settings,
                                       code_starts=code_starts, report=report)
        c = float(latent[0])
        return 2.5 * (0.5 + 0.1 * c**2 - 0.01 * c**4), report

    alone, report = radius(0)
    assert alone == pytest.approx(1.25, abs=0.01) and report["start"] == 0
    started, report = radius(1)
    assert started == pytest.approx(1 / 1.03, abs=0.005) and report["start"] == 1
    sphere = SdfQuery(np.array([[0.5, 0.0, 0.0], [0.0, 0.9, 0.0]]), np.array([0.5 - 1 / 1.03, 0.9 - 1 / 1.03]),
                      np.zeros((1, 3)))
    nearest = nearest_codes(model, sphere, 2, clamp=None)[:, 0]
    assert nearest[0] == 3.5 and abs(nearest[1]) == 1.0  # radius 0.56, then 1.48 (±1 alike)


def test_code_restarts_leave_a_local_minimum_of_the_code_for_the_training_code_basin():
    """A sphere of radius 0.3 (code ≈ ±3.42) seen by a model whose code starts at the mean, 0, where
    the radius 0.5 is a local minimum of the objective: Levenberg–Marquardt alone stays there;
    restarts from the training codes nearest the scan at its pose (3.5: radius 0.22) reach the
    true radius."""
    decoder = _TwoBasinSphereDecoder()
    rng = np.random.default_rng(0)
    directions = rng.normal(size=(1500, 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    points = directions * rng.uniform(0.1, 0.8, size=(1500, 1))
    sdf = np.linalg.norm(points, axis=1) - 0.3
    query = SdfQuery(points, sdf, directions * 0.3)
    prior = LatentPrior.of_codes(np.array([[-2.0], [-1.0], [0.0], [1.0], [3.5]]), shrinkage=0.01)
    start = Init(scale=1.0, psi=0.0, rho=0.0, theta=0.0, translation=np.zeros(3))
    settings = replace(SETTINGS, latent_space="whitened", prune_after=None, iterations=30, clamp_canonical=None,
                       yaw_screen_samples=300)
    pose = frozenset({"scale", "psi", "rho", "theta", "translation"})

    def radius(code_starts: int) -> tuple[float, object]:
        out = solve(decoder, query, [start], replace(settings, code_starts=code_starts), fixed=pose,
                    generator=torch.Generator().manual_seed(0), prior=prior)
        c = float(out.batch.latent[0, 0].detach())
        return 0.5 + 0.1 * c**2 - 0.01 * c**4, out

    alone, _ = radius(0)
    restarted, out = radius(2)
    assert alone == pytest.approx(0.5, abs=0.01)
    assert restarted == pytest.approx(0.3, abs=0.005)
    assert len(out.survivors) == 1 and out.survivors.tolist() == [0]  # one hypothesis per start comes back
    assert out.evaluations >= 5 * 300  # every training code screened at the pose


def test_code_copies_pruned_early_still_leave_the_local_minimum_and_the_parts_add_up():
    """The two-basin sphere again, the training codes scored on their own 50 samples and only the
    best copy going on after 2 iterations: the true radius is still reached, and the decoder
    evaluations split by part add up (3 hypotheses linearized and stepped twice, then one)."""
    decoder = _TwoBasinSphereDecoder()
    rng = np.random.default_rng(0)
    directions = rng.normal(size=(1500, 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    points = directions * rng.uniform(0.1, 0.8, size=(1500, 1))
    query = SdfQuery(points, np.linalg.norm(points, axis=1) - 0.3, directions * 0.3)
    prior = LatentPrior.of_codes(np.array([[-2.0], [-1.0], [0.0], [1.0], [3.5]]), shrinkage=0.01)
    start = Init(scale=1.0, psi=0.0, rho=0.0, theta=0.0, translation=np.zeros(3))
    settings = replace(SETTINGS, latent_space="whitened", prune_after=None, iterations=12, clamp_canonical=None,
                       yaw_screen_samples=300, code_starts=2, code_screen_samples=50, code_starts_prune_after=2,
                       tolerance=0.0)
    out = solve(decoder, query, [start], settings, fixed=frozenset({"scale", "psi", "rho", "theta", "translation"}),
                generator=torch.Generator().manual_seed(0), prior=prior)
    c = float(out.batch.latent[0, 0].detach())
    assert 0.5 + 0.1 * c**2 - 0.01 * c**4 == pytest.approx(0.3, abs=0.005)
    assert len(out.survivors) == 1 and out.survivors.tolist() == [0]
    parts = out.evaluation_parts
    n = parts["starts"]  # the start linearized once before the restarts
    assert parts["code scoring"] == 5 * 50
    assert parts["survivors"] == 3 * n * (1 + 2) + n * (12 - 2)
    assert parts["final losses"] == min(settings.eval_samples, len(query.sdf))
    assert sum(parts.values()) == out.evaluations


def test_polish_takes_adam_steps_on_fresh_samples_and_lowers_the_objective(widening, widened_mesh):
    """The Adam update written out equals torch.optim.Adam's; a polish from a slightly wrong pose
    lowers the objective and moves the pose towards the truth."""
    from jsrte.fit.adam import adam_step
    from jsrte.fit.gauss_newton import ProblemDrawer
    from jsrte.fit.polish import polish

    torch.manual_seed(0)
    mine = torch.randn(6, dtype=torch.float64, requires_grad=True)
    theirs = mine.detach().clone().requires_grad_(True)
    reference = torch.optim.Adam([theirs], lr=0.05)
    state = [(torch.zeros(6, dtype=torch.float64), torch.zeros(6, dtype=torch.float64))]
    for step in range(1, 8):
        (mine**3).sum().backward()
        adam_step([mine], state, step, 0.05)
        mine.grad = None
        reference.zero_grad()
        (theirs**3).sum().backward()
        reference.step()
    torch.testing.assert_close(mine, theirs)

    truth, up = tilted_truth(theta=0.7)
    query = make_query(widened_mesh, truth, up, np.random.default_rng(7))
    psi, rho = spherical_from_axis(up)
    start = Init(truth.s * 1.05, psi, rho, 0.7 + 0.05, truth.t + np.array([0.03, 0.0, -0.02]),
                 latent=TRUE_CODE, base_rotation=rotation_between([0, 1, 0], up))
    batch = HypothesisBatch([start], 3, latent_init_std=0.0, fixed=frozenset({"psi", "rho"}))
    settings = replace(SETTINGS, polish_iterations=60, polish_lr=0.005, polish_samples=1500)
    draw = ProblemDrawer(query, [start], settings, generator=torch.Generator().manual_seed(0), whitened=False,
                         device=torch.device("cpu"))
    fixed_set = draw(4000)

    def objective() -> float:
        with torch.no_grad():
            return float(hypothesis_losses(widening.decoder, batch, fixed_set.points, fixed_set.sdf,
                                           clamp=fixed_set.clamp, latent_penalty=0.0)[0])

    before = objective()
    assert polish(widening.decoder, batch, draw, settings) == 60 * 1500
    assert objective() < 0.5 * before
    assert np.linalg.norm(batch.transform(0).t - truth.t) < 0.5 * np.linalg.norm(start.translation - truth.t)
    assert float(batch.psi[0]) == psi  # held



def test_the_translation_search_finds_a_translation_off_by_a_third_of_the_scale(widening, widened_mesh):
    """A start off by 0.3 s across the up axis: the search's grid moves it within a grid step of the
    truth (one iteration), scored on ``yaw_screen_samples`` or on ``translation_search_samples``
    samples, and the solve then recovers the known transform and code."""
    truth, up = tilted_truth(theta=1.0)
    query = make_query(widened_mesh, truth, up, np.random.default_rng(5))
    psi, rho = spherical_from_axis(up)
    across = np.cross(up, [1.0, 0.0, 0.0])
    across *= 0.3 * truth.s / np.linalg.norm(across)
    start = Init(scale=truth.s, psi=psi, rho=rho, theta=1.0, translation=truth.t + across, latent=np.zeros(3),
                 base_rotation=rotation_between([0, 1, 0], up))
    settings = replace(SETTINGS, prune_after=None, translation_search=0.4, translation_search_step=0.1)

    def error(out) -> float:
        return float(np.linalg.norm(out.batch.translation[0].detach().numpy() - truth.t))

    def run(iterations: int, search: float):
        return solve(widening.decoder, query, [start], replace(settings, iterations=iterations,
                                                               translation_search=search),
                     fixed=frozenset({"psi", "rho"}), generator=torch.Generator().manual_seed(0))

    assert len(translation_offsets(settings)) == 81 and not translation_offsets(settings)[0].any()
    searched, alone = run(1, 0.4), run(1, 0.0)
    assert error(searched) < 0.1 * truth.s < error(alone)
    assert searched.evaluation_parts["translation search"] == 81 * settings.yaw_screen_samples
    own = solve(widening.decoder, query, [start], replace(settings, iterations=1, translation_search_samples=700),
                fixed=frozenset({"psi", "rho"}), generator=torch.Generator().manual_seed(0))
    assert own.evaluation_parts["translation search"] == 81 * 700  # scored on its own sample count
    assert error(own) < 0.1 * truth.s
    joint = run(40, 0.4)
    assert float(joint.batch.scale[0].detach()) == pytest.approx(truth.s, rel=0.02)
    assert rotation_angle_deg(joint.batch.transform(0).R, truth.R) < 2.0
    assert error(joint) < 0.03
    assert float(joint.batch.latent[0, 0].detach()) == pytest.approx(TRUE_CODE[0], abs=0.03)


def test_the_survivors_are_solved_on_a_fresh_larger_sample_set(widening, widened_mesh):
    """``samples_after_pruning``: the 12 starts take their first iterations on 300 samples, the
    survivors go on from the first pruning on 3000 fresh ones (counted in the evaluations), and
    the known transform is recovered."""
    truth, up = tilted_truth(theta=0.7)
    query = make_query(widened_mesh, truth, up, np.random.default_rng(7))
    settings = replace(SETTINGS, iterations=12, samples_per_iteration=300, samples_after_pruning=3000,
                       prune_after=3, prune_keep=1, tolerance=0.0)
    result = fit_query(widening, query, settings, seed=0)
    assert result.info["iterations"] == 12
    before = 12 * 300 * (1 + 3)  # the linearization at the starts, then 3 steps of 12 starts
    after = 3000 * (1 + 9)  # the survivor linearized afresh, then 9 steps
    assert result.info["decoder_evaluations"] == before + after + min(settings.eval_samples, len(query.sdf))
    assert result.transform.s == pytest.approx(truth.s, rel=0.02)
    assert rotation_angle_deg(result.transform.R, truth.R) < 2.0
    assert np.linalg.norm(result.transform.t - truth.t) < 0.03


def test_near_tie_compares_the_best_hypothesis_with_the_best_at_another_pose():
    """Objectives 1.00 (yaw 0), 1.01 (yaw 10°, the same pose) and 1.04 (yaw 90°): a tie within 5%
    but not within 3%; without the 90° hypothesis no tie at all, however close the same pose is."""
    from jsrte.fit.polish import near_tie

    starts = [Init(1.0, 0.0, 0.0, np.deg2rad(yaw), np.zeros(3)) for yaw in (0.0, 10.0, 90.0)]
    batch = HypothesisBatch(starts, 3, latent_init_std=0.0)
    objective = torch.tensor([1.0, 1.01, 1.04], dtype=torch.float64)
    assert near_tie(batch, objective, 0.05) and not near_tie(batch, objective, 0.03)
    batch.keep(torch.tensor([0, 1]))
    assert not near_tie(batch, objective[:2], 0.05)
    shifted = HypothesisBatch([starts[0], Init(1.0, 0.0, 0.0, 0.0, np.array([0.3, 0.0, 0.0]))], 3,
                              latent_init_std=0.0)
    assert near_tie(shifted, torch.tensor([1.0, 1.04], dtype=torch.float64), 0.05)  # moved by 0.3 s


def test_the_adam_stage_runs_on_a_near_tie_or_always_and_carries_both_poses_on(widening, widened_mesh):
    """Two starts, the true yaw 0.15 rad and 4 cm off and the yaw a quarter turn away, after one
    Levenberg–Marquardt iteration: with a margin that every pair meets, both take the Adam stage
    (its evaluations counted: 60 steps, 2 hypotheses, 1000 samples) and the right one ends nearer
    the truth than the solve alone leaves it; with a margin no pair meets, no stage, unless it is
    asked for always."""
    truth, up = tilted_truth(theta=0.7)
    query = make_query(widened_mesh, truth, up, np.random.default_rng(7))
    psi, rho = spherical_from_axis(up)
    base = rotation_between([0, 1, 0], up)
    starts = [Init(truth.s, psi, rho, 0.7 + 0.15, truth.t + np.array([0.04, 0.0, 0.0]), latent=np.zeros(3),
                   base_rotation=base),
              Init(truth.s, psi, rho, 0.7 + np.pi / 2, truth.t, latent=np.zeros(3), base_rotation=base)]
    settings = replace(SETTINGS, prune_after=None, iterations=1, tolerance=0.0, adam_stage="near-tie",
                       adam_stage_iterations=60, adam_stage_decay_after=30, adam_stage_lr=0.02,
                       adam_stage_samples=1000)

    def run(margin: float):
        return solve(widening.decoder, query, starts, replace(settings, adam_stage_margin=margin),
                     fixed=frozenset({"psi", "rho"}), generator=torch.Generator().manual_seed(0))

    def error(out) -> tuple[float, float]:
        right = int(np.flatnonzero(out.survivors == 0)[0])
        transform = out.batch.transform(right)
        return rotation_angle_deg(transform.R, truth.R), float(np.linalg.norm(transform.t - truth.t))

    tied, alone = run(100.0), run(1e-12)
    assert tied.evaluation_parts["adam stage"] == 60 * 2 * 1000
    assert "adam stage" not in alone.evaluation_parts
    always = solve(widening.decoder, query, starts, replace(settings, adam_stage="always", adam_stage_margin=1e-12),
                   fixed=frozenset({"psi", "rho"}), generator=torch.Generator().manual_seed(0))
    assert always.evaluation_parts["adam stage"] == 60 * 2 * 1000
    assert sum(tied.evaluation_parts.values()) == tied.evaluations
    assert sorted(tied.survivors.tolist()) == [0, 1]  # both poses carried on to the comparison
    (rot_tied, t_tied), (rot_alone, t_alone) = error(tied), error(alone)
    assert rot_tied < 0.5 * rot_alone and t_tied < t_alone
    assert rot_tied < 2.0
    assert int(tied.survivors[int(np.argmin(tied.losses))]) == 0  # the right pose wins


class _TwoCodeBoxDecoder(torch.nn.Module):
    """f(x, z): a box whose half-extents along x and y are 0.3 + 0.1 z_0 and 0.3 + 0.1 z_1 (0.3 along z)."""

    def __init__(self) -> None:
        super().__init__()
        self.config = DecoderConfig(latent_size=2, hidden=8, depth=2, skip_layer=1)

    def forward(self, points: torch.Tensor, codes: torch.Tensor) -> torch.Tensor:
        half = torch.cat([0.3 + 0.1 * codes, torch.full_like(codes[:, :1], 0.3)], dim=-1)
        q = points.abs() - half
        return q.clamp(min=0).norm(dim=-1) + q.max(dim=-1).values.clamp(max=0)


def test_the_retrieval_start_picks_the_training_code_that_made_the_surface():
    """A box made by training code 5 of 8, seen at a known pose: with the pose held and no solver
    iteration, the retrieval start's code is that training code (each of the 8 scored on 200
    samples); the mean of all 8 in whitened space is the training codes' mean."""
    rng = np.random.default_rng(3)
    codes = rng.normal(size=(8, 2)) * 1.5
    decoder = _TwoCodeBoxDecoder()
    points = rng.uniform(-0.6, 0.6, size=(3000, 3))
    sdf = decoder(torch.as_tensor(points), torch.as_tensor(codes[5]).expand(3000, 2)).numpy()
    near = np.abs(sdf) < 0.02
    query = SdfQuery(points, sdf, points[near])
    prior = LatentPrior.of_codes(codes, shrinkage=0.01)
    start = Init(scale=1.0, psi=0.0, rho=0.0, theta=0.0, translation=np.zeros(3))
    pose = frozenset({"scale", "psi", "rho", "theta", "translation"})
    settings = replace(SETTINGS, latent_space="whitened", prune_after=None, iterations=0, clamp_canonical=None,
                       retrieval_start=1, retrieval_samples=200)

    def code(k: int) -> tuple[np.ndarray, dict]:
        out = solve(decoder, query, [start], replace(settings, retrieval_start=k), fixed=pose,
                    generator=torch.Generator().manual_seed(0), prior=prior)
        return out.batch.latent[0].detach().numpy(), out.evaluation_parts

    best, parts = code(1)
    np.testing.assert_allclose(best, codes[5], atol=1e-9)
    assert parts["retrieval"] == 8 * 200
    np.testing.assert_allclose(code(8)[0], codes.mean(axis=0), atol=1e-9)


def test_levenberg_marquardt_after_the_adam_stage_settles_the_code_it_left(widening, widened_mesh):
    """One start at the true pose, a short Adam stage at a large learning rate (it leaves the width
    code about 0.3 off): 5 Levenberg–Marquardt iterations after it bring the code to less than half
    that distance from the truth, and their evaluations are counted (at most one linearization and 5 steps on the
    solve's 2000 samples)."""
    truth, up = tilted_truth(theta=0.4)
    query = make_query(widened_mesh, truth, up, np.random.default_rng(8))
    psi, rho = spherical_from_axis(up)
    start = Init(truth.s, psi, rho, 0.4, truth.t, latent=np.zeros(3), base_rotation=rotation_between([0, 1, 0], up))
    settings = replace(SETTINGS, prune_after=None, iterations=2, adam_stage="always", adam_stage_iterations=10,
                       adam_stage_decay_after=10, adam_stage_lr=0.1, adam_stage_samples=500)

    def run(refine: int):
        out = solve(widening.decoder, query, [start], replace(settings, refine_iterations=refine),
                    fixed=frozenset({"psi", "rho"}), generator=torch.Generator().manual_seed(0))
        return abs(float(out.batch.latent[0, 0].detach()) - TRUE_CODE[0]), out.evaluation_parts

    (stage_only, parts_stage), (refined, parts) = run(0), run(5)
    assert "refine" not in parts_stage
    assert 2000 <= parts["refine"] <= 6 * 2000
    assert refined < 0.5 * stage_only


def test_only_the_contenders_take_the_adam_stage(widening, widened_mesh):
    """``contenders``: of objectives 1.01 (yaw 10°), 1.00 (yaw 0), 1.04 (yaw 90°) and 1.02 (yaw 5°),
    the best and the 90° one within 5%, the best alone within 3%. In a solve with
    ``adam_stage_contenders_only``, two starts 0.1 rad apart (one pose): only the better takes the
    stage (60 steps on 1000 samples, one hypothesis), the other is recorded as pruned."""
    from jsrte.fit.polish import contenders

    starts = [Init(1.0, 0.0, 0.0, np.deg2rad(yaw), np.zeros(3)) for yaw in (10.0, 0.0, 90.0, 5.0)]
    batch = HypothesisBatch(starts, 3, latent_init_std=0.0)
    objective = torch.tensor([1.01, 1.0, 1.04, 1.02], dtype=torch.float64)
    assert contenders(batch, objective, 0.05) == [1, 2]
    assert contenders(batch, objective, 0.03) == [1]

    truth, up = tilted_truth(theta=0.7)
    query = make_query(widened_mesh, truth, up, np.random.default_rng(7))
    psi, rho = spherical_from_axis(up)
    base = rotation_between([0, 1, 0], up)
    near = [Init(truth.s, psi, rho, 0.7 + d, truth.t, latent=np.zeros(3), base_rotation=base) for d in (0.1, 0.0)]
    settings = replace(SETTINGS, prune_after=None, iterations=1, tolerance=0.0, adam_stage="always",
                       adam_stage_iterations=60, adam_stage_samples=1000, adam_stage_contenders_only=True)
    out = solve(widening.decoder, query, near, settings, fixed=frozenset({"psi", "rho"}),
                generator=torch.Generator().manual_seed(0))
    assert out.evaluation_parts["adam stage"] == 60 * 1 * 1000
    assert len(out.survivors) == 1 and len(out.pruned_losses) == 1
    assert set(out.pruned_losses) | set(out.survivors.tolist()) == {0, 1}
