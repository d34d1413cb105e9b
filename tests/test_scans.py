"""Virtual scanner, scan loading and the real-scan preprocessing, against known answers."""

from __future__ import annotations

import json
import sys

import numpy as np
import pytest
import trimesh

from jsrte.errors import JsrteError
from jsrte.scans.io import ScanCloud, load_scan, read_scan_info
from jsrte.scans.preprocess import (
    check_units,
    estimate_normals,
    hidden_point_removal,
    prepare_scan,
    remove_outliers,
    segment_floor,
)
from jsrte.scans.scanner import ScannerSettings, VirtualScan, scan_mesh, write_scan

NO_OUTLIERS = ScannerSettings(outlier_fraction=0.0)


def stand_in_chair() -> trimesh.Trimesh:
    """A small chair (seat, back, four legs) in the canonical frame: +y up, front -z."""
    move = trimesh.transformations.translation_matrix
    upright = trimesh.transformations.rotation_matrix(np.pi / 2, [1, 0, 0])
    parts = [trimesh.creation.box([0.5, 0.05, 0.5], transform=move([0, 0.45, 0])),
             trimesh.creation.box([0.5, 0.5, 0.05], transform=move([0, 0.72, 0.225]))]
    for x in (-0.22, 0.22):
        for z in (-0.22, 0.22):
            parts.append(trimesh.creation.cylinder(0.02, 0.45, sections=12,
                                                   transform=move([x, 0.225, z]) @ upright))
    return trimesh.util.concatenate(parts)


@pytest.fixture(scope="module")
def chair() -> trimesh.Trimesh:
    return stand_in_chair()


@pytest.fixture(scope="module")
def chair_scan(chair) -> VirtualScan:
    return scan_mesh(chair, rng=np.random.default_rng(3), settings=NO_OUTLIERS)


def sigma(scan: VirtualScan) -> np.ndarray:
    """Noise std (n,) of each point, from its distance to its camera (>= its depth)."""
    s = scan.settings
    distance = np.linalg.norm(scan.points - scan.cameras[scan.view], axis=1)
    return s.noise_scale * (s.noise_a_m + s.noise_b_per_m * distance**2)


# --- scanner ---------------------------------------------------------------------------------


def test_object_points_lie_on_the_transformed_mesh(chair, chair_scan):
    scan = chair_scan
    posed = trimesh.Trimesh(scan.scan_from_mesh.apply(chair.vertices), chair.faces, process=False)
    obj = scan.is_object
    _, distance, _ = trimesh.proximity.closest_point(posed, scan.points[obj])
    within = distance <= 4.0 * sigma(scan)[obj] + 1e-5
    assert obj.sum() > 500
    assert within.mean() > 0.999
    assert distance.max() < 0.15


def test_floor_points_lie_on_the_floor_plane(chair_scan):
    scan = chair_scan
    floor = ~scan.is_object
    height = scan.points[floor] @ scan.up - scan.floor_offset
    assert floor.sum() > 500
    assert (np.abs(height) <= 4.0 * sigma(scan)[floor] + 1e-5).mean() > 0.999


def test_pose_real_size_on_the_floor(chair, chair_scan):
    scan = chair_scan
    g = scan.scan_from_mesh
    heights = g.apply(chair.vertices) @ scan.up - scan.floor_offset
    assert heights.min() == pytest.approx(0.0, abs=1e-9)
    assert 0.6 <= heights.max() <= 1.2
    assert g.R @ np.array([0.0, 1.0, 0.0]) == pytest.approx(scan.up)  # mesh +y is up
    assert abs(scan.floor_offset) > 1e-6 or not np.allclose(scan.up, [0, 1, 0])  # random frame


def test_cameras_above_floor_on_an_arc(chair, chair_scan):
    scan = chair_scan
    centre = scan.scan_from_mesh.apply(chair.bounds.mean(0, keepdims=True))[0]
    rel = scan.cameras - centre
    elevation = np.degrees(np.arcsin(rel @ scan.up / np.linalg.norm(rel, axis=1)))
    assert len(scan.cameras) == 3
    assert np.all(scan.cameras @ scan.up - scan.floor_offset > 0.3)
    assert np.all((elevation > 14.0) & (elevation < 46.0))
    flat = rel - np.outer(rel @ scan.up, scan.up)
    flat /= np.linalg.norm(flat, axis=1, keepdims=True)
    span = np.degrees(np.arccos(np.clip(flat[0] @ flat[-1], -1, 1)))
    assert span == pytest.approx(120.0, abs=1.0)


def test_normals_face_their_camera(chair_scan):
    scan = chair_scan
    towards = scan.cameras[scan.view] - scan.points
    assert np.all(np.einsum("ij,ij->i", scan.normals, towards) >= 0)
    assert np.linalg.norm(scan.normals, axis=1) == pytest.approx(1.0)


def test_same_seed_same_scan(chair):
    settings = ScannerSettings(width=64, height=48)
    a = scan_mesh(chair, rng=np.random.default_rng(7), settings=settings)
    b = scan_mesh(chair, rng=np.random.default_rng(7), settings=settings)
    c = scan_mesh(chair, rng=np.random.default_rng(8), settings=settings)
    assert np.array_equal(a.points, b.points) and np.array_equal(a.normals, b.normals)
    assert np.array_equal(a.scan_from_mesh.matrix(), b.scan_from_mesh.matrix())
    assert len(a.points) != len(c.points) or not np.allclose(a.points, c.points)


def test_world_up_y_and_no_floor(chair):
    scan = scan_mesh(chair, rng=np.random.default_rng(0),
                     settings=ScannerSettings(random_world_frame=False, floor=False))
    assert scan.up == pytest.approx([0.0, 1.0, 0.0])
    assert scan.floor_offset == pytest.approx(0.0)
    assert scan.is_object.all()
    assert scan.points[:, 1].min() > -0.05


def test_outliers_are_flagged_and_off_the_surface(chair):
    scan = scan_mesh(chair, rng=np.random.default_rng(1),
                     settings=ScannerSettings(outlier_fraction=0.02, floor=False))
    posed = trimesh.Trimesh(scan.scan_from_mesh.apply(chair.vertices), chair.faces, process=False)
    _, distance, _ = trimesh.proximity.closest_point(posed, scan.points[scan.is_outlier])
    assert scan.is_outlier.sum() > 10
    assert np.median(distance) > 0.02


def test_bad_settings_are_refused(chair):
    with pytest.raises(JsrteError, match="below"):
        scan_mesh(chair, rng=np.random.default_rng(0),
                  settings=ScannerSettings(elevation_deg=(-10.0, 20.0)))


def test_write_scan_and_load_it_back(tmp_path, chair_scan):
    ply = tmp_path / "scan.ply"
    assert write_scan(chair_scan, ply, seed=3) == ply
    info = json.loads(ply.with_suffix(".json").read_text())
    assert info["seed"] == 3 and info["n_points"] == len(chair_scan.points)
    cloud = load_scan(ply)
    assert np.allclose(cloud.points, chair_scan.points)
    assert np.allclose(cloud.normals, chair_scan.normals)
    meta = read_scan_info(ply)
    assert np.allclose(meta.scan_from_mesh.matrix(), chair_scan.scan_from_mesh.matrix())
    assert np.allclose(meta.up, chair_scan.up) and len(meta.cameras) == 3
    assert not list(tmp_path.glob(".*"))  # no temporary files left


# --- loading ---------------------------------------------------------------------------------


def test_load_point_cloud_formats(tmp_path):
    points = np.random.default_rng(0).normal(size=(100, 3))
    np.savetxt(tmp_path / "a.xyz", points)
    import open3d as o3d

    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
    o3d.io.write_point_cloud(str(tmp_path / "a.pcd"), cloud)
    for name in ("a.xyz", "a.pcd"):
        loaded = load_scan(tmp_path / name)
        assert loaded.points == pytest.approx(points, abs=1e-5)
        assert loaded.normals is None


def test_load_sparse_mesh_is_sampled_densely(tmp_path):
    mesh = trimesh.creation.icosphere(subdivisions=1, radius=0.5)
    mesh.export(tmp_path / "sphere.ply")
    loaded = load_scan(tmp_path / "sphere.ply", dense_points=2000)
    assert len(loaded.points) == 2000
    radius = np.linalg.norm(loaded.points, axis=1)
    assert radius.max() <= 0.5 + 1e-6 and radius.min() > 0.35
    assert np.all(np.einsum("ij,ij->i", loaded.normals, loaded.points) > 0)  # outward
    dense = load_scan(tmp_path / "sphere.ply", dense_points=10)
    assert len(dense.points) == len(mesh.vertices)


@pytest.mark.parametrize(
    ("name", "content", "message"),
    [
        ("missing.ply", None, "no such file"),
        ("empty.ply", b"", "empty"),
        ("bad.ply", b"not a ply at all\n", "not a PLY"),
        ("nan.xyz", b"0 0 0\nnan 1 2\n1 1 1\n", "NaN"),
        ("scan.las", b"xx", "unsupported"),
        ("blank.xyz", b"\n\n", "no points"),
    ],
)
def test_load_errors_name_the_file(tmp_path, name, content, message):
    path = tmp_path / name
    if content is not None:
        path.write_bytes(content)
    with pytest.raises(JsrteError, match=message) as error:
        load_scan(path)
    assert name in str(error.value)


# --- preprocessing ---------------------------------------------------------------------------


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_segment_floor_recovers_up_in_a_random_frame(chair, seed):
    scan = scan_mesh(chair, rng=np.random.default_rng(seed))
    floor = segment_floor(scan.points, rng=np.random.default_rng(0))
    angle = np.degrees(np.arccos(np.clip(floor.normal @ scan.up, -1.0, 1.0)))
    assert angle < 2.0  # and the sign: the normal points towards the object
    assert floor.offset == pytest.approx(scan.floor_offset, abs=0.01)
    assert floor.inliers[~scan.is_object].mean() > 0.5
    assert floor.inliers[scan.is_object].mean() < 0.05


@pytest.mark.parametrize("shape", ["box", "sphere"])
@pytest.mark.parametrize("with_normals", [True, False])
def test_segment_floor_refuses_a_scan_without_floor(shape, with_normals):
    mesh = (trimesh.creation.box([1.0, 0.6, 0.8]) if shape == "box"
            else trimesh.creation.icosphere(subdivisions=3))
    scan = scan_mesh(mesh, rng=np.random.default_rng(0),
                     settings=ScannerSettings(floor=False, width=96, height=72))
    with pytest.raises(JsrteError, match="no floor found.*--up"):
        segment_floor(scan.points, normals=scan.normals if with_normals else None,
                      rng=np.random.default_rng(0))


def test_segment_floor_looks_past_a_table_top():
    """A low table seen from high up: its top is the biggest plane, the floor the second."""
    move = trimesh.transformations.translation_matrix
    parts = [trimesh.creation.box([1.2, 0.04, 0.8], transform=move([0, 0.4, 0]))]
    parts += [trimesh.creation.box([0.04, 0.4, 0.04], transform=move([x, 0.2, z]))
              for x in (-0.55, 0.55) for z in (-0.35, 0.35)]
    settings = ScannerSettings(target_height_m=(0.4, 0.4), crop_factor=1.0,
                               elevation_deg=(55.0, 75.0), width=80, height=60)
    scan = scan_mesh(trimesh.util.concatenate(parts), rng=np.random.default_rng(0),
                     settings=settings)
    top = scan.points @ scan.up - scan.floor_offset > 0.35
    assert top.mean() > 2 * (~scan.is_object).mean()
    floor = segment_floor(scan.points, normals=scan.normals, rng=np.random.default_rng(0))
    assert floor.normal @ scan.up > np.cos(np.radians(1.0))


def test_prepare_scan_keeps_the_object(chair):
    scan = scan_mesh(chair, rng=np.random.default_rng(5),
                     settings=ScannerSettings(outlier_fraction=0.01))
    prepared = prepare_scan(ScanCloud(scan.points, scan.normals), rng=np.random.default_rng(0))
    on_object = scan.is_object[prepared.index]
    assert on_object.mean() > 0.995
    assert on_object.sum() > 0.8 * scan.is_object.sum()
    assert scan.is_outlier[prepared.index].sum() < 0.3 * scan.is_outlier.sum()
    assert prepared.up @ scan.up > np.cos(np.radians(2.0))
    assert np.allclose(prepared.normals, scan.normals[prepared.index])


def test_prepare_scan_with_known_up_and_estimated_normals(chair):
    scan = scan_mesh(chair, rng=np.random.default_rng(6), settings=NO_OUTLIERS)
    prepared = prepare_scan(ScanCloud(scan.points, None), up=scan.up, viewpoints=scan.cameras,
                            rng=np.random.default_rng(0))
    assert prepared.up == pytest.approx(scan.up)
    assert scan.is_object[prepared.index].mean() > 0.995
    assert len(prepared.index) > 0.7 * scan.is_object.sum()  # hidden point removal keeps most
    agree = np.einsum("ij,ij->i", prepared.normals, scan.normals[prepared.index]) > 0
    assert agree.mean() > 0.9


def test_prepare_scan_without_floor_needs_up(chair):
    scan = scan_mesh(chair, rng=np.random.default_rng(0), settings=ScannerSettings(floor=False))
    with pytest.raises(JsrteError, match="--up"):
        prepare_scan(ScanCloud(scan.points, scan.normals), rng=np.random.default_rng(0))
    prepared = prepare_scan(ScanCloud(scan.points, scan.normals), up=scan.up,
                            rng=np.random.default_rng(0))
    assert prepared.floor is None and len(prepared.points) > 0.8 * len(scan.points)


def sphere_points(n: int, radius: float, rng: np.random.Generator) -> np.ndarray:
    v = rng.normal(size=(n, 3))
    return radius * v / np.linalg.norm(v, axis=1, keepdims=True)


def test_remove_outliers_finds_far_points():
    rng = np.random.default_rng(0)
    points = np.concatenate([sphere_points(3000, 0.3, rng), rng.uniform(-1, 1, size=(30, 3))])
    keep = remove_outliers(points)
    assert keep[:3000].mean() > 0.9
    assert keep[3000:].mean() < 0.2


def test_hidden_point_removal_drops_the_far_side():
    points = sphere_points(4000, 0.3, np.random.default_rng(1))
    viewpoint = np.array([0.0, 0.0, 2.0])
    visible = hidden_point_removal(points, viewpoint)
    near = points[:, 2] > 0.05
    far = points[:, 2] < -0.05
    assert visible[near].mean() > 0.95
    assert visible[far].mean() < 0.02


@pytest.mark.parametrize("viewpoints", [None, np.array([[0.0, 0.0, 2.0], [2.0, 0.0, 0.0]])])
def test_estimate_normals_outward_on_a_sphere(viewpoints):
    points = sphere_points(3000, 0.3, np.random.default_rng(2))
    normals = estimate_normals(points, viewpoints=viewpoints)
    cosine = np.einsum("ij,ij->i", normals, points / 0.3)
    if viewpoints is None:
        assert np.mean(cosine > 0.9) > 0.99
    else:  # only the points those viewpoints see are sure to face outward
        seen = (points[:, 2] > 0.05) | (points[:, 0] > 0.05)
        assert np.mean(cosine[seen] > 0.9) > 0.99


def test_check_units_catches_millimetres(chair_scan, tmp_path):
    assert 0.5 < check_units(chair_scan.points) < 10.0
    with pytest.raises(JsrteError, match="millimetres"):
        check_units(chair_scan.points * 1000.0, "scan.ply")
    with pytest.raises(JsrteError, match="too small|wrong units"):
        check_units(chair_scan.points * 0.001)
    with pytest.raises(JsrteError, match=r"scan_mm\.ply.*millimetres"):
        prepare_scan(ScanCloud(chair_scan.points * 1000.0, None, tmp_path / "scan_mm.ply"),
                     rng=np.random.default_rng(0))


# --- CLI -------------------------------------------------------------------------------------


def run_cli(monkeypatch, *args: str) -> int:
    from jsrte.cli import main

    monkeypatch.setattr(sys, "argv", ["jsrte", *map(str, args)])
    with pytest.raises(SystemExit) as stop:
        main()
    return stop.value.code or 0


def test_cli_scan_end_to_end(tmp_path, monkeypatch, capsys):
    mesh = tmp_path / "box.obj"
    trimesh.creation.box([0.5, 0.8, 0.4]).export(mesh)
    out = tmp_path / "out" / "SCAN.ply"
    args = ["scan", mesh, "--out", out, "--seed", "4", "--width", "80", "--height", "60"]
    assert run_cli(monkeypatch, *args, "--world-up-y", "--height-range", "1.0,1.0") == 0
    info = json.loads(out.with_suffix(".json").read_text())
    assert info["seed"] == 4 and info["up"] == pytest.approx([0, 1, 0])
    cloud = load_scan(out)
    assert len(cloud.points) == info["n_points"] > 100
    object_height = cloud.points[:, 1].max()
    assert object_height == pytest.approx(1.0, abs=0.05)

    assert run_cli(monkeypatch, *args) == 2  # exists
    assert "--overwrite" in capsys.readouterr().err
    assert run_cli(monkeypatch, *args, "--overwrite", "--no-floor", "--views", "2") == 0
    assert json.loads(out.with_suffix(".json").read_text())["settings"]["views"] == 2


def test_cli_scan_bad_mesh_is_one_line_and_writes_nothing(tmp_path, monkeypatch, capsys):
    bad = tmp_path / "bad.obj"
    bad.write_text("this is not a mesh\n")
    out = tmp_path / "scan.ply"
    assert run_cli(monkeypatch, "scan", bad, "--out", out) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "bad.obj" in err
    assert list(tmp_path.iterdir()) == [bad]
