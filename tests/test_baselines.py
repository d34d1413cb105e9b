"""The baselines: registration, descriptors, the PointNet classifier, each method end to end, CLI."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import trimesh

from jsrte.baselines import BASELINE_NAMES, BaselineFailed, ShapeDatabase, get_baseline
from jsrte.baselines import pcl as pcl_binding
from jsrte.baselines.fpfh_ransac import FpfhSettings
from jsrte.baselines.pointnet import PointNetSettings, canonicalize, train_classifier
from jsrte.baselines.registration import coarse_alignment, icp_assignment, register, upright_rotation
from jsrte.geometry.mesh import unit_sphere_normalization
from jsrte.geometry.sim3 import Sim3, rotation_angle_deg
from jsrte.result import FitResult
from jsrte.shapes import generate_set

needs_pcl = pytest.mark.skipif(not pcl_binding.available(),
                               reason="PCL (libpcl-dev) is not installed; see jsrte.baselines.pcl")

UP = np.array([0.2, 0.95, -0.1]) / np.linalg.norm([0.2, 0.95, -0.1])
TINY_POINTNET = PointNetSettings(points=128, epochs=10, copies_per_epoch=6, batch_size=16, lr=3e-3,
                                 lr_decay_every=8, widths=(32, 64, 128), head=(64,), dropout=0.1)
SMALL_POINTNET = PointNetSettings(points=256, epochs=12, copies_per_epoch=6, batch_size=16, lr=3e-3,
                                  lr_decay_every=8, widths=(32, 64, 128), head=(64,), dropout=0.1)


@pytest.fixture(scope="module")
def database() -> ShapeDatabase:
    return ShapeDatabase([s.mesh for s in generate_set("chair", 4, 0)], samples=6000, persist=False)


def truth(yaw_deg: float = 50.0, scale: float = 0.7) -> Sim3:
    """A scan_from_canonical pose: upright about UP, a yaw, a scale, a translation (metres)."""
    return Sim3(scale, upright_rotation(UP, np.radians(yaw_deg)), np.array([1.5, -0.3, 2.0]))


def query_of(database: ShapeDatabase, index: int, g: Sim3, stride: int = 2) -> tuple[np.ndarray, np.ndarray]:
    return g.apply(database.points(index)[::stride]), g.apply_vectors(database.normals(index)[::stride])


# --- registration ----------------------------------------------------------------------------------


def test_icp_with_optimal_assignment_recovers_a_similarity_exactly(database):
    rng = np.random.default_rng(0)
    source = database.points(0)[rng.choice(6000, 300, replace=False)]
    g = truth(yaw_deg=37.0, scale=1.8)
    target = g.apply(source)[rng.permutation(300)]
    init, _ = coarse_alignment(target, source, UP)
    found, rmse, _, converged = icp_assignment(source, target, init)
    assert converged and rmse < 1e-6
    assert abs(found.s - g.s) < 1e-6
    assert np.abs(found.R - g.R).max() < 1e-6
    assert np.abs(found.t - g.t).max() < 1e-6


def test_coarse_search_and_icp_recover_yaw_scale_translation_of_a_chair(database):
    g = truth(yaw_deg=130.0, scale=0.6)
    query = g.apply(database.points(1)[1::3])  # other samples of the same surface
    reg = register(query, database.points(1), UP, rng=np.random.default_rng(1))
    assert abs(reg.yaw_deg - 130.0) <= 10.0 + 1e-9  # the 20° grid
    assert rotation_angle_deg(reg.transform.R, g.R) < 4.0
    assert abs(reg.transform.s / g.s - 1.0) < 0.03
    assert np.linalg.norm(reg.transform.t - g.t) < 0.03 * g.s


# --- descriptors -----------------------------------------------------------------------------------


@needs_pcl
def test_shot_at_keypoints_of_a_rotated_cloud_matches(database):
    from jsrte.baselines.harris_shot import HarrisShotSettings, match_descriptors

    st = HarrisShotSettings()
    points, normals = database.points(2), database.normals(2)
    keypoints, _ = pcl_binding.harris3d(points, normals, radius=st.harris_radius,
                                        threshold=st.harris_threshold)
    assert len(keypoints) >= 10
    r = upright_rotation(UP, 1.1)
    a = pcl_binding.shot(points, normals, keypoints, radius=st.shot_radius)
    b = pcl_binding.shot(points @ r.T, normals @ r.T, keypoints @ r.T, radius=st.shot_radius)
    ok = np.all(np.isfinite(a), axis=1) & np.all(np.isfinite(b), axis=1)
    m = match_descriptors(b[ok], a[ok], max_distance_sq=0.25)
    assert np.mean(m.query == m.shape) > 0.9 and len(m) > 0.9 * ok.sum()


@needs_pcl
def test_ourcvfh_of_a_rotated_shape_is_nearest_its_original():
    from jsrte.baselines.ourcvfh_icp import OurCvfhSettings, ourcvfh_signatures, signature_distance

    db = ShapeDatabase([s.mesh for s in generate_set("chair", 5, 0)], samples=6000, persist=False)
    st = OurCvfhSettings()
    originals = [ourcvfh_signatures(db.points(i), db.normals(i), st)["signatures"] for i in range(5)]
    r = Sim3(2.5, upright_rotation(np.array([0.3, 0.2, 0.93]), 2.0), np.array([3.0, 1.0, -1.0]))
    for i in range(5):
        turned = ourcvfh_signatures(r.apply(db.points(i)), r.apply_vectors(db.normals(i)), st)["signatures"]
        assert int(np.argmin([signature_distance(turned, o) for o in originals])) == i


def test_pointnet_learns_a_three_shape_toy_set():
    meshes = [trimesh.creation.box((1.0, 0.2, 0.6)), trimesh.creation.icosphere(3),
              trimesh.creation.cylinder(0.2, 1.5)]
    pools = [canonicalize(trimesh.sample.sample_surface(m, 3000, seed=i)[0], np.array([0.0, 1.0, 0.0]))
             for i, m in enumerate(meshes)]
    trained = train_classifier(pools, TINY_POINTNET)
    rng = np.random.default_rng(5)
    clouds, labels = [], []
    for label, pool in enumerate(pools):
        for _ in range(10):
            turned = pool[rng.choice(len(pool), 128)] @ upright_rotation(np.array([0.0, 1.0, 0.0]),
                                                                         rng.uniform(0, 6.3)).T
            clouds.append(turned + rng.normal(0, 0.01, turned.shape))
            labels.append(label)
    accuracy = np.mean(trained.predict(np.stack(clouds)).argmax(1) == np.array(labels))
    assert accuracy > 0.9


# --- end to end ------------------------------------------------------------------------------------


def mean_alignment_error(result: FitResult, query: np.ndarray) -> float:
    """Mean distance from the query points to the retrieved shape placed by the result."""
    placed = result.mesh
    _, dist, _ = trimesh.proximity.closest_point(placed, query[::10])
    return float(dist.mean())


@pytest.mark.parametrize("name", BASELINE_NAMES)
def test_each_baseline_retrieves_a_database_shape_and_places_it(name, database, tmp_path):
    if name in ("harris3d-shot", "ourcvfh-icp") and not pcl_binding.available():
        pytest.skip("PCL is not installed")
    options = {"pointnet-icp": {"settings": SMALL_POINTNET, "cache": tmp_path},
               "fpfh-ransac-icp": {"settings": FpfhSettings(ransac_iterations=10_000)}}.get(name, {})
    baseline = get_baseline(name, **options)
    g = truth(yaw_deg=200.0, scale=0.8)
    points, normals = query_of(database, 2, g)
    result = baseline.fit(points, normals, UP, database, rng=np.random.default_rng(0))
    assert isinstance(result, FitResult) and result.method == name and result.latent is None
    assert result.info["retrieved_index"] == 2
    assert mean_alignment_error(result, points) < 0.02 * g.s  # 2% of the unit radius
    assert abs(result.transform.s / g.s - 1.0) < 0.05
    json.dumps(result.to_json())


@pytest.mark.parametrize("name", BASELINE_NAMES)
def test_a_five_point_query_fails_clearly(name, database, tmp_path):
    options = {"settings": TINY_POINTNET, "cache": tmp_path} if name == "pointnet-icp" else {}
    points = np.random.default_rng(0).normal(size=(5, 3))
    with pytest.raises(BaselineFailed, match="only 5 points"):
        get_baseline(name, **options).fit(points, points, UP, database, rng=np.random.default_rng(0))


# --- CLI (run_cli: tests/conftest.py) ------------------------------------------------------------


def test_cli_help_lists_the_four_baselines():
    from typer.testing import CliRunner

    from jsrte.cli import _register, app

    _register()
    out = CliRunner().invoke(app, ["baseline", "--help"], env={"COLUMNS": "200"}).output
    for name in BASELINE_NAMES:
        assert name in out


def test_cli_baseline_writes_the_fit_files(tmp_path, monkeypatch, run_cli):
    monkeypatch.setenv("JSRTE_CACHE", str(tmp_path / "cache"))
    model = tmp_path / "model"
    code, _, err = run_cli(["train", "--category", "chair", "--shapes", "3", "--steps", "2",
                            "--samples", "3000", "--out", str(model), "--no-progress"])
    assert code == 0, err
    mesh = tmp_path / "query.obj"
    chair = generate_set("chair", 3, 0)[1].mesh
    expected_scale = truth().s * unit_sphere_normalization(chair).scale
    chair.apply_transform(truth().matrix())
    chair.export(mesh)
    out = tmp_path / "out"
    args = ["baseline", "fpfh-ransac-icp", str(mesh), "--model", str(model), "--out", str(out),
            "--up", ",".join(map(str, UP))]
    code, stdout, err = run_cli(args)
    assert code == 0, err
    for name in ("fit.json", "shape.ply", "shape_canonical.ply", "overlay.png"):
        assert (out / name).is_file()
    fit = json.loads((out / "fit.json").read_text())
    assert fit["method"] == "fpfh-ransac-icp" and fit["retrieved_index"] == 1 and fit["latent"] is None
    assert abs(fit["scale"] / expected_scale - 1.0) < 0.05
    code, _, err = run_cli(args)
    assert code == 2 and "--overwrite" in err
    code, _, err = run_cli(["baseline", "nope", str(mesh), "--model", str(model),
                            "--out", str(tmp_path / "x")])
    assert code == 2 and "unknown baseline" in err and not (tmp_path / "x").exists()


def test_model_database_is_cached(tmp_path, monkeypatch):
    class FakeModel:
        name = "fake"
        meta = {"sha256": "ab" * 32, "data": {"source": "procedural", "category": "chair", "set_seed": 0,
                                              "n_shapes": 2}}

    monkeypatch.setenv("JSRTE_CACHE", str(tmp_path))
    first = ShapeDatabase.from_model(FakeModel(), samples=500)
    assert len(list(Path(tmp_path, "databases").glob("*.npz"))) == 1
    second = ShapeDatabase.from_model(FakeModel(), samples=500)
    assert np.allclose(first.meshes[1].vertices, second.meshes[1].vertices)
    assert abs(np.linalg.norm(first.meshes[0].vertices, axis=1).max() * 1.03 - 1.0) < 0.05
