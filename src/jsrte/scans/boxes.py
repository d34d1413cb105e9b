"""Boxes: clutter that no shipped model covers, told apart by its shape before any fit.

A candidate is a box when it is an upright cuboid seen solid:

- its points lie on the faces of their upright bounding cuboid (:func:`upright_cuboid`: the
  smallest rectangle about the up axis holding 98% of them, from the floor to their top),
  within ``face_band_m``;
- they cover its top;
- no line of sight from a camera to anything it saw (floor, walls, other objects, the candidate
  itself) passes through the cuboid's inside, ``inner_margin_m`` within its faces; without
  known cameras, the floor under it was seen nowhere: a solid box hides the floor it stands on
  from every viewpoint.

A table's points also lie on the faces of its cuboid (its top, its legs at the corners) and
cover its top, but the cameras see the floor and the wall through the space under it; a sofa's
seat and a bed's mattress lie inside their cuboids (the back and the headboard stand higher).

A box can also hide inside a bigger cluster, touching the chair it half hides: :func:`peel_box`
looks for the cuboid under each dense horizontal level of the cluster and takes it out where
it passes the same tests.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
import trimesh


@dataclass(frozen=True)
class BoxSettings:
    """What makes a candidate a box (metres, shares of its points or of its cuboid's top).

    Chosen on the candidates of the tuning rooms (100-129 of seed 0): of the 16 candidates that
    were most of one box, 13 pass (the other three, with 0.42-0.62 of their points on the faces,
    are left to the models); every candidate of furniture fails, the nearest a bed's piece seen
    through at 0.34 and a sofa whose points covered 0.56 of its cuboid's top. The length was
    added on rooms 130-169, where six pieces of furniture longer than any box passed the others.
    """

    face_band_m: float = 0.03
    """A point lies on a face within this distance (depth noise and a box's rounded edges)."""
    min_on_faces: float = 0.8
    """At least this share of the points lie on the faces (boxes: 0.84-1.0)."""
    min_top_coverage: float = 0.8
    """At least this share of the top's ``cell_m`` cells hold a point on it (boxes: 0.86-1.0)."""
    cell_m: float = 0.04
    """The cells of the top's coverage."""
    min_width_m: float = 0.2
    """Both horizontal edges at least this long: a thinner slab is a piece (a headboard, a
    wall's remnant, a sofa's back), all of whose points lie near some face."""
    max_length_m: float = 0.8
    """A box reported as one has every edge at most this long: a longer cuboid seen solid is a
    piece of furniture (a bed's mattress and base, a sofa's seat, a table; standing up, a sofa's
    arm), left to the models (:func:`candidate_boxes`; one taken out of a cluster stays a
    candidate of its own). On the tuning rooms (100-169 of seed 0) the longest horizontal edge of
    every box that passed the tests was 0.36-0.70 m, of every such piece 0.84-1.91 m; every box
    stood at most 0.71 m tall, a sofa's arm that came near the tests 0.91 m."""
    inner_margin_m: float = 0.05
    """The inside crossed by no line of sight: the cuboid shrunk by this on every side."""
    max_seen_through: float = 0.25
    """At most this many lines of sight through the inside per point of the candidate (noise
    and flying pixels; on the tuning rooms boxes 0.0-0.2, tables 0.44 and more)."""
    floor_band_m: float = 0.03
    """Without cameras: a point of the scan within this of the floor's plane is floor."""
    max_floor_seen_under: float = 0.2
    """Without cameras: at most this share of the footprint (``cell_m`` cells, ``inner_margin_m``
    within its edges) holds a point of the floor. On the tuning rooms (100-169 of seed 0)
    boxes 0.0-0.13, the furniture that passed the other tests 0.29 (a sofa's arm, 8 floor points
    under it) and 0.96-1.0 (chairs and small tables, seen under their seat or top)."""


@dataclass(frozen=True)
class Cuboid:
    """An upright cuboid in the scan's frame.

    Attributes
    ----------
    centre : (3,) float64 its centre (scan units)
    axes : (3, 3) float64 rows: its two horizontal edge directions and the up axis (unit)
    extents : (3,) float64 its edge lengths along ``axes`` (scan units)
    """

    centre: np.ndarray
    axes: np.ndarray
    extents: np.ndarray

    def local(self, points: np.ndarray) -> np.ndarray:
        """(n, 3) ``points`` (n, 3) in the cuboid's frame (origin at its centre, along its axes)."""
        return (np.asarray(points, float) - self.centre) @ self.axes.T

    def mesh(self) -> trimesh.Trimesh:
        """The cuboid as a closed triangle mesh in the scan's frame."""
        frame = np.eye(4)
        frame[:3, :3] = self.axes.T
        frame[:3, 3] = self.centre
        return trimesh.creation.box(extents=self.extents, transform=frame)

    def to_json(self) -> dict[str, Any]:
        """The cuboid as scene.json records it (centre, axes rows, extents; scan units)."""
        return {"centre": np.round(self.centre, 5).tolist(), "axes": np.round(self.axes, 6).tolist(),
                "extents": np.round(self.extents, 5).tolist()}


@dataclass(frozen=True)
class BoxEvidence:
    """How much a candidate looks like a box (:func:`box_evidence`).

    Attributes
    ----------
    cuboid : its points' upright bounding cuboid
    on_faces : share of its points within ``face_band_m`` of a face (top or side)
    top_coverage : share of the top's cells holding a point on the top
    seen_through : lines of sight through the cuboid's inside per point; None when not measured
        (no cameras, or the cheaper tests failed)
    floor_seen_under : without cameras, the share of its footprint where the floor was seen;
        None when not measured (cameras known, or the cheaper tests failed)
    is_box : whether every test passed
    plausible : whether the tests of its points alone passed (width, faces, top), the lines of
        sight aside
    """

    cuboid: Cuboid
    on_faces: float
    top_coverage: float
    seen_through: float | None
    is_box: bool
    plausible: bool = False
    floor_seen_under: float | None = None

    def to_json(self) -> dict[str, Any]:
        """The evidence as scene.json records it."""
        through = None if self.seen_through is None else round(self.seen_through, 4)
        under = None if self.floor_seen_under is None else round(self.floor_seen_under, 4)
        return {"on_faces": round(self.on_faces, 4), "top_coverage": round(self.top_coverage, 4),
                "seen_through": through, "floor_seen_under": under}


YAW_STEPS = 90
"""Yaws tried for the bounding rectangle, over a quarter turn (1 degree apart)."""
KEPT_PERCENT = 1.0
"""The bounding rectangle and the top leave out this percentage of the points on each side
(flying pixels and mixed pixels at the edges)."""
PEEL_LEVELS = 4
"""At most this many horizontal levels of a cluster (its densest, 4 cm or more apart) are tried
as a box's top."""
PEEL_LEVEL_SHARE = 0.03
"""A level holds at least this share of the cluster's points (in its 1 cm bin and the two
beside it)."""
PEEL_TOP_BAND_M = 0.02
"""A box's top: the points within this of its level."""
PEEL_TOP_POINTS = 60
"""A box's top holds at least this many points."""
PEEL_LOWEST_M = 0.15
"""A box's top lies at least this high above the floor."""
SIGHT_POINTS = 20_000
"""At most this many of the points seen near a cuboid (a fixed draw) are tested for lines of
sight through it."""


def upright_cuboid(points: np.ndarray, up: np.ndarray, floor_offset: float) -> Cuboid:
    """The upright cuboid of ``points`` (n, 3): about the unit ``up`` (3,), the rectangle of
    least area holding all but :data:`KEPT_PERCENT` of them on each side, from the floor (the
    plane ``up . x = floor_offset``) to all but that percentage of them."""
    up = np.asarray(up, float) / np.linalg.norm(up)
    first = np.cross(up, [1.0, 0.0, 0.0] if abs(up[0]) < 0.9 else [0.0, 0.0, 1.0])
    first /= np.linalg.norm(first)
    second = np.cross(up, first)
    flat = np.asarray(points, float) @ np.stack([first, second]).T
    yaws = np.linspace(0.0, np.pi / 2, YAW_STEPS, endpoint=False)
    cos, sin = np.cos(yaws), np.sin(yaws)
    turned = np.stack([flat @ np.array([c, s]) for c, s in zip(cos, sin, strict=True)] +
                      [flat @ np.array([-s, c]) for c, s in zip(cos, sin, strict=True)], axis=1)
    low, high = np.percentile(turned, [KEPT_PERCENT, 100.0 - KEPT_PERCENT], axis=0)
    span = (high - low).reshape(2, YAW_STEPS)
    k = int(np.argmin(span[0] * span[1]))
    c, s = cos[k], sin[k]
    axis_a, axis_b = c * first + s * second, -s * first + c * second
    mid = np.array([(low[k] + high[k]) / 2.0, (low[k + YAW_STEPS] + high[k + YAW_STEPS]) / 2.0])
    top = float(np.percentile(np.asarray(points, float) @ up, 100.0 - KEPT_PERCENT))
    height = max(top - floor_offset, 1e-6)
    centre = mid[0] * axis_a + mid[1] * axis_b + (floor_offset + height / 2.0) * up
    return Cuboid(centre, np.stack([axis_a, axis_b, up]), np.array([span[0, k], span[1, k], height]))


def box_evidence(points: np.ndarray, up: np.ndarray, floor_offset: float, seen: np.ndarray | None,
                 viewpoints: np.ndarray | None, settings: BoxSettings = BoxSettings(),
                 cuboid: Cuboid | None = None) -> BoxEvidence:
    """How much the candidate of ``points`` (n, 3) looks like a box (the module's tests), on a
    floor ``up . x = floor_offset``; ``seen`` (m, 3): every point the sensor saw, ``viewpoints``
    (k, 3): the cameras (the lines of sight are measured where both are given, the floor under
    it where only ``seen`` is, and either only where the cheaper tests pass). The box's
    ``cuboid`` is the points' upright cuboid unless given."""
    cuboid = upright_cuboid(points, up, floor_offset) if cuboid is None else cuboid
    local = cuboid.local(points)
    half = cuboid.extents / 2.0
    gap = np.abs(half - np.abs(local))
    gap[:, 2] = np.abs(half[2] - local[:, 2])  # the top only: the bottom stands on the floor
    on_faces = float((gap.min(axis=1) < settings.face_band_m).mean())
    top_coverage = _top_coverage(local[gap[:, 2] < settings.face_band_m, :2], half[:2], settings.cell_m)
    plausible = (min(cuboid.extents[:2]) >= settings.min_width_m and on_faces >= settings.min_on_faces
                 and top_coverage >= settings.min_top_coverage)
    through = under = None
    if plausible and seen is not None and viewpoints is not None and len(viewpoints):
        through = _seen_through(cuboid, seen, np.asarray(viewpoints, float), settings) / len(points)
    elif plausible and seen is not None:
        under = _floor_seen_under(cuboid, np.asarray(seen, float), up, floor_offset, settings)
    is_box = plausible and (through <= settings.max_seen_through if through is not None
                            else under is not None and under <= settings.max_floor_seen_under)
    return BoxEvidence(cuboid, on_faces, top_coverage, through, is_box, plausible, under)


def candidate_boxes(cands: object, positions: list[int],
                    settings: BoxSettings = BoxSettings()) -> dict[int, BoxEvidence]:
    """The candidates at ``positions`` of ``cands`` (``jsrte.fit.query.ScanCandidates``) that
    are boxes, by position, with their evidence (:func:`box_evidence`, the scan's floor, points
    seen and cameras; a box the segmentation took out of a cluster keeps the evidence it was
    taken out on) and are short enough (:func:`reported_as_box`); none without a floor."""
    segmented = cands.segmented
    if segmented.floor is None:
        return {}
    points = np.asarray(segmented.cloud.points, float)[segmented.index]
    seen = segmented.seen_points()
    found = {}
    for k in positions:
        evidence = cands.segmentation.candidates[k].box
        if evidence is None:
            evidence = box_evidence(points[cands.segmentation.candidates[k].index], segmented.up,
                                    float(segmented.floor.offset), seen, segmented.viewpoints, settings)
        if reported_as_box(evidence, settings):
            found[k] = evidence
    return found


def reported_as_box(evidence: BoxEvidence, settings: BoxSettings = BoxSettings()) -> bool:
    """Whether a candidate of ``evidence`` is a box to report: it passed every test of
    :func:`box_evidence` and no edge of its cuboid is longer than ``max_length_m``."""
    return evidence.is_box and max(evidence.cuboid.extents) <= settings.max_length_m


def peel_box(points: np.ndarray, heights: np.ndarray, up: np.ndarray, seen: np.ndarray,
             viewpoints: np.ndarray | None, eps: float, min_rest: int,
             settings: BoxSettings = BoxSettings(),
             accept: Callable[[np.ndarray], bool] | None = None) -> tuple[np.ndarray, BoxEvidence] | None:
    """The points of a box among ``points`` (n, 3) of one cluster standing on the floor
    (``heights`` (n,) above it, m; ``up`` (3,) its unit normal), as a mask (n,), with the
    evidence that it is one; None when the cluster holds none.

    Each of the cluster's densest horizontal levels (:func:`dense_levels`) is tried as a box's
    top: the points on it with nothing above them (:func:`_open_top`) are clustered (DBSCAN at
    ``eps``, the segmentation's radius); each piece of :data:`PEEL_TOP_POINTS` or more gives an
    upright cuboid (:func:`upright_cuboid` of the piece, from the floor to the level), and the
    cluster's points within ``face_band_m`` of it are the box if they pass :func:`box_evidence`
    for that cuboid (a top's edges place it better than the points beside its faces, a
    neighbour's among them) with ``seen`` (m, 3), every point the sensor saw (the floor's too),
    and its ``viewpoints`` (k, 3; None: unknown, the floor under it tells), and at least
    ``min_rest`` points are left beside it. Where given, ``accept`` judges each cuboid whose
    points pass the tests of their own (a mask (n,) of the box's points: True to go on) before
    its costly lines of sight; one it refuses is passed over for the next (a sofa's base before
    the box against its arm).
    """
    from jsrte.geometry.point_ops import dbscan_labels

    up = np.asarray(up, float) / np.linalg.norm(up)
    floor_offset = float(np.median(points @ up - heights))
    band = settings.face_band_m
    for level in dense_levels(heights):
        top = _open_top(points, heights, up, level)
        labels = dbscan_labels(points[top], eps, 5)
        for k in range(labels.max(initial=-1) + 1):
            piece = top[labels == k]
            if len(piece) < PEEL_TOP_POINTS:
                continue
            cuboid = upright_cuboid(points[piece], up, floor_offset)
            local = np.abs(cuboid.local(points))
            inside = np.all(local[:, :2] <= cuboid.extents[:2] / 2.0 + band, axis=1) & (heights <= level + band)
            if inside.sum() < PEEL_TOP_POINTS or (~inside).sum() < min_rest:
                continue
            if not box_evidence(points[inside], up, floor_offset, None, None, settings, cuboid).plausible:
                continue
            if accept is not None and not accept(inside):
                continue
            evidence = box_evidence(points[inside], up, floor_offset, seen, viewpoints, settings, cuboid)
            if evidence.is_box:
                return inside, evidence
    return None


def _open_top(points: np.ndarray, heights: np.ndarray, up: np.ndarray, level: float) -> np.ndarray:
    """Indices of the points of ``points`` (n, 3) at ``level`` (within :data:`PEEL_TOP_BAND_M`)
    with no point higher above them (none of those higher than the band within
    :data:`PEEL_TOP_BAND_M` across the unit ``up`` (3,)): a top, not the slice of a chair's back
    or a table's leg at that height."""
    from pykdtree.kdtree import KDTree

    at_level = np.flatnonzero(np.abs(heights - level) < PEEL_TOP_BAND_M)
    higher = heights > level + PEEL_TOP_BAND_M
    if not higher.any() or not len(at_level):
        return at_level
    across = np.linalg.svd(up.reshape(1, 3))[2][1:]  # (2, 3) a basis of the floor's plane
    tree = KDTree(np.ascontiguousarray(points[higher] @ across.T))
    distance, _ = tree.query(np.ascontiguousarray(points[at_level] @ across.T), k=1)
    return at_level[distance > PEEL_TOP_BAND_M]


def dense_levels(heights: np.ndarray) -> list[float]:
    """Up to :data:`PEEL_LEVELS` heights (m) at which many of ``heights`` (n,) lie: 1 cm bins
    from :data:`PEEL_LOWEST_M` up, each summed with its two neighbours, densest first, each
    holding :data:`PEEL_LEVEL_SHARE` of the points (and 60 or more), 4 cm or more apart."""
    edges = np.arange(PEEL_LOWEST_M, float(heights.max(initial=0.0)) + 0.02, 0.01)
    if len(edges) < 2:
        return []
    counts = np.convolve(np.histogram(heights, bins=edges)[0], [1, 1, 1], mode="same")
    least = max(PEEL_TOP_POINTS, PEEL_LEVEL_SHARE * len(heights))
    levels: list[float] = []
    for b in np.argsort(-counts, kind="stable"):
        if counts[b] < least or len(levels) == PEEL_LEVELS:
            break
        level = float(edges[b]) + 0.005
        if all(abs(level - other) >= 0.04 for other in levels):
            levels.append(level)
    return levels


def _top_coverage(top: np.ndarray, half: np.ndarray, cell: float) -> float:
    """Share of the cells (``cell`` wide) of the rectangle ±``half`` (2,) holding a point of
    ``top`` (t, 2, the rectangle's frame)."""
    cells = np.maximum(1, (2.0 * half / cell).astype(int))
    index = np.clip(((top + half) / (2.0 * np.maximum(half, 1e-9)) * cells).astype(int), 0, cells - 1)
    return len(np.unique(index[:, 0] * cells[1] + index[:, 1])) / float(cells[0] * cells[1])


def _floor_seen_under(cuboid: Cuboid, seen: np.ndarray, up: np.ndarray, floor_offset: float,
                      settings: BoxSettings) -> float | None:
    """Share of the cuboid's footprint, ``inner_margin_m`` within its edges, whose ``cell_m``
    cells hold a point of ``seen`` (m, 3) on the floor (within ``floor_band_m`` of the plane
    ``up . x = floor_offset``): nothing is seen under a solid box, from anywhere. None where the
    footprint is too small to look under."""
    inner = cuboid.extents[:2] / 2.0 - settings.inner_margin_m
    if np.any(inner <= 0):
        return None
    floor = seen[np.abs(seen @ (np.asarray(up, float) / np.linalg.norm(up)) - floor_offset) < settings.floor_band_m]
    local = cuboid.local(floor)[:, :2]
    under = local[np.all(np.abs(local) < inner, axis=1)]
    return _top_coverage(under, inner, settings.cell_m) if len(under) else 0.0


def _seen_through(cuboid: Cuboid, seen: np.ndarray, viewpoints: np.ndarray, settings: BoxSettings) -> float:
    """How many lines of sight, from each camera to each point it sees (a z-buffer over the
    points of ``seen`` (m, 3) within three radii of the cuboid, at most :data:`SIGHT_POINTS` of
    them drawn, the count scaled back to all), cross the cuboid's inside (the cuboid shrunk by
    ``inner_margin_m``): the slab test in the cuboid's frame."""
    from jsrte.sdf.from_scan import visible_pairs

    radius = float(np.linalg.norm(cuboid.extents)) / 2.0
    near = np.asarray(seen, float)
    near = near[np.linalg.norm(near - cuboid.centre, axis=1) < 3.0 * radius]
    share = min(1.0, SIGHT_POINTS / max(len(near), 1))
    if share < 1.0:
        near = near[np.random.default_rng(0).choice(len(near), SIGHT_POINTS, replace=False)]
    pairs = visible_pairs(near, viewpoints)
    if not len(pairs):
        return 0.0
    start = cuboid.local(near[pairs[:, 0]])
    direction = cuboid.local(viewpoints[pairs[:, 1]]) - start
    inside = cuboid.extents / 2.0 - settings.inner_margin_m
    if np.any(inside <= 0):
        return 0.0
    with np.errstate(divide="ignore", invalid="ignore"):
        near_t = (-inside - start) / direction
        far_t = (inside - start) / direction
    enter = np.nanmax(np.minimum(near_t, far_t), axis=1)
    leave = np.nanmin(np.maximum(near_t, far_t), axis=1)
    return float(((enter < leave) & (leave > 0.0) & (enter < 1.0)).sum()) / share
