"""What each camera of a scan saw, and where it saw through a fitted surface.

A depth camera that returned a point at range r along a line of sight saw empty space along
that line up to r. A fitted shape whose surface lies on such a line, well short of the point,
is contradicted by the scan: the camera saw through it. Unlike the share of the fitted surface
that the object's points cover (low for an object seen from one side, right or wrong), this
only counts surface the cameras could have seen and did not: a bed fitted too long over the
floor, a sofa laid over a table and the floor beside it.

The lines of sight come from the scan itself: the camera centres (the scan's JSON sidecar
``cameras``) and, for every point, which camera saw it (the PLY vertex property ``view``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class SightSettings:
    """When a camera saw through a point (lengths in metres)."""

    neighbour_px: float = 1.5
    """A point's lines of sight: the camera's readings whose direction lies within this many
    pixels (the median angle between a reading and its nearest neighbour of the same camera) of
    the point's own."""
    min_readings: int = 2
    """At least this many readings along those lines ..."""
    max_readings: int = 4
    """... of the nearest this many, all beyond the point, say the camera saw through it."""
    depth_tolerance_m: float = 0.03
    noise_a_m: float = 0.0015
    noise_b_per_m: float = 0.0019
    sigmas: float = 3.0
    """Beyond: farther than the point's range by ``max(depth_tolerance_m, sigmas * (a + b r²))``
    (a Kinect-like depth noise at range r)."""
    clearance_m: float = 0.06
    """Only points farther than this from every reading count: near an observed surface a fit
    off by a few centimetres, or a thin leg, is seen past at its edges. On six tuning rooms
    (101-122 of seed 0) right chairs' fits were seen through at 0.07-0.20 of their surface with
    3 cm, at 0.01-0.04 (and one 0.15) with 6 cm; a bed fitted as a sofa at 0.50 and 0.43."""


@dataclass(frozen=True)
class CameraViews:
    """A scan's readings by camera: ``centres`` (k, 3) the camera centres; for camera k,
    ``directions[k]`` a KD-tree over the unit directions from its centre to its readings,
    ``ranges[k]`` (m_k,) their distances (scan units) and ``pixels[k]`` the median angle
    (radians) between neighbouring readings; ``readings`` a KD-tree over every reading."""

    centres: np.ndarray
    directions: tuple
    ranges: tuple
    pixels: tuple
    readings: object

    @classmethod
    def of_scan(cls, points: np.ndarray, view: np.ndarray | None,
                cameras: np.ndarray | None) -> CameraViews | None:
        """The readings ``points`` (n, 3) by the camera that saw each (``view`` (n,) int into
        ``cameras`` (k, 3)); None where either is unknown."""
        from scipy.spatial import cKDTree

        if view is None or cameras is None or not len(points):
            return None
        points = np.asarray(points, dtype=np.float64)
        centres = np.asarray(cameras, dtype=np.float64).reshape(-1, 3)
        view = np.asarray(view)
        trees, ranges, pixels = zip(*(lines_of_sight(points[view == k], centre) for k, centre in enumerate(centres)),
                                    strict=True)
        return cls(centres, trees, ranges, pixels, cKDTree(points))

    def seen_through(self, points: np.ndarray, settings: SightSettings = SightSettings()) -> np.ndarray:
        """(m,) bool: True for the ``points`` (m, 3) that some camera saw through (every one of
        its nearest readings along the point's line of sight lies beyond it) and that lie
        farther than ``settings.clearance_m`` from every reading."""
        points = np.asarray(points, dtype=np.float64)
        through = np.zeros(len(points), dtype=bool)
        for centre, tree, ranges, pixel in zip(self.centres, self.directions, self.ranges, self.pixels, strict=True):
            if tree is None or not pixel > 0:
                continue
            through |= _beyond(points, centre, tree, ranges, pixel, settings)
        clear = self.readings.query(points, k=1)[0] > settings.clearance_m
        return through & clear


def lines_of_sight(readings: np.ndarray, centre: np.ndarray) -> tuple[object | None, np.ndarray, float]:
    """The ``readings`` (m, 3) of the camera at ``centre`` (3,) as lines of sight: a KD-tree over
    their unit directions (``tree.data``; None for fewer than two readings), their ranges (m,) and
    the median angle (radians) between a reading and its nearest neighbour: about one pixel."""
    from scipy.spatial import cKDTree

    offset = np.asarray(readings, dtype=np.float64) - centre
    ranges = np.linalg.norm(offset, axis=1)
    if len(offset) < 2:
        return None, ranges, 0.0
    tree = cKDTree(offset / np.maximum(ranges, 1e-12)[:, None])
    return tree, ranges, float(np.median(tree.query(tree.data, k=2)[0][:, 1]))


def _beyond(points: np.ndarray, centre: np.ndarray, tree: object, ranges: np.ndarray, pixel: float,
            settings: SightSettings) -> np.ndarray:
    """(m,) bool: the camera at ``centre`` has at least ``min_readings`` readings (directions in
    ``tree``, distances ``ranges``) within ``neighbour_px * pixel`` of each of ``points``' lines
    of sight, all beyond the point."""
    offset = points - centre
    distance = np.linalg.norm(offset, axis=1)
    angle, nearest = tree.query(offset / np.maximum(distance, 1e-12)[:, None], k=settings.max_readings,
                                distance_upper_bound=settings.neighbour_px * pixel)
    found = np.isfinite(angle)
    tolerance = np.maximum(settings.depth_tolerance_m,
                           settings.sigmas * (settings.noise_a_m + settings.noise_b_per_m * distance**2))
    reading = ranges[np.where(found, nearest, 0)]
    beyond = np.where(found, reading > (distance + tolerance)[:, None], True).all(axis=1)
    return beyond & (found.sum(axis=1) >= settings.min_readings)
