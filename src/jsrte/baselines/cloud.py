"""Point-cloud helpers of the descriptor baselines: scale-free normalization, voxel subsampling,
radius neighbourhoods (as CSR arrays, so per-point statistics vectorize) and PCA normals."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from jsrte.metrics.surface import bounding_sphere


@dataclass(frozen=True)
class UnitCloud:
    """A cloud moved into its own unit bounding sphere: ``unit = (points - centre) / radius``.

    Attributes
    ----------
    points : (n, 3) float64, unit-sphere coordinates
    normals : (n, 3) float64 unit normals (rotation only: unchanged by the normalization)
    centre : (3,) float64, bounding-sphere centre in the input's units
    radius : float, bounding-sphere radius in the input's units
    """

    points: np.ndarray
    normals: np.ndarray
    centre: np.ndarray
    radius: float

    def to_input(self, unit_points: np.ndarray) -> np.ndarray:
        """Unit-sphere points (k, 3) back to the input's units (k, 3)."""
        return np.asarray(unit_points, dtype=np.float64) * self.radius + self.centre


def unit_cloud(points: np.ndarray, normals: np.ndarray, *, voxel: float | None = None) -> UnitCloud:
    """Normalize ``points`` (n, 3) to their bounding sphere, then keep one point per ``voxel``
    (a cube side in unit-sphere units; None keeps all). This is how the scale-free descriptors
    see a cloud: the same object in metres and in canonical units gives the same unit cloud."""
    centre, radius = bounding_sphere(points)
    radius = max(radius, 1e-12)
    unit = (np.asarray(points, dtype=np.float64) - centre) / radius
    normals = np.asarray(normals, dtype=np.float64)
    if voxel is not None:
        keep = voxel_subsample(unit, voxel)
        unit, normals = unit[keep], normals[keep]
    return UnitCloud(unit, normals, centre, radius)


def voxel_subsample(points: np.ndarray, voxel: float) -> np.ndarray:
    """Indices (sorted) of one point per occupied voxel of side ``voxel``: the one nearest its
    voxel's centre (so the subsample does not depend on the input's order)."""
    cells = np.floor(points / voxel)
    offset = np.linalg.norm(points - (cells + 0.5) * voxel, axis=1)
    order = np.lexsort((offset, cells[:, 2], cells[:, 1], cells[:, 0]))
    sorted_cells = cells[order]
    first = np.ones(len(order), dtype=bool)
    first[1:] = np.any(sorted_cells[1:] != sorted_cells[:-1], axis=1)
    return np.sort(order[first])


@dataclass(frozen=True)
class Neighbourhoods:
    """Radius neighbourhoods in CSR form: the neighbours of centre ``i`` are
    ``index[indptr[i]:indptr[i + 1]]`` at distances ``distance[...]``; ``owner`` repeats ``i``.

    Attributes
    ----------
    indptr : (k + 1,) int64
    index : (e,) int64, indices into the searched cloud
    distance : (e,) float64
    owner : (e,) int64, the centre of each entry
    """

    indptr: np.ndarray
    index: np.ndarray
    distance: np.ndarray
    owner: np.ndarray

    @property
    def counts(self) -> np.ndarray:
        """(k,) neighbours per centre."""
        return np.diff(self.indptr)


def radius_neighbours(tree: cKDTree, centres: np.ndarray, radius: float) -> Neighbourhoods:
    """The points of ``tree`` within ``radius`` of each of ``centres`` (k, 3), self included."""
    lists = tree.query_ball_point(np.asarray(centres, dtype=np.float64), r=radius, return_sorted=False, workers=-1)
    counts = np.fromiter((len(x) for x in lists), dtype=np.int64, count=len(lists))
    indptr = np.concatenate([[0], np.cumsum(counts)])
    index = np.fromiter((j for x in lists for j in x), dtype=np.int64, count=int(indptr[-1]))
    owner = np.repeat(np.arange(len(lists)), counts)
    distance = np.linalg.norm(tree.data[index] - np.asarray(centres, dtype=np.float64)[owner], axis=1)
    return Neighbourhoods(indptr, index, distance, owner)


def segment_sum(values: np.ndarray, owner: np.ndarray, n: int) -> np.ndarray:
    """Sum ``values`` (e, ...) per owner (e,) into (n, ...)."""
    out = np.zeros((n,) + values.shape[1:], dtype=np.float64)
    np.add.at(out, owner, values)
    return out


def pca_normals(points: np.ndarray, radius: float, *, min_neighbours: int = 3
                ) -> tuple[np.ndarray, np.ndarray]:
    """PCA normals and surface variation of each point (PCL's ``NormalEstimation``).

    Returns ``(normals (n, 3), curvature (n,))`` with curvature ``λ0 / (λ0 + λ1 + λ2)``
    (λ0 the smallest eigenvalue of the neighbourhood covariance); normals are unoriented
    (orient them by the caller's convention). Points with fewer than ``min_neighbours``
    neighbours get curvature 1 and normal +z.
    """
    tree = cKDTree(points)
    nb = radius_neighbours(tree, points, radius)
    n = len(points)
    counts = nb.counts.astype(np.float64)
    p = points[nb.index]
    mean = segment_sum(p, nb.owner, n) / np.maximum(counts, 1)[:, None]
    d = p - mean[nb.owner]
    cov = segment_sum(d[:, :, None] * d[:, None, :], nb.owner, n) / np.maximum(counts, 1)[:, None, None]
    values, vectors = np.linalg.eigh(cov)
    normals = vectors[:, :, 0]
    curvature = values[:, 0] / np.maximum(values.sum(axis=1), 1e-300)
    bad = counts < min_neighbours
    normals[bad] = [0.0, 0.0, 1.0]
    curvature[bad] = 1.0
    return normals, curvature
