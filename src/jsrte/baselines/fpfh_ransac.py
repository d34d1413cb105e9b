"""Open3D FPFH + RANSAC + ICP: the off-the-shelf global registration pipeline of today.

Not in the paper: the fourth column of our table, the pipeline a user would reach for now
(Open3D's "global registration" tutorial, Rusu et al. 2009 FPFH + RANSAC, then ICP). Open3D's
RANSAC estimates a rigid motion, so scale is handled by first bringing both clouds into their
own unit bounding spheres; the ICP refinement then estimates a similarity (point-to-point with
scaling) to absorb what the spheres got wrong (a partial scan's sphere is smaller).

Recognition: the database shape whose registration has the best fitness (fraction of its
points with a query point within the correspondence distance), ties by the lower inlier RMSE.
Registering every database shape costs ~0.1-0.3 s each, so only the ``top_k`` shapes nearest
to the query by a cheap global descriptor (the mean FPFH histogram, L1) are registered.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from jsrte.baselines.cloud import unit_cloud
from jsrte.baselines.database import Arrays, ShapeDatabase
from jsrte.baselines.protocol import BaselineFailed, Stopwatch, baseline_result, check_query
from jsrte.geometry.sim3 import Sim3
from jsrte.result import FitResult


@dataclass(frozen=True)
class FpfhSettings:
    """Parameters; lengths in units of each cloud's bounding-sphere radius."""

    voxel: float = 0.03
    """Voxel subsampling (Open3D's tutorial uses 5 cm on ~2 m scenes)."""
    feature_radius: float = 0.15
    """FPFH radius (5 voxels, as in the tutorial), at most ``max_nn`` neighbours."""
    normal_radius: float = 0.06
    max_nn: int = 100
    distance: float = 0.045
    """RANSAC correspondence distance (1.5 voxels)."""
    ransac_iterations: int = 100_000
    ransac_confidence: float = 0.999
    edge_length_ratio: float = 0.9
    icp_distance: float = 0.06
    icp_iterations: int = 50
    top_k: int = 10
    """Database shapes registered (nearest by mean FPFH); 0: all."""
    min_points: int = 30


def fpfh_arrays(points: np.ndarray, normals: np.ndarray, settings: FpfhSettings) -> Arrays:
    """The unit cloud and FPFH features (k, 33) of a cloud (any units)."""
    import open3d as o3d

    cloud = unit_cloud(points, normals, voxel=settings.voxel)
    pcd = _pcd(cloud.points, cloud.normals)
    feature = o3d.pipelines.registration.compute_fpfh_feature(
        pcd, o3d.geometry.KDTreeSearchParamHybrid(radius=settings.feature_radius, max_nn=settings.max_nn))
    fpfh = np.asarray(feature.data, dtype=np.float64).T
    return {"points": cloud.points, "normals": cloud.normals, "fpfh": fpfh,
            "centre": cloud.centre, "radius": np.array([cloud.radius]), "mean_fpfh": fpfh.mean(axis=0)}


def _pcd(points: np.ndarray, normals: np.ndarray):  # noqa: ANN202 (open3d type)
    import open3d as o3d

    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.asarray(points, dtype=np.float64)))
    pcd.normals = o3d.utility.Vector3dVector(np.asarray(normals, dtype=np.float64))
    return pcd


def _feature(fpfh: np.ndarray):  # noqa: ANN202 (open3d type)
    import open3d as o3d

    f = o3d.pipelines.registration.Feature()
    f.data = np.ascontiguousarray(fpfh.T, dtype=np.float64)
    return f


@dataclass(frozen=True)
class Alignment:
    """One database shape registered onto the query, in unit-sphere coordinates.

    Attributes
    ----------
    matrix : (4, 4) query-unit-from-shape-unit similarity
    fitness : fraction of shape points with a query point within ``icp_distance``
    rmse : RMS distance of those pairs (unit-sphere units)
    """

    matrix: np.ndarray
    fitness: float
    rmse: float


def align(shape: Arrays, query: Arrays, settings: FpfhSettings, seed: int) -> Alignment:
    """FPFH + RANSAC (rigid, Open3D) then ICP (similarity) of ``shape`` onto ``query``."""
    import open3d as o3d

    reg = o3d.pipelines.registration
    o3d.utility.set_verbosity_level(o3d.utility.VerbosityLevel.Error)
    o3d.utility.random.seed(seed)
    src, dst = _pcd(shape["points"], shape["normals"]), _pcd(query["points"], query["normals"])
    coarse = reg.registration_ransac_based_on_feature_matching(
        src, dst, _feature(shape["fpfh"]), _feature(query["fpfh"]), True, settings.distance,
        reg.TransformationEstimationPointToPoint(False), 3,
        [reg.CorrespondenceCheckerBasedOnEdgeLength(settings.edge_length_ratio),
         reg.CorrespondenceCheckerBasedOnDistance(settings.distance)],
        reg.RANSACConvergenceCriteria(settings.ransac_iterations, settings.ransac_confidence))
    fine = reg.registration_icp(
        src, dst, settings.icp_distance, coarse.transformation,
        reg.TransformationEstimationPointToPoint(True),
        reg.ICPConvergenceCriteria(max_iteration=settings.icp_iterations))
    result = fine if fine.fitness >= coarse.fitness else coarse
    return Alignment(np.asarray(result.transformation), float(result.fitness), float(result.inlier_rmse))


def _unit_to_input(arrays: Arrays) -> Sim3:
    """The Sim3 taking unit-sphere coordinates of a cloud back to its input units."""
    return Sim3(float(arrays["radius"][0]), np.eye(3), arrays["centre"])


class FpfhRansacIcp:
    """The ``fpfh-ransac-icp`` baseline (see the module docstring)."""

    name = "fpfh-ransac-icp"

    def __init__(self, settings: FpfhSettings = FpfhSettings()) -> None:  # noqa: B008 (frozen)
        self.settings = settings

    def database_descriptors(self, database: ShapeDatabase) -> list[Arrays]:
        """Unit clouds and FPFH features of every database shape (cached)."""
        return database.descriptors(
            "fpfh", self.settings,
            lambda i: fpfh_arrays(database.points(i), database.normals(i), self.settings))

    def fit(self, query_points: np.ndarray, query_normals: np.ndarray, up: np.ndarray,
            database: ShapeDatabase, *, rng: np.random.Generator) -> FitResult:
        st = self.settings
        clock = Stopwatch()
        points, normals, up = check_query(query_points, query_normals, up)
        shapes = self.database_descriptors(database)
        clock.lap("database")
        query = fpfh_arrays(points, normals, st)
        if len(query["points"]) < st.min_points:
            raise BaselineFailed(f"only {len(query['points'])} query points after voxel subsampling "
                                 f"(need {st.min_points})")
        gap = np.array([np.abs(s["mean_fpfh"] - query["mean_fpfh"]).sum() for s in shapes])
        candidates = np.argsort(gap, kind="stable")[: st.top_k or len(shapes)]
        seed = int(rng.integers(2**31))
        found = {int(i): align(shapes[i], query, st, seed) for i in candidates}
        best = min(found, key=lambda i: (-found[i].fitness, found[i].rmse))
        clock.lap("recognize_register")
        a = found[best]
        if a.fitness <= 0:
            raise BaselineFailed("FPFH + RANSAC found no alignment with any inliers")
        canonical_to_unit = _unit_to_input(shapes[best]).inverse()
        transform = _unit_to_input(query) @ Sim3.from_matrix(a.matrix) @ canonical_to_unit
        return baseline_result(
            self.name, database, best, transform, loss=a.rmse * float(query["radius"][0]),
            criterion={"name": "fitness", "value": a.fitness}, timing=clock.done(),
            info={"candidates": [int(i) for i in candidates], "inlier_rmse_unit": a.rmse})
