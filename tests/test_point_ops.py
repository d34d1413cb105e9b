"""The scan preprocessing's point operations (jsrte.geometry.point_ops) and the PLY reader give
what Open3D gives (imported here only, as the reference), and what geometry says they must."""

import warnings

import numpy as np
import open3d as o3d
import pytest

from jsrte.geometry.point_ops import (
    dbscan_labels,
    pca_normals,
    smallest_eigenvectors,
    statistical_inliers,
    visible_points,
)
from jsrte.scans.io import load_scan


def _unit_sphere(n: int, rng: np.random.Generator) -> np.ndarray:
    v = rng.normal(size=(n, 3))
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def _clouds() -> dict[str, np.ndarray]:
    """Random and structured clouds, some with duplicate points and exact distance ties."""
    rng = np.random.default_rng(7)
    grid = np.stack(np.meshgrid(*[np.arange(9.0) * 0.1] * 3), -1).reshape(-1, 3)
    rotation = np.linalg.qr(rng.normal(size=(3, 3)))[0]
    plane = np.c_[rng.random((1500, 2)), np.zeros(1500)] @ rotation.T + [1.0, -2.0, 0.5]
    room = np.vstack([rng.random((1500, 3)) * [4, 0.01, 4], _unit_sphere(800, rng) * 0.4 + [2, 0.5, 2],
                      rng.normal(size=(30, 3)) * 3])
    duplicated = np.vstack([rng.random((600, 3)), np.repeat(rng.random((5, 3)), 25, axis=0)])
    plane_grid = np.c_[grid[grid[:, 2] == 0, :2] * [1.0, 1.3], np.zeros(81)] @ rotation.T
    return {"uniform": rng.random((2000, 3)), "gaussian": rng.normal(size=(2000, 3)), "grid": grid,
            "plane_grid": plane_grid,
            "sphere": _unit_sphere(2000, rng), "plane": plane, "room": room, "duplicated": duplicated}


CLOUDS = _clouds()


def _cloud(points: np.ndarray) -> o3d.geometry.PointCloud:
    return o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.asarray(points, np.float64)))


def _as_mask(n: int, index: list[int]) -> np.ndarray:
    mask = np.zeros(n, dtype=bool)
    mask[np.asarray(index, dtype=np.int64)] = True
    return mask


def _spacing(points: np.ndarray) -> float:
    from jsrte.geometry.point_ops import median_spacing

    return median_spacing(points)


# --- the same as Open3D ---------------------------------------------------------------------------


@pytest.mark.parametrize("name", sorted(CLOUDS))
@pytest.mark.parametrize("neighbours,ratio", [(20, 2.0), (6, 1.0)])
def test_statistical_inliers_equal_open3d(name, neighbours, ratio):
    points = CLOUDS[name]
    _, kept = _cloud(points).remove_statistical_outlier(neighbours, ratio)
    expected = _as_mask(len(points), kept)
    mine = statistical_inliers(points, neighbours, ratio)
    assert 0 < expected.sum() < len(points) or name == "grid"
    np.testing.assert_array_equal(mine, expected)


@pytest.mark.parametrize("name", sorted(CLOUDS))
@pytest.mark.parametrize("factor", [1000.0, 30.0])
def test_visible_points_equal_open3d(name, factor):
    points = CLOUDS[name]
    extent = float(np.linalg.norm(np.ptp(points, axis=0)))
    for direction in ([3.0, 2.0, 1.0], [0.0, 0.5, 0.0], [-1.0, 4.0, -2.0]):
        viewpoint = points.mean(0) + np.array(direction) * extent
        _, visible = _cloud(points).hidden_point_removal(viewpoint, factor * extent)
        np.testing.assert_array_equal(visible_points(points, viewpoint, factor * extent),
                                      _as_mask(len(points), visible))


@pytest.mark.parametrize("name", sorted(set(CLOUDS) - {"grid"}))
@pytest.mark.parametrize("spacings,max_nn", [(6.0, 30), (2.0, 30), (40.0, 10)])
def test_pca_normals_equal_open3d(name, spacings, max_nn):
    """The same normals. Not on a cubic grid: its neighbourhoods are isotropic (any direction is
    a normal), and where the ``max_nn``-th nearest neighbour ties with the next, which of the
    tied points a kd-tree returns is its own choice (on the planar grid any choice gives the
    plane's normal)."""
    points = CLOUDS[name]
    radius = spacings * _spacing(points)
    cloud = _cloud(points)
    cloud.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius, max_nn))
    expected = np.asarray(cloud.normals)
    mine = pca_normals(points, radius, max_nn)
    error = np.minimum(np.abs(mine - expected).max(1), np.abs(mine + expected).max(1))
    assert error.max() < 1e-6, (np.argmax(error), error.max())


@pytest.mark.parametrize("name", sorted(CLOUDS))
@pytest.mark.parametrize("spacings,min_points", [(4.0, 10), (1.5, 5), (8.0, 40)])
def test_dbscan_labels_equal_open3d(name, spacings, min_points):
    points = CLOUDS[name]
    eps = spacings * _spacing(points)
    expected = np.asarray(_cloud(points).cluster_dbscan(eps, min_points))
    np.testing.assert_array_equal(dbscan_labels(points, eps, min_points), expected)


def test_dbscan_counts_a_neighbour_at_exactly_eps_out_as_open3d():
    """On a grid of unit spacing, eps 1: only distances below eps count (every point is noise)."""
    points = np.stack(np.meshgrid(*[np.arange(5.0)] * 3), -1).reshape(-1, 3)
    assert (dbscan_labels(points, 1.0, 2) == -1).all()
    assert (np.asarray(_cloud(points).cluster_dbscan(1.0, 2)) == -1).all()
    assert (dbscan_labels(points, 1.01, 2) == 0).all()


# --- what geometry says ----------------------------------------------------------------------------


def test_normals_of_a_plane_are_its_normal():
    rng = np.random.default_rng(1)
    normal = np.array([1.0, 2.0, -2.0]) / 3.0
    across = np.linalg.svd(normal[None])[2][1:]
    points = rng.random((3000, 2)) @ across + 0.3 * normal
    found = pca_normals(points, 6 * _spacing(points), 30)
    np.testing.assert_allclose(np.abs(found @ normal), 1.0, atol=1e-9)


def test_normals_of_a_sphere_are_radial():
    points = _unit_sphere(5000, np.random.default_rng(2))
    found = pca_normals(points, 6 * _spacing(points), 30)
    assert np.percentile(np.abs(np.einsum("ij,ij->i", found, points)), 5) > 0.995


def test_eigenvectors_of_known_matrices():
    rng = np.random.default_rng(3)
    rotations = np.linalg.qr(rng.normal(size=(200, 3, 3)))[0]
    values = np.sort(rng.random((200, 3)) * 5, axis=1) + [0.0, 0.5, 1.0]
    matrices = np.einsum("nij,nj,nkj->nik", rotations, values, rotations)
    found = smallest_eigenvectors(matrices)
    np.testing.assert_allclose(np.abs(np.einsum("ni,ni->n", found, rotations[:, :, 0])), 1.0, atol=1e-8)
    special = np.array([np.zeros((3, 3)), np.diag([2.0, 1.0, 3.0]), np.diag([1.0, 2.0, 3.0]), np.eye(3)])
    np.testing.assert_array_equal(smallest_eigenvectors(special), [[0, 0, 1], [0, 1, 0], [1, 0, 0], [0, 0, 1]])


def test_two_separated_blobs_are_two_clusters_numbered_by_first_point():
    rng = np.random.default_rng(4)
    blobs = np.vstack([rng.random((300, 3)) * 0.3 + [1, 0, 0], rng.random((300, 3)) * 0.3])
    labels = dbscan_labels(blobs, 0.1, 10)
    assert set(labels[:300]) == {0} and set(labels[300:]) == {1}


def test_a_far_point_is_an_outlier_and_noise():
    rng = np.random.default_rng(5)
    points = np.vstack([rng.random((500, 3)), [[10.0, 10.0, 10.0]]])
    kept = statistical_inliers(points, 20, 2.0)
    assert not kept[-1] and kept.mean() > 0.9
    assert dbscan_labels(points, 0.2, 10)[-1] == -1


def test_coinciding_points_are_dropped_as_open3d_does():
    """A point whose neighbours all coincide with it scores 0 and is dropped."""
    points = np.vstack([np.random.default_rng(6).random((200, 3)), np.zeros((30, 3))])
    kept = statistical_inliers(points, 20, 2.0)
    assert not kept[200:].any() and kept[:200].mean() > 0.9


@pytest.mark.parametrize("distance", [5.0, 50.0])
def test_hidden_point_removal_sees_the_near_cap_of_a_sphere(distance):
    """From ``distance`` radii, a unit sphere's visible cap is z > 1/distance: (1 - 1/distance)/2 of it."""
    points = _unit_sphere(4000, np.random.default_rng(8))
    visible = visible_points(points, np.array([0.0, 0.0, distance]), 1000 * 2.0)
    assert visible.mean() == pytest.approx((1 - 1 / distance) / 2, abs=0.02)
    horizon = 1 / distance
    assert visible[points[:, 2] > horizon + 0.05].all() and not visible[points[:, 2] < horizon - 0.1].any()


def test_hidden_point_removal_of_too_few_or_flat_points_sees_all():
    assert visible_points(np.eye(3), np.array([5.0, 5.0, 5.0]), 100.0).all()
    flat = np.c_[np.random.default_rng(9).random((50, 2)), np.zeros(50)]
    assert visible_points(flat, np.array([0.5, 0.5, 0.0]), 100.0).all()
    cloud = np.random.default_rng(9).random((50, 3))
    assert visible_points(cloud, cloud[7], 100.0).all()  # a point at the viewpoint: no direction to it
    assert not visible_points(cloud, np.array([0.5, 0.5, 5.0]), 100.0).all()


# --- reading PLY files --------------------------------------------------------------------------------


@pytest.mark.parametrize("ascii", [False, True])
@pytest.mark.parametrize("normals", [False, True])
def test_ply_reads_as_open3d_reads_it(tmp_path, ascii, normals):
    rng = np.random.default_rng(10)
    cloud = _cloud(rng.normal(size=(300, 3)))
    if normals:
        cloud.normals = o3d.utility.Vector3dVector(_unit_sphere(300, rng))
    path = tmp_path / "cloud.ply"
    assert o3d.io.write_point_cloud(str(path), cloud, write_ascii=ascii)
    expected = o3d.io.read_point_cloud(str(path))
    loaded = load_scan(path)
    np.testing.assert_array_equal(loaded.points, np.asarray(expected.points))
    if normals:
        unit = np.asarray(expected.normals) / np.linalg.norm(np.asarray(expected.normals), axis=1, keepdims=True)
        np.testing.assert_allclose(loaded.normals, unit, atol=1e-15)
    else:
        assert loaded.normals is None


@pytest.mark.parametrize("fmt", ["ascii", "binary_little_endian", "binary_big_endian"])
@pytest.mark.parametrize("kind", ["f4", "f8", "i4", "u1", "i2"])
def test_ply_of_any_property_type_and_byte_order(tmp_path, fmt, kind):
    from plyfile import PlyData, PlyElement

    rng = np.random.default_rng(11)
    values = (rng.random((60, 3)) * 100).astype(kind)
    vertex = np.zeros(60, dtype=[("x", kind), ("y", kind), ("z", kind), ("nx", "f4"), ("ny", "f4"),
                                 ("nz", "f4"), ("red", "u1")])
    for i, axis in enumerate("xyz"):
        vertex[axis] = values[:, i]
    vertex["ny"] = 1.0
    element = PlyElement.describe(vertex, "vertex")
    path = tmp_path / "cloud.ply"
    PlyData([element], text=fmt == "ascii", byte_order="<" if fmt != "binary_big_endian" else ">").write(str(path))
    loaded = load_scan(path)
    np.testing.assert_array_equal(loaded.points, values.astype(np.float64))
    np.testing.assert_array_equal(loaded.normals, np.tile([0.0, 1.0, 0.0], (60, 1)))


def _vertices(n: int, seed: int) -> np.ndarray:
    vertex = np.zeros(n, dtype=[("x", "f8"), ("y", "f8"), ("z", "f8")])
    for axis, values in zip("xyz", np.random.default_rng(seed).normal(size=(3, n)), strict=True):
        vertex[axis] = values
    return vertex


@pytest.mark.parametrize("text", [True, False])
def test_ply_with_another_element_before_the_vertices(tmp_path, text):
    from plyfile import PlyData, PlyElement

    camera = np.array([(1.0, 2.0, 3, 7), (4.0, 5.0, 6, 8)], dtype=[("px", "f4"), ("py", "f8"), ("k", "u1"),
                                                                    ("j", "i2")])
    vertex = _vertices(40, 12)
    path = tmp_path / "cloud.ply"
    PlyData([PlyElement.describe(camera, "camera"), PlyElement.describe(vertex, "vertex")], text=text).write(str(path))
    loaded = load_scan(path)
    np.testing.assert_array_equal(loaded.points, np.column_stack([vertex[a] for a in "xyz"]))


def test_ply_with_a_list_before_the_vertices_is_read_by_open3d(tmp_path):
    from plyfile import PlyData, PlyElement

    from jsrte.scans.ply import read_ply_cloud

    tags = np.empty(2, dtype=[("ids", "O")])
    tags["ids"] = [np.array([1, 2, 3], np.int32), np.array([4], np.int32)]
    vertex = _vertices(30, 13)
    path = tmp_path / "cloud.ply"
    PlyData([PlyElement.describe(tags, "tags"), PlyElement.describe(vertex, "vertex")]).write(str(path))
    assert read_ply_cloud(path) is None
    np.testing.assert_array_equal(load_scan(path).points, np.column_stack([vertex[a] for a in "xyz"]))


@pytest.mark.parametrize("length", [0.0, 1e200])
def test_ply_normals_of_no_usable_length_are_dropped_without_a_warning(tmp_path, length):
    from plyfile import PlyData, PlyElement

    rng = np.random.default_rng(12)
    rows = np.zeros(50, dtype=[(k, "f8") for k in ("x", "y", "z", "nx", "ny", "nz")])
    for k, column in zip(("x", "y", "z"), rng.normal(size=(3, 50)), strict=True):
        rows[k] = column
    rows["nx"] = rows["ny"] = length  # the square of 1e200 overflows a float64
    rows["ny"][0] = 1.0
    path = tmp_path / "cloud.ply"
    PlyData([PlyElement.describe(rows, "vertex")]).write(str(path))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        loaded = load_scan(path)
    assert loaded.normals is None and len(loaded.points) == 50
