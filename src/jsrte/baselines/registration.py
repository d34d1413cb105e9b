"""The supplementary's registration of a retrieved shape onto a query (OURCVFH+ICP, PointNet+ICP).

1. Coarse: the scale from the bounding-sphere radii (query over shape), the translation from
   their centres, and the rotation about the known up axis by a search in 20° steps that
   minimizes the *maximum* distance from a query point to its nearest shape point.
2. Fine: an ICP variant (Besl & McKay 1992) on equal-size uniform subsamples of both clouds
   whose correspondences come from an optimal assignment (``scipy.optimize.linear_sum_assignment``
   on squared distances: one-to-one, so the scale cannot collapse) and whose update is
   Umeyama's least-squares similarity (with scale).

Canonical shapes have +y up; the query's up axis maps canonical +y, then the yaw turns about it
(``R = R_θ(up) · R_{y→up}``). All transforms are ``scan_from_canonical`` Sim3s.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from pykdtree.kdtree import KDTree
from scipy.optimize import linear_sum_assignment
from scipy.spatial.distance import cdist

from jsrte.geometry.sim3 import Sim3, axis_angle_matrix, rotation_between, umeyama
from jsrte.metrics.surface import bounding_sphere

CANONICAL_UP = np.array([0.0, 1.0, 0.0])


@dataclass(frozen=True)
class IcpSettings:
    """The registration of the supplementary ('OURCVFH + ICP')."""

    coarse_step_deg: float = 20.0
    """Yaw search step about the known up axis (the paper: 20°)."""
    samples: int = 500
    """Points drawn from each cloud for the optimal assignment (equal sizes)."""
    max_iterations: int = 50
    tolerance: float = 1e-10
    """Stop when the assignment repeats, or the transform's matrix moves less than this (relative)."""


@dataclass(frozen=True)
class Registration:
    """A registration's outcome.

    Attributes
    ----------
    transform : ``scan_from_canonical`` after ICP
    coarse : the coarse estimate (before ICP)
    yaw_deg : the coarse yaw about the up axis (degrees)
    rmse : root mean square distance of the final assigned pairs (scan units)
    iterations : ICP iterations run
    converged : the assignment stopped changing before ``max_iterations``
    """

    transform: Sim3
    coarse: Sim3
    yaw_deg: float
    rmse: float
    iterations: int
    converged: bool

    def to_json(self) -> dict:
        return {"coarse": self.coarse.to_dict(), "yaw_deg": self.yaw_deg, "icp_rmse": self.rmse,
                "icp_iterations": self.iterations, "icp_converged": self.converged}


def upright_rotation(up: np.ndarray, theta: float) -> np.ndarray:
    """``R_θ(up) · R_{y→up}`` (3, 3): canonical +y onto ``up`` (3,), then a yaw of ``theta`` rad."""
    up = np.asarray(up, dtype=np.float64) / np.linalg.norm(up)
    return axis_angle_matrix(up, theta) @ rotation_between(CANONICAL_UP, up)


def coarse_alignment(query: np.ndarray, shape: np.ndarray, up: np.ndarray, *,
                     step_deg: float = IcpSettings.coarse_step_deg) -> tuple[Sim3, float]:
    """The coarse ``scan_from_canonical`` of ``shape`` (m, 3) onto ``query`` (n, 3) and its yaw.

    Scale = query bounding-sphere radius / shape radius; translation maps the shape's centre onto
    the query's; the yaw (every ``step_deg`` degrees) minimizes the largest distance from a query
    point to the nearest shape point. Returns ``(transform, yaw_deg)``.
    """
    cq, rq = bounding_sphere(query)
    cs, rs = bounding_sphere(shape)
    s = rq / rs
    tree = KDTree(np.ascontiguousarray(shape, dtype=np.float64))
    best: tuple[float, Sim3, float] | None = None
    for yaw in np.arange(0.0, 360.0, step_deg):
        r = upright_rotation(up, np.radians(yaw))
        g = Sim3(s, r, cq - s * r @ cs)
        dist, _ = tree.query(np.ascontiguousarray(g.inverse().apply(query)), k=1)
        worst = float(dist.max()) * s
        if best is None or worst < best[0] - 1e-12:
            best = (worst, g, float(yaw))
    return best[1], best[2]


def icp_assignment(source: np.ndarray, target: np.ndarray, init: Sim3, *,
                   max_iterations: int = IcpSettings.max_iterations,
                   tolerance: float = IcpSettings.tolerance) -> tuple[Sim3, float, int, bool]:
    """ICP with one-to-one correspondences from an optimal assignment and Umeyama updates.

    Parameters
    ----------
    source : (n, 3) points to move (canonical units)
    target : (n, 3) points to reach (scan units); same count as ``source``
    init : the starting ``target_from_source`` similarity

    Returns
    -------
    (transform, rmse, iterations, converged) : the final similarity, the RMS distance of its
    assigned pairs, the iterations run, and whether the assignment stopped changing.
    """
    source = np.asarray(source, dtype=np.float64)
    target = np.asarray(target, dtype=np.float64)
    if source.shape != target.shape:
        raise ValueError(f"icp_assignment needs equal-size clouds, got {source.shape} and {target.shape}")
    g, previous = init, None
    for it in range(1, max_iterations + 1):
        cost = cdist(g.apply(source), target, "sqeuclidean")
        _, cols = linear_sum_assignment(cost)
        new = umeyama(source, target[cols], with_scale=True)
        moved = np.abs(new.matrix() - g.matrix()).max() / max(1.0, np.abs(g.matrix()).max())
        g = new
        if (previous is not None and np.array_equal(cols, previous)) or moved < tolerance:
            return g, _rmse(g, source, target[cols]), it, True
        previous = cols
    cost = cdist(g.apply(source), target, "sqeuclidean")
    _, cols = linear_sum_assignment(cost)
    return g, _rmse(g, source, target[cols]), max_iterations, False


def _rmse(g: Sim3, source: np.ndarray, target: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.sum((g.apply(source) - target) ** 2, axis=1))))


def register(query: np.ndarray, shape: np.ndarray, up: np.ndarray, *, rng: np.random.Generator,
             settings: IcpSettings = IcpSettings()) -> Registration:  # noqa: B008 (frozen)
    """Place ``shape`` (m, 3, canonical) onto ``query`` (n, 3, scan units) with the known ``up`` (3,).

    Coarse alignment on all points, then ICP with optimal assignment on ``settings.samples``
    points drawn uniformly from each cloud (fewer if a cloud has fewer).
    """
    coarse, yaw = coarse_alignment(query, shape, up, step_deg=settings.coarse_step_deg)
    n = min(settings.samples, len(query), len(shape))
    q = query[rng.choice(len(query), n, replace=False)]
    s = shape[rng.choice(len(shape), n, replace=False)]
    g, rmse, iterations, converged = icp_assignment(s, q, coarse, max_iterations=settings.max_iterations,
                                                    tolerance=settings.tolerance)
    return Registration(g, coarse, yaw, rmse, iterations, converged)
