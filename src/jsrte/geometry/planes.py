"""Planes in point clouds: a seeded RANSAC that gives the same plane for the same seed, and a
least-squares refit to its inliers.

Open3D's ``segment_plane`` runs its iterations on several threads, and which of two equally
good samples wins depends on their timing: the same seed can give a slightly different floor
from one run to the next, and with it a different fit. Here the samples are drawn from the
caller's generator and scored in one vectorized pass, so one seed gives one answer.
"""

from __future__ import annotations

import numpy as np

SCORE_POINTS = 2000
"""Every sampled plane is first scored on this many points (a fixed random subset)."""
RESCORED = 8
"""The best this many planes on the subset are scored again on every point; the best wins."""


def ransac_plane(points: np.ndarray, distance: float, iterations: int, rng: np.random.Generator,
                 ) -> tuple[np.ndarray, float, np.ndarray]:
    """The plane through three of ``points`` (n, 3) with the most points within ``distance``.

    ``iterations`` triples are drawn from ``rng``; degenerate ones (collinear) are skipped.
    Returns the unit normal (3,), the offset (normal · x = offset, same units as the points)
    and the inlier indices (k,), sorted; (zeros, 0.0, empty) when no triple spans a plane.
    """
    points = np.asarray(points, dtype=np.float64)
    n = len(points)
    if n < 3:
        return np.zeros(3), 0.0, np.zeros(0, dtype=np.int64)
    triples = rng.integers(0, n, size=(iterations, 3))
    a, b, c = points[triples[:, 0]], points[triples[:, 1]], points[triples[:, 2]]
    normals = np.cross(b - a, c - a)
    length = np.linalg.norm(normals, axis=1)
    valid = length > 1e-12
    if not valid.any():
        return np.zeros(3), 0.0, np.zeros(0, dtype=np.int64)
    normals = normals[valid] / length[valid, None]
    offsets = np.einsum("ij,ij->i", normals, a[valid])
    subset = points if n <= SCORE_POINTS else points[rng.choice(n, SCORE_POINTS, replace=False)]
    counts = _inlier_counts(subset, normals, offsets, distance)
    shortlist = np.argsort(-counts, kind="stable")[:RESCORED]
    full = _inlier_counts(points, normals[shortlist], offsets[shortlist], distance)
    best = shortlist[int(np.argmax(full))]
    inliers = np.flatnonzero(np.abs(points @ normals[best] - offsets[best]) < distance)
    return normals[best], float(offsets[best]), inliers


def _inlier_counts(points: np.ndarray, normals: np.ndarray, offsets: np.ndarray, distance: float,
                   chunk: int = 256) -> np.ndarray:
    """For each plane (m normals (m, 3), offsets (m,)), how many ``points`` (n, 3) lie within ``distance``."""
    counts = np.empty(len(normals), dtype=np.int64)
    for start in range(0, len(normals), chunk):
        stop = start + chunk
        residual = np.abs(points @ normals[start:stop].T - offsets[start:stop])
        counts[start:stop] = (residual < distance).sum(axis=0)
    return counts


def refit_plane(points: np.ndarray, normal: np.ndarray, offset: float, distance: float,
                rounds: int = 3) -> tuple[np.ndarray, float]:
    """Least-squares plane through the inliers (within ``distance``) of ``normal · x = offset``
    among ``points`` (n, 3), iterated ``rounds`` times; the normal keeps its side."""
    n = normal / np.linalg.norm(normal)
    d = offset / np.linalg.norm(normal)
    for _ in range(rounds):
        inliers = points[np.abs(points @ n - d) < distance]
        if len(inliers) < 3:
            break
        centre = inliers.mean(0)
        _, _, vt = np.linalg.svd(inliers - centre, full_matrices=False)
        n = vt[2] if vt[2] @ n >= 0 else -vt[2]
        d = float(centre @ n)
    return n, d
