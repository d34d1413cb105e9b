"""SDF samples built from a scan with outward normals (paper supplementary, "SDF Sampling").

For every surface point, two samples at ``+/- surface_offset_m`` along its normal with SDF
``+/- surface_offset_m``. Then ``n_freespace`` freespace samples: a randomly chosen surface
point moved a uniform ``[freespace_min_m, freespace_max_m]`` along its outward normal; the SDF
is the distance to the nearest surface point (k-d tree), positive when the sample lies on the
outward-normal side of that nearest point. Everything in scan units (metres).

Beyond the paper, when the sensor's viewpoints are known (:func:`ray_freespace_samples`):
every scan point seen from a viewpoint proves the line of sight in front of it empty. Samples
on those segments near the object (the floor seen between a chair's legs, the wall behind an
open back) carry SDF = distance to the nearest object point, as the freespace samples do; with
the fit's clamped loss they mostly say "outside, at least the clamp away". The paper's
normal-direction freespace samples never reach such gaps, and a fit left unconstrained there
tends to fill them (a solid base under a four-legged chair).
"""

from __future__ import annotations

import numpy as np

from jsrte.presets import ScanSdf


def scan_sdf_samples(
    points: np.ndarray, normals: np.ndarray, *, rng: np.random.Generator,
    settings: ScanSdf = ScanSdf(),
) -> tuple[np.ndarray, np.ndarray]:
    """SDF samples of a scan, exactly as the paper's supplementary builds them.

    Parameters
    ----------
    points : (n, 3) float, surface points (metres)
    normals : (n, 3) float, outward normals (normalized here)
    rng : picks the freespace source points and distances
    settings : offsets and counts (``jsrte.presets.ScanSdf``)

    Returns
    -------
    xyz : (2 n + n_freespace, 3) float32, sample positions (metres): the ``+offset`` samples,
        the ``-offset`` samples, then the freespace samples
    sdf : (2 n + n_freespace,) float32, signed distances (metres; negative inside)
    """
    from pykdtree.kdtree import KDTree

    points = np.ascontiguousarray(points, dtype=np.float64)
    normals = np.asarray(normals, dtype=np.float64)
    if points.ndim != 2 or points.shape[1] != 3 or normals.shape != points.shape or not len(points):
        raise ValueError(f"need (n>0, 3) points and normals of equal shape, got "
                         f"{points.shape} and {normals.shape}")
    length = np.linalg.norm(normals, axis=1)
    if not np.all(np.isfinite(points)) or not np.all(length > 1e-12):
        raise ValueError("points must be finite and normals non-zero")
    normals = normals / length[:, None]

    delta = settings.surface_offset_m
    near_xyz = np.concatenate([points + delta * normals, points - delta * normals])
    near_sdf = np.concatenate([np.full(len(points), delta), np.full(len(points), -delta)])

    source = rng.integers(0, len(points), size=settings.n_freespace)
    distance = rng.uniform(settings.freespace_min_m, settings.freespace_max_m,
                           size=settings.n_freespace)
    free_xyz = points[source] + distance[:, None] * normals[source]
    nearest_distance, nearest = KDTree(points).query(free_xyz, k=1)
    outward = np.einsum("ij,ij->i", free_xyz - points[nearest], normals[nearest]) >= 0
    free_sdf = np.where(outward, nearest_distance, -nearest_distance)

    xyz = np.concatenate([near_xyz, free_xyz]).astype(np.float32)
    sdf = np.concatenate([near_sdf, free_sdf]).astype(np.float32)
    return xyz, sdf


def ray_freespace_samples(
    object_points: np.ndarray, observed_points: np.ndarray, viewpoints: np.ndarray, *,
    rng: np.random.Generator, settings: ScanSdf = ScanSdf(),
) -> tuple[np.ndarray, np.ndarray]:
    """Free-space samples on the lines of sight from ``viewpoints`` to what they saw.

    Parameters
    ----------
    object_points : (n, 3) float, the object's scan points (metres)
    observed_points : (m, 3) float, everything the sensor saw (object, floor, clutter; metres)
    viewpoints : (k, 3) float, sensor centres (metres)
    rng : picks segments and positions along them
    settings : ``n_ray_freespace``, ``ray_per_point``, ``ray_margin_m``, ``ray_region_factor``

    Returns
    -------
    xyz : (r, 3) float32, sample positions (metres), r <= min(``n_ray_freespace``,
        ``ray_per_point`` n): inside the grown bounding sphere of the object, at least
        ``ray_margin_m`` in front of the point seen and from every object point
    sdf : (r,) float32, distance to the nearest object point (metres, positive: outside)
    """
    from pykdtree.kdtree import KDTree

    from jsrte.metrics.surface import bounding_sphere

    object_points = np.ascontiguousarray(object_points, dtype=np.float64)
    viewpoints = np.asarray(viewpoints, dtype=np.float64).reshape(-1, 3)
    n = min(settings.n_ray_freespace, int(settings.ray_per_point * len(object_points)))
    if n <= 0 or not len(viewpoints) or not len(object_points):
        return np.zeros((0, 3), np.float32), np.zeros(0, np.float32)
    centre, radius = bounding_sphere(object_points)
    radius *= settings.ray_region_factor
    seen = np.asarray(observed_points, dtype=np.float64)
    seen = seen[np.linalg.norm(seen - centre, axis=1) < radius]
    pairs = visible_pairs(seen, viewpoints)
    if not len(pairs):
        return np.zeros((0, 3), np.float32), np.zeros(0, np.float32)
    pick = pairs[rng.integers(0, len(pairs), size=n)]
    start, towards = seen[pick[:, 0]], viewpoints[pick[:, 1]] - seen[pick[:, 0]]
    towards /= np.linalg.norm(towards, axis=1, keepdims=True)
    exit_distance = _sphere_exit(start, towards, centre, radius)
    along = settings.ray_margin_m + rng.uniform(size=n) * (exit_distance - settings.ray_margin_m)
    xyz = start + along[:, None] * towards
    distance, _ = KDTree(object_points).query(xyz, k=1)
    keep = (exit_distance > settings.ray_margin_m) & (distance >= settings.ray_margin_m)
    return xyz[keep].astype(np.float32), distance[keep].astype(np.float32)


def visible_pairs(points: np.ndarray, viewpoints: np.ndarray) -> np.ndarray:
    """(p, 2) int: (point index, viewpoint index) for every point a viewpoint sees."""
    from jsrte.geometry.point_ops import median_spacing

    pairs = [np.zeros((0, 2), dtype=np.int64)]
    spacing = median_spacing(points) if len(points) >= 4 else None
    for k, viewpoint in enumerate(viewpoints):
        visible = np.flatnonzero(zbuffer_visible(points, viewpoint, spacing=spacing))
        pairs.append(np.column_stack([visible, np.full(len(visible), k)]))
    return np.concatenate(pairs)


def zbuffer_visible(points: np.ndarray, viewpoint: np.ndarray, *, cell_spacings: float = 2.0,
                    depth_tolerance_m: float = 0.02, spacing: float | None = None) -> np.ndarray:
    """Mask (n,) of the ``points`` (n, 3) that ``viewpoint`` (3,) sees: a point z-buffer.

    The points are projected through a pinhole at the viewpoint looking at their centre, onto
    square cells ``cell_spacings`` times the points' median spacing wide (at their median
    distance); a point is visible when it is within ``depth_tolerance_m`` of the nearest point
    of its cell. Unlike hidden point removal (Katz et al. 2007), which judges points seen
    through narrow gaps (the floor between a chair's legs) hidden, this keeps them. ``spacing``:
    the points' median spacing where the caller has it
    (:func:`jsrte.geometry.point_ops.median_spacing`).
    """
    from jsrte.geometry.point_ops import median_spacing

    points = np.ascontiguousarray(points, dtype=np.float64)
    if len(points) < 4:
        return np.ones(len(points), dtype=bool)
    offset = points - viewpoint
    forward = offset.mean(axis=0)
    forward /= np.linalg.norm(forward)
    side = np.cross(forward, [0.0, 0.0, 1.0] if abs(forward[2]) < 0.9 else [1.0, 0.0, 0.0])
    side /= np.linalg.norm(side)
    across = np.cross(forward, side)
    depth = offset @ forward
    ahead = depth > 1e-6
    spacing = median_spacing(points) if spacing is None else spacing
    cell = cell_spacings * spacing / float(np.median(depth[ahead]))
    safe = np.where(ahead, depth, 1.0)
    ix = np.floor((offset @ side) / safe / cell).astype(np.int64)
    iy = np.floor((offset @ across) / safe / cell).astype(np.int64)
    ix, iy = ix - ix.min(), iy - iy.min()
    _, key = np.unique(ix * (iy.max() + 1) + iy, return_inverse=True)  # one number per cell
    key = key.reshape(-1)
    nearest = np.full(key.max() + 1, np.inf)
    np.minimum.at(nearest, key[ahead], depth[ahead])
    return ahead & (depth <= nearest[key] + depth_tolerance_m)


def _sphere_exit(start: np.ndarray, direction: np.ndarray, centre: np.ndarray, radius: float) -> np.ndarray:
    """(n,) distance along unit ``direction`` (n, 3) from ``start`` (n, 3, inside the sphere)
    to where the ray leaves the sphere (``centre`` (3,), ``radius``)."""
    offset = start - centre
    b = np.einsum("ij,ij->i", direction, offset)
    c = np.einsum("ij,ij->i", offset, offset) - radius**2
    return -b + np.sqrt(np.maximum(b * b - c, 0.0))
