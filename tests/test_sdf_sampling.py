"""DeepSDF-style SDF sampling of meshes."""

import numpy as np
import pytest
import trimesh

from jsrte.errors import JsrteError
from jsrte.geometry.mesh import load_mesh, unit_sphere_normalization
from jsrte.presets import SdfSampling
from jsrte.sdf.mesh_sdf import SdfSamples, sample_sdf, signed_distance

SMALL = SdfSampling(n_points=20_000)


def test_sphere_sdf_values_and_signs():
    sphere = trimesh.creation.icosphere(subdivisions=5, radius=0.5)
    points = np.random.default_rng(0).uniform(-1, 1, size=(5000, 3))
    expected = np.linalg.norm(points, axis=1) - 0.5
    d = signed_distance(sphere, points)
    np.testing.assert_allclose(d, expected, atol=3e-3)  # icosphere chords vs the true sphere
    assert np.all(np.sign(d[np.abs(expected) > 3e-3]) == np.sign(expected[np.abs(expected) > 3e-3]))


def test_box_sdf_values():
    box = trimesh.creation.box(extents=(0.6, 0.4, 0.2))
    pts = np.array([[0, 0, 0], [0.5, 0, 0], [0, 0.3, 0], [0.4, 0.3, 0], [0.25, 0, 0]])
    expected = np.array([-0.1, 0.2, 0.1, np.hypot(0.1, 0.1), -0.05])
    np.testing.assert_allclose(signed_distance(box, pts), expected, atol=5e-4)  # float32 inside


def test_signs_on_open_mesh_by_winding_number():
    box = trimesh.creation.box(extents=(1, 1, 1)).subdivide().subdivide()
    keep = np.ones(len(box.faces), bool)
    keep[::50] = False  # cut holes
    holed = trimesh.Trimesh(box.vertices, box.faces[keep], process=False)
    assert not holed.is_watertight
    pts = np.random.default_rng(1).uniform(-0.8, 0.8, size=(4000, 3))
    truth = np.where(np.abs(pts).max(1) < 0.5, -1, 1)
    margin = np.abs(np.abs(pts).max(1) - 0.5) > 0.02
    agree = np.sign(signed_distance(holed, pts))[margin] == truth[margin]
    assert agree.mean() > 0.999


def test_samples_normalized_and_reproducible():
    mesh = trimesh.creation.box(extents=(2.0, 1.0, 0.5))
    mesh.apply_translation([3, 4, 5])
    a = sample_sdf(mesh, rng=np.random.default_rng(7), settings=SMALL)
    b = sample_sdf(mesh, rng=np.random.default_rng(7), settings=SMALL)
    np.testing.assert_array_equal(a.points, b.points)
    np.testing.assert_array_equal(a.sdf, b.sdf)
    norm = unit_sphere_normalization(mesh)
    np.testing.assert_allclose(a.centre, [3, 4, 5])
    assert a.scale == pytest.approx(norm.scale)
    assert a.points.dtype == np.float32 and a.points.shape == (SMALL.n_points, 3)
    # the normalized mesh lies in the unit sphere with DeepSDF's padding
    canon = norm.to_canonical(mesh.vertices)
    assert np.linalg.norm(canon, axis=1).max() == pytest.approx(1 / 1.03)
    # near-surface samples cluster at the surface; uniform ones fill the cube
    n_near = int(SMALL.n_points * SMALL.near_fraction)
    assert np.median(np.abs(a.sdf[:n_near])) < 0.03
    assert np.abs(a.points[n_near:]).max() <= 1.0
    # SDF values scale back to mesh units: points * scale + centre, sdf * scale
    mesh_pts = a.points[:200].astype(np.float64) * a.scale + a.centre
    np.testing.assert_allclose(signed_distance(mesh, mesh_pts), a.sdf[:200] * a.scale, atol=1e-4)


def test_sample_file_round_trip_and_bad_file(tmp_path):
    s = sample_sdf(trimesh.creation.icosphere(), rng=np.random.default_rng(0), settings=SMALL)
    s.save(tmp_path / "s.npz")
    back = SdfSamples.load(tmp_path / "s.npz")
    np.testing.assert_array_equal(back.points, s.points)
    (tmp_path / "bad.npz").write_bytes(b"not a zip")
    with pytest.raises(JsrteError, match="bad.npz"):
        SdfSamples.load(tmp_path / "bad.npz")


def test_bad_meshes_are_refused(tmp_path):
    (tmp_path / "empty.obj").write_text("")
    with pytest.raises(JsrteError, match="empty"):
        load_mesh(tmp_path / "empty.obj")
    (tmp_path / "nan.obj").write_text("v nan 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    with pytest.raises(JsrteError, match="NaN"):
        load_mesh(tmp_path / "nan.obj")
    (tmp_path / "flat.obj").write_text("v 0 0 0\nv 1 0 0\nv 2 0 0\nf 1 2 3\n")
    with pytest.raises(JsrteError, match="zero surface area|no triangles"):
        load_mesh(tmp_path / "flat.obj")
    with pytest.raises(JsrteError, match="no such file"):
        load_mesh(tmp_path / "missing.ply")
