"""F-score (F@5%), Chamfer and bounding sphere against known answers; the ``score`` command."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import trimesh

from cli_runner import run_cli
from jsrte.errors import JsrteError
from jsrte.metrics.surface import FScore, bounding_sphere, chamfer, fscore, sample_surface
from jsrte.presets import FitSettings


def sphere_points(n: int, radius: float, rng: np.random.Generator) -> np.ndarray:
    directions = rng.normal(size=(n, 3))
    return radius * directions / np.linalg.norm(directions, axis=1, keepdims=True)


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(0)


def test_bounding_sphere_is_box_centre_and_largest_distance():
    points = np.array([[0.0, 0.0, 0.0], [2.0, 0.0, 0.0], [0.0, 4.0, 0.0], [0.5, 0.5, 6.0]])
    centre, radius = bounding_sphere(points)
    np.testing.assert_allclose(centre, [1.0, 2.0, 3.0])
    assert radius == pytest.approx(np.linalg.norm(points - centre, axis=1).max())


def test_defaults_are_the_papers():
    result = fscore(np.eye(3), np.eye(3), rng=np.random.default_rng(0))
    _, radius = bounding_sphere(np.eye(3))
    assert result.threshold == pytest.approx(FitSettings.fscore_fraction * radius)


def test_mesh_sampling_is_uniform_and_seeded():
    box = trimesh.creation.box((1.0, 2.0, 3.0))
    a = sample_surface(box, 30000, rng=np.random.default_rng(1))
    b = sample_surface(box, 30000, rng=np.random.default_rng(1))
    np.testing.assert_array_equal(a, b)
    assert np.abs(box.nearest.signed_distance(a[:500])).max() < 1e-9  # on the surface
    # faces normal to z have area 2 each of 22: fraction 4/22 of the samples
    on_z = np.isclose(np.abs(a[:, 2]), 1.5)
    assert on_z.mean() == pytest.approx(4 / 22, abs=0.01)


def test_point_arrays_are_subsampled_to_n_points(rng):
    points = rng.normal(size=(5000, 3))
    assert len(sample_surface(points, 3000, rng=rng)) == 3000
    assert len(sample_surface(points[:10], 3000, rng=rng)) == 10


def test_identical_points_score_one(rng):
    points = sphere_points(2000, 1.0, rng)
    result = fscore(points, points, rng=rng)
    assert (result.fscore, result.precision, result.recall, result.chamfer) == (1.0, 1.0, 1.0, 0.0)


def test_mesh_against_itself_close_to_one(rng):
    chair_like = trimesh.util.concatenate([
        trimesh.creation.box((0.8, 0.1, 0.8)),
        trimesh.creation.box((0.8, 0.9, 0.08), transform=trimesh.transformations.translation_matrix(
            (0.0, 0.45, 0.36))),
    ])
    assert fscore(chair_like, chair_like, rng=rng).fscore > 0.97
    sphere = trimesh.creation.icosphere(4)
    assert fscore(sphere, sphere, n_points=30000, rng=rng).fscore > 0.99
    # with the paper's 3000 points a sphere scores only ~0.85 against itself (module docstring)
    assert fscore(sphere, sphere, rng=rng).fscore == pytest.approx(0.845, abs=0.03)


def test_concentric_sphere_two_thresholds_away_scores_zero(rng):
    r, fraction = 0.8, 0.05
    truth = trimesh.creation.icosphere(4, radius=r)
    pred = trimesh.creation.icosphere(4, radius=r * (1 + 2 * fraction))
    result = fscore(pred, truth, fraction=fraction, rng=rng)
    assert result.threshold == pytest.approx(fraction * r, rel=1e-6)
    assert result.precision == 0.0 and result.recall == 0.0 and result.fscore == 0.0
    wider = fscore(pred, truth, fraction=4 * fraction, rng=rng)
    assert wider.precision > 0.99 and wider.recall > 0.99 and wider.fscore > 0.99


def test_translated_sphere_matches_analytic_fscore(rng):
    """Sphere of radius r moved by d: the set of points within eps of the other sphere is a
    band of the polar cosine u with r^2 + d^2 - 2 r d u in ((r - eps)^2, (r + eps)^2); by
    Archimedes the area fraction is the band's length over 2 (d = 2 eps gives exactly 1/2)."""
    r, fraction = 1.0, 0.05
    eps = fraction * r
    d = 2 * eps
    lo = (r * r + d * d - (r + eps) ** 2) / (2 * r * d)
    hi = (r * r + d * d - (r - eps) ** 2) / (2 * r * d)
    expected = (min(hi, 1.0) - max(lo, -1.0)) / 2.0
    assert expected == pytest.approx(0.5)
    truth = sphere_points(60000, r, rng)
    pred = truth + [d, 0.0, 0.0]
    result = fscore(pred, truth, fraction=fraction, n_points=60000, rng=rng)
    # nearest *samples* are a little farther than the surface: a small negative bias
    assert result.precision == pytest.approx(expected, abs=0.03)
    assert result.recall == pytest.approx(expected, abs=0.03)
    assert result.fscore == pytest.approx(expected, abs=0.03)


def test_fscore_by_construction():
    """Half of a well-separated point set moved far away: P = R = F = 1/2."""
    grid = np.stack(np.meshgrid(*[np.arange(10.0)] * 3, indexing="ij"), axis=-1).reshape(-1, 3)
    pred = grid.copy()
    pred[::2] += 100.0
    result = fscore(pred, grid, fraction=0.01, n_points=len(grid), rng=np.random.default_rng(0))
    assert (result.precision, result.recall, result.fscore) == (0.5, 0.5, 0.5)
    # precision 1/2, recall 1 -> F = 2/3
    union = np.concatenate([grid, grid + 100.0])
    result = fscore(union, grid, fraction=0.01, n_points=len(union), rng=np.random.default_rng(0))
    assert result.precision == 0.5 and result.recall == 1.0
    assert result.fscore == pytest.approx(2 / 3)


def test_threshold_is_strict():
    truth = np.array([[0.0, 0.0, 0.0], [2.0, 0.0, 0.0]])  # radius 1
    exactly = fscore(truth + [0.0, 0.5, 0.0], truth, fraction=0.5, rng=np.random.default_rng(0))
    assert exactly.fscore == 0.0
    inside = fscore(truth + [0.0, 0.49, 0.0], truth, fraction=0.5, rng=np.random.default_rng(0))
    assert inside.fscore == 1.0


@pytest.mark.parametrize("empty", [None, np.zeros((0, 3)),
                                   trimesh.Trimesh(np.zeros((0, 3)), np.zeros((0, 3), int))])
def test_empty_prediction_scores_zero(empty, rng):
    truth = trimesh.creation.icosphere(2)
    result = fscore(empty, truth, rng=rng)
    assert isinstance(result, FScore)
    assert (result.fscore, result.precision, result.recall) == (0.0, 0.0, 0.0)
    assert math.isinf(result.chamfer)
    assert result.threshold == pytest.approx(0.05)


def test_empty_truth_is_an_error(rng):
    with pytest.raises(JsrteError):
        fscore(np.eye(3), None, rng=rng)
    with pytest.raises(JsrteError):
        fscore(np.eye(3), np.zeros((0, 3)), rng=rng)


def test_chamfer_of_concentric_spheres_is_radius_difference(rng):
    a = sphere_points(20000, 1.0, rng)
    b = sphere_points(20000, 1.1, rng)
    assert chamfer(a, b) == pytest.approx(0.1, rel=0.02)
    assert chamfer(a, a) == 0.0
    assert chamfer(a, np.zeros((0, 3))) == math.inf


def test_chamfer_is_symmetric_mean_of_directed_means():
    a = np.array([[0.0, 0.0, 0.0]])
    b = np.array([[1.0, 0.0, 0.0], [3.0, 0.0, 0.0]])
    # a -> b: 1; b -> a: (1 + 3) / 2 = 2; mean 1.5
    assert chamfer(a, b) == pytest.approx(1.5)
    assert chamfer(b, a) == pytest.approx(1.5)


# --- jsrte score ---------------------------------------------------------------------------


def test_score_command_prints_one_json_line(tmp_path, monkeypatch, capsys):
    trimesh.creation.icosphere(3).export(tmp_path / "truth.ply")
    trimesh.creation.icosphere(3, radius=1.02).export(tmp_path / "pred.obj")
    code, out, err = run_cli(monkeypatch, capsys, "score", str(tmp_path / "pred.obj"),
                             str(tmp_path / "truth.ply"), "--fraction", "0.1", "--seed", "3")
    assert code == 0, err
    lines = out.strip().splitlines()
    assert len(lines) == 1
    values = json.loads(lines[0])
    assert set(values) == {"fscore", "precision", "recall", "threshold", "chamfer"}
    assert values["threshold"] == pytest.approx(0.1, rel=1e-4)
    assert values["fscore"] > 0.9


def test_score_command_errors_are_one_line(tmp_path, monkeypatch, capsys):
    trimesh.creation.icosphere(1).export(tmp_path / "truth.ply")
    code, out, err = run_cli(monkeypatch, capsys, "score", str(tmp_path / "missing.obj"),
                             str(tmp_path / "truth.ply"))
    assert code == 2 and out == ""
    assert "missing.obj" in err and len(err.strip().splitlines()) == 1
    code, _, err = run_cli(monkeypatch, capsys, "score", str(tmp_path / "truth.ply"),
                           str(tmp_path / "truth.ply"), "--points", "0")
    assert code == 2 and "--points" in err
