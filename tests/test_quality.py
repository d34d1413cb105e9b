"""The fit's quality block and flag: a recovered shape is "ok", the same shape at the wrong place
is "doubtful"; free-space violation, loss margin and code distance on cases with known answers."""

import json
from dataclasses import replace

import numpy as np
import pytest
import torch

from analytic import LShapeDecoder, TableDecoder
from jsrte.fit.optimize import SdfQuery
from jsrte.fit.quality import (
    FREE_SPACE_MIN_M,
    RULE,
    SAME_SHAPE_DISTANCE,
    assess,
    fitted_sdf,
    flag_of,
    latent_distance,
    loss_margin,
    pose_distance,
    quality_columns,
    surface_coverage,
    surface_points,
    top_coverage,
)
from jsrte.fit.solve import fit_query
from jsrte.geometry.sim3 import Sim3, axis_angle_matrix
from jsrte.model.checkpoint import DeepSdfModel
from jsrte.model.meshing import decode_mesh
from jsrte.presets import FAST
from jsrte.result import FitResult, HypothesisReport
from jsrte.sdf.mesh_sdf import signed_distance

SETTINGS = replace(FAST.fit, iterations=150, samples_per_iteration=1500, lr_decay_every=100, prune_after=20,
                   prune_keep=2, selection="loss", extract_resolution=48)
TRUTH = Sim3(0.8, axis_angle_matrix(np.array([0.0, 1.0, 0.0]), 2.2), np.array([1.0, 0.4, -0.5]))


@pytest.fixture(scope="module")
def lshape():
    return DeepSdfModel(LShapeDecoder(), torch.zeros(1, 4), {"name": "lshape", "canonical_height": 1.5,
                                                             "canonical_radius": 0.95})


@pytest.fixture(scope="module")
def placed_lshape(lshape):
    mesh = decode_mesh(lshape.decoder, torch.zeros(4), resolution=48).mesh
    mesh.vertices = TRUTH.apply(mesh.vertices)
    return mesh


@pytest.fixture(scope="module")
def query(placed_lshape):
    rng = np.random.default_rng(0)
    surface = np.asarray(placed_lshape.sample(3000, seed=1))
    points = np.concatenate([surface + rng.normal(size=surface.shape) * 0.02,
                             surface + rng.normal(size=surface.shape) * 0.15])
    return SdfQuery(points, signed_distance(placed_lshape, points), surface, up=np.array([0.0, 1.0, 0.0]),
                    floor_offset=float(placed_lshape.vertices[:, 1].min()))


@pytest.fixture(scope="module")
def fitted(lshape, query):
    return fit_query(lshape, query, SETTINGS, n_hypotheses=3, seed=0)  # one start 6° from the truth


def test_a_recovered_shape_is_ok_and_its_block_is_finite_json(fitted):
    q = fitted.quality
    assert fitted.flag == "ok"
    assert q["inlier_share"] > 0.95
    assert q["mean_abs_sdf_rel"] < 0.01
    assert q["free_space_violation"] < 0.01
    assert q["scale_m"] == pytest.approx(TRUTH.s, rel=0.03)
    assert q["surface_coverage"] > 0.9  # the query's points lie all over the shape
    doc = json.loads(json.dumps(fitted.to_json(), allow_nan=False))
    assert doc["flag"] == "ok"
    numbers = [v for k, v in doc["quality"].items() if k not in ("latent_norm_ratio", "latent_mahalanobis_ratio",
                                                                   "loss_margin_rel")]
    assert all(isinstance(v, (int, float)) and np.isfinite(v) for v in numbers)
    columns = quality_columns(fitted)
    assert columns["flag"] == "ok" and columns["quality_inlier_share"] == pytest.approx(q["inlier_share"], abs=1e-5)


@pytest.mark.parametrize("moved", [
    Sim3(1.0, np.eye(3), np.array([0.3, 0.0, 0.0])),  # the object 30 cm away from the fitted one
    Sim3(1.0, axis_angle_matrix(np.array([0.0, 1.0, 0.0]), np.pi / 2), np.zeros(3)),  # turned a quarter
], ids=["shifted", "turned"])
def test_the_same_fit_against_an_object_elsewhere_is_doubtful(lshape, fitted, query, moved):
    centre = query.surface.mean(0)
    elsewhere = moved.apply(query.surface - centre) + centre
    q = assess(lshape.decoder, fitted, surface=elsewhere, points=query.points, sdf=query.sdf)
    assert q["inlier_share"] < 0.4
    assert q["mean_abs_sdf_rel"] > 0.03
    assert q["surface_coverage"] < 0.4  # 0.97 where the points are
    assert flag_of(q) == "doubtful"


def test_free_space_violation_is_the_share_of_free_samples_inside(lshape):
    """Free-space samples labelled so, a quarter of them inside the analytic L-shape: violation 0.25;
    samples below ``FREE_SPACE_MIN_M`` are not free space and do not count."""
    rng = np.random.default_rng(3)
    transform = Sim3(2.0, np.eye(3), np.array([0.5, 0.0, 0.0]))
    candidates = transform.apply(rng.uniform(-1, 1, size=(20_000, 3)))
    sdf = fitted_sdf(lshape.decoder, np.zeros(4), transform, candidates)
    inside, outside = candidates[sdf < -0.01][:100], candidates[sdf > 0.01][:300]
    ignored = candidates[sdf < -0.01][100:200]
    points = np.concatenate([inside, outside, ignored])
    labels = np.concatenate([np.full(400, 0.2), np.full(100, FREE_SPACE_MIN_M / 2)])
    result = FitResult("jsrte", transform, np.zeros(4, np.float32), None, 1.0, {})
    q = assess(lshape.decoder, result, surface=inside[:10], points=points, sdf=labels)
    assert q["free_space_samples"] == 400
    assert q["free_space_violation"] == pytest.approx(0.25)
    assert flag_of(q) == "doubtful" and RULE["free_space_violation_max"] < 0.25


def test_loss_margin_compares_the_winner_with_the_best_other_pose():
    winner = Sim3(1.0, np.eye(3), np.zeros(3))
    turned = Sim3(1.0, axis_angle_matrix(np.array([0.0, 1.0, 0.0]), np.pi), np.zeros(3))
    nearby = Sim3(1.0, axis_angle_matrix(np.array([0.0, 1.0, 0.0]), 0.1), np.zeros(3))
    hypotheses = [HypothesisReport(0, {}, 0.010, transform=winner), HypothesisReport(1, {}, 0.011, transform=nearby),
                  HypothesisReport(2, {}, 0.015, transform=turned), HypothesisReport(3, {}, 0.001, pruned=True)]
    result = FitResult("jsrte", winner, np.zeros(4), None, 0.010, {}, hypotheses=hypotheses)
    assert loss_margin(result) == pytest.approx(0.5)
    result.hypotheses = hypotheses[:2]
    assert loss_margin(result) is None


def _turned(pose: Sim3, angle: float) -> Sim3:
    """``pose`` turned by ``angle`` (radians) about its own up axis, its centre kept."""
    return Sim3(pose.s, pose.R @ axis_angle_matrix(np.array([0.0, 1.0, 0.0]), angle), pose.t)


def test_a_symmetry_of_the_shape_is_no_other_pose():
    """A table turned half a turn is the same table: no rival, no margin; a quarter turn, or an
    L-shape turned half a turn, is another shape there and its loss is the margin."""
    winner = Sim3(1.7, axis_angle_matrix(np.array([0.0, 1.0, 0.0]), 0.4), np.array([2.0, 0.7, -1.0]))
    latent = np.zeros(4)
    for decoder, angle, same in ((TableDecoder(), np.pi, True), (TableDecoder(), np.pi / 2, False),
                                 (LShapeDecoder(), np.pi, False)):
        surface = surface_points(decoder, latent, np.random.default_rng(0))
        distance = pose_distance(decoder, latent, winner, _turned(winner, angle), surface)
        assert (distance < SAME_SHAPE_DISTANCE) == same, (type(decoder).__name__, angle, distance)
        hypotheses = [HypothesisReport(0, {}, 0.010, transform=winner),
                      HypothesisReport(1, {}, 0.0105, transform=_turned(winner, angle))]
        result = FitResult("jsrte", winner, latent, None, 0.010, {}, hypotheses=hypotheses)
        surface_scan = winner.apply(surface[:500])
        q = assess(decoder, result, surface=surface_scan, points=surface_scan, sdf=np.zeros(len(surface_scan)))
        assert q["loss_margin_rel"] == (None if same else pytest.approx(0.05))


def test_an_ambiguous_pose_is_doubtful_even_when_the_points_fit():
    fits_well = {"inlier_share": 0.95, "free_space_violation": 0.0}
    assert flag_of(fits_well | {"loss_margin_rel": None}) == "ok"  # every surviving start agreed
    assert flag_of(fits_well | {"loss_margin_rel": 2 * RULE["loss_margin_min"]}) == "ok"
    assert flag_of(fits_well | {"loss_margin_rel": RULE["loss_margin_min"] / 2}) == "doubtful"


def test_a_shape_its_points_cover_little_of_is_doubtful_even_when_they_lie_on_it():
    """A table fitted by the chair model lies on the table's points but is mostly guessed: the
    points cover little of the fitted surface."""
    fits_well = {"inlier_share": 0.95, "free_space_violation": 0.0, "loss_margin_rel": None}
    assert flag_of(fits_well | {"surface_coverage": 2 * RULE["surface_coverage_min"]}) == "ok"
    assert flag_of(fits_well | {"surface_coverage": RULE["surface_coverage_min"] / 2}) == "doubtful"
    assert flag_of(fits_well | {"surface_coverage": None}) == "ok"  # no mesh: nothing to cover
    lenient = {k: v for k, v in RULE.items() if k != "surface_coverage_min"}
    assert flag_of(fits_well | {"surface_coverage": 0.01}, lenient) == "ok"


def test_code_distance_is_relative_to_the_training_codes():
    rng = np.random.default_rng(0)
    codes = rng.normal(size=(400, 8)) * np.array([1.0, 1, 1, 1, 1, 1, 1, 0.01])
    typical = latent_distance(codes[0], codes)
    assert 0.3 < typical["latent_mahalanobis_ratio"] < 3.0
    assert 0.3 < typical["latent_norm_ratio"] < 3.0
    off = np.zeros(8)
    off[7] = 2.0  # typical in norm, far along a direction the training codes never varied in
    far = latent_distance(off, codes)
    assert far["latent_norm_ratio"] < 1.0
    assert far["latent_mahalanobis_ratio"] > 5.0


def test_surface_coverage_is_the_share_of_the_fitted_surface_near_the_points():
    """A unit sphere placed at scale 0.5: points on its upper half cover half its surface, points
    on all of it nearly all, points 10 cm off it none (1.5 cm is covered at this scale)."""
    import trimesh

    sphere = trimesh.creation.icosphere(subdivisions=4)
    placed = Sim3(0.5, axis_angle_matrix(np.array([0.0, 0.0, 1.0]), 0.7), np.array([1.0, 0.0, -2.0]))
    on = placed.apply(sphere.sample(20_000, seed=1))
    upper = on[on[:, 1] > 0.0]
    assert surface_coverage(sphere, placed, on) > 0.97
    assert surface_coverage(sphere, placed, upper) == pytest.approx(0.5, abs=0.04)
    outside = placed.t + (on - placed.t) * 1.2  # a sphere 10 cm larger
    assert surface_coverage(sphere, placed, outside) == 0.0
    assert surface_coverage(None, placed, on) is None and surface_coverage(sphere, placed, on[:0]) is None


def test_top_coverage_is_the_share_of_the_fitted_top_near_the_points():
    """The same placed sphere: its top is the cap above 0.8 of its radius (canonical +y, whatever
    the rotation places it at). Points on its upper half cover all of that cap, points on its
    lower half none of it, though each covers half the surface."""
    import trimesh

    sphere = trimesh.creation.icosphere(subdivisions=4)
    placed = Sim3(0.5, axis_angle_matrix(np.array([0.0, 0.0, 1.0]), 0.7), np.array([1.0, 0.0, -2.0]))
    canonical = sphere.sample(20_000, seed=1)
    upper, lower = placed.apply(canonical[canonical[:, 1] > 0.0]), placed.apply(canonical[canonical[:, 1] < 0.0])
    assert top_coverage(sphere, placed, upper) > 0.97
    assert top_coverage(sphere, placed, lower) == 0.0
    assert surface_coverage(sphere, placed, lower) == pytest.approx(0.5, abs=0.04)
    assert top_coverage(None, placed, upper) is None and top_coverage(sphere, placed, upper[:0]) is None
