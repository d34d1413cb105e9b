"""Mixed pixels: the per-point camera index in scan files and the veil test that uses it."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from jsrte.geometry.sim3 import Sim3
from jsrte.scans.io import ScanCloud, load_scan
from jsrte.scans.ply import read_ply_scan, write_ply_scan
from jsrte.scans.preprocess import PrepareSettings, segment_scan
from jsrte.scans.scanner import ScannerSettings, VirtualScan, write_scan
from jsrte.scans.veil import VeilSettings, mixed_pixels, scan_mixed_pixels

FOCAL = 100.0
"""Pixels per unit of image plane of the synthetic depth images (0.57 degree pixels)."""


def edge_view(camera: np.ndarray, rng: np.random.Generator, *, near: float = 1.0, far: float = 1.6,
              ) -> tuple[np.ndarray, np.ndarray]:
    """One 60 x 40 depth image from ``camera`` looking along +z: a near wall (depth ``near``)
    over the left half of the image in front of a far wall (depth ``far``); every other edge
    pixel of the near wall (the column beside the far wall) reads a depth between the two, 20-80%
    of the way (mixed pixels). Kinect noise on every depth. Returns points (p, 3) and the mixed
    pixels' mask (p,)."""
    u, v = np.meshgrid((np.arange(60) - 29.5) / FOCAL, (np.arange(40) - 19.5) / FOCAL)
    column = np.broadcast_to(np.arange(60), u.shape)
    row = np.broadcast_to(np.arange(40)[:, None], u.shape)
    depth = np.where(column < 30, near, far).astype(np.float64)
    mixed = (column == 29) & (row % 2 == 0)
    depth[mixed] = near + rng.uniform(0.2, 0.8, size=int(mixed.sum())) * (far - near)
    s = VeilSettings()
    depth = depth + rng.normal(size=depth.shape) * (s.noise_a_m + s.noise_b_per_m * depth**2)
    rays = np.stack([u, v, np.ones_like(u)], axis=-1)
    return (camera + depth[..., None] * rays).reshape(-1, 3), mixed.reshape(-1)


def test_mixed_pixels_between_two_surfaces_are_removed_and_the_surfaces_kept():
    rng = np.random.default_rng(0)
    cameras = np.array([[0.0, 0.0, 0.0], [0.3, 0.1, -0.2]])  # two views of the same walls, interleaved
    views = [edge_view(c, rng) for c in cameras]
    points = np.concatenate([p for p, _ in views])
    truth = np.concatenate([m for _, m in views])
    view = np.repeat([0, 1], [len(p) for p, _ in views])
    found = mixed_pixels(points, view, cameras)
    assert truth.sum() == 40
    assert np.array_equal(found, truth)  # every mixed pixel, and not one surface point


def test_a_point_within_the_noise_of_a_surface_is_kept():
    close, _ = edge_view(np.zeros(3), np.random.default_rng(1), near=1.0, far=1.02)
    assert not mixed_pixels(close, np.zeros(len(close), int), np.zeros((1, 3))).any()


def test_the_test_is_skipped_without_camera_indices():
    points, _ = edge_view(np.zeros(3), np.random.default_rng(2))
    view = np.zeros(len(points), int)
    assert scan_mixed_pixels(points, None, np.zeros((1, 3))) is None
    assert scan_mixed_pixels(points, view, None) is None
    assert scan_mixed_pixels(points, view + 1, np.zeros((1, 3))) is None  # no such camera
    assert scan_mixed_pixels(points, view, np.zeros((1, 3)), None) is None
    assert scan_mixed_pixels(points, view, np.zeros((1, 3))).sum() == 20


def small_scan(view: np.ndarray | None = None) -> VirtualScan:
    rng = np.random.default_rng(3)
    points = rng.normal(size=(50, 3))
    normals = points / np.linalg.norm(points, axis=1, keepdims=True)
    return VirtualScan(points=points, normals=normals, is_object=points[:, 1] > 0,
                       is_outlier=np.zeros(50, bool), scan_from_mesh=Sim3.identity(),
                       up=np.array([0.0, 1.0, 0.0]), floor_offset=0.0, cameras=np.zeros((3, 3)),
                       view=np.arange(50) % 3 if view is None else view, settings=ScannerSettings())


def test_the_camera_index_round_trips_through_the_scan_file(tmp_path):
    scan = small_scan()
    path = write_scan(scan, tmp_path / "scan.ply")
    cloud = load_scan(path)
    assert np.array_equal(cloud.points, scan.points) and np.allclose(cloud.normals, scan.normals)
    assert cloud.view.dtype == np.int64 and np.array_equal(cloud.view, scan.view)
    import open3d as o3d  # other readers skip the property

    assert np.array_equal(np.asarray(o3d.io.read_point_cloud(str(path)).points), scan.points)


def test_an_ascii_file_with_a_camera_index_reads_it(tmp_path):
    path = tmp_path / "scan.ply"
    path.write_text("ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\n"
                    "property float z\nproperty uchar view\nend_header\n0.5 1 2 3\n1 0.25 3 1\n")
    points, normals, view = read_ply_scan(path)
    assert np.array_equal(points, [[0.5, 1, 2], [1, 0.25, 3]]) and normals is None
    assert view.tolist() == [3, 1]


def test_a_file_without_camera_index_loads_and_segments_without_the_test(tmp_path):
    from jsrte.scans.scanner import scan_mesh
    from test_scans import stand_in_chair

    scan = scan_mesh(stand_in_chair(), rng=np.random.default_rng(0),
                     settings=ScannerSettings(width=80, height=60, random_world_frame=False))
    plain = tmp_path / "plain.ply"
    colors = np.zeros((len(scan.points), 3), np.uint8)
    write_ply_scan(plain, scan.points, scan.normals, colors)
    cloud = load_scan(plain)
    assert cloud.view is None and np.array_equal(cloud.points, scan.points)
    on = PrepareSettings(veil=VeilSettings())
    segmented = segment_scan(cloud, rng=np.random.default_rng(0), viewpoints=scan.cameras, settings=on)
    assert segmented.mixed is None and "mixed_pixels" not in segmented.segmentation.removed
    default = segment_scan(replace(cloud, view=scan.view), rng=np.random.default_rng(0), viewpoints=scan.cameras)
    assert default.mixed is None and np.array_equal(default.index, segmented.index)  # off by default
    with_view = segment_scan(replace(cloud, view=scan.view), rng=np.random.default_rng(0), viewpoints=scan.cameras,
                             settings=on)
    assert with_view.mixed is not None and len(with_view.mixed) == len(scan.points)
    removed = with_view.segmentation.removed["mixed_pixels"]
    # a clean scan has no mixed pixels: what goes are its flying pixels and a few points at
    # grazing angles or on parts one pixel thin (3.5% of this coarse 80 x 60 scan)
    assert removed == len(segmented.index) - len(with_view.index)
    assert 0 < removed <= 0.05 * len(segmented.index)


def test_a_camera_index_that_does_not_fit_the_points_is_refused(tmp_path):
    from jsrte.errors import JsrteError

    path = tmp_path / "bad.ply"
    scan = small_scan()
    write_ply_scan(path, scan.points, scan.normals, np.zeros((50, 3), np.uint8), -scan.view - 1)
    with pytest.raises(JsrteError, match="bad.ply.*negative|negative.*bad.ply"):
        load_scan(path)
    assert ScanCloud(scan.points).view is None


def test_the_fit_veil_leaves_mixed_pixels_out_of_the_fit_but_not_of_the_segmentation(tmp_path):
    from jsrte.scans.scanner import scan_mesh
    from test_scans import stand_in_chair

    scan = scan_mesh(stand_in_chair(), rng=np.random.default_rng(0),
                     settings=ScannerSettings(width=80, height=60, random_world_frame=False))
    cloud = load_scan(write_scan(scan, tmp_path / "scan.ply"))
    plain = segment_scan(cloud, rng=np.random.default_rng(0), viewpoints=scan.cameras)
    veiled = segment_scan(cloud, rng=np.random.default_rng(0), viewpoints=scan.cameras,
                          settings=PrepareSettings(fit_veil=VeilSettings()))
    assert plain.fit_mixed is None and veiled.mixed is None
    assert np.array_equal(plain.index, veiled.index)  # the same points segmented, the same candidates
    candidate = veiled.index[veiled.segmentation.candidates[veiled.segmentation.chosen].index]
    left_out = veiled.fit_mixed[candidate]
    assert left_out.sum() > 0
    prepared = veiled.prepare()
    assert not veiled.fit_mixed[prepared.index].any()  # none of the fit's points is a mixed pixel
    assert set(prepared.index) <= set(candidate[~left_out])
    assert set(plain.prepare().index) & set(candidate[left_out])  # which the plain fit keeps
