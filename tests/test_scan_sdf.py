"""SDF samples from a scan (paper supplementary "SDF Sampling") against analytic answers."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from jsrte.presets import FAST, LINE_OF_SIGHT_SAMPLES, PAPER, ScanSdf, with_line_of_sight
from jsrte.scans.io import ScanCloud
from jsrte.scans.preprocess import prepare_scan
from jsrte.scans.scanner import ScannerSettings, scan_mesh
from jsrte.sdf.from_scan import ray_freespace_samples, scan_sdf_samples, visible_pairs, zbuffer_visible

RADIUS = 0.4
SMALL = ScanSdf(n_freespace=4000)


def sphere(n: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Points on a sphere of radius RADIUS centred at (1, 2, 3) and their outward normals."""
    v = np.random.default_rng(seed).normal(size=(n, 3))
    normals = v / np.linalg.norm(v, axis=1, keepdims=True)
    return np.array([1.0, 2.0, 3.0]) + RADIUS * normals, normals


def true_sdf(xyz: np.ndarray) -> np.ndarray:
    return np.linalg.norm(xyz - np.array([1.0, 2.0, 3.0]), axis=1) - RADIUS


def test_shapes_dtypes_and_layout():
    points, normals = sphere(1000)
    xyz, sdf = scan_sdf_samples(points, normals, rng=np.random.default_rng(0), settings=SMALL)
    assert xyz.shape == (2 * 1000 + 4000, 3) and sdf.shape == (6000,)
    assert xyz.dtype == np.float32 and sdf.dtype == np.float32
    assert np.all(sdf[:1000] == np.float32(0.01)) and np.all(sdf[1000:2000] == np.float32(-0.01))


def test_surface_samples_are_plus_minus_delta_along_the_normal():
    points, normals = sphere(2000)
    xyz, sdf = scan_sdf_samples(points, normals, rng=np.random.default_rng(0), settings=SMALL)
    assert xyz[:2000] == pytest.approx(points + 0.01 * normals, abs=1e-6)
    assert xyz[2000:4000] == pytest.approx(points - 0.01 * normals, abs=1e-6)
    assert true_sdf(xyz[:4000].astype(np.float64)) == pytest.approx(sdf[:4000], abs=1e-5)


def test_freespace_sdf_matches_the_sphere():
    points, normals = sphere(20_000)
    xyz, sdf = scan_sdf_samples(points, normals, rng=np.random.default_rng(1), settings=SMALL)
    free_xyz, free_sdf = xyz[40_000:].astype(np.float64), sdf[40_000:]
    exact = true_sdf(free_xyz)
    assert np.all(free_sdf > 0)  # outside a convex shape
    assert exact.min() >= 0.07 - 1e-5 and exact.max() <= 0.20 + 1e-5
    # nearest scan point vs the true surface: error below spacing^2 / (2 * 0.07)
    assert free_sdf == pytest.approx(exact, abs=2e-3)
    assert np.all(free_sdf >= exact - 1e-5)  # no scan point is closer than the surface


def test_freespace_sign_is_negative_behind_the_nearest_surface():
    """Two facing walls 0.1 m apart (normals pointing away from the gap's far side): a sample
    pushed from the lower wall past the upper one lies behind it, so its SDF is negative."""
    rng = np.random.default_rng(2)
    xy = rng.uniform(-0.5, 0.5, size=(20_000, 2))
    lower = np.column_stack([xy[:10_000], np.zeros(10_000)])
    upper = np.column_stack([xy[10_000:], np.full(10_000, 0.1)])
    points = np.concatenate([lower, upper])
    normals = np.concatenate([np.tile([0.0, 0.0, 1.0], (10_000, 1)),
                              np.tile([0.0, 0.0, -1.0], (10_000, 1))])
    settings = ScanSdf(n_freespace=5000, freespace_min_m=0.12, freespace_max_m=0.14)
    xyz, sdf = scan_sdf_samples(points, normals, rng=rng, settings=settings)
    free, free_sdf = xyz[40_000:], sdf[40_000:]
    inner = np.all(np.abs(free[:, :2]) < 0.4, axis=1)  # away from the walls' edges
    free, free_sdf = free[inner], free_sdf[inner]
    from_lower = np.abs(free[:, 2] - 0.13) < 0.011  # pushed up from z = 0
    from_upper = ~from_lower  # pushed down to z in [-0.04, -0.02]: behind the lower wall
    assert from_lower.sum() > 1000 and from_upper.sum() > 1000
    assert free_sdf[from_lower] == pytest.approx(-(free[from_lower, 2] - 0.1), abs=0.005)
    assert free_sdf[from_upper] == pytest.approx(free[from_upper, 2], abs=0.005)
    assert np.all(free_sdf < 0)


def test_normals_are_normalized_and_validated():
    points, normals = sphere(500)
    a = scan_sdf_samples(points, 3.0 * normals, rng=np.random.default_rng(0), settings=SMALL)
    b = scan_sdf_samples(points, normals, rng=np.random.default_rng(0), settings=SMALL)
    assert np.array_equal(a[0], b[0]) and np.array_equal(a[1], b[1])
    with pytest.raises(ValueError):
        scan_sdf_samples(points, normals[:10], rng=np.random.default_rng(0))
    normals[0] = 0.0
    with pytest.raises(ValueError):
        scan_sdf_samples(points, normals, rng=np.random.default_rng(0))


def test_paper_defaults():
    settings = ScanSdf()
    assert (settings.surface_offset_m, settings.freespace_min_m, settings.freespace_max_m,
            settings.n_freespace) == (0.01, 0.07, 0.20, 25_000)


@pytest.mark.parametrize("preset, flag, expected", [
    (PAPER, None, 0), (PAPER, True, LINE_OF_SIGHT_SAMPLES), (FAST, None, LINE_OF_SIGHT_SAMPLES), (FAST, False, 0)])
def test_line_of_sight_follows_the_preset_unless_asked(preset, flag, expected):
    """``paper`` keeps the paper's query; ``fast`` adds line-of-sight free space; a flag overrides."""
    assert with_line_of_sight(preset.scan_sdf, flag).n_ray_freespace == expected


def test_samples_from_a_prepared_scan_agree_with_the_true_sdf():
    """Scanner -> preprocessing -> samples: the signs match the posed sphere's exact SDF."""
    mesh = trimesh.creation.icosphere(subdivisions=4, radius=0.5)
    scan = scan_mesh(mesh, rng=np.random.default_rng(0), settings=ScannerSettings(noise_scale=0.5))
    prepared = prepare_scan(ScanCloud(scan.points, scan.normals), rng=np.random.default_rng(0))
    xyz, sdf = scan_sdf_samples(prepared.points, prepared.normals, rng=np.random.default_rng(0),
                                settings=SMALL)
    g = scan.scan_from_mesh
    exact = (np.linalg.norm(g.inverse().apply(xyz), axis=1) - 0.5) * g.s
    n = len(prepared.points)
    assert np.mean(np.sign(sdf[:n]) == np.sign(exact[:n])) > 0.9  # outside, 1 cm out
    assert np.mean(np.sign(sdf[n:2 * n]) == np.sign(exact[n:2 * n])) > 0.9  # inside
    assert np.mean(np.abs(sdf[2 * n:] - exact[2 * n:]) < 0.03) > 0.95  # freespace


def visible_post_points(centre_x: float, camera: np.ndarray, n: int, rng) -> np.ndarray:
    """Points on the camera-facing half of a vertical post (radius 0.03 m, height 0.5 m)."""
    angle = rng.uniform(0, 2 * np.pi, n)
    around = np.column_stack([np.cos(angle), np.zeros(n), np.sin(angle)])
    points = np.array([centre_x, 0.0, 0.0]) + 0.03 * around + np.outer(rng.uniform(0, 0.5, n), [0, 1, 0])
    facing = np.einsum("ij,ij->i", around, camera - points) > 0
    return points[facing]


def test_ray_freespace_fills_the_gap_between_posts_and_never_enters_them():
    """Two posts 0.4 m apart on a floor, seen from the front: the lines of sight to the floor
    between them are free, so samples lie in the gap with SDF = distance to the nearest post."""
    rng = np.random.default_rng(3)
    camera = np.array([0.0, 0.6, 1.5])
    posts = np.concatenate([visible_post_points(x, camera, 4000, rng) for x in (-0.2, 0.2)])
    floor = np.column_stack([rng.uniform(-1, 1, 20_000), np.zeros(20_000), rng.uniform(-1, 0.3, 20_000)])
    settings = ScanSdf(n_ray_freespace=5000)
    xyz, sdf = ray_freespace_samples(posts, np.concatenate([posts, floor]), camera[None], rng=rng,
                                     settings=settings)
    assert xyz.dtype == np.float32 and len(xyz) == len(sdf) > 2000
    xyz = xyz.astype(np.float64)
    to_axis = np.minimum(np.hypot(xyz[:, 0] + 0.2, xyz[:, 2]), np.hypot(xyz[:, 0] - 0.2, xyz[:, 2]))
    assert to_axis.min() > 0.03  # never inside a post (rays may graze the unseen side)
    assert np.all(sdf >= settings.ray_margin_m)
    assert np.all(sdf >= to_axis - 0.03 - 1e-6)  # nearest post point is no closer than the post
    between = (np.abs(xyz[:, 0]) < 0.12) & (xyz[:, 1] < 0.4) & (np.abs(xyz[:, 2]) < 0.15)
    assert between.sum() > 50  # the gap between the posts got free-space evidence
    centre = (posts.min(0) + posts.max(0)) / 2
    radius = np.linalg.norm(posts - centre, axis=1).max() * settings.ray_region_factor
    assert np.linalg.norm(xyz - centre, axis=1).max() <= radius + 1e-6


def test_ray_freespace_off_or_without_viewpoints_gives_nothing():
    points, _ = sphere(500)
    cases = ((ScanSdf(n_ray_freespace=0), np.zeros((1, 3))), (ScanSdf(n_ray_freespace=1000), np.zeros((0, 3))))
    for settings, views in cases:
        xyz, sdf = ray_freespace_samples(points, points, views, rng=np.random.default_rng(0), settings=settings)
        assert xyz.shape == (0, 3) and sdf.shape == (0,)


def test_the_point_zbuffer_hides_the_points_behind_a_wall_from_one_side_only():
    """A 1 m square wall at z = 0 and a smaller square 0.5 m behind it (z = -0.5), seen from
    z = +3 and from z = -3: from the front the square behind is hidden and the wall seen; from
    the back the square is seen and the wall only around the square's shadow."""
    def square(half: float, step: float, z: float) -> np.ndarray:
        u = np.arange(-half, half + 1e-9, step)
        x, y = np.meshgrid(u, u)
        return np.column_stack([x.ravel(), y.ravel(), np.full(x.size, z)])

    wall, behind = square(0.5, 0.01, 0.0), square(0.2, 0.01, -0.5)
    n = len(wall)
    points = np.concatenate([wall, behind])
    front, back = np.array([0.0, 0.0, 3.0]), np.array([0.0, 0.0, -3.0])
    seen_front = zbuffer_visible(points, front)
    assert seen_front[:n].mean() > 0.99 and seen_front[n:].mean() < 0.01
    seen_back = zbuffer_visible(points, back)
    assert seen_back[n:].mean() > 0.99
    reach = np.abs(wall[:, :2]).max(axis=1)  # the square's shadow on the wall reaches 0.24 m
    assert seen_back[:n][reach < 0.2].mean() < 0.01 and seen_back[:n][reach > 0.3].mean() > 0.98
    pairs = visible_pairs(points, np.stack([front, back]))  # (point, viewpoint) for each seen point
    assert np.array_equal(pairs[pairs[:, 1] == 0, 0], np.flatnonzero(seen_front))
    assert np.array_equal(pairs[pairs[:, 1] == 1, 0], np.flatnonzero(seen_back))
