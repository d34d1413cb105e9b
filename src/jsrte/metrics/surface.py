"""Surface metrics: F-score at a fraction of the bounding-sphere radius (the paper's F@5%), Chamfer.

The paper (supplementary, 'Metrics', after Tatarchenko et al. 2019) samples 3000 points on
each surface; a predicted point is a true positive when its distance to the nearest
ground-truth point is *strictly* below ``epsilon = 0.05 r``, ``r`` the radius of the ground
truth's bounding sphere; recall is the same in the other direction; F is their harmonic mean.

Note: with 3000 points the metric saturates below 1 on shapes with a large area relative to
``r^2``: two independent samplings of the same sphere (area ``4 pi r^2``) score about 0.85,
because samples lie ~0.065 r apart. Compact shapes such as chairs score ~0.99 against
themselves.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import trimesh
from pykdtree.kdtree import KDTree

from jsrte.errors import JsrteError
from jsrte.presets import FitSettings

Surface = trimesh.Trimesh | np.ndarray | None
"""A mesh or an (n, 3) point array; None (or a mesh without faces, or no points) is empty."""


@dataclass(frozen=True)
class FScore:
    """F-score of a predicted surface against a ground truth.

    Attributes
    ----------
    fscore : float in [0, 1], harmonic mean of precision and recall (0 when both are 0)
    precision : float in [0, 1], fraction of predicted points within ``threshold`` of the truth
    recall : float in [0, 1], fraction of ground-truth points within ``threshold`` of the prediction
    threshold : float, the distance threshold (units of the inputs)
    chamfer : float, :func:`chamfer` of the two point samples (inf for an empty prediction)
    """

    fscore: float
    precision: float
    recall: float
    threshold: float
    chamfer: float

    def as_dict(self) -> dict[str, float]:
        """The fields as a plain dict (for JSON)."""
        return {
            "fscore": self.fscore,
            "precision": self.precision,
            "recall": self.recall,
            "threshold": self.threshold,
            "chamfer": self.chamfer,
        }


def bounding_sphere(points: np.ndarray) -> tuple[np.ndarray, float]:
    """The DeepSDF bounding sphere: axis-aligned bounding-box centre and largest distance to it.

    This is the sphere DeepSDF normalizes by (not the minimal enclosing sphere, which can be
    up to ~13% smaller); the paper's F@5% threshold is 5% of this radius.

    Parameters
    ----------
    points : (n, 3) float, n >= 1

    Returns
    -------
    centre : (3,) float64
    radius : float
    """
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    if len(points) == 0:
        raise ValueError("bounding_sphere needs at least one point")
    centre = (points.min(axis=0) + points.max(axis=0)) / 2.0
    radius = float(np.linalg.norm(points - centre, axis=1).max())
    return centre, radius


def sample_surface(surface: Surface, n_points: int, *, rng: np.random.Generator) -> np.ndarray:
    """Points on a surface: (m, 3) float64, m <= n_points (m = 0 for an empty surface).

    A mesh is sampled uniformly by area (``n_points`` points); a point array with more than
    ``n_points`` points is subsampled without replacement, a smaller one returned as is.
    """
    if surface is None:
        return np.zeros((0, 3))
    if isinstance(surface, trimesh.Trimesh):
        return _sample_mesh(surface, n_points, rng)
    points = np.asarray(surface, dtype=np.float64).reshape(-1, 3)
    if len(points) > n_points:
        points = points[rng.choice(len(points), size=n_points, replace=False)]
    return points


def fscore(
    pred: Surface,
    truth: Surface,
    *,
    fraction: float = FitSettings.fscore_fraction,
    n_points: int = FitSettings.fscore_points,
    rng: np.random.Generator,
) -> FScore:
    """F-score of ``pred`` against ``truth`` at ``fraction`` of the truth's bounding-sphere radius.

    Parameters
    ----------
    pred : trimesh.Trimesh, (n, 3) float array or None
        The prediction; empty (None, no faces, zero area, no points) scores F = P = R = 0
        and an infinite Chamfer distance.
    truth : trimesh.Trimesh or (n, 3) float array
        The ground truth; its bounding sphere (:func:`bounding_sphere` of its vertices or
        points) sets the threshold.
    fraction : float
        Threshold as a fraction of the truth's bounding-sphere radius (paper: 0.05).
    n_points : int
        Points sampled on each mesh / kept of each point array (paper: 3000).
    rng : numpy.random.Generator
        Seeds the surface sampling (truth first, then prediction).

    Returns
    -------
    FScore
    """
    if not fraction > 0:
        raise ValueError(f"fraction must be positive, got {fraction}")
    if n_points < 1:
        raise ValueError(f"n_points must be >= 1, got {n_points}")
    threshold = fraction * _truth_radius(truth)
    truth_points = sample_surface(truth, n_points, rng=rng)
    pred_points = sample_surface(pred, n_points, rng=rng)
    if len(pred_points) == 0:
        return FScore(fscore=0.0, precision=0.0, recall=0.0, threshold=threshold, chamfer=np.inf)
    pred_to_truth = _nearest_distances(pred_points, truth_points)
    truth_to_pred = _nearest_distances(truth_points, pred_points)
    precision = float(np.mean(pred_to_truth < threshold))
    recall = float(np.mean(truth_to_pred < threshold))
    f = 2.0 * precision * recall / (precision + recall) if precision + recall > 0 else 0.0
    chamfer_distance = float((pred_to_truth.mean() + truth_to_pred.mean()) / 2.0)
    return FScore(fscore=f, precision=precision, recall=recall, threshold=threshold,
                  chamfer=chamfer_distance)


def chamfer(a: np.ndarray, b: np.ndarray) -> float:
    """Symmetric Chamfer distance of two point sets (L2 distances, not squared).

    ``(mean_i min_j |a_i - b_j| + mean_j min_i |b_j - a_i|) / 2``, in the points' units;
    inf when either set is empty.

    Parameters
    ----------
    a : (n, 3) float
    b : (m, 3) float
    """
    a = np.asarray(a, dtype=np.float64).reshape(-1, 3)
    b = np.asarray(b, dtype=np.float64).reshape(-1, 3)
    if len(a) == 0 or len(b) == 0:
        return float("inf")
    return float((_nearest_distances(a, b).mean() + _nearest_distances(b, a).mean()) / 2.0)


def _truth_radius(truth: Surface) -> float:
    if truth is None:
        raise JsrteError("the ground truth surface is empty")
    if isinstance(truth, trimesh.Trimesh):
        if len(truth.faces) == 0 or not truth.area > 0:
            raise JsrteError("the ground truth mesh has no surface")
        points = truth.vertices[np.unique(truth.faces)]
    else:
        points = np.asarray(truth, dtype=np.float64).reshape(-1, 3)
        if len(points) == 0:
            raise JsrteError("the ground truth holds no points")
    _, radius = bounding_sphere(points)
    if not radius > 0:
        raise JsrteError("the ground truth is degenerate (all points coincide)")
    return radius


def _sample_mesh(mesh: trimesh.Trimesh, n_points: int, rng: np.random.Generator) -> np.ndarray:
    """Uniform area-weighted samples on a mesh (n_points, 3); (0, 3) for a mesh without area."""
    if len(mesh.faces) == 0:
        return np.zeros((0, 3))
    triangles = np.asarray(mesh.triangles, dtype=np.float64)  # (f, 3, 3)
    areas = np.linalg.norm(np.cross(triangles[:, 1] - triangles[:, 0],
                                    triangles[:, 2] - triangles[:, 0]), axis=1)
    total = areas.sum()
    if not total > 0 or not np.isfinite(total):
        return np.zeros((0, 3))
    cumulative = np.cumsum(areas)
    face = np.searchsorted(cumulative, rng.random(n_points) * cumulative[-1], side="right")
    face = np.minimum(face, len(areas) - 1)
    u, v = rng.random(n_points), rng.random(n_points)
    flip = u + v > 1.0  # fold the unit square onto the triangle: uniform barycentrics
    u, v = np.where(flip, 1.0 - u, u), np.where(flip, 1.0 - v, v)
    t = triangles[face]
    return t[:, 0] + u[:, None] * (t[:, 1] - t[:, 0]) + v[:, None] * (t[:, 2] - t[:, 0])


def _nearest_distances(queries: np.ndarray, data: np.ndarray) -> np.ndarray:
    """Distance from each query (n, 3) to its nearest data point (m, 3): (n,) float64."""
    distances, _ = KDTree(np.ascontiguousarray(data, dtype=np.float64)).query(
        np.ascontiguousarray(queries, dtype=np.float64), k=1)
    return np.asarray(distances, dtype=np.float64)
