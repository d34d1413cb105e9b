"""The paper's real-scan preprocessing (supplementary, "SDF Sampling").

Floor plane by RANSAC (its normal is the up axis, the rotation axis ω), floor removal, the
object's clusters above the floor, statistical outlier removal, hidden point removal (Katz et
al. 2007) when the viewpoints are known, and outward normals. Planes by a seeded RANSAC
(jsrte.geometry.planes: the same seed, the same floor), the filters and normals by
jsrte.geometry.point_ops (Open3D's semantics, without importing it); lengths in scan units
(metres).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from jsrte.errors import JsrteError
from jsrte.geometry.planes import ransac_plane, refit_plane
from jsrte.geometry.point_ops import median_spacing
from jsrte.scans.io import ScanCloud
from jsrte.scans.segment import ClassShape, Segmentation, SegmentSettings, segment_objects
from jsrte.scans.veil import VeilSettings, scan_mixed_pixels
from jsrte.timing import timed_stage

UP_HINT = "pass the up axis explicitly with --up X,Y,Z"
SEGMENT_SEED = 0
"""Seed of the walls' RANSAC (apart from the caller's stream, so that the samples drawn after
preprocessing do not depend on how many planes were tried)."""


@dataclass(frozen=True)
class PrepareSettings:
    """Parameters of the preprocessing; lengths in metres."""

    floor_distance_m: float = 0.02
    """RANSAC inlier distance of the floor plane."""
    floor_ransac_iterations: int = 1000
    floor_candidates: int = 5
    """Planes tried, biggest first, until one is plausibly a floor (a big table top can hide
    more of the floor than it shows)."""
    floor_min_fraction: float = 0.05
    """A floor holds at least this fraction of the points."""
    floor_one_side: float = 0.9
    """At least this fraction of the points off the plane must lie on one side of it."""
    floor_sectors: int = 8
    floor_min_sectors: int = 4
    """A floor surrounds the object: its points beyond the object's outline (farther in the
    plane from the object's centre than 98% of the object's points) fill at least
    ``floor_min_sectors`` of ``floor_sectors`` equal angular sectors around the object (1% of
    its points each). A face of the object (a box side, a chair back) fills two or three."""
    floor_up_tolerance_deg: float = 10.0
    """With a given up axis, a plane this close to perpendicular to it is taken as the floor."""
    floor_clearance_m: float = 0.02
    """Points less than this high above the floor are removed (raised to 3x the floor noise)."""
    sor_neighbours: int = 20
    sor_std_ratio: float = 2.0
    """Statistical outlier removal: drop points whose mean neighbour distance exceeds the
    average by this many standard deviations."""
    hpr_radius_factor: float = 1000.0
    """Hidden point removal radius, in units of the cloud's extent. Larger keeps more noisy
    visible points (Open3D's example uses 100, which drops ~40% of a noisy depth scan's
    points; 1000 drops ~2% and still removes ~98% of truly hidden points)."""
    orient_rings: tuple[float, ...] = (0.0, 30.0, 60.0)
    orient_azimuths: int = 8
    orient_distance_factor: float = 3.0
    """Without known viewpoints, normals face synthetic viewpoints: ``orient_azimuths`` around
    the up axis at each elevation (degrees) of ``orient_rings`` plus one overhead, at this many
    object radii from the centroid (a sphere of such rings when up is unknown)."""
    orient_decisive: float = 0.5
    orient_neighbours: int = 10
    """A visibility vote is decisive when its margin exceeds this fraction of its total;
    other points follow this many nearest decided points."""
    normal_max_nn: int = 30
    normal_radius_factor: float = 6.0
    """Normal estimation radius, in units of the median nearest-neighbour spacing."""
    min_extent_m: float = 0.02
    max_extent_m: float = 10.0
    """An object outside this size (largest bounding-box side, metres) has the wrong units."""
    units_check: bool = True
    """Refuse a scan whose object (or, when no floor is found, the whole scan) is outside
    ``min_extent_m``..``max_extent_m``; False skips the check (``--no-units-check``)."""
    min_points: int = 50
    """Fewer points left than this after preprocessing is an error."""
    veil: VeilSettings | None = None
    """With settings, mixed pixels (:mod:`jsrte.scans.veil`) are removed from what stands on the
    floor when the scan says which camera saw each point. None (the default) keeps them: on the
    tuning rooms the removal separated one more chair of 20 but lowered the mean F@5% (the split
    and the screen came out otherwise room by room; docs/clutter.md)."""
    fit_veil: VeilSettings | None = None
    """With settings, the mixed pixels are left out of each candidate's points when it is
    prepared for a fit (:func:`prepare_object`), not of the segmentation: the clusters, cuts and
    candidates stay those of ``veil``. None (the default) keeps them: in whole scenes it moved
    class choices and fits both ways (docs/clutter.md, "Whole scenes", step 3)."""


@dataclass(frozen=True)
class Floor:
    """A floor plane ``normal . x = offset``; ``normal`` (3,) unit, towards the object.

    Attributes
    ----------
    normal : (3,) float64
    offset : float
    inliers : (n,) bool over the points it was found in
    """

    normal: np.ndarray
    offset: float
    inliers: np.ndarray

    def height(self, points: np.ndarray) -> np.ndarray:
        """Signed height (n,) of ``points`` (n, 3) above the floor."""
        return np.asarray(points, dtype=np.float64) @ self.normal - self.offset


@dataclass(frozen=True)
class PreparedScan:
    """The object's points ready for SDF sampling.

    Attributes
    ----------
    points : (m, 3) float64
    normals : (m, 3) float64, unit, outward
    up : (3,) float64, unit up axis (floor normal, or as given)
    floor : the floor found, or None
    index : (m,) int64, each point's index in the input cloud
    segmentation : how the object was told from walls and other objects (None: not segmented)
    """

    points: np.ndarray
    normals: np.ndarray
    up: np.ndarray
    floor: Floor | None
    index: np.ndarray = field(repr=False)
    segmentation: Segmentation | None = field(default=None, repr=False)


# --- floor -----------------------------------------------------------------------------------


def segment_floor(
    points: np.ndarray, *, rng: np.random.Generator, normals: np.ndarray | None = None,
    viewpoints: np.ndarray | None = None, up: np.ndarray | None = None, distance_m: float | None = None,
    settings: PrepareSettings = PrepareSettings(),
) -> Floor:
    """Find the floor: the biggest RANSAC plane (:func:`jsrte.geometry.planes.ransac_plane`) that is plausibly a floor.

    A plausible floor holds at least ``floor_min_fraction`` of the points, has (almost) all
    other points on one side, surrounds the object, and was seen from the object's side
    (its points' ``normals``, which face the sensor, point to that side; the ``viewpoints``
    lie on it): a table top or a side of the object fails that. Where the up axis is known
    (``up`` (3,) given, or cameras carried level: :func:`camera_plane_normal`), the floor is
    instead the biggest plane level with it that has the points above it: in a room, walls and
    other objects stand around the object and hide the floor. Up to ``floor_candidates``
    planes are tried, biggest first. The plane is refit to its inliers by least squares; its
    normal points to the side where the object lies.

    Parameters
    ----------
    points : (n, 3) float
    rng : seeds the RANSAC
    normals : (n, 3) float, sensor-facing normals if known
    viewpoints : (k, 3) float, camera centres if known
    up : (3,) float, the up axis if known (any length)
    distance_m : inlier distance (default ``settings.floor_distance_m``)

    Raises ``JsrteError`` saying no floor was found (and suggesting ``--up``) otherwise.
    """
    points = np.asarray(points, dtype=np.float64)
    distance = settings.floor_distance_m if distance_m is None else distance_m
    if len(points) < 3:
        raise JsrteError(f"no floor found: only {len(points)} points; {UP_HINT}")
    remaining = np.arange(len(points))
    reasons = []
    walk_up = camera_plane_normal(viewpoints) if up is None else np.asarray(up, float) / np.linalg.norm(up)
    for _ in range(settings.floor_candidates):
        if len(remaining) < 3:
            break
        normal, offset, found = ransac_plane(points[remaining], distance, settings.floor_ransac_iterations, rng)
        if len(found) < 3:
            break
        normal, offset = refit_plane(points, normal, offset, distance)
        floor, reason = _as_floor(points, normal, offset, distance, settings, walk_up=walk_up,
                                  up_known=up is not None)
        if floor is not None:
            reason = _sensor_side_objection(floor, points, normals, viewpoints)
        if floor is not None and not reason:
            return floor
        reasons.append(reason)
        near = np.abs(points[remaining] @ normal - offset) < distance
        near[np.asarray(found, dtype=np.int64)] = True
        remaining = remaining[~near]
    detail = "; ".join(reasons) if reasons else "no plane"
    raise JsrteError(f"no floor found ({detail}); {UP_HINT}")


def _sensor_side_objection(floor: Floor, points: np.ndarray, normals: np.ndarray | None,
                     viewpoints: np.ndarray | None) -> str:
    """Why ``floor`` cannot be the floor given the sensor's side, or "" if it can."""
    if viewpoints is not None:
        below = floor.height(np.asarray(viewpoints, dtype=np.float64).reshape(-1, 3)) < 0
        if below.any():
            return f"a plane with {int(below.sum())} viewpoint(s) below it"
    if normals is not None:
        facing = np.asarray(normals, dtype=np.float64)[floor.inliers] @ floor.normal
        if np.median(facing) < 0:
            return "a plane seen from the side away from the object (a top or side of it)"
    return ""


def camera_plane_normal(viewpoints: np.ndarray | None, *, min_spread_m: float = 0.05,
                        max_tilt_ratio: float = 0.2) -> np.ndarray | None:
    """Unit normal (3,) of the plane through four or more ``viewpoints`` (k, 3) when they lie
    on one (a scan walked round at a steady height: the plane is level, its normal is the up
    axis up to sign), else None: fewer than four (three always lie on a plane), spread across
    less than ``min_spread_m`` (RMS), or off the plane by more than ``max_tilt_ratio`` of that.

    The normal's error is about ``atan`` of the ratio (at most about 11 degrees), so a walk
    that is nearly a straight line (in a room of three tables side by side, cameras 1.2 m along
    and 0.14 m across their line, 1 cm up and down) still gives the up axis within a degree."""
    if viewpoints is None:
        return None
    viewpoints = np.asarray(viewpoints, dtype=np.float64).reshape(-1, 3)
    if len(viewpoints) < 4:
        return None
    _, singular, vt = np.linalg.svd(viewpoints - viewpoints.mean(0), full_matrices=False)
    spread = singular[1] / np.sqrt(len(viewpoints))
    if spread < min_spread_m or singular[2] > max_tilt_ratio * singular[1]:
        return None
    return vt[2]


def _as_floor(points: np.ndarray, normal: np.ndarray, offset: float, distance: float,
              s: PrepareSettings, *, walk_up: np.ndarray | None = None,
              up_known: bool = False) -> tuple[Floor | None, str]:
    """The plane as a Floor (normal towards the object) if plausible, else None and why.

    When the up axis is known up to its sign (``walk_up`` (3,): the normal of the plane the
    viewpoints were carried level in) or with it (``up_known``: the points must lie above the
    plane along it), the floor is the plane within ``floor_up_tolerance_deg`` of level, whether
    or not it surrounds the object (in a room, walls and other objects stand around it and hide
    the floor)."""
    height = points @ normal - offset
    inliers = np.abs(height) < distance
    if inliers.mean() < s.floor_min_fraction:
        return None, f"biggest plane holds only {inliers.mean():.1%} of the points"
    off = np.abs(height) > 3.0 * distance
    if off.sum() < s.min_points:
        return None, "nothing stands on the biggest plane"
    above = float((height[off] > 0).mean())
    if max(above, 1.0 - above) < s.floor_one_side:
        return None, f"a plane with points on both sides ({above:.0%} above)"
    if above < 0.5:
        normal, offset, height = -normal, -offset, -height
    obj = points[height > 3.0 * distance]
    if walk_up is not None:
        tilt = float(np.degrees(np.arccos(min(1.0, abs(float(walk_up @ normal))))))
        if tilt > s.floor_up_tolerance_deg:
            level = "the up axis" if up_known else "the level of the viewpoints"
            return None, f"a plane tilted {tilt:.0f} degrees from {level}"
        if up_known and normal @ walk_up < 0:
            return None, "a plane with the points under it along the up axis (a top or a ceiling)"
        return Floor(normal=normal, offset=float(offset), inliers=inliers), ""
    sectors = _sectors_around(points[inliers], obj, normal, s.floor_sectors)
    if sectors < s.floor_min_sectors:
        return None, (f"a plane that does not surround the object (a face of it; "
                      f"{sectors}/{s.floor_sectors} sectors)")
    return Floor(normal=normal, offset=float(offset), inliers=inliers), ""


def _sectors_around(plane_points: np.ndarray, obj: np.ndarray, normal: np.ndarray,
                    sectors: int) -> int:
    """Number of angular sectors around the object's centre (in the plane) holding at least
    1% of ``plane_points`` (m, 3) that lie beyond the object's outline."""
    from jsrte.geometry.sim3 import rotation_between

    to_plane = rotation_between(normal, np.array([0.0, 0.0, 1.0]))
    centre = obj.mean(0)
    flat_obj = ((obj - centre) @ to_plane.T)[:, :2]
    flat = ((plane_points - centre) @ to_plane.T)[:, :2]
    outside = np.linalg.norm(flat, axis=1) > np.percentile(np.linalg.norm(flat_obj, axis=1), 98)
    angle = np.arctan2(flat[outside, 1], flat[outside, 0])
    counts = np.histogram(angle, bins=sectors, range=(-np.pi, np.pi))[0]
    return int((counts >= max(1.0, 0.01 * len(plane_points))).sum())


# --- filters ---------------------------------------------------------------------------------


def remove_outliers(
    points: np.ndarray, *, neighbours: int = PrepareSettings.sor_neighbours,
    std_ratio: float = PrepareSettings.sor_std_ratio,
) -> np.ndarray:
    """Statistical outlier removal: the keep mask (n,) bool of ``points`` (n, 3)
    (:func:`jsrte.geometry.point_ops.statistical_inliers`, Open3D's semantics)."""
    from jsrte.geometry.point_ops import statistical_inliers

    return statistical_inliers(points, neighbours, std_ratio)


def hidden_point_removal(
    points: np.ndarray, viewpoint: np.ndarray, *,
    radius_factor: float = PrepareSettings.hpr_radius_factor,
) -> np.ndarray:
    """Katz et al. 2007: mask (n,) bool of the ``points`` (n, 3) visible from ``viewpoint`` (3,)
    (:func:`jsrte.geometry.point_ops.visible_points`, Open3D's semantics). The spherical-flip
    radius is ``radius_factor`` times the extent."""
    from jsrte.geometry.point_ops import visible_points

    points = np.asarray(points, dtype=np.float64)
    if len(points) < 4:
        return np.ones(len(points), dtype=bool)
    extent = float(np.linalg.norm(points.max(0) - points.min(0)))
    return visible_points(points, viewpoint, radius_factor * extent)


@timed_stage("normals")
def estimate_normals(
    points: np.ndarray, *, viewpoints: np.ndarray | None = None, up: np.ndarray | None = None,
    settings: PrepareSettings = PrepareSettings(),
) -> np.ndarray:
    """Unit normals (n, 3) of ``points`` (n, 3) by local PCA, oriented outward.

    Each normal is turned towards the viewpoints that see its point (hidden point removal
    decides which; a majority vote among them, the nearest viewpoint for points none sees).
    Without ``viewpoints`` (k, 3), synthetic viewpoints surround the object
    (:func:`synthetic_viewpoints`; only above it when ``up`` (3,) is given): a scan sees the
    outside of its object, so facing the viewpoints means pointing outward.

    The PCA takes each point's ``normal_max_nn`` nearest neighbours within
    ``normal_radius_factor`` median spacings (:func:`jsrte.geometry.point_ops.pca_normals`,
    Open3D's hybrid search and eigen solver).
    """
    from jsrte.geometry.point_ops import pca_normals

    points = np.asarray(points, dtype=np.float64)
    radius = settings.normal_radius_factor * median_spacing(points)
    normals = pca_normals(points, radius, settings.normal_max_nn)
    if viewpoints is None:
        viewpoints = synthetic_viewpoints(points, up=up, settings=settings)
    return orient_towards_viewpoints(points, normals, viewpoints, settings=settings)


@timed_stage("normals")
def orient_towards_viewpoints(
    points: np.ndarray, normals: np.ndarray, viewpoints: np.ndarray, *,
    settings: PrepareSettings = PrepareSettings(),
) -> np.ndarray:
    """``normals`` (n, 3) flipped so each faces the viewpoints (k, 3) that see its point.

    Visibility is hidden point removal per viewpoint; each viewpoint that sees a point votes
    for the side it lies on, weighted by the cosine. Where the vote is not decisive (a thin
    surface seen from one side only is "seen" from both sides: the margin is below
    ``orient_decisive`` of the total), the point agrees with its ``orient_neighbours``
    nearest decided points instead.
    """
    from pykdtree.kdtree import KDTree

    points = np.ascontiguousarray(points, dtype=np.float64)
    normals = np.array(normals, dtype=np.float64)
    viewpoints = np.asarray(viewpoints, dtype=np.float64).reshape(-1, 3)
    vote = np.zeros(len(points))
    total = np.zeros(len(points))
    for viewpoint in viewpoints:
        towards = viewpoint - points
        cosine = np.einsum("ij,ij->i", normals, towards) / np.maximum(
            np.linalg.norm(towards, axis=1), 1e-12)
        seen = hidden_point_removal(points, viewpoint, radius_factor=settings.hpr_radius_factor)
        vote += np.where(seen, cosine, 0.0)
        total += np.where(seen, np.abs(cosine), 0.0)
    normals[vote < 0] *= -1.0
    decided = (total > 0) & (np.abs(vote) > settings.orient_decisive * total)
    if decided.any() and not decided.all():
        k = min(settings.orient_neighbours, int(decided.sum()))
        _, near = KDTree(points[decided]).query(points[~decided], k=k)
        near = near.reshape(len(near), k)
        agreement = np.einsum("ikj,ij->i", normals[decided][near], normals[~decided])
        undecided = np.flatnonzero(~decided)
        normals[undecided[agreement < 0]] *= -1.0
    return normals


def synthetic_viewpoints(
    points: np.ndarray, *, up: np.ndarray | None = None,
    settings: PrepareSettings = PrepareSettings(),
) -> np.ndarray:
    """Viewpoints (k, 3) around ``points`` (n, 3): rings of ``orient_azimuths`` about ``up``
    at the elevations ``orient_rings`` plus one overhead, ``orient_distance_factor`` radii
    from the centroid; without ``up`` the rings are mirrored below (a whole sphere)."""
    from jsrte.geometry.sim3 import rotation_between

    points = np.asarray(points, dtype=np.float64)
    centre = points.mean(0)
    radius = float(np.linalg.norm(points - centre, axis=1).max()) or 1.0
    elevations = list(settings.orient_rings)
    if up is None:
        elevations += [-e for e in settings.orient_rings if e > 0]
    directions = [np.array([0.0, 1.0, 0.0])] + ([np.array([0.0, -1.0, 0.0])] if up is None else [])
    for elevation in np.radians(elevations):
        for azimuth in np.linspace(0.0, 2 * np.pi, settings.orient_azimuths, endpoint=False):
            directions.append(np.array([np.cos(elevation) * np.cos(azimuth), np.sin(elevation),
                                        np.cos(elevation) * np.sin(azimuth)]))
    rotation = np.eye(3) if up is None else rotation_between(np.array([0.0, 1.0, 0.0]), up)
    return centre + settings.orient_distance_factor * radius * np.array(directions) @ rotation.T


def check_units(
    points: np.ndarray, path: object = None, *,
    settings: PrepareSettings = PrepareSettings(), what: str = "the object",
) -> float:
    """Raise ``JsrteError`` if the size of ``points`` (the object, normally) is implausible in
    metres; returns the size.

    The size is the largest side of the bounding box of the 1st-99th percentiles (stray
    points do not count). Above ``max_extent_m`` the scan is probably in millimetres (or
    centimetres); below ``min_extent_m`` the units are wrong too. A room around the object
    may be any size: only the object is checked once it is found.
    """
    points = np.asarray(points, dtype=np.float64)
    lo, hi = np.percentile(points, [1, 99], axis=0)
    size = float((hi - lo).max())
    hint = "convert it to metres, or pass --no-units-check if it is in metres"
    if size > settings.max_extent_m:
        raise JsrteError(
            f"{what} is {size:.4g} units across, implausible for metres: probably in "
            f"millimetres or centimetres; {hint}", path)
    if size < settings.min_extent_m:
        raise JsrteError(
            f"{what} is only {size:.3g} units across (< {settings.min_extent_m * 100:.0f} cm in "
            f"metres): wrong units or a degenerate scan; {hint}", path)
    return size


# --- the pipeline ----------------------------------------------------------------------------


@dataclass(frozen=True)
class SegmentedScan:
    """A scan cut into candidate objects, before any one is prepared for the fit.

    Attributes
    ----------
    cloud : the scan
    index : (m,) int64 indices into ``cloud.points`` of the points above the floor (the cloud
        that ``segmentation``'s indices refer to)
    up : (3,) float64 unit up axis
    floor : the floor found, or None
    segmentation : the candidates and the one chosen so far
    viewpoints : (k, 3) camera centres, or None
    settings : the preprocessing's settings
    mixed : (n,) bool over ``cloud.points``, the mixed pixels found (left out of ``index`` and of
        the free-space evidence), or None when the test did not run
    fit_mixed : (n,) bool over ``cloud.points``, the mixed pixels left out of each candidate's
        points for its fit (``PrepareSettings.fit_veil``), or None
    """

    cloud: ScanCloud
    index: np.ndarray = field(repr=False)
    up: np.ndarray
    floor: Floor | None
    segmentation: Segmentation = field(repr=False)
    viewpoints: np.ndarray | None = None
    settings: PrepareSettings = PrepareSettings()
    mixed: np.ndarray | None = field(default=None, repr=False)
    fit_mixed: np.ndarray | None = field(default=None, repr=False)

    def seen_points(self) -> np.ndarray:
        """(m, 3) every point the sensor saw on a surface: the cloud without its mixed pixels
        (the free-space evidence of the lines of sight)."""
        points = np.asarray(self.cloud.points)
        return points if self.mixed is None else points[~self.mixed]

    def heights(self) -> np.ndarray:
        """(m,) heights (m) above the floor of the points of ``index`` (:func:`heights_above_floor`)."""
        return heights_above_floor(self.cloud.points[self.index], self.floor, self.up)

    def prepare(self, candidate: int | None = None, *, keep: np.ndarray | None = None) -> PreparedScan:
        """The candidate at position ``candidate`` of the segmentation (default: the chosen one)
        ready for the fit: :func:`prepare_object` on its points (only those of ``keep`` (p,)
        bool over them, if given)."""
        k = self.segmentation.chosen if candidate is None else candidate
        chosen = self.segmentation.candidates[k].index
        if keep is not None:
            chosen = chosen[keep]
        return prepare_object(self, self.index[chosen])


def heights_above_floor(points: np.ndarray, floor: Floor | None, up: np.ndarray) -> np.ndarray:
    """(n,) heights (m) of ``points`` (n, 3) above ``floor``; without one, along ``up`` (3,) over the lowest."""
    if floor is not None:
        return floor.height(points)
    heights = np.asarray(points, dtype=np.float64) @ up
    return heights - heights.min()


@timed_stage("floor and cleaning")
def segment_scan(
    cloud: ScanCloud, *, rng: np.random.Generator, up: np.ndarray | None = None,
    viewpoints: np.ndarray | None = None, shape: ClassShape | None = None, at: np.ndarray | None = None,
    settings: PrepareSettings = PrepareSettings(), segment: SegmentSettings = SegmentSettings(),
) -> SegmentedScan:
    """The first half of :func:`prepare_scan`: the floor (and up axis) and the candidate objects
    above it (:func:`jsrte.scans.segment.segment_objects`; the one nearest ``at`` (3,), else the
    one most like ``shape``, else the largest, is chosen). Mixed pixels (:mod:`jsrte.scans.veil`)
    are left out first when the cloud says which of the ``viewpoints`` saw each point
    (``cloud.view``); their count is the segmentation's ``removed["mixed_pixels"]``. Each
    candidate can then be prepared for a fit (:meth:`SegmentedScan.prepare`)."""
    points = cloud.points
    index = np.arange(len(points))
    if viewpoints is not None:
        viewpoints = np.asarray(viewpoints, dtype=np.float64).reshape(-1, 3)
    try:
        floor, up_axis = _floor_and_up(cloud, up, viewpoints, rng, settings)
    except JsrteError:
        if settings.units_check:  # a scan in millimetres has no floor in metres: say so first
            check_units(points, cloud.path, settings=settings, what="the scan, with no floor found,")
        raise
    if floor is not None:
        index = index[_above_floor(points, floor, settings)]
    mixed = scan_mixed_pixels(points, cloud.view, viewpoints, settings.veil)
    if mixed is not None:
        n_above = len(index)
        index = index[~mixed[index]]
        n_mixed = n_above - len(index)
    _require(index, settings, cloud.path, "above the floor")
    heights = heights_above_floor(points[index], floor, up_axis)
    if not settings.units_check:  # sizes in other units than metres: no size is implausible
        segment = replace(segment, min_height_m=0.0, min_width_m=0.0, max_height_m=np.inf, max_width_m=np.inf)
    try:
        segmentation = segment_objects(points[index], heights, up_axis, rng=np.random.default_rng(SEGMENT_SEED),
                                       shape=shape, at=at, viewpoints=viewpoints,
                                       normals=None if cloud.normals is None else cloud.normals[index],
                                       seen=points if mixed is None else points[~mixed],
                                       settings=segment, path=cloud.path)
    except JsrteError:
        if settings.units_check:  # nothing of an object's size: say first if the units look wrong
            check_units(points[index], cloud.path, settings=settings, what="what stands on the floor")
        raise
    if mixed is not None:
        segmentation.removed = {"mixed_pixels": n_mixed} | segmentation.removed
    fit_mixed = scan_mixed_pixels(points, cloud.view, viewpoints, settings.fit_veil)
    return SegmentedScan(cloud=cloud, index=index, up=up_axis, floor=floor, segmentation=segmentation,
                         viewpoints=viewpoints, settings=settings, mixed=mixed, fit_mixed=fit_mixed)


@timed_stage("floor and cleaning")
def prepare_object(segmented: SegmentedScan, index: np.ndarray) -> PreparedScan:
    """The second half of :func:`prepare_scan`: the object's points ``index`` (p,) (into the
    scan's cloud) cleaned (mixed pixels where ``PrepareSettings.fit_veil`` asks, statistical
    outliers, hidden points), checked for metres, with outward normals."""
    cloud, viewpoints, settings = segmented.cloud, segmented.viewpoints, segmented.settings
    points = cloud.points
    if segmented.fit_mixed is not None:
        index = index[~segmented.fit_mixed[index]]
        _require(index, settings, cloud.path, "without its mixed pixels")
    index = index[remove_outliers(points[index], neighbours=settings.sor_neighbours,
                                  std_ratio=settings.sor_std_ratio)]
    if viewpoints is not None:
        visible = np.zeros(len(index), dtype=bool)
        for viewpoint in viewpoints:
            visible |= hidden_point_removal(points[index], viewpoint,
                                            radius_factor=settings.hpr_radius_factor)
        index = index[visible]
    _require(index, settings, cloud.path, "after outlier removal")
    if settings.units_check:
        check_units(points[index], cloud.path, settings=settings)
    kept = points[index]
    if cloud.normals is None:
        normals = estimate_normals(kept, viewpoints=viewpoints, up=segmented.up, settings=settings)
    elif viewpoints is not None:
        normals = orient_towards_viewpoints(kept, cloud.normals[index], viewpoints,
                                            settings=settings)
    else:
        normals = cloud.normals[index].copy()
    return PreparedScan(points=kept, normals=normals, up=segmented.up, floor=segmented.floor, index=index,
                        segmentation=segmented.segmentation)


def prepare_scan(
    cloud: ScanCloud, *, rng: np.random.Generator, up: np.ndarray | None = None,
    viewpoints: np.ndarray | None = None, shape: ClassShape | None = None, at: np.ndarray | None = None,
    settings: PrepareSettings = PrepareSettings(), segment: SegmentSettings = SegmentSettings(),
) -> PreparedScan:
    """The paper's preprocessing of a real scan: the object's points with outward normals.

    Steps: floor plane (RANSAC, :func:`segment_floor`) whose normal is the up
    axis unless ``up`` is given (then a plane perpendicular to ``up`` is still removed as
    floor if found); points within the floor clearance (or below the floor) removed; walls
    removed and the object told from other objects (:func:`jsrte.scans.segment.segment_objects`:
    the cluster nearest ``at``, else the one that matches ``shape`` best, else the largest,
    with the fragments near it); statistical outlier removal; hidden point removal from
    ``viewpoints`` (k, 3) if given; the object's size checked for metres (:func:`check_units`,
    unless ``settings.units_check`` is False); normals kept from the file (re-oriented towards
    the viewpoints that see them if viewpoints are known) or estimated. The two halves are
    :func:`segment_scan` and :func:`prepare_object`.

    Parameters
    ----------
    cloud : the scan (metres)
    rng : seeds the floor's RANSAC (the walls' RANSAC has its own fixed seed)
    up : (3,) the up axis if known (skips relying on the floor for it)
    viewpoints : (k, 3) camera centres if known
    shape : the class's proportions, to pick its object among several
    at : (3,) pick the object nearest this point instead (scan units)
    """
    return segment_scan(cloud, rng=rng, up=up, viewpoints=viewpoints, shape=shape, at=at, settings=settings,
                        segment=segment).prepare()


def _floor_and_up(cloud: ScanCloud, up: np.ndarray | None, viewpoints: np.ndarray | None,
                  rng: np.random.Generator, s: PrepareSettings) -> tuple[Floor | None, np.ndarray]:
    """The floor (None if there is none, allowed only with ``up``) and the unit up axis."""
    if up is None:
        try:
            floor = segment_floor(cloud.points, rng=rng, normals=cloud.normals,
                                  viewpoints=viewpoints, settings=s)
        except JsrteError as exc:
            raise JsrteError(str(exc), cloud.path) from None
        return floor, floor.normal
    up = np.asarray(up, dtype=np.float64).reshape(3)
    if not np.linalg.norm(up) > 0:
        raise JsrteError("the up axis must be a non-zero vector")
    up = up / np.linalg.norm(up)
    try:  # a floor found along ``up`` is level with it, the points above it
        return segment_floor(cloud.points, rng=rng, normals=cloud.normals,
                             viewpoints=viewpoints, up=up, settings=s), up
    except JsrteError:
        return None, up


def _above_floor(points: np.ndarray, floor: Floor, s: PrepareSettings) -> np.ndarray:
    """Mask of points clearly above the floor: higher than the clearance, raised to three
    times the floor's noise (the RMS height of the points below the plane)."""
    height = floor.height(points)
    below = height[(height < 0) & (height > -5.0 * s.floor_distance_m)]
    noise = float(np.sqrt(np.mean(below**2))) if len(below) else 0.0
    return height > max(s.floor_clearance_m, 3.0 * noise)


def _require(index: np.ndarray, s: PrepareSettings, path: object, where: str) -> None:
    if len(index) < s.min_points:
        raise JsrteError(f"only {len(index)} scan points left {where} (need {s.min_points})", path)
