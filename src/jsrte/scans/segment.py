"""Segmentation of a scan that holds more than the object: walls, other objects, clutter.

Above the floor (found by :func:`jsrte.scans.preprocess.segment_floor`), in order:

1. **Walls**: large vertical planes (Open3D RANSAC, repeated) with everything else on one
   side of them are removed.
2. **Clusters**: DBSCAN (Open3D) of what is left.
3. **Join**: clusters closer than ``join_m`` are merged when one is a small fragment of the
   other (a chair's legs cut off its seat by sparse sampling) or when the merge matches the
   class as well as the bigger one alone (a chair's back on thin posts). Two big clusters
   joined on the class's proportions stay candidates beside their union (its ``parts``): a
   chair beside a box can match the class's proportions too, and the quick fit decides.
   Without a class (a scene's ``join_keeps_parts_without_class``), two clusters that could
   each be an object, neither over the other, stay the parts of their join; so do two up to
   ``join_apart_m`` apart, neither a wall's piece nor a box (a bed whose middle was not seen).
4. **Split**: a cluster that holds two touching objects is cut in two at its narrowest neck
   (normalized cut of its neighbour graph); the split is kept when one of its parts matches
   the class better than the whole (:func:`class_score`), and its parts are cut again. The
   whole stays a candidate beside its parts (its ``parts``; theirs, its ``parent``): one
   object cut at a narrow place (a bed's headboard) and two objects side by side look alike
   to proportions, and a quick fit (``jsrte.fit.screen``) tells them apart. A cluster whose
   neck is refused for want of class evidence keeps it (its ``neck``), for the screen.
   Before any cut, a box that the cluster holds beside something else (an upright cuboid seen
   solid: :func:`jsrte.scans.boxes.peel_box`) is taken out of it where that cut would be kept
   as any other (a weak neck, the rest matching the class better than the whole): a chair half
   hidden by the box it touches has no neck the normalized cut finds first. The whole stays a
   candidate beside the box and the rest, and the rest may be cut again.
5. **Candidates**: clusters too small, flat, thin or big to be an object are dropped; the
   others are ranked by how well their proportions and height profile match the class
   (:class:`ClassShape`, from the model), or by their distance to a point given by the user.

Every candidate, chosen or not, is described (centre, extent, points, score, why rejected) so
that the fit records what it chose. Lengths in metres, heights above the floor.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from jsrte.errors import JsrteError
from jsrte.geometry.planes import ransac_plane, refit_plane
from jsrte.geometry.point_ops import median_spacing

PROFILE_BINS = 8
"""Bins of a height profile (share of the points at each fraction of the object's height)."""
PROFILE_WEIGHT = 0.2
"""Weight of the height profiles' L1 distance in :func:`class_score` (a scan sees a profile
skewed by its views, so the proportions weigh more)."""


@dataclass(frozen=True)
class ClassShape:
    """What segmentation knows of the class: its proportions, whatever the size.

    Attributes
    ----------
    name : the class's name (for messages)
    aspect : height over bounding-sphere radius of the class's mean shape
    profile : (PROFILE_BINS,) share of the mean shape's surface at each fraction of its height
        (None: proportions only)
    """

    name: str
    aspect: float
    profile: np.ndarray | None = None

    @classmethod
    def of_mesh(cls, name: str, vertices: np.ndarray, samples: np.ndarray) -> ClassShape:
        """From a mesh standing upright (+y up): its ``vertices`` (n, 3) and surface ``samples`` (m, 3)."""
        from jsrte.metrics.surface import bounding_sphere

        height = float(np.ptp(vertices[:, 1]))
        radius = bounding_sphere(vertices)[1]
        heights = samples[:, 1] - vertices[:, 1].min()
        return cls(name=name, aspect=height / radius, profile=height_profile(heights, height))


@dataclass(frozen=True)
class SegmentSettings:
    """Parameters of the segmentation; lengths in metres."""

    wall_distance_m: float = 0.03
    """RANSAC inlier distance of a wall plane."""
    wall_ransac_iterations: int = 1000
    wall_max_planes: int = 8
    """Planes tried, biggest first (walls and other planes), until one holds too few points."""
    wall_min_points: int = 300
    wall_band_max_m: float = 0.1
    """Points within three robust standard deviations of a wall's plane (at most this far) are
    the wall's: far walls are seen with centimetres of depth noise."""
    wall_vertical_tolerance_deg: float = 10.0
    """A wall's normal is this close to horizontal."""
    wall_min_span_m: float = 1.2
    """A wall's points span this far, across or up (2nd to 98th percentile): bigger than the
    face of an object of a room."""
    wall_min_height_m: float = 0.85
    """A wall's points rise this far (2nd to 98th percentile): walls are seen from the floor to
    above most furniture; a headboard or a table's side is lower."""
    wall_normals_agree: float = 0.8
    """Without viewpoints, this share of a wall's points' normals face one side of it, the room's."""
    wall_one_side: float = 0.95
    """At least this share of the other points (off the plane) lie on one side of a wall."""
    cluster_eps_factor: float = 4.0
    """DBSCAN radius, in units of the median nearest-neighbour spacing."""
    cluster_min_points: int = 10
    split_depth: int = 2
    """A cluster is split at most this many times over (up to four touching objects)."""
    peel_boxes: bool = True
    """Take a box out of a cluster before cutting it (:func:`jsrte.scans.boxes.peel_box`), where
    that cut would be kept as any other (with a class: a neck of at most ``cut_max``, what is
    left matching the class better than the whole by ``split_margin``; without: a neck of at
    most ``cut_max_without_class``): needs the sensor's viewpoints, or without them every point
    the sensor saw, the floor's too (a box hides the floor under it)."""
    cut_samples: int = 2000
    cut_neighbours: int = 10
    """The normalized cut's graph: this many points, each joined to this many nearest."""
    cut_vectors: int = 1
    """Eigenvectors of the graph each tried for the normalized cut (:func:`normalized_cut`): 1,
    the Fiedler vector alone. 3 gives a chair pushed against a sofa or a bed a candidate of its
    own more often, with more candidates to screen (docs/clutter.md, Limits)."""
    cut_max: float = 0.02
    """Only a cut of at most this value is a neck between two objects (a cut through one
    object's surface costs more)."""
    connected_parts: bool = True
    """Each part of a cut is one connected piece at the clustering radius (:func:`_connected_sides`)."""
    split_margin: float = 0.1
    """A split is kept when a part's class score beats the whole's by this much."""
    cut_max_without_class: float | None = None
    """Without a class shape, a neck of at most this value both of whose parts could be objects
    is split, the whole staying a candidate beside its parts: for whole scenes, where fits of
    the whole and of its parts decide (``jsrte.fit.scene``). None: without a class nothing is
    split (but a cluster too big to be an object)."""
    size_weight: float = 0.1
    """Candidates are ranked by class score plus this times log(most points / their points):
    of two shapes alike, the bigger is the object (not a shred of another)."""
    join_m: float = 0.1
    """Clusters closer than this may be one object."""
    fragment_share: float = 0.25
    """A cluster with less than this share of a neighbour's points is a fragment of it."""
    join_slack: float = 0.05
    """Two big clusters merge when the merge's class score is at most the bigger's plus this."""
    join_keeps_parts: bool = True
    """Two big clusters merged on class evidence stay candidates as the merge's parts (the
    screen judges the merge against them); False: the merge alone is a candidate."""
    join_apart_m: float | None = None
    """Without a class and with ``join_keeps_parts_without_class``, two clusters farther apart than
    ``join_m`` but within this, each of which could be an object, neither lying over the other
    and neither a wall's piece nor a box (:func:`_join_apart`), are joined after the other joins,
    both staying candidates as the join's parts: the head and the foot of a bed whose middle the
    scan did not see. None: no such join (whole scenes: 0.4, ``jsrte.fit.scene.SCENE_SEGMENT``)."""
    join_keeps_parts_without_class: bool = False
    """Without a class (whole scenes, where every two big clusters closer than ``join_m`` merge),
    the two stay candidates as the merge's parts too: two tables 3-7 cm apart, or a chair beside
    a bed, are clusters of their own before the join."""
    support_share: float = 0.5
    """A cluster with this share of its points under a floating one (a leg under a table's top)
    joins it."""
    min_points: int = 50
    """Fewer points than this: too few to fit."""
    shred_points: int = 300
    """Clusters of fewer points are shreds: joined to a neighbour if near one, never cut."""
    min_height_m: float = 0.15
    """Lower than this (2nd to 98th percentile of the heights above the floor): too flat."""
    floating_top_m: float | None = None
    """A cluster whose underside (2nd percentile of its heights) lies this far or more above the
    floor is as tall as its top (98th percentile) for the flatness test: a table's top seen
    without the pedestal or legs under it, which it hides from cameras above, stands on
    something; the candidate ``floats``. None: every cluster is as tall as its own thickness
    (whole scenes: 0.6, ``jsrte.fit.scene.SCENE_SEGMENT``, which holds the fits of a candidate
    that floats to the floor)."""
    piece_share: float | None = None
    """A part of a split (with no parts of its own) too big to be an object whose largest
    connected piece (DBSCAN at the scene's radius) holds this share of its points or more, and is
    not too big, is that piece: the cut gave it a scrap of a neighbour far from it (a chair with
    a hundred points of a bed's head 3 m away). The scrap's points stay in the split's whole
    only (the part's ``summary["scrap_points"]`` counts them). None: a part is judged whole
    (whole scenes: 0.9, ``jsrte.fit.scene.SCENE_SEGMENT``)."""
    min_width_m: float = 0.08
    """Narrower than this across (largest horizontal side): too thin."""
    min_depth_m: float = 0.013
    """A cluster split from nothing whose points lie within this (standard deviation) of one
    vertical plane is a piece of a wall that was not found as one (too little of it seen): on
    the tuning rooms (100-119 of seed 0 and room 0) such pieces held 0.2-1.0 cm, the flattest
    objects (a bed seen from its head, a sofa from behind) 1.8 cm or more."""
    max_height_m: float = 2.5
    max_width_m: float = 3.0
    """Taller or wider than this: too big to be an object of a room."""


@dataclass
class Candidate:
    """A cluster that may be the object.

    Attributes
    ----------
    index : (m,) int64 indices of its points in the segmented cloud
    score : class score (lower matches better; None without a class)
    rejected : why it cannot be the object ("" when it can)
    parent : position (in the segmentation's candidates) of the whole it was split from, if any
    parts : positions of the candidates it was split into (empty: not split); the parts hold
        its points, so a candidate with parts overlaps them
    neck : a cluster left whole: its two parts at a weak neck where the split was refused for
        want of class evidence (empty: none); the screen may still cut it there
        (``jsrte.fit.screen.cut_necks``)
    box : the evidence that it is a box (``jsrte.scans.boxes.BoxEvidence``), where it was taken
        out of a cluster as one (None: not taken out)
    floats : its underside lies ``SegmentSettings.floating_top_m`` or more above the floor (a
        table's top seen without the legs or pedestal under it)
    """

    index: np.ndarray
    score: float | None = None
    rejected: str = ""
    summary: dict[str, Any] = field(default_factory=dict)
    parent: int | None = None
    parts: list[int] = field(default_factory=list)
    neck: list[Candidate] = field(default_factory=list)
    box: Any = None
    floats: bool = False


@dataclass
class Segmentation:
    """The result: the chosen object, the candidates, what was removed.

    Attributes
    ----------
    index : (m,) int64 indices of the chosen object's points in the segmented cloud
    chosen : position of the chosen candidate in ``candidates``
    candidates : every candidate, the chosen one included
    walls : the walls removed (normal, offset, points)
    removed : points removed as walls, as DBSCAN noise, in small clusters (and, first, as mixed
        pixels: ``jsrte.scans.preprocess.segment_scan``)
    how : how the object was chosen ("class", "at", "largest")
    """

    index: np.ndarray
    chosen: int
    candidates: list[Candidate]
    walls: list[dict[str, Any]]
    removed: dict[str, int]
    how: str

    def to_json(self) -> dict[str, Any]:
        """fit.json's ``segmentation`` block."""
        return {"chosen": self.chosen, "chosen_by": self.how, "walls": self.walls, "removed": self.removed,
                "candidates": [c.summary | {"score": None if c.score is None else round(c.score, 4),
                                            "rejected": c.rejected, "chosen": k == self.chosen} | _family(c)
                               for k, c in enumerate(self.candidates)]}


def _family(candidate: Candidate) -> dict[str, Any]:
    """A candidate's ``parent`` and ``parts`` in fit.json (only for a split's whole and parts)."""
    family: dict[str, Any] = {}
    if candidate.parent is not None:
        family["parent"] = candidate.parent
    if candidate.parts:
        family["parts"] = list(candidate.parts)
    return family


def height_profile(heights: np.ndarray, top: float) -> np.ndarray:
    """(PROFILE_BINS,) share of ``heights`` (n,) in each equal band of ``[0, top]``."""
    counts = np.histogram(np.clip(heights / max(top, 1e-9), 0.0, 1.0), bins=PROFILE_BINS,
                          range=(0.0, 1.0))[0].astype(np.float64)
    return counts / max(counts.sum(), 1.0)


def class_score(points: np.ndarray, heights: np.ndarray, shape: ClassShape | None) -> float | None:
    """How unlike the class ``points`` (n, 3) with ``heights`` (n,) above the floor are (lower is
    better; None without a class): |log| of the ratio of aspects (height over bounding-sphere
    radius) plus ``PROFILE_WEIGHT`` times the L1 distance of the height profiles."""
    from jsrte.metrics.surface import bounding_sphere

    if shape is None:
        return None
    top = float(np.percentile(heights, 98))
    radius = bounding_sphere(points)[1]
    score = abs(float(np.log(max(top, 1e-6) / max(radius, 1e-6) / shape.aspect)))
    if shape.profile is not None:
        score += PROFILE_WEIGHT * float(np.abs(height_profile(heights, top) - shape.profile).sum())
    return score


def segment_objects(
    points: np.ndarray, heights: np.ndarray, up: np.ndarray, *, rng: np.random.Generator,
    shape: ClassShape | None = None, at: np.ndarray | None = None,
    viewpoints: np.ndarray | None = None, normals: np.ndarray | None = None,
    seen: np.ndarray | None = None, settings: SegmentSettings = SegmentSettings(), path: object = None,
) -> Segmentation:
    """Find the object among ``points`` (n, 3) standing on the floor (``heights`` (n,) above it,
    ``up`` (3,) its unit normal).

    The object is the candidate nearest ``at`` (3,) when given, else the one that matches
    ``shape`` best, else the one with the most points. The sensor's ``viewpoints`` (k, 3) or the
    points' sensor-facing ``normals`` (n, 3), when known, tell walls from the faces of furniture
    (:func:`find_walls`). With the ``viewpoints``, every point the sensor ``seen`` (m, 3; default
    ``points``) tells a box seen solid (``peel_boxes``); without them, ``seen`` (the floor's
    points among them) tells it by the floor hidden under it. Raises ``JsrteError`` (naming ``path``)
    when no candidate is left, saying what was removed.
    """
    points = np.ascontiguousarray(points, dtype=np.float64)
    is_wall, walls = find_walls(points, up, rng=rng, viewpoints=viewpoints, normals=normals, settings=settings)
    kept = np.flatnonzero(~is_wall)
    removed = {"walls": int(is_wall.sum())}
    if len(kept) < settings.min_points:
        raise JsrteError(f"no object left after segmentation: {len(walls)} wall(s) removed "
                         f"({removed['walls']} points), {len(kept)} points left", path)
    eps = settings.cluster_eps_factor * median_spacing(points[kept])
    labels = _dbscan(points[kept], eps, settings.cluster_min_points)
    removed["dbscan_noise"] = int((labels < 0).sum())
    clusters = [kept[labels == k] for k in range(labels.max(initial=-1) + 1)]
    clusters = _join(clusters, points, heights, shape, settings)
    clusters = _join_supported(clusters, points, heights, up, settings)
    sight = None
    if settings.peel_boxes and viewpoints is not None and len(viewpoints):
        sight = Sight(points if seen is None else np.asarray(seen, float), np.asarray(viewpoints, float))
    elif settings.peel_boxes and seen is not None:  # no cameras: the floor hidden under a box tells it
        sight = Sight(np.asarray(seen, float), None)
    if shape is None and settings.join_keeps_parts_without_class and settings.join_apart_m:
        clusters = _join_apart(clusters, points, heights, up, settings, sight)
    nodes: list[_Node] = []
    for c in clusters:
        _family_tree(c, points, heights, up, shape, settings, eps, nodes, sight=sight)
    candidates = _family_candidates(nodes, points, heights, up, shape, settings, eps)
    removed["small_clusters"] = int(sum(len(c.index) for c in candidates if c.rejected.startswith("too few")))
    chosen, how = _choose(candidates, points, at, settings.size_weight)
    if chosen is None:
        reasons = "; ".join(sorted({c.rejected for c in candidates})) or "no cluster"
        raise JsrteError(f"no object left after segmentation: {len(walls)} wall(s) removed "
                         f"({removed['walls']} points), {removed['dbscan_noise']} scattered points, "
                         f"{len(candidates)} cluster(s) rejected ({reasons})", path)
    return Segmentation(index=candidates[chosen].index, chosen=chosen, candidates=candidates, walls=walls,
                        removed=removed, how=how)


def find_walls(points: np.ndarray, up: np.ndarray, *, rng: np.random.Generator,
               viewpoints: np.ndarray | None = None, normals: np.ndarray | None = None,
               settings: SegmentSettings = SegmentSettings()) -> tuple[np.ndarray, list[dict[str, Any]]]:
    """Walls among ``points`` (n, 3): planes found by RANSAC (``ransac_plane``), biggest first, that are
    vertical (``up`` (3,)), span more than ``wall_min_span_m``, rise ``wall_min_height_m`` and
    have (almost) every other point on one side: the room's. A wall faces the room, where the
    sensor and the furniture are; a face of a piece of furniture (a bed's side, a table's apron)
    has the rest of that piece behind it, away from the sensor. The room's side is that of the
    ``viewpoints`` (k, 3), all of them, else the one the plane's points' ``normals`` (n, 3) face
    (sensor-facing, as depth scans give them); with neither, either side.
    Returns the wall mask (n,) bool and each wall's description."""
    s = settings
    is_wall = np.zeros(len(points), dtype=bool)
    walls: list[dict[str, Any]] = []
    remaining = np.arange(len(points))
    across_tolerance = np.sin(np.radians(s.wall_vertical_tolerance_deg))
    for _ in range(s.wall_max_planes):
        if len(remaining) < s.wall_min_points:
            break
        normal, offset, found = ransac_plane(points[remaining], s.wall_distance_m, s.wall_ransac_iterations, rng)
        if len(found) < s.wall_min_points:
            break
        normal, offset = refit_plane(points[remaining], normal, offset, s.wall_distance_m)
        distance = points @ normal - offset
        near = np.abs(distance[remaining]) < s.wall_distance_m
        room_sides = _sensor_sides(normal, offset, remaining[near], viewpoints, normals, s)
        if abs(float(normal @ up)) < across_tolerance and _is_wall(points[remaining[near]], distance, normal,
                                                                   up, ~is_wall, room_sides, s):
            plane = np.abs(distance) < _wall_band(distance, s)
            is_wall |= plane
            side = np.sign(np.median(distance[~plane & (np.abs(distance) > 3 * s.wall_distance_m)]))
            walls.append({"normal": (side * normal).tolist(), "offset": float(side * offset),
                          "points": int(plane.sum())})
        remaining = remaining[~near]
    return is_wall, walls


def _wall_band(distance: np.ndarray, s: SegmentSettings) -> float:
    """Half-width (m) of the band removed around a wall: three times the robust std of the
    points' signed ``distance`` (n,) to it near it (far walls are seen with more depth noise),
    at least ``wall_distance_m`` and at most ``wall_band_max_m``."""
    near = distance[np.abs(distance) < s.wall_band_max_m]
    if not len(near):
        return s.wall_distance_m
    sigma = 1.4826 * float(np.median(np.abs(near - np.median(near))))
    return float(np.clip(3.0 * sigma, s.wall_distance_m, s.wall_band_max_m))


def _sensor_sides(normal: np.ndarray, offset: float, inliers: np.ndarray, viewpoints: np.ndarray | None,
                  normals: np.ndarray | None, s: SegmentSettings) -> set[int]:
    """The sides (+1: the one ``normal`` (3,) points to, -1: the other) of the plane
    ``normal . x = offset`` the room may be on, as the sensor tells it: every one of the
    ``viewpoints`` (k, 3) is in the room (none on both sides: no wall), else the plane's points
    (``inliers`` (m,) indices into ``normals`` (n, 3)) face the room (a plane seen from both sides,
    a headboard, is no wall); with neither, either side."""
    if viewpoints is not None and len(viewpoints):
        sides = {int(side) for side in np.sign(viewpoints @ normal - offset)}
        return sides if len(sides) == 1 else set()
    if normals is not None and len(inliers):
        facing = float((normals[inliers] @ normal > 0).mean())
        return {1} if facing >= s.wall_normals_agree else {-1} if facing <= 1.0 - s.wall_normals_agree else set()
    return {1, -1}


def _is_wall(inliers: np.ndarray, distance: np.ndarray, normal: np.ndarray, up: np.ndarray,
             others: np.ndarray, room_sides: set[int], s: SegmentSettings) -> bool:
    """Whether a vertical plane's ``inliers`` (m, 3) make a wall: wide or tall enough, and the
    points (``others`` (n,) mask) off it (by signed ``distance`` (n,)) on one side of it, one of
    the ``room_sides`` (+1: where ``normal`` (3,) points, -1: the other)."""
    across = np.cross(up, normal)
    across /= np.linalg.norm(across)
    width = np.ptp(np.percentile(inliers @ across, [2, 98]))
    height = np.ptp(np.percentile(inliers @ up, [2, 98]))
    if max(width, height) < s.wall_min_span_m or height < s.wall_min_height_m or not room_sides:
        return False
    off = distance[others & (np.abs(distance) > 3 * s.wall_distance_m)]
    if not len(off):
        return True
    share = {1: float((off > 0).mean()), -1: float((off < 0).mean())}
    return max(share[side] for side in room_sides) >= s.wall_one_side


def _dbscan(points: np.ndarray, eps: float, min_points: int) -> np.ndarray:
    """DBSCAN labels (n,) of ``points`` (n, 3), -1: noise (:func:`jsrte.geometry.point_ops.dbscan_labels`:
    Open3D's clusters, numbered by their first point)."""
    from jsrte.geometry.point_ops import dbscan_labels

    if len(points) < min_points or eps <= 0:
        return np.full(len(points), -1)
    return dbscan_labels(points, eps, min_points)


@dataclass
class _Cluster:
    """A cluster of points (``index``) and the big clusters it was joined from on class evidence
    alone (``members``; empty: none), which stay candidates as its parts; ``apart``: they lie
    farther apart than ``join_m`` (:func:`_join_apart`)."""

    index: np.ndarray
    members: list[_Cluster] = field(default_factory=list)
    apart: bool = False


@dataclass
class _Node:
    """A cluster of a split tree: its points ``index``, the position of its ``parent`` in the
    tree's list (None: a root), a refused weak ``neck``, the value of the cut that split it
    (``cut_value``; None: not split), whether it was joined from its parts (``joined``) lying
    farther apart than ``join_m`` (``apart``), whether a box was taken out of it (``peeled``)
    and, for such a box, its evidence (``box``, ``jsrte.scans.boxes.BoxEvidence``)."""

    index: np.ndarray
    parent: int | None
    neck: list[np.ndarray] = field(default_factory=list)
    cut_value: float | None = None
    joined: bool = False
    apart: bool = False
    peeled: bool = False
    box: Any = None


@dataclass(frozen=True)
class Sight:
    """What the sensor saw: every point ``seen`` (m, 3) on a surface, the floor's too, and its
    ``viewpoints`` (k, 3), None where the cameras are not known."""

    seen: np.ndarray
    viewpoints: np.ndarray | None


def _family_tree(cluster: _Cluster, points: np.ndarray, heights: np.ndarray, up: np.ndarray,
                 shape: ClassShape | None, s: SegmentSettings, eps: float, nodes: list[_Node],
                 parent: int | None = None, depth: int = 0, sight: Sight | None = None) -> None:
    """Append to ``nodes`` ``cluster``, its members (joined clusters) as its parts, and what
    each is split into (:func:`_split_tree`; ``eps``: the clustering radius), each parent
    before its parts."""
    if not cluster.members:
        _split_tree(cluster.index, points, heights, up, shape, s, eps, nodes, parent, depth, sight)
        return
    nodes.append(_Node(cluster.index, parent, joined=True, apart=cluster.apart))
    parent = len(nodes) - 1
    depth += shape is not None  # without a class the join uses up no level of cuts
    for member in cluster.members:
        _family_tree(member, points, heights, up, shape, s, eps, nodes, parent, depth, sight)


def _split_tree(cluster: np.ndarray, points: np.ndarray, heights: np.ndarray, up: np.ndarray,
                shape: ClassShape | None, s: SegmentSettings, eps: float, nodes: list[_Node],
                parent: int | None = None, depth: int = 0, sight: Sight | None = None) -> None:
    """Append to ``nodes`` ``cluster`` (indices) and its parts, split by the normalized cut of
    its neighbour graph (:func:`normalized_cut`: the narrowest neck between two bodies, where
    touching objects meet), each parent before its parts. A split is kept when one part matches
    the class better than the whole by ``split_margin`` and both parts could be objects (neither
    too flat nor too thin), or when the whole is too big to be an object (then the whole is
    left out: it can only be parts); each part is split again, ``split_depth`` deep. A weak neck
    refused for want of class evidence is kept as the ``neck`` of a cluster left whole (not of a
    part). Before a cut, a box is taken out of the cluster where ``sight`` shows one
    (:func:`_peel`): the box is a part not cut further, the rest is cut as any cluster."""
    peeled = _peel(cluster, points, heights, up, shape, s, eps, sight) if depth < s.split_depth else None
    if peeled is not None:
        box, evidence = peeled
        nodes.append(_Node(cluster, parent, peeled=True))
        parent = len(nodes) - 1
        nodes.append(_Node(cluster[box], parent, box=evidence))
        _split_tree(cluster[~box], points, heights, up, shape, s, eps, nodes, parent, depth + 1, sight)
        return
    cut = _cut(cluster, points, heights, shape, s, eps, depth)
    if cut is None or not cut[2]:
        nodes.append(_Node(cluster, parent, cut[0] if cut is not None and depth == 0 else []))
        return
    parts, too_big, _, value = cut
    if not too_big:
        nodes.append(_Node(cluster, parent, cut_value=value))
        parent = len(nodes) - 1
    for part in parts:
        _split_tree(part, points, heights, up, shape, s, eps, nodes, parent, depth + 1, sight)


def _peel(cluster: np.ndarray, points: np.ndarray, heights: np.ndarray, up: np.ndarray,
          shape: ClassShape | None, s: SegmentSettings, eps: float,
          sight: Sight | None) -> tuple[np.ndarray, Any] | None:
    """The mask (over ``cluster``'s indices) of the first box it holds beside an object-sized
    rest, and the box's evidence (``jsrte.scans.boxes.peel_box``, each cuboid offered in turn),
    kept as a cut is: with a class, at a weak neck (a cut value of at most ``cut_max``) and with
    the rest matching the class better than the whole by ``split_margin``; without one, at a
    neck of at most ``cut_max_without_class``. None where there is none, or where nothing can
    test it. A sofa's base and a bed's mattress are upright cuboids seen solid too, but joined to
    the back or the headboard that rises from them by more than a neck: refused, they are passed
    over for the next cuboid (a box against the sofa's arm)."""
    from jsrte.scans.boxes import peel_box

    most = s.cut_max if shape is not None else s.cut_max_without_class
    if sight is None or most is None or len(cluster) < 2 * s.shred_points:
        return None
    whole = class_score(points[cluster], heights[cluster], shape)

    def kept(box: np.ndarray) -> bool:
        rest = cluster[~box]
        if not _object_sized(points[rest], heights[rest], s):
            return False
        if shape is not None and class_score(points[rest], heights[rest], shape) >= whole - s.split_margin:
            return False
        return cut_value(points[cluster], box, samples=s.cut_samples, neighbours=s.cut_neighbours) <= most

    return peel_box(points[cluster], heights[cluster], up, sight.seen, sight.viewpoints, eps, s.shred_points,
                    accept=kept)


def _cut(cluster: np.ndarray, points: np.ndarray, heights: np.ndarray, shape: ClassShape | None,
         s: SegmentSettings, eps: float, depth: int) -> tuple[list[np.ndarray], bool, bool, float] | None:
    """The two parts of ``cluster`` at its weakest neck (each made connected at the clustering
    radius ``eps``: :func:`_connected_sides`), whether the whole is too big to be an
    object, whether the split is kept (:func:`_split_tree`; not kept: no part matches the
    class better by ``split_margin``) and the cut's value; None when it has no neck both of
    whose parts could be objects."""
    if len(cluster) < 2 * s.shred_points or depth >= s.split_depth:
        return None
    whole = class_score(points[cluster], heights[cluster], shape)
    too_big = _too_big(points[cluster], heights[cluster], s)
    if whole is None and not too_big and s.cut_max_without_class is None:
        return None
    side, value = normalized_cut(points[cluster], samples=s.cut_samples, neighbours=s.cut_neighbours,
                                 vectors=s.cut_vectors)
    if s.connected_parts:
        side = _connected_sides(points[cluster], side, eps)
    parts = [cluster[side], cluster[~side]]
    if value > s.cut_max or min(len(p) for p in parts) < s.shred_points:
        return None
    if not too_big and not _could_be_objects(parts, points, heights, s, floating_top=whole is not None):
        return None
    if whole is None:
        return parts, too_big, too_big or value <= s.cut_max_without_class, value
    best = min((class_score(points[p], heights[p], shape) or 0.0) for p in parts)
    return parts, too_big, too_big or best < whole - s.split_margin, value


def _could_be_objects(parts: list[np.ndarray], points: np.ndarray, heights: np.ndarray, s: SegmentSettings,
                      floating_top: bool) -> bool:
    """Whether both ``parts`` (two index arrays) of a cut could be objects: neither too flat nor
    too thin (a table's top is not cut from the legs under it, nor a slab from what it lies
    on); with ``floating_top`` (a class says which part is its object), one may be a top that
    floats beside the other: its underside ``min_height_m`` or more above the floor, the other
    part not under it (less than ``support_share`` of it within ``join_m`` across the up axis),
    a table whose legs the scan did not see, cut from the chair beside it."""
    unsized = [k for k, p in enumerate(parts) if not _object_sized(points[p], heights[p], s)]
    if not unsized:
        return True
    if len(unsized) == 2 or not floating_top:
        return False
    top, other = parts[unsized[0]], parts[1 - unsized[0]]
    if float(np.percentile(heights[top], 2)) < s.min_height_m:
        return False
    both = np.concatenate([top, other])
    flat = _flat(points[both], heights[both])  # (n, 2) across the up axis
    return _share_under(flat[: len(top)], flat[len(top):], s.join_m) < s.support_share


def _share_under(top: np.ndarray, other: np.ndarray, reach: float) -> float:
    """The share of ``other`` (m, 2) within ``reach`` of a point of ``top`` (n, 2): both given
    across the up axis, so the share of one cluster's points under (or over) another's."""
    from pykdtree.kdtree import KDTree

    distance = KDTree(np.ascontiguousarray(top)).query(np.ascontiguousarray(other), k=1)[0]
    return float((distance <= reach).mean())


def _connected_sides(points: np.ndarray, side: np.ndarray, eps: float) -> np.ndarray:
    """``side`` (n,) bool, a two-way cut of ``points`` (n, 3), with every piece of either side
    that lies apart (farther than ``eps``) from the rest of its side but touches the other side
    given to the other side: the cut works on a sparse sample of the points, and it can leave
    a scrap of one object (a bed's corner, a whole box) on the side of another, metres from
    it. A piece that touches neither (a table's leg seen apart from its top) stays."""
    from pykdtree.kdtree import KDTree

    moved = side.copy()
    for mask in (side, ~side):
        own, other = np.flatnonzero(mask), np.flatnonzero(~mask)
        if len(own) < 2 or not len(other):
            continue
        labels = _dbscan(points[own], eps, 1)
        stray = labels != np.argmax(np.bincount(labels))
        if not stray.any():
            continue
        gap, _ = KDTree(points[other]).query(points[own[stray]], k=1)
        touching = np.unique(labels[stray][gap < eps])
        moved[own[np.isin(labels, touching)]] = not side[own[0]]
    return moved


def _family_candidates(nodes: list[_Node], points: np.ndarray, heights: np.ndarray, up: np.ndarray,
                       shape: ClassShape | None, s: SegmentSettings, eps: float = 0.0) -> list[Candidate]:
    """The candidates of the split trees' ``nodes``, most points first, with their ``parent``
    and ``parts`` as positions in that order; a part too big to be an object may be its largest
    piece (``SegmentSettings.piece_share``, pieces at the DBSCAN radius ``eps``)."""
    parent = [n.parent for n in nodes]
    has_parts = {n.parent for n in nodes}
    order = sorted(range(len(nodes)), key=lambda k: -len(nodes[k].index))
    position = {k: p for p, k in enumerate(order)}
    candidates = [_candidate(nodes[k].index, points, heights, up, shape, s) for k in order]
    for p, k in enumerate(order):
        if parent[k] is not None and k not in has_parts and candidates[p].rejected.startswith("too big"):
            candidates[p] = _largest_piece(candidates[p], points, heights, up, shape, s, eps)
    for k in order:
        candidates[position[k]].neck = [_candidate(part, points, heights, up, shape, s) for part in nodes[k].neck]
        if nodes[k].cut_value is not None:
            candidates[position[k]].summary["cut"] = round(nodes[k].cut_value, 5)
        if nodes[k].joined:
            candidates[position[k]].summary["joined"] = True
        if nodes[k].apart:
            candidates[position[k]].summary["joined_apart"] = True
        if nodes[k].peeled:
            candidates[position[k]].summary["box_taken_out"] = True
        if nodes[k].box is not None:
            candidates[position[k]].box = nodes[k].box
            candidates[position[k]].summary["box"] = nodes[k].box.to_json()
    for k in order:
        if parent[k] is not None:
            candidates[position[k]].parent = position[parent[k]]
            candidates[position[parent[k]]].parts.append(position[k])
    for c in (c for c in candidates if c.parent is None and not c.parts and not c.rejected):
        depth = _vertical_depth(points[c.index], up)
        if depth < s.min_depth_m:
            c.rejected = f"a wall's piece ({100 * depth:.1f} cm deep < {100 * s.min_depth_m:.1f} cm)"
    return candidates


def _vertical_depth(points: np.ndarray, up: np.ndarray, tolerance_deg: float = 10.0) -> float:
    """Standard deviation (m) of ``points`` (n, 3) across their best-fitting plane when that plane
    is vertical (its normal within ``tolerance_deg`` of the floor's plane, ``up`` (3,)), else inf."""
    if len(points) < 4:
        return np.inf
    variances, axes = np.linalg.eigh(np.cov((points - points.mean(0)).T))
    if abs(float(axes[:, 0] @ up)) > np.sin(np.radians(tolerance_deg)):
        return np.inf
    return float(np.sqrt(max(variances[0], 0.0)))


def normalized_cut(points: np.ndarray, *, samples: int = 2000, neighbours: int = 10,
                   seed: int = 0, vectors: int = 1) -> tuple[np.ndarray, float]:
    """Two-way normalized cut (Shi and Malik 2000) of ``points`` (n, 3): mask (n,) of one side,
    and the cut's value (0: two parts apart; about 2 / neighbours when cut through a surface).

    Up to ``samples`` points (a fixed random subset) make a symmetric k-nearest-neighbour graph
    with Gaussian weights of the distance; each of the ``vectors`` leading non-trivial
    eigenvectors of its normalized Laplacian (scipy; the first is the Fiedler vector) is cut at
    the threshold of lowest normalized cut, and the lowest of those cuts is kept (where three
    bodies touch, the Fiedler vector may cut through one of them and the next one between
    them); every point takes the side of its nearest sample.
    """
    from pykdtree.kdtree import KDTree
    from scipy.sparse import diags
    from scipy.sparse.linalg import eigsh

    points = np.ascontiguousarray(points, dtype=np.float64)
    pick, graph, degree = _neighbour_graph(points, samples, neighbours, seed)
    sub = points[pick]
    scale = diags(1.0 / np.sqrt(degree))
    normalized = scale @ graph @ scale
    try:
        start = np.random.default_rng(seed).uniform(0.5, 1.5, size=len(sub))
        values, found = eigsh(normalized, k=min(vectors + 1, len(sub) - 1), which="LA", tol=1e-4,
                              maxiter=5000, v0=start)
    except Exception:  # no convergence: no cut
        return np.ones(len(points), dtype=bool), float("inf")
    best, best_cut = None, np.inf
    for column in np.argsort(-values)[1:]:
        embedding = found[:, column] / np.sqrt(degree)
        for threshold in np.quantile(embedding, np.linspace(0.05, 0.95, 19)):
            side = embedding > threshold
            value = _ncut_value(graph, degree, side)
            if value < best_cut:
                best, best_cut = side, value
    if best is None:
        return np.ones(len(points), dtype=bool), float("inf")
    _, nearest = KDTree(sub).query(points, k=1)
    return best[nearest], best_cut


def cut_value(points: np.ndarray, side: np.ndarray, *, samples: int = 2000, neighbours: int = 10,
              seed: int = 0) -> float:
    """The normalized cut's value of the two-way cut ``side`` (n,) bool of ``points`` (n, 3), on
    the graph :func:`normalized_cut` builds (the same sample): how weak a neck it cuts."""
    pick, graph, degree = _neighbour_graph(np.ascontiguousarray(points, dtype=np.float64), samples,
                                           neighbours, seed)
    return _ncut_value(graph, degree, np.asarray(side, bool)[pick])


def _neighbour_graph(points: np.ndarray, samples: int, neighbours: int, seed: int
                     ) -> tuple[np.ndarray, object, np.ndarray]:
    """The sorted indices (s,) of up to ``samples`` of ``points`` (n, 3) (a fixed random draw),
    their symmetric k-nearest-neighbour graph (s, s) with Gaussian weights of the distance
    (scipy sparse) and its degrees (s,)."""
    from pykdtree.kdtree import KDTree
    from scipy.sparse import coo_matrix

    pick = np.sort(np.random.default_rng(seed).permutation(len(points))[:samples])
    sub = points[pick]
    k = min(neighbours + 1, len(sub))
    distance, near = KDTree(sub).query(sub, k=k)
    sigma = float(np.median(distance[:, 1:])) or 1e-6
    rows = np.repeat(np.arange(len(sub)), k - 1)
    weight = np.exp(-(distance[:, 1:].reshape(-1) / sigma) ** 2)
    graph = coo_matrix((weight, (rows, near[:, 1:].reshape(-1))), shape=(len(sub), len(sub))).tocsr()
    graph = graph.maximum(graph.T)
    return pick, graph, np.asarray(graph.sum(axis=1)).reshape(-1) + 1e-12


def _ncut_value(graph: object, degree: np.ndarray, side: np.ndarray) -> float:
    """Normalized cut value of the two-way cut ``side`` (s,) bool of the graph (s, s) with ``degree`` (s,)."""
    if not side.any() or side.all():
        return float("inf")
    cut = float(graph[side][:, ~side].sum())
    return cut / degree[side].sum() + cut / degree[~side].sum()


def _object_sized(points: np.ndarray, heights: np.ndarray, s: SegmentSettings) -> bool:
    """Whether ``points`` (n, 3) at ``heights`` (n,) are tall and wide enough to be an object."""
    tall = float(np.ptp(np.percentile(heights, [2, 98])))
    return tall >= s.min_height_m and _width(points, heights) >= s.min_width_m


def _too_big(points: np.ndarray, heights: np.ndarray, s: SegmentSettings) -> bool:
    return float(np.percentile(heights, 98)) > s.max_height_m or _width(points, heights) > s.max_width_m


def _width(points: np.ndarray, heights: np.ndarray) -> float:
    """Largest horizontal side (m) of the points' box (2nd to 98th percentile), about the up
    axis estimated from how ``heights`` vary with ``points``."""
    flat = _flat(points, heights)
    return float(np.ptp(np.percentile(flat, [2, 98], axis=0), axis=0).max()) if len(flat) else 0.0


def _flat(points: np.ndarray, heights: np.ndarray) -> np.ndarray:
    """(n, 2) horizontal coordinates of ``points`` (n, 3) (principal axes of the floor plane)."""
    centred = points - points.mean(0)
    if len(points) < 4:
        return centred[:, :2]
    up = np.linalg.lstsq(np.column_stack([centred, np.ones(len(points))]), heights, rcond=None)[0][:3]
    up = up / max(np.linalg.norm(up), 1e-12)
    basis = np.linalg.svd(up[None, :])[2][1:]
    return centred @ basis.T


def _join(clusters: list[np.ndarray], points: np.ndarray, heights: np.ndarray, shape: ClassShape | None,
          s: SegmentSettings) -> list[_Cluster]:
    """Merge clusters closer than ``join_m``: clusters of fewer than ``shred_points`` points
    into the nearest big one (the largest cluster is big whatever its size); then big ones,
    closest pairs first, a fragment (less than ``fragment_share`` of the other's points)
    always (into the nearest of a merge's members), two big ones when the merge matches the
    class as well as the bigger alone (within ``join_slack``; always without a class): with a
    class and ``join_keeps_parts``, the two stay the merge's ``members``."""
    clusters = sorted((c for c in clusters if len(c)), key=len, reverse=True)
    if not clusters:
        return []
    big_points = [c for k, c in enumerate(clusters) if k == 0 or len(c) >= s.shred_points]  # the largest at least
    small = [c for k, c in enumerate(clusters) if k > 0 and len(c) < s.shred_points]
    big = [_Cluster(c) for c in _attach_small(big_points, small, points, s.join_m)]
    gaps = np.full((len(big), len(big)), np.inf)
    for i in range(len(big)):
        for j in range(i + 1, len(big)):
            gaps[i, j] = gaps[j, i] = _gap(points[big[i].index], points[big[j].index], s.join_m)
    alive = list(range(len(big)))
    refused: set[tuple[int, int]] = set()
    stacked: dict[tuple[int, int], bool] = {}  # without a class: one lies over the other
    apart = shape is None and s.join_keeps_parts_without_class

    def first(i: int, j: int) -> bool:  # without a class, a top joins what it stands on first
        if not apart:
            return True
        if (i, j) not in stacked:
            stacked[i, j] = _one_over_other(big[i].index, big[j].index, points, heights, s)
        return stacked[i, j]

    while True:
        pairs = sorted((not first(i, j), gaps[i, j], i, j) for i in alive for j in alive
                       if i < j and gaps[i, j] <= s.join_m and (i, j) not in refused)
        if not pairs:
            return [big[k] for k in alive]
        _, _, i, j = pairs[0]
        bigger, smaller = (i, j) if len(big[i].index) >= len(big[j].index) else (j, i)
        union = np.concatenate([big[bigger].index, big[smaller].index])
        fragment = len(big[smaller].index) < s.fragment_share * len(big[bigger].index)
        if fragment or _merge_matches(big[bigger].index, union, points, heights, shape, s):
            big[i] = _merged(big[bigger], big[smaller], fragment, points, heights, shape, s)
            gaps[i] = gaps[:, i] = np.minimum(gaps[i], gaps[j])
            gaps[i, i] = np.inf
            alive.remove(j)
            refused = {pair for pair in refused if i not in pair}
            stacked = {pair: v for pair, v in stacked.items() if i not in pair}
        else:
            refused.add((i, j))


def _merged(bigger: _Cluster, smaller: _Cluster, fragment: bool, points: np.ndarray, heights: np.ndarray,
            shape: ClassShape | None, s: SegmentSettings) -> _Cluster:
    """The join of two clusters: a ``fragment`` taken into the nearest member of the ``bigger``;
    two big ones with their members kept (with a class and ``join_keeps_parts``) or not.
    Without a class and with ``join_keeps_parts_without_class``, the two stay members where
    each could be an object and neither lies under the other (:func:`_kept_apart`), and the
    smaller is taken into the bigger's nearest member otherwise."""
    union = np.concatenate([bigger.index, smaller.index])
    if shape is None and s.join_keeps_parts_without_class:
        if _kept_apart(smaller.index, bigger, points, heights, s):
            return _Cluster(union, [bigger, smaller])
        return _absorb(bigger, smaller.index, points)
    if fragment:
        return _absorb(bigger, smaller.index, points)
    return _Cluster(union, [bigger, smaller] if s.join_keeps_parts and shape is not None else [])


def _kept_apart(smaller: np.ndarray, bigger: _Cluster, points: np.ndarray, heights: np.ndarray,
                s: SegmentSettings) -> bool:
    """Whether the ``smaller`` cluster (indices) and the member of the ``bigger`` nearest it could
    each be an object, neither lying under the other (a chair beside a bed, a table beside a
    table; not a table's legs under its top, nor its top seen apart from them)."""
    host = _nearest_member(bigger, smaller, points)
    if not (_object_sized(points[smaller], heights[smaller], s) and _object_sized(points[host], heights[host], s)):
        return False
    return not _one_over_other(host, smaller, points, heights, s)


def _one_over_other(a: np.ndarray, b: np.ndarray, points: np.ndarray, heights: np.ndarray, s: SegmentSettings
                    ) -> bool:
    """Whether ``support_share`` of cluster ``a`` (indices) lies under or over ``b``, or of ``b``
    under or over ``a`` (within ``join_m`` across the up axis): a table's legs and its top."""
    both = np.concatenate([a, b])
    flat = _flat(points[both], heights[both])  # (n, 2) across the up axis
    return max(_share_under(flat[: len(a)], flat[len(a):], s.join_m),
               _share_under(flat[len(a):], flat[: len(a)], s.join_m)) >= s.support_share


def _nearest_member(cluster: _Cluster, fragment: np.ndarray, points: np.ndarray) -> np.ndarray:
    """The points (indices) of the innermost member of ``cluster`` nearest ``fragment``."""
    if not cluster.members:
        return cluster.index
    return _nearest_member(cluster.members[_nearest(cluster.members, fragment, points)], fragment, points)


def _nearest(members: list[_Cluster], fragment: np.ndarray, points: np.ndarray) -> int:
    """The position of the member (of ``members``) nearest the points ``fragment`` (indices)."""
    return int(np.argmin([_gap(points[m.index], points[fragment], np.inf) for m in members]))


def _absorb(cluster: _Cluster, fragment: np.ndarray, points: np.ndarray) -> _Cluster:
    """``cluster`` with the points ``fragment`` (indices) added, to its nearest member too."""
    members = list(cluster.members)
    if members:
        k = _nearest(members, fragment, points)
        members[k] = _absorb(members[k], fragment, points)
    return _Cluster(np.concatenate([cluster.index, fragment]), members)


def _join_supported(clusters: list[_Cluster], points: np.ndarray, heights: np.ndarray, up: np.ndarray,
                    s: SegmentSettings) -> list[_Cluster]:
    """A cluster that floats (its lowest points ``min_height_m`` or more above the floor: a
    table's top seen apart from its legs) rests on what stands under it: it takes in every
    cluster lying below its underside (within ``join_m``) with ``support_share`` of its points
    under it (within ``join_m`` of one of its points, across the ``up`` axis (3,)); what it
    took in is one object with it (no members)."""
    across = np.linalg.svd(up.reshape(1, 3))[2][1:]  # (2, 3) a basis of the floor's plane
    clusters = sorted(clusters, key=lambda c: -float(np.percentile(heights[c.index], 2)))  # highest first
    alive = [True] * len(clusters)
    for i, top in enumerate(clusters):
        underside = float(np.percentile(heights[top.index], 2))
        if not alive[i] or underside < s.min_height_m:
            continue
        top_across = points[top.index] @ across.T
        for j, below in enumerate(clusters):
            if j == i or not alive[j] or float(np.percentile(heights[below.index], 98)) > underside + s.join_m:
                continue
            if _share_under(top_across, points[below.index] @ across.T, s.join_m) >= s.support_share:
                top = _Cluster(np.concatenate([top.index, below.index]))
                alive[j] = False
        clusters[i] = top
    return [c for c, keep in zip(clusters, alive, strict=True) if keep]


def _join_apart(clusters: list[_Cluster], points: np.ndarray, heights: np.ndarray, up: np.ndarray,
                s: SegmentSettings, sight: Sight | None = None) -> list[_Cluster]:
    """Join, closest first, two ``clusters`` farther apart than ``join_m`` but within
    ``join_apart_m`` where their join is not too big to be an object and each could be one,
    neither lying over the other (:func:`_kept_apart`), neither a wall's piece (a vertical
    slab thinner than ``min_depth_m``, rejected on its own) nor, where ``sight`` tells it, a box
    (``jsrte.scans.boxes.reported_as_box``: no object's part): the two stay the join's members."""
    clusters = list(clusters)
    refused: set[tuple[int, int]] = set()  # pairs (by identity) already judged apart
    gaps: dict[tuple[int, int], float] = {}  # (a joined cluster keeps its members, and their identities, alive)
    could_be_part: dict[int, bool] = {}  # by identity: neither a wall's piece nor a box

    def gap(a: _Cluster, b: _Cluster) -> float:
        if (id(a), id(b)) not in gaps:
            gaps[id(a), id(b)] = _gap(points[a.index], points[b.index], s.join_apart_m)
        return gaps[id(a), id(b)]

    def may_be_part(c: _Cluster) -> bool:
        if id(c) not in could_be_part:
            could_be_part[id(c)] = not (_vertical_depth(points[c.index], up) < s.min_depth_m
                                        or _is_box(c.index, points, heights, up, sight))
        return could_be_part[id(c)]

    while True:
        pairs = sorted((g, i, j) for i in range(len(clusters)) for j in range(i + 1, len(clusters))
                       if (id(clusters[i]), id(clusters[j])) not in refused
                       and s.join_m < (g := gap(clusters[i], clusters[j])) <= s.join_apart_m
                       and may_be_part(clusters[i]) and may_be_part(clusters[j]))
        for _, i, j in pairs:
            bigger, smaller = sorted((clusters[i], clusters[j]), key=lambda c: -len(c.index))
            union = np.concatenate([bigger.index, smaller.index])
            if not _too_big(points[union], heights[union], s) and _kept_apart(smaller.index, bigger, points,
                                                                                heights, s):
                joined = _Cluster(union, [bigger, smaller], apart=True)
                clusters = [c for k, c in enumerate(clusters) if k not in (i, j)] + [joined]
                break
            refused.add((id(clusters[i]), id(clusters[j])))
        else:
            return clusters


def _is_box(cluster: np.ndarray, points: np.ndarray, heights: np.ndarray, up: np.ndarray,
            sight: Sight | None) -> bool:
    """Whether the points at ``cluster`` are a box that a scene reports as one
    (``jsrte.scans.boxes.box_evidence`` with what the sensor saw, ``reported_as_box``); False
    without ``sight``."""
    from jsrte.scans.boxes import box_evidence, reported_as_box

    if sight is None:
        return False
    floor_offset = float(np.median(points[cluster] @ up - heights[cluster]))
    return reported_as_box(box_evidence(points[cluster], up, floor_offset, sight.seen, sight.viewpoints))


def _attach_small(big: list[np.ndarray], small: list[np.ndarray], points: np.ndarray, join_m: float
                  ) -> list[np.ndarray]:
    """``big`` clusters each with the ``small`` ones whose nearest big cluster is within ``join_m``."""
    from pykdtree.kdtree import KDTree

    if not small:
        return big
    owner = np.concatenate([np.full(len(c), k) for k, c in enumerate(big)])
    tree = KDTree(np.ascontiguousarray(points[np.concatenate(big)]))
    grown = [[c] for c in big]
    for c in small:
        distance, nearest = tree.query(np.ascontiguousarray(points[c]), k=1)
        if distance.min() <= join_m:
            grown[int(owner[nearest[int(np.argmin(distance))]])].append(c)
    return [np.concatenate(parts) for parts in grown]


def _gap(a: np.ndarray, b: np.ndarray, join_m: float) -> float:
    """Distance (m) between point sets ``a`` and ``b`` (inf when their boxes are farther than ``join_m``)."""
    from pykdtree.kdtree import KDTree

    if _box_gap(a, b) > join_m:
        return float("inf")
    small, large = (a, b) if len(a) <= len(b) else (b, a)
    return float(KDTree(np.ascontiguousarray(large)).query(np.ascontiguousarray(small), k=1)[0].min())


def _merge_matches(bigger: np.ndarray, union: np.ndarray, points: np.ndarray, heights: np.ndarray,
                   shape: ClassShape | None, s: SegmentSettings) -> bool:
    if _too_big(points[union], heights[union], s):
        return False
    alone = class_score(points[bigger], heights[bigger], shape)
    if alone is None:
        return True
    together = class_score(points[union], heights[union], shape)
    return together is not None and together <= alone + s.join_slack


def _largest_piece(candidate: Candidate, points: np.ndarray, heights: np.ndarray, up: np.ndarray,
                   shape: ClassShape | None, s: SegmentSettings, eps: float) -> Candidate:
    """``candidate`` (rejected as too big) as its largest connected piece at the DBSCAN radius
    ``eps`` where that piece holds ``s.piece_share`` of its points and is no longer rejected;
    else ``candidate`` as it is."""
    if s.piece_share is None or eps <= 0:
        return candidate
    labels = _dbscan(points[candidate.index], eps, s.cluster_min_points)
    if not (labels >= 0).any():
        return candidate
    largest = labels == np.bincount(labels[labels >= 0]).argmax()
    if largest.sum() < s.piece_share * len(labels):
        return candidate
    piece = _candidate(candidate.index[largest], points, heights, up, shape, s)
    if piece.rejected:
        return candidate
    piece.summary["scrap_points"] = int(len(labels) - largest.sum())
    return piece


def _box_gap(a: np.ndarray, b: np.ndarray) -> float:
    """Gap (m) between the bounding boxes of point sets ``a`` and ``b``: a lower bound of their distance."""
    gap = np.maximum(0.0, np.maximum(a.min(0) - b.max(0), b.min(0) - a.max(0)))
    return float(np.linalg.norm(gap))


def _candidate(index: np.ndarray, points: np.ndarray, heights: np.ndarray, up: np.ndarray,
               shape: ClassShape | None, s: SegmentSettings) -> Candidate:
    """A cluster described and judged: too few points, too flat, thin or big, or a candidate."""
    p, h = points[index], heights[index]
    top = float(np.percentile(h, 98)) if len(h) else 0.0
    underside = float(np.percentile(h, 2)) if len(h) else 0.0
    floats = s.floating_top_m is not None and underside >= s.floating_top_m
    tall = top if floats else top - underside
    width = _width(p, h)
    summary = {"points": int(len(index)), "centre": ((p.min(0) + p.max(0)) / 2.0).round(4).tolist(),
               "height_m": round(top, 3), "width_m": round(width, 3)}
    if len(index) < s.min_points:
        rejected = f"too few points ({len(index)} < {s.min_points})"
    elif tall < s.min_height_m:
        rejected = f"too flat ({tall:.2f} m tall < {s.min_height_m} m)"
    elif width < s.min_width_m:
        rejected = f"too thin ({width:.2f} m across < {s.min_width_m} m)"
    elif top > s.max_height_m or width > s.max_width_m:
        rejected = f"too big ({top:.2f} m tall, {width:.2f} m across)"
    else:
        rejected = ""
    score = class_score(p, h, shape) if len(index) else None
    return Candidate(index=index, score=score, rejected=rejected, summary=summary, floats=floats)


def leftover_candidates(index: np.ndarray, points: np.ndarray, heights: np.ndarray, up: np.ndarray,
                        settings: SegmentSettings) -> list[Candidate]:
    """The points ``index`` (m,) (into ``points`` (n, 3), ``heights`` (n,) above the floor, ``up``
    (3,)) clustered again as :func:`segment_objects` clusters (DBSCAN at the radius it uses for
    ``points``): each cluster of at least ``shred_points`` that may be an object, as a candidate
    (no class score). For the points a scene's fits left unexplained (``jsrte.fit.scene``)."""
    eps = settings.cluster_eps_factor * median_spacing(points)
    labels = _dbscan(points[index], eps, settings.cluster_min_points)
    clusters = [index[labels == k] for k in range(labels.max(initial=-1) + 1)]
    described = [_candidate(c, points, heights, up, None, settings) for c in clusters
                 if len(c) >= settings.shred_points]
    return [c for c in described if not c.rejected]


def _choose(candidates: list[Candidate], points: np.ndarray, at: np.ndarray | None, size_weight: float
            ) -> tuple[int | None, str]:
    """Position of the object among ``candidates`` that were not split (a split's whole holds
    its parts' points) and how it was chosen: nearest ``at``; else lowest class score plus
    ``size_weight`` log(most points / its points); else most points. A split's whole gets its
    rank too (the screen weighs it against its parts)."""
    from pykdtree.kdtree import KDTree

    if at is not None:
        sized = [k for k, c in enumerate(candidates) if len(c.index) >= 4 and not c.parts]
        if not sized:
            return None, "at"
        query = np.asarray(at, dtype=np.float64).reshape(1, 3)
        distance = [float(KDTree(np.ascontiguousarray(points[candidates[k].index])).query(query, k=1)[0][0])
                    for k in sized]
        for k, d in zip(sized, distance, strict=True):
            candidates[k].summary["distance_to_at_m"] = round(d, 4)
        return sized[int(np.argmin(distance))], "at"
    valid = [k for k, c in enumerate(candidates) if not c.rejected and not c.parts]
    if not valid:
        return None, "class"
    wholes = [k for k, c in enumerate(candidates) if not c.rejected and c.parts]
    if all(candidates[k].score is not None for k in valid + wholes):
        most = max(len(candidates[k].index) for k in valid)
        def rank_of(c: Candidate) -> float:
            return c.score + size_weight * float(np.log(most / len(c.index)))

        rank = {k: rank_of(candidates[k]) for k in valid + wholes}
        for k in valid + wholes:
            candidates[k].summary["rank"] = round(rank[k], 4)
            for part in candidates[k].neck:
                if part.score is not None:
                    part.summary["rank"] = round(rank_of(part), 4)
        return min(valid, key=rank.__getitem__), "class"
    return max(valid, key=lambda k: len(candidates[k].index)), "largest"
