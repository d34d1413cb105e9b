"""OUR-CVFH + ICP: a global descriptor for recognition, then the supplementary's registration.

The paper's second baseline (section 4.2; supplementary 'OURCVFH + ICP'): one OUR-CVFH
descriptor set (Aldoma et al. 2012, PCL's ``OURCVFHEstimation``) per database shape, the query's
nearest neighbour among them, then :func:`jsrte.baselines.registration.register` (bounding
spheres, 20° yaw search about the known up axis, ICP with optimal assignment + Umeyama).

OUR-CVFH gives one 308-bin signature per smooth region and unique reference frame (SGURF):
three CVFH angle histograms (45 bins each, from the region's centroid and mean normal to every
point), the shape distribution of the cloud in the SGURF's 8 octants (8 x 13 bins), and the
tail of VFH's viewpoint histogram. The viewpoint part (bins 239-307) is left out of the
comparison: database shapes are complete meshes with no viewpoint and the query's camera is
unknown, so it would only add noise. Bins are normalized (PCL's ``normalize_bins``) so clouds
of different densities compare. Clouds are scaled into their unit bounding sphere first
(radii below are in those units). Two shapes are as far apart as their closest pair of
signatures (L1).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from jsrte.baselines import pcl
from jsrte.baselines.cloud import unit_cloud
from jsrte.baselines.database import Arrays, ShapeDatabase
from jsrte.baselines.protocol import BaselineFailed, Stopwatch, baseline_result, check_query
from jsrte.baselines.registration import IcpSettings, register
from jsrte.result import FitResult

SIGNATURE_BINS = 239
"""Bins compared: f1, f2, f3 (3 x 45) and the octant shape distribution (8 x 13)."""


@dataclass(frozen=True)
class OurCvfhSettings:
    """OUR-CVFH parameters (PCL's names); lengths in units of the bounding-sphere radius."""

    voxel: float = 0.02
    eps_angle_deg: float = 7.5
    """Smooth-region growing: neighbours' normals within this angle (PCL example: 0.13 rad)."""
    curvature_threshold: float = 0.03
    """Points with a larger surface variation are left out of the smooth regions (PCL default)."""
    cluster_tolerance: float = 0.04
    radius_normals: float = 0.04
    min_points: int = 50
    axis_ratio: float = 0.8
    min_axis_value: float = 0.925
    refine_clusters: float = 1.0


def ourcvfh_signatures(points: np.ndarray, normals: np.ndarray, settings: OurCvfhSettings) -> Arrays:
    """OUR-CVFH signatures of a cloud (any units): ``{"signatures": (m, 239) float32}``."""
    cloud = unit_cloud(points, normals, voxel=settings.voxel)
    desc, _, _ = pcl.ourcvfh(
        cloud.points, cloud.normals, eps_angle=np.radians(settings.eps_angle_deg),
        curvature_threshold=settings.curvature_threshold, cluster_tolerance=settings.cluster_tolerance,
        radius_normals=settings.radius_normals, min_points=settings.min_points,
        axis_ratio=settings.axis_ratio, min_axis_value=settings.min_axis_value, normalize_bins=True,
        refine_clusters=settings.refine_clusters)
    desc = np.asarray(desc, dtype=np.float32)[:, :SIGNATURE_BINS]
    return {"signatures": desc[np.all(np.isfinite(desc), axis=1)]}


def signature_distance(a: np.ndarray, b: np.ndarray) -> float:
    """L1 distance of the closest pair of signatures of two sets (m, d) and (k, d); inf if empty."""
    if len(a) == 0 or len(b) == 0:
        return float("inf")
    return float(np.abs(a[:, None, :].astype(np.float64) - b[None].astype(np.float64)).sum(-1).min())


class OurCvfhIcp:
    """The ``ourcvfh-icp`` baseline (see the module docstring)."""

    name = "ourcvfh-icp"

    def __init__(self, settings: OurCvfhSettings = OurCvfhSettings(),  # noqa: B008 (frozen)
                 icp: IcpSettings = IcpSettings()) -> None:  # noqa: B008 (frozen)
        self.settings, self.icp = settings, icp

    def database_descriptors(self, database: ShapeDatabase) -> list[Arrays]:
        """OUR-CVFH signatures of every database shape (cached)."""
        return database.descriptors(
            "ourcvfh", self.settings,
            lambda i: ourcvfh_signatures(database.points(i), database.normals(i), self.settings))

    def recognize(self, points: np.ndarray, normals: np.ndarray, database: ShapeDatabase
                  ) -> tuple[int, float]:
        """Index of the nearest database shape and its signature distance."""
        query = ourcvfh_signatures(points, normals, self.settings)["signatures"]
        if len(query) == 0:
            raise BaselineFailed("OUR-CVFH produced no signature for the query")
        shapes = self.database_descriptors(database)
        dist = np.array([signature_distance(query, d["signatures"]) for d in shapes])
        if not np.isfinite(dist).any():
            raise BaselineFailed("no database shape has an OUR-CVFH signature")
        best = int(np.argmin(dist))
        return best, float(dist[best])

    def fit(self, query_points: np.ndarray, query_normals: np.ndarray, up: np.ndarray,
            database: ShapeDatabase, *, rng: np.random.Generator) -> FitResult:
        clock = Stopwatch()
        points, normals, up = check_query(query_points, query_normals, up)
        self.database_descriptors(database)
        clock.lap("database")
        best, dist = self.recognize(points, normals, database)
        clock.lap("recognize")
        reg = register(points, database.points(best), up, rng=rng, settings=self.icp)
        clock.lap("register")
        return baseline_result(self.name, database, best, reg.transform, loss=reg.rmse,
                               criterion={"name": "ourcvfh_l1", "value": dist}, timing=clock.done(),
                               info=reg.to_json())
