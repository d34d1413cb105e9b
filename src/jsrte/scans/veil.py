"""Mixed pixels: depth readings that lie between two surfaces, on neither.

At a depth edge a depth camera often returns, for a pixel that straddles the edge, a depth
between the near and the far surface (a *mixed pixel*, or a *veil* of points along the
silhouette). Such points float in the gap between an object and what stands behind it, and
bridge the two: a clustering then takes a chair and a box 5 cm behind it for one object.

Seen in the fused cloud they look like surface points (as dense, as planar). Seen in their own
depth image they do not: a surface point has an image neighbour at about its own range (the
same surface, one pixel over), while a mixed pixel's image neighbours lie on the near surface
or on the far one, each well off its range along the line of sight. This is the classic veil
test of laser scans, done here on the points of each camera: the image neighbours of a point
are the points of the same view whose direction from that camera lies within
``neighbour_px`` pixels of its own (angular neighbours; no image grid is needed, only the
camera centres and which camera saw each point).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class VeilSettings:
    """When a point counts as a mixed pixel (lengths in metres)."""

    neighbour_px: float = 1.8
    """Image neighbours: directions within this many pixels (the median angle between a point
    and its nearest neighbour of the same view, a little under one pixel) of the point's own:
    its 8 neighbours."""
    noise_a_m: float = 0.0015
    noise_b_per_m: float = 0.0019
    """The sensor's depth noise std at range r: ``a + b * r**2`` (Kinect-like)."""
    sigmas: float = 3.0
    """A neighbour at most this many noise stds (of the point's range) off the point's range
    supports it ..."""
    min_tolerance_m: float = 0.02
    """... or at most this far, whichever is more."""


def mixed_pixels(points: np.ndarray, view: np.ndarray, cameras: np.ndarray,
                 settings: VeilSettings = VeilSettings()) -> np.ndarray:
    """(n,) bool, True for the mixed pixels among ``points`` (n, 3), each seen by the camera
    ``cameras[view[i]]`` (``view`` (n,) int, ``cameras`` (k, 3), same units as the points):
    points whose :func:`veil_score` exceeds 1 (image neighbours in their own view, none of them
    within the tolerance of the point's range). A point with no image neighbour is kept."""
    return veil_score(points, view, cameras, settings) > 1.0


def veil_score(points: np.ndarray, view: np.ndarray, cameras: np.ndarray,
               settings: VeilSettings = VeilSettings()) -> np.ndarray:
    """(n,) float: for each of ``points`` (n, 3), the smallest range difference to an image
    neighbour in its own view (``view`` (n,) int into ``cameras`` (k, 3)), in units of the
    tolerance at its range, ``max(min_tolerance_m, sigmas * (a + b * r**2))``; 0 for a point with
    no image neighbour (alone in its view). Above 1: a mixed pixel."""
    from jsrte.scans.views import lines_of_sight

    points = np.asarray(points, dtype=np.float64)
    cameras = np.asarray(cameras, dtype=np.float64).reshape(-1, 3)
    score = np.zeros(len(points))
    for k, camera in enumerate(cameras):
        index = np.flatnonzero(view == k)
        tree, ranges, pixel = lines_of_sight(points[index], camera)
        if tree is None or not pixel > 0:
            continue
        distance, neighbour = tree.query(tree.data, k=9, distance_upper_bound=settings.neighbour_px * pixel)
        found = np.isfinite(distance[:, 1:])
        other = np.where(found, neighbour[:, 1:], 0)
        sigma = settings.noise_a_m + settings.noise_b_per_m * ranges**2
        tolerance = np.maximum(settings.min_tolerance_m, settings.sigmas * sigma)
        gap = np.where(found, np.abs(ranges[other] - ranges[:, None]), np.inf).min(axis=1)
        score[index] = np.where(np.isfinite(gap), gap / tolerance, 0.0)
    return score


def scan_mixed_pixels(points: np.ndarray, view: np.ndarray | None, cameras: np.ndarray | None,
                      settings: VeilSettings | None = VeilSettings()) -> np.ndarray | None:
    """:func:`mixed_pixels` when it can run: the points' camera indices ``view`` (n,) are known
    and each names one of the ``cameras`` (k, 3); else None (no test; also when ``settings`` is
    None)."""
    if settings is None or view is None or cameras is None or len(view) != len(points):
        return None
    cameras = np.asarray(cameras, dtype=np.float64).reshape(-1, 3)
    if not len(view) or view.min() < 0 or view.max() >= len(cameras):
        return None
    return mixed_pixels(points, view, cameras, settings)
