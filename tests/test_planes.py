"""The seeded plane RANSAC: a known plane recovered among outliers, the same answer for the same seed."""

import numpy as np

from jsrte.geometry.planes import ransac_plane, refit_plane


def _plane_with_clutter(rng):
    normal = np.array([0.2, 0.95, -0.1])
    normal /= np.linalg.norm(normal)
    u = np.cross(normal, [1.0, 0.0, 0.0])
    u /= np.linalg.norm(u)
    v = np.cross(normal, u)
    ab = rng.uniform(-2, 2, size=(6000, 2))
    floor = 0.7 * normal + ab[:, :1] * u + ab[:, 1:] * v + rng.normal(scale=0.004, size=(6000, 1)) * normal
    clutter = rng.uniform(-2, 2, size=(4000, 3)) + 1.2 * normal  # a cloud of points above it
    return np.concatenate([floor, clutter]), normal, 0.7


def test_a_plane_among_clutter_is_recovered():
    points, normal, offset = _plane_with_clutter(np.random.default_rng(0))
    found, d, inliers = ransac_plane(points, 0.02, 500, np.random.default_rng(1))
    side = np.sign(found @ normal)
    assert np.degrees(np.arccos(min(1.0, side * found @ normal))) < 2.0 and abs(side * d - offset) < 0.02
    assert np.mean(inliers < 6000) > 0.95 and len(inliers) > 0.97 * 6000
    refit, d2 = refit_plane(points, found, d, 0.02)
    assert np.degrees(np.arccos(min(1.0, side * refit @ normal))) < 0.2 and abs(side * d2 - offset) < 0.002


def test_the_same_seed_gives_the_same_plane_and_another_seed_the_same_plane_near_enough():
    points, _, _ = _plane_with_clutter(np.random.default_rng(2))
    runs = [ransac_plane(points, 0.02, 300, np.random.default_rng(7)) for _ in range(3)]
    assert all(np.array_equal(r[0], runs[0][0]) and np.array_equal(r[2], runs[0][2]) for r in runs)
    other = ransac_plane(points, 0.02, 300, np.random.default_rng(8))
    assert abs(other[0] @ runs[0][0]) > 0.999


def test_no_plane_through_collinear_points():
    line = np.outer(np.linspace(0, 1, 50), [1.0, 2.0, 3.0])
    normal, offset, inliers = ransac_plane(line, 0.01, 100, np.random.default_rng(0))
    assert len(inliers) == 0 and not normal.any()
