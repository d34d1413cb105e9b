"""SDF samples built from a scan with outward normals (paper supplementary, "SDF Sampling").

For every surface point, two samples at ``+/- surface_offset_m`` along its normal with SDF
``+/- surface_offset_m``. Then ``n_freespace`` freespace samples: a randomly chosen surface
point moved a uniform ``[freespace_min_m, freespace_max_m]`` along its outward normal; the SDF
is the distance to the nearest surface point (k-d tree), positive when the sample lies on the
outward-normal side of that nearest point. Everything in scan units (metres).
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
