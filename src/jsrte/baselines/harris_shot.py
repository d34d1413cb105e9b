"""Harris3D + SHOT: local keypoints and descriptors for recognition and registration.

The paper's first baseline (section 4.2; supplementary 'Harris3D + SHOT', PCL's
implementations): Harris 3D keypoints and SHOT descriptors (Tombari et al. 2010) on the query
and on every database shape; recognition by descriptor matching; the similarity transform from
the matched keypoints (RANSAC over the correspondences + Umeyama with scale).

Scale: the query is in metres, the database in canonical units, and SHOT/Harris are not
scale-invariant. As a user of scale-free retrieval would, every cloud is first brought into its
own unit bounding sphere (:func:`~jsrte.baselines.cloud.unit_cloud`) and voxel-subsampled there,
so the keypoint and descriptor support radii are fractions of each cloud's bounding-sphere
radius. A partial scan's sphere is smaller than its complete shape's, so its radii are
relatively smaller too: that mismatch is part of this baseline's weakness on partial scans.

Recognition and registration, as PCL's recognition pipeline does them (descriptor matching,
then geometric verification of the correspondences): each query descriptor is matched to its
nearest descriptor of each database shape (squared distance below ``max_distance_sq``); RANSAC
(3-point samples, Umeyama with scale, inliers within a fraction of the query's radius) finds
each shape's largest geometrically consistent set of matches; the shape with the most inliers
wins (ties: smaller inlier RMSE), and its similarity is refit on its inliers. (A strict
threshold such as the 0.25 of PCL's correspondence-grouping tutorial leaves no match at all
between SHOTs of a noisy partial scan and of clean CAD shapes: their nearest squared distances
are 0.5-1.1.)
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from jsrte.baselines import pcl
from jsrte.baselines.cloud import unit_cloud
from jsrte.baselines.database import Arrays, ShapeDatabase
from jsrte.baselines.protocol import BaselineFailed, Stopwatch, baseline_result, check_query
from jsrte.baselines.ransac import ransac_similarity
from jsrte.result import FitResult


@dataclass(frozen=True)
class HarrisShotSettings:
    """Parameters; lengths in units of each cloud's bounding-sphere radius."""

    voxel: float = 0.02
    """Voxel subsampling of each unit cloud (about 6000 points on a complete chair)."""
    harris_radius: float = 0.05
    """Harris 3D neighbourhood and non-maximum suppression radius (30-140 keypoints per chair)."""
    harris_threshold: float = 1e-6
    """Minimum Harris response (PCL's default is float epsilon)."""
    harris_refine: bool = True
    shot_radius: float = 0.25
    """SHOT support radius (its local reference frame uses the same)."""
    max_distance_sq: float = 1.0
    """A match's largest squared descriptor distance (SHOT descriptors have unit length)."""
    ransac_iterations: int = 1000
    inlier_fraction: float = 0.05
    """RANSAC inlier distance, as a fraction of the query's bounding-sphere radius."""
    min_keypoints: int = 3


def keypoint_descriptors(points: np.ndarray, normals: np.ndarray, settings: HarrisShotSettings) -> Arrays:
    """Harris 3D keypoints and their SHOT descriptors of a cloud (any units).

    Returns ``{"keypoints": (k, 3) in the input's units, "shot": (k, 352) float32}``, keypoints
    without a valid SHOT removed.
    """
    cloud = unit_cloud(points, normals, voxel=settings.voxel)
    kp, _ = pcl.harris3d(cloud.points, cloud.normals, radius=settings.harris_radius,
                         threshold=settings.harris_threshold, refine=settings.harris_refine)
    if len(kp) == 0:
        return {"keypoints": np.zeros((0, 3)), "shot": np.zeros((0, 352), np.float32)}
    desc = pcl.shot(cloud.points, cloud.normals, kp, radius=settings.shot_radius)
    ok = np.all(np.isfinite(desc), axis=1) & (np.abs(desc).sum(axis=1) > 0)
    return {"keypoints": cloud.to_input(kp[ok]), "shot": desc[ok].astype(np.float32)}


@dataclass(frozen=True)
class Matches:
    """Descriptor matches between a query and one database shape.

    Attributes
    ----------
    query : (m,) int64, query keypoint indices
    shape : (m,) int64, database keypoint indices
    distance : (m,) float64, descriptor distances
    """

    query: np.ndarray
    shape: np.ndarray
    distance: np.ndarray

    def __len__(self) -> int:
        return len(self.query)


def match_descriptors(query: np.ndarray, shape: np.ndarray, *, max_distance_sq: float) -> Matches:
    """Each ``query`` descriptor (a, d) matched to its nearest ``shape`` descriptor (b, d) when
    their squared Euclidean distance is below ``max_distance_sq``."""
    if len(query) == 0 or len(shape) == 0:
        return Matches(np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0))
    q = np.asarray(query, dtype=np.float64)
    s = np.asarray(shape, dtype=np.float64)
    d2 = np.maximum((q**2).sum(1)[:, None] + (s**2).sum(1)[None] - 2.0 * q @ s.T, 0.0)
    nearest = np.argmin(d2, axis=1)
    rows = np.arange(len(q))
    best = d2[rows, nearest]
    keep = best < max_distance_sq
    return Matches(rows[keep], nearest[keep], np.sqrt(best[keep]))


class HarrisShot:
    """The ``harris3d-shot`` baseline (see the module docstring)."""

    name = "harris3d-shot"

    def __init__(self, settings: HarrisShotSettings = HarrisShotSettings()) -> None:  # noqa: B008 (frozen)
        self.settings = settings

    def database_descriptors(self, database: ShapeDatabase) -> list[Arrays]:
        """Keypoints (canonical units) and SHOT descriptors of every database shape (cached)."""
        return database.descriptors(
            "harris3d-shot", self.settings,
            lambda i: keypoint_descriptors(database.points(i), database.normals(i), self.settings))

    def fit(self, query_points: np.ndarray, query_normals: np.ndarray, up: np.ndarray,
            database: ShapeDatabase, *, rng: np.random.Generator) -> FitResult:
        st = self.settings
        clock = Stopwatch()
        points, normals, up = check_query(query_points, query_normals, up)
        shapes = self.database_descriptors(database)
        clock.lap("database")
        query = keypoint_descriptors(points, normals, st)
        if len(query["keypoints"]) < st.min_keypoints:
            raise BaselineFailed(f"Harris 3D found {len(query['keypoints'])} keypoints with a valid SHOT "
                                 f"on the query (need {st.min_keypoints})")
        radius = float(np.linalg.norm(points - (points.min(0) + points.max(0)) / 2, axis=1).max())
        verified = {}
        for i, d in enumerate(shapes):
            m = match_descriptors(query["shot"], d["shot"], max_distance_sq=st.max_distance_sq)
            found = ransac_similarity(d["keypoints"][m.shape], query["keypoints"][m.query],
                                      threshold=st.inlier_fraction * radius, iterations=st.ransac_iterations,
                                      rng=rng)
            if found is not None:
                verified[i] = (found, len(m))
        if not verified:
            raise BaselineFailed("no database shape has 3 SHOT matches to the query that RANSAC can fit")
        best = min(verified, key=lambda i: (-int(verified[i][0].inliers.sum()), verified[i][0].rmse))
        found, n_matches = verified[best]
        clock.lap("recognize_register")
        return baseline_result(
            self.name, database, best, found.transform, loss=found.rmse,
            criterion={"name": "ransac_inliers", "value": int(found.inliers.sum())}, timing=clock.done(),
            info={"query_keypoints": len(query["keypoints"]), "matches": n_matches})
