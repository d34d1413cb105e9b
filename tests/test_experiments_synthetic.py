"""The synthetic experiment: samplers draw from the paper's ranges, every hypothesis is scored on
its own, the Fig. 2 binning, and a tiny end-to-end run (library and CLI) writes its tables and plot."""

import csv
from dataclasses import replace
from math import pi
from pathlib import Path

import numpy as np
import pytest
import torch
from scipy import stats

from analytic import LShapeDecoder
from cli_runner import run_cli
from jsrte.errors import JsrteError
from jsrte.experiments.plots import binned_counts
from jsrte.experiments.settings import SCENARIOS, SyntheticTruth
from jsrte.experiments.synthetic import (
    Pose,
    SyntheticCase,
    SyntheticConfig,
    fit_hypotheses,
    fixed_parameters,
    inits_around,
    run_synthetic,
    sample_deltas,
    sample_truth,
    score_outcome,
    uniform_directions,
)
from jsrte.fit.query import SdfQuery
from jsrte.geometry.sim3 import rotation_angle_deg
from jsrte.model.checkpoint import DeepSdfModel
from jsrte.model.meshing import decode_mesh
from jsrte.presets import SMOKE
from jsrte.sdf.mesh_sdf import signed_distance

N = 20_000


def test_scenarios_are_the_paper_tables():
    known, unknown = SCENARIOS["known"], SCENARIOS["unknown"]
    assert known.known_axis and not unknown.known_axis
    for s in (known, unknown):
        assert s.scale_delta == (0.0, 0.3) and s.theta_delta == pytest.approx((-pi / 9, pi / 9))
        assert s.translation_delta_norm == (0.0, 0.15)
    assert unknown.axis_delta == pytest.approx((-pi / 36, pi / 36))
    for name in ("known-wide", "unknown-wide"):
        s = SCENARIOS[name]
        assert s.scale_delta == (0.0, 0.5) and s.theta_delta == pytest.approx((-2 * pi / 9, 2 * pi / 9))
        assert s.translation_delta_norm == (0.0, 0.20)
    assert SCENARIOS["unknown-wide"].axis_delta == pytest.approx((-pi / 36, pi / 36))
    assert fixed_parameters(known) == {"psi", "rho"} and fixed_parameters(unknown) == frozenset()


def test_uniform_directions_are_uniform_on_the_sphere():
    d = uniform_directions(N, rng=np.random.default_rng(0))
    assert np.allclose(np.linalg.norm(d, axis=1), 1.0)
    assert np.all(np.abs(d.mean(0)) < 0.03)
    assert np.allclose(d.T @ d / N, np.eye(3) / 3, atol=0.02)
    # Archimedes: each coordinate of a uniform direction is uniform on [-1, 1]
    for k in range(3):
        assert stats.kstest(d[:, k], stats.uniform(-1, 2).cdf).pvalue > 1e-3


def test_truth_sampler_draws_from_the_paper_ranges():
    rng = np.random.default_rng(1)
    poses = [sample_truth(rng=rng) for _ in range(4000)]
    s = np.array([p.scale for p in poses])
    angles = np.array([[p.psi, p.rho, p.theta] for p in poses])
    t = np.array([p.translation for p in poses])
    norms = np.linalg.norm(t, axis=1)
    assert s.min() >= 0.5 and s.max() < 2.0 and s.min() < 0.52 and s.max() > 1.98
    assert angles.min() >= -pi and angles.max() < pi and angles.min() < -3.1 and angles.max() > 3.1
    assert norms.min() >= 0.0 and norms.max() < 4.0 and norms.max() > 3.95
    assert stats.kstest(s, stats.uniform(0.5, 1.5).cdf).pvalue > 1e-3
    assert stats.kstest(norms, stats.uniform(0, 4).cdf).pvalue > 1e-3
    assert stats.kstest((t / norms[:, None])[:, 2], stats.uniform(-1, 2).cdf).pvalue > 1e-3
    wider = sample_truth(rng=rng, ranges=SyntheticTruth(scale=(3.0, 3.5)))
    assert 3.0 <= wider.scale < 3.5


@pytest.mark.parametrize("name", list(SCENARIOS))
def test_initializations_are_drawn_from_the_scenario_ranges(name):
    scenario = SCENARIOS[name]
    d = sample_deltas(scenario, N, rng=np.random.default_rng(2))
    for values, (lo, hi) in ((d.scale, scenario.scale_delta), (d.theta, scenario.theta_delta),
                             (np.linalg.norm(d.translation, axis=1), scenario.translation_delta_norm)):
        assert values.min() >= lo and values.max() < hi
        assert values.min() < lo + 0.01 * (hi - lo) and values.max() > hi - 0.01 * (hi - lo)
        assert stats.kstest(values, stats.uniform(lo, hi - lo).cdf).pvalue > 1e-3
    directions = d.translation / np.linalg.norm(d.translation, axis=1, keepdims=True)
    assert np.all(np.abs(directions.mean(0)) < 0.03)
    if scenario.known_axis:
        assert np.all(d.psi == 0) and np.all(d.rho == 0)
    else:
        for values in (d.psi, d.rho):
            assert values.min() >= -pi / 36 and values.max() < pi / 36 and np.ptp(values) > 0.99 * pi / 18

    truth = Pose(1.3, 0.4, -2.0, 1.0, np.array([1.0, 2.0, -0.5]))
    inits = inits_around(truth, d)
    assert inits[7].scale == pytest.approx(1.3 * (1 + d.scale[7]))
    assert inits[7].theta == pytest.approx(1.0 + d.theta[7])
    assert inits[7].psi == pytest.approx(0.4 + d.psi[7]) and inits[7].rho == pytest.approx(-2.0 + d.rho[7])
    assert np.allclose(inits[7].translation, truth.translation + d.translation[7])
    assert inits[7].base_rotation is None and inits[7].latent is None


def test_pose_is_the_papers_axis_angle_rotation():
    pose = Pose(1.5, 0.7, -1.2, 0.9, np.array([0.1, -0.2, 0.3]))
    r = pose.rotation()
    axis = np.array([np.sin(0.7) * np.cos(-1.2), np.sin(0.7) * np.sin(-1.2), np.cos(0.7)])
    assert np.allclose(r.T @ r, np.eye(3)) and np.linalg.det(r) == pytest.approx(1.0)
    assert np.allclose(r @ axis, axis)
    assert rotation_angle_deg(r, np.eye(3)) == pytest.approx(np.degrees(0.9))
    x = np.array([[1.0, 2.0, 3.0]])
    assert np.allclose(pose.transform().apply(x), 1.5 * x @ r.T + pose.translation)


def test_fscore_bins_count_initializations_per_shape():
    f = [np.array([0.0, 0.05, 0.1, 0.3, 0.8, 0.95, 1.0]), np.array([0.99, 0.91, 0.2])]
    counts = binned_counts(f)
    assert counts.shape == (2, 10)
    assert counts[0].tolist() == [2, 1, 0, 1, 0, 0, 0, 0, 1, 2]
    assert counts[1].tolist() == [0, 0, 1, 0, 0, 0, 0, 0, 0, 2]
    assert counts.sum(1).tolist() == [7, 3]


@pytest.fixture(scope="module")
def lshape():
    decoder = LShapeDecoder()
    return DeepSdfModel(decoder, torch.zeros(1, 4), {"name": "lshape"})


def lshape_case(lshape) -> SyntheticCase:
    """The L-shape (what the analytic decoder gives for every z) under a known transform."""
    truth = Pose(1.6, 0.8, 2.5, -1.0, np.array([1.5, -2.0, 0.5]))
    mesh = decode_mesh(lshape.decoder, torch.zeros(4), resolution=40).mesh
    mesh.vertices = truth.transform().apply(mesh.vertices)
    rng = np.random.default_rng(3)
    surface = np.asarray(mesh.sample(3000, seed=1))
    points = np.concatenate([surface + rng.normal(size=surface.shape) * 0.03,
                             surface + rng.normal(size=surface.shape) * 0.2])
    return SyntheticCase("chair", 0, truth, mesh, SdfQuery(points, signed_distance(mesh, points), surface))


def test_every_hypothesis_is_fitted_and_scored_on_its_own(lshape):
    case = lshape_case(lshape)
    t = case.truth
    near = inits_around(t, sample_deltas(SCENARIOS["known"], 1, rng=np.random.default_rng(4)))
    far = replace(near[0], translation=t.translation + [0.0, 5.0, 0.0])  # far outside the clamp: stays
    settings = replace(SMOKE.fit, iterations=40, samples_per_iteration=1000)
    outcomes = fit_hypotheses(lshape, case.query, [near[0], far], settings, fixed=fixed_parameters(
        SCENARIOS["known"]), seed=0, resolution=40)
    assert len(outcomes) == 2
    scores = [score_outcome(o, case, rng=np.random.default_rng(0)) for o in outcomes]
    assert scores[0]["fscore"] > 0.9 and scores[0]["rotation_error_deg"] < 5
    assert scores[1]["fscore"] == 0.0 and scores[1]["translation_error"] > 4.5
    for o in outcomes:  # the known axis stayed where it started (ψ, ρ fixed): R maps the true axis to itself
        axis = np.array([np.sin(t.psi) * np.cos(t.rho), np.sin(t.psi) * np.sin(t.rho), np.cos(t.psi)])
        assert np.allclose(o.transform.R @ axis, axis, atol=1e-9)


def test_a_preset_that_prunes_twice_still_scores_every_initialization(lshape):
    """The default preset prunes after 20 and again after 60 iterations; the synthetic experiment
    scores each initialization, so both prunings must be off there."""
    case = lshape_case(lshape)
    inits = inits_around(case.truth, sample_deltas(SCENARIOS["known"], 5, rng=np.random.default_rng(4)))
    settings = replace(SMOKE.fit, iterations=12, samples_per_iteration=500, prune_after=4, prune_keep=3,
                       prune_again_after=8, prune_again_keep=1)
    outcomes = fit_hypotheses(lshape, case.query, inits, settings, fixed=fixed_parameters(SCENARIOS["known"]),
                              seed=0, resolution=24)
    assert len(outcomes) == 5
    assert len({round(o.loss, 9) for o in outcomes}) == 5  # five separate fits, not one repeated


def test_a_start_perturbed_on_purpose_is_not_held_by_the_scale_prior(lshape):
    """The synthetic starts are the truth perturbed (30% too large here): even a preset with a
    strong scale prior fits the true scale, since the prior only suits the data's own estimate."""
    case = lshape_case(lshape)
    start = replace(inits_around(case.truth, sample_deltas(SCENARIOS["known"], 1, rng=np.random.default_rng(4)))[0],
                    scale=1.3 * case.truth.scale)
    settings = replace(SMOKE.fit, iterations=60, samples_per_iteration=1000, scale_prior=1.0)
    outcome, = fit_hypotheses(lshape, case.query, [start], settings, fixed=fixed_parameters(SCENARIOS["known"]),
                              seed=0, resolution=40)
    assert outcome.transform.s == pytest.approx(case.truth.scale, rel=0.05)


# --- end to end ---------------------------------------------------------------------------------


def sphere_model(name: str = "tiny"):
    """A hand-set decoder: f(x, z) = |x|_1 - 0.5 (an octahedron), a real model file's worth."""
    from jsrte.model.decoder import Decoder, DecoderConfig

    d = 8
    decoder = Decoder(DecoderConfig(latent_size=d, hidden=16, depth=2, skip_layer=2, weight_norm=False))
    with torch.no_grad():
        first, second = decoder.layers
        first.weight.zero_()
        first.bias.zero_()
        for i in range(3):
            first.weight[2 * i, d + i], first.weight[2 * i + 1, d + i] = 1.0, -1.0
        second.weight.copy_(torch.eye(16))
        second.bias.zero_()
        decoder.head.weight.zero_()
        decoder.head.weight[0, :6] = 1.0
        decoder.head.bias.fill_(-0.5)
    return DeepSdfModel(decoder, torch.zeros(2, d), {"name": name, "category": "chair"})


TINY = dict(shapes=2, inits=3, fit=SMOKE.fit, preset_name="smoke", resolution=16)


def test_tiny_run_writes_runs_summary_and_plot(tmp_path):
    from jsrte.presets import SdfSampling

    config = SyntheticConfig(categories=("chair", "table"), scenarios=("known", "unknown-wide"),
                             sampling=SdfSampling(n_points=3000), **TINY)
    report = run_synthetic(config, {"chair": sphere_model(), "table": None}, tmp_path)
    with open(tmp_path / "runs.csv") as fh:
        runs = list(csv.DictReader(fh))
    assert len(runs) == 2 * 3 * 2
    assert {r["scenario"] for r in runs} == {"known", "unknown-wide"} and {r["category"] for r in runs} == {"chair"}
    assert all(0.0 <= float(r["fscore"]) <= 1.0 for r in runs)
    assert all(0.0 <= float(r["delta_scale"]) < 0.5 for r in runs)
    known = [r for r in runs if r["scenario"] == "known"]
    assert all(float(r["delta_psi"]) == 0.0 for r in known)
    # the same shape gets the same truth in every scenario
    assert {r["true_scale"] for r in runs if r["shape_index"] == "0"} == {known[0]["true_scale"]}
    with open(tmp_path / "summary.csv") as fh:
        summary = list(csv.DictReader(fh))
    assert [(r["scenario"], r["category"], r["status"][:7]) for r in summary] == [
        ("known", "chair", "ok"), ("known", "table", "skipped"),
        ("unknown-wide", "chair", "ok"), ("unknown-wide", "table", "skipped")]
    assert set(report.skipped) == {"table"} and "no model" in report.skipped["table"]
    md = (tmp_path / "summary.md").read_text()
    assert "held out" in md and "EVAL_SET_SEED" in md and "most F@5% above 0.8" in md
    assert "table: skipped" in md and "fscore_boxplots.png" in md
    assert (tmp_path / "fscore_boxplots.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def tiny_cli_args(tmp_path, *, shapes: int, inits: int, scenarios: str) -> tuple[Path, list]:
    """A saved tiny model and the arguments of a seconds-long ``jsrte experiment synthetic`` on it."""
    from jsrte.model.checkpoint import save_model

    model_path = tmp_path / "tiny.safetensors"
    save_model(sphere_model(), model_path)
    out = tmp_path / "syn"
    return model_path, ["experiment", "synthetic", "--out", out, "--categories", "chair", "--model", model_path,
                        "--shapes", str(shapes), "--inits", str(inits), "--scenarios", scenarios, "--preset",
                        "smoke", "--samples", "2000", "--resolution", "16", "--threads", "1"]


def test_cli_runs_with_a_model_file_and_refuses_bad_options(tmp_path, monkeypatch, capsys):
    model_path, args = tiny_cli_args(tmp_path, shapes=1, inits=2, scenarios="unknown")
    out = tmp_path / "syn"
    rc, stdout, err = run_cli(monkeypatch, capsys, *args)
    assert rc == 0, err
    assert "unknown" in stdout and "median F@5%" in stdout
    for name in ("runs.csv", "summary.csv", "summary.md", "fscore_boxplots.png"):
        assert (out / name).is_file()
    rc, _, err = run_cli(monkeypatch, capsys, *args)
    assert rc == 2 and "--overwrite" in err

    bad = tmp_path / "bad"
    rc, _, err = run_cli(monkeypatch, capsys, "experiment", "synthetic", "--out", bad, "--categories",
                         "chair,table", "--model", model_path)
    assert rc == 2 and "one class" in err
    rc, _, err = run_cli(monkeypatch, capsys, "experiment", "synthetic", "--out", bad, "--categories", "chair",
                         "--model", model_path, "--scenarios", "known,sideways")
    assert rc == 2 and "sideways" in err
    assert not bad.exists()


def read_rows(path) -> list[dict]:
    with open(path) as fh:
        return [{k: v for k, v in r.items() if k != "seconds"} for r in csv.DictReader(fh)]


def test_an_interrupted_run_resumes_to_the_rows_of_an_uninterrupted_one(tmp_path):
    from jsrte.presets import SdfSampling

    config = SyntheticConfig(categories=("chair",), scenarios=("known", "unknown"),
                             sampling=SdfSampling(n_points=2000), **TINY)
    whole, cut = tmp_path / "whole", tmp_path / "cut"
    whole.mkdir()
    cut.mkdir()
    run_synthetic(config, {"chair": sphere_model()}, whole)
    rows = read_rows(whole / "runs.csv")
    assert len(rows) == 2 * 2 * 3
    # an interruption after shape 0's two scenarios and one run of shape 1's first
    (cut / "config.json").write_bytes((whole / "config.json").read_bytes())
    lines = (whole / "runs.csv").read_text().splitlines(keepends=True)
    (cut / "runs.csv").write_text("".join(lines[:1 + 2 * 3 + 1]))
    log = []
    report = run_synthetic(config, {"chair": sphere_model()}, cut, resume=True, log=log.append)
    assert report.resumed_runs == 6 and "resuming: 6 runs" in log[0]
    assert sum("shape 0" in line for line in log) == 0  # shape 0 was not fitted again
    assert read_rows(cut / "runs.csv") == rows
    assert (cut / "summary.md").is_file() and "resumed: 6 runs" in (cut / "summary.md").read_text()

    (cut / "runs.csv").write_text("name,value\nx,1\n")
    with pytest.raises(JsrteError, match="runs.csv: unreadable runs table"):
        run_synthetic(config, {"chair": sphere_model()}, cut, resume=True)
    other = replace(config, inits=4)
    with pytest.raises(JsrteError, match="settings differ.*inits"):
        run_synthetic(other, {"chair": sphere_model()}, cut, resume=True)
    retrained = DeepSdfModel(sphere_model().decoder, torch.zeros(2, 8), {"name": "tiny", "sha256": "f00"})
    with pytest.raises(JsrteError, match="settings differ.*models"):
        run_synthetic(config, {"chair": retrained}, cut, resume=True)


def test_cli_resumes_and_refuses_to_overwrite_an_unfinished_run(tmp_path, monkeypatch, capsys):
    _, args = tiny_cli_args(tmp_path, shapes=2, inits=2, scenarios="known")
    out = tmp_path / "syn"
    rc, _, err = run_cli(monkeypatch, capsys, *args, "--resume")
    assert rc == 2 and "nothing to resume" in err and not out.exists()
    rc, _, err = run_cli(monkeypatch, capsys, *args)
    assert rc == 0, err
    (out / "summary.md").unlink()  # as if stopped before the end
    rows = (out / "runs.csv").read_text()
    rc, _, err = run_cli(monkeypatch, capsys, *args)
    assert rc == 2 and "--resume" in err and (out / "runs.csv").read_text() == rows
    rc, _, err = run_cli(monkeypatch, capsys, *args, "--resume", "--overwrite")
    assert rc == 2 and "give one" in err
    rc, stdout, err = run_cli(monkeypatch, capsys, *args, "--resume")
    assert rc == 0, err
    assert "resuming: 4 runs" in stdout and "shape 1" not in stdout and (out / "summary.md").is_file()
    rc, _, err = run_cli(monkeypatch, capsys, *args, "--inits", "3", "--resume")
    assert rc == 2 and "settings differ" in err
