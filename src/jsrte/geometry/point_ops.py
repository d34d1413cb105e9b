"""Point-cloud operations of the scan preprocessing, with NumPy, pykdtree and SciPy.

Each one computes what Open3D's function of the same purpose computes (same neighbour
searches, same formulas, same order of floating-point sums), so that the kept points, the
visible points and the clusters are the same and the normals agree to rounding, without
importing Open3D (about half a second of a fit's start-up):

- :func:`statistical_inliers`: ``PointCloud.remove_statistical_outlier``
- :func:`visible_points`: ``PointCloud.hidden_point_removal`` (Katz et al. 2007; qhull, as
  Open3D, through ``scipy.spatial.ConvexHull``)
- :func:`pca_normals`: ``PointCloud.estimate_normals`` with ``KDTreeSearchParamHybrid``
  (covariance from raw moments, Open3D's closed-form 3x3 eigen solver)
- :func:`dbscan_labels`: ``PointCloud.cluster_dbscan``

Lengths are in the points' units.
"""

from __future__ import annotations

import numpy as np


def _tree(points: np.ndarray):  # noqa: ANN202 (pykdtree type)
    from pykdtree.kdtree import KDTree

    return KDTree(points)


def _sequential_sum(values: np.ndarray) -> np.ndarray:
    """Sum (n,) of ``values`` (n, k) over k, left to right (as a C++ loop adds them)."""
    total = np.zeros(len(values))
    for column in values.T:
        total = total + column
    return total


def statistical_inliers(points: np.ndarray, neighbours: int, std_ratio: float) -> np.ndarray:
    """Statistical outlier removal: the keep mask (n,) bool of ``points`` (n, 3).

    A point's score is its mean distance to its ``neighbours`` nearest points (itself
    included, as Open3D counts it); points scoring at least the mean score plus ``std_ratio``
    standard deviations (Bessel-corrected) are dropped, and so are points whose score is 0
    (all their neighbours coincide with them).
    """
    points = np.ascontiguousarray(points, dtype=np.float64)
    if neighbours < 1 or std_ratio <= 0:
        raise ValueError("the number of neighbours and the standard deviation ratio must be positive")
    if len(points) < 2:  # none, or no spread: Open3D's threshold is NaN and keeps nothing
        return np.zeros(len(points), dtype=bool)
    k = min(neighbours, len(points))
    distance2, _ = _knn(points, k)
    score = _sequential_sum(np.sqrt(distance2)) / k
    valid = score > 0
    mean = float(np.cumsum(np.where(valid, score, 0.0))[-1]) / len(points)
    deviation2 = np.where(valid, (score - mean) * (score - mean), 0.0)
    std = np.sqrt(float(np.cumsum(deviation2)[-1]) / (len(points) - 1))
    return valid & (score < mean + std_ratio * std)


def _knn(points: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
    """Squared distances (n, k) float64 and indices (n, k) int64 of the ``k`` nearest of
    ``points`` (n, 3) to each of them (itself first), nearest first. pykdtree sums the squares
    x, y, z in order, as nanoflann (Open3D's kd-tree) does: the same distances."""
    distance2, index = _tree(points).query(points, k=k, sqr_dists=True)
    return distance2.reshape(len(points), k), np.asarray(index, dtype=np.int64).reshape(len(points), k)


def _distance2(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Squared distances (...) between ``a`` and ``b`` (..., 3), summed x, y, z in that order."""
    d = a - b
    return (d[..., 0] * d[..., 0] + d[..., 1] * d[..., 1]) + d[..., 2] * d[..., 2]


def median_spacing(points: np.ndarray) -> float:
    """Median distance from a point (n, 3) to its nearest other point (0 if fewer than 2)."""
    from pykdtree.kdtree import KDTree

    points = np.ascontiguousarray(points, dtype=np.float64)
    if len(points) < 2:
        return 0.0
    distance, _ = KDTree(points).query(points, k=2)
    return float(np.median(distance[:, 1]))


def visible_points(points: np.ndarray, viewpoint: np.ndarray, radius: float) -> np.ndarray:
    """Hidden point removal (Katz et al. 2007): mask (n,) bool of the ``points`` (n, 3) visible
    from ``viewpoint`` (3,).

    The points are flipped about a sphere of ``radius`` around the viewpoint; the visible ones
    are the vertices of the convex hull of the flipped points and the viewpoint. Fewer than four
    points, points all in one plane with the viewpoint (no hull), or a point at the viewpoint
    are all visible (Open3D raises an error on the last two).
    """
    from scipy.spatial import ConvexHull, QhullError

    points = np.asarray(points, dtype=np.float64)
    if radius <= 0:
        raise ValueError("the radius must be positive")
    if len(points) < 4:
        return np.ones(len(points), dtype=bool)
    offset = points - np.asarray(viewpoint, dtype=np.float64).reshape(3)
    norm = np.sqrt(_distance2(offset, np.zeros(3)))[:, None]
    with np.errstate(divide="ignore", invalid="ignore"):
        flipped = offset + 2.0 * (radius - norm) * offset / norm
    try:
        hull = ConvexHull(np.vstack([flipped, np.zeros((1, 3))]), qhull_options="Qt")
    except (QhullError, ValueError):  # flat, or a point at the viewpoint itself (no direction)
        return np.ones(len(points), dtype=bool)
    visible = np.zeros(len(points) + 1, dtype=bool)
    visible[hull.vertices] = True
    return visible[:-1]


def pca_normals(points: np.ndarray, radius: float, max_nn: int) -> np.ndarray:
    """Unit normals (n, 3) of ``points`` (n, 3), unoriented: the least-variance direction of
    each point's neighbours (its ``max_nn`` nearest closer than ``radius``, itself included).

    A point with fewer than three such neighbours gets (0, 0, 1), as in Open3D.
    """
    points = np.ascontiguousarray(points, dtype=np.float64)
    if len(points) == 0:
        return np.zeros((0, 3))
    distance2, index = _knn(points, min(max_nn, len(points)))
    near = distance2 < radius * radius
    covariance = _raw_moment_covariance(points, index, near)
    covariance[near.sum(1) < 3] = np.eye(3)
    return smallest_eigenvectors(covariance)


def _raw_moment_covariance(points: np.ndarray, index: np.ndarray, use: np.ndarray) -> np.ndarray:
    """Covariances (n, 3, 3) of the neighbours ``points[index]`` ((n, k) indices, those of
    ``use`` (n, k) bool) from sums of coordinates and their products, added in neighbour order
    as Open3D does."""
    padded = np.vstack([points, np.zeros((1, 3))]).T.copy()  # (3, n + 1): unused neighbours add zeros
    neighbour = np.where(use, index, len(points)).T
    sums = np.zeros((9, len(points)))
    for x, y, z in zip(*(coordinate[neighbour] for coordinate in padded), strict=True):
        sums += (x, y, z, x * x, x * y, x * z, y * y, y * z, z * z)
    m = sums / np.maximum(use.sum(1), 1)
    xy, xz, yz = m[4] - m[0] * m[1], m[5] - m[0] * m[2], m[7] - m[1] * m[2]
    return np.stack([np.stack([m[3] - m[0] * m[0], xy, xz], -1),
                     np.stack([xy, m[6] - m[1] * m[1], yz], -1),
                     np.stack([xz, yz, m[8] - m[2] * m[2]], -1)], -2)


def smallest_eigenvectors(covariance: np.ndarray) -> np.ndarray:
    """Unit eigenvectors (n, 3) of the smallest eigenvalues of symmetric ``covariance`` (n, 3, 3).

    Open3D's closed-form solver (Eberly, "A Robust Eigensolver for 3x3 Symmetric Matrices"),
    with its special cases: a zero matrix gives (0, 0, 1), a diagonal one the axis of its
    smallest diagonal entry.
    """
    a = np.array(covariance, dtype=np.float64)
    scale = a.reshape(len(a), 9).max(1)
    zero = scale == 0
    a = a / np.where(zero, 1.0, scale)[:, None, None]
    off = a[:, 0, 1] ** 2 + a[:, 0, 2] ** 2 + a[:, 1, 2] ** 2
    result = _diagonal_case(a * np.where(zero, 1.0, scale)[:, None, None])
    general = (off > 0) & ~zero
    if general.any():
        result[general] = _general_case(a[general], off[general])
    result[zero] = (0.0, 0.0, 1.0)
    return result


def _diagonal_case(a: np.ndarray) -> np.ndarray:
    """The axis (n, 3) of the smallest diagonal entry of ``a`` (n, 3, 3) (z on ties, as Open3D)."""
    d0, d1, d2 = a[:, 0, 0], a[:, 1, 1], a[:, 2, 2]
    result = np.tile([0.0, 0.0, 1.0], (len(a), 1))
    result[(d1 < d0) & (d1 < d2)] = (0.0, 1.0, 0.0)
    result[(d0 < d1) & (d0 < d2)] = (1.0, 0.0, 0.0)
    return result


def _general_case(a: np.ndarray, off: np.ndarray) -> np.ndarray:
    """Smallest-eigenvalue eigenvectors (n, 3) of scaled ``a`` (n, 3, 3) with non-zero
    off-diagonal sum of squares ``off`` (n,)."""
    q = (a[:, 0, 0] + a[:, 1, 1] + a[:, 2, 2]) / 3
    b00, b11, b22 = a[:, 0, 0] - q, a[:, 1, 1] - q, a[:, 2, 2] - q
    p = np.sqrt((b00 * b00 + b11 * b11 + b22 * b22 + off * 2) / 6)
    c00 = b11 * b22 - a[:, 1, 2] * a[:, 1, 2]
    c01 = a[:, 0, 1] * b22 - a[:, 1, 2] * a[:, 0, 2]
    c02 = a[:, 0, 1] * a[:, 1, 2] - b11 * a[:, 0, 2]
    half_det = np.clip((b00 * c00 - a[:, 0, 1] * c01 + a[:, 0, 2] * c02) / (p * p * p) * 0.5, -1.0, 1.0)
    angle = np.arccos(half_det) / 3.0
    beta2 = np.cos(angle) * 2
    beta0 = np.cos(angle + 2.09439510239319549) * 2
    beta1 = -(beta0 + beta2)
    evals = np.stack([q + p * beta0, q + p * beta1, q + p * beta2], 1)
    upper = half_det >= 0  # first vector: the eigenvector of eval 2, else of eval 0
    first = np.where(upper, 2, 0)
    e_first = evals[np.arange(len(a)), first]
    with np.errstate(divide="ignore", invalid="ignore"):  # rows whose answer comes earlier
        v_first = _eigenvector0(a, e_first)
        v_mid = _eigenvector1(a, v_first, evals[:, 1])
    v_last = np.where(upper[:, None], np.cross(v_mid, v_first), np.cross(v_first, v_mid))
    e_other = evals[np.arange(len(a)), 2 - first]
    first_smallest = (e_first < e_other) & (e_first < evals[:, 1])
    mid_smallest = (evals[:, 1] < evals[:, 0]) & (evals[:, 1] < evals[:, 2])
    return np.where(first_smallest[:, None], v_first, np.where(mid_smallest[:, None], v_mid, v_last))


def _eigenvector0(a: np.ndarray, value: np.ndarray) -> np.ndarray:
    """Unit eigenvectors (n, 3) of ``a`` (n, 3, 3) for the simple eigenvalues ``value`` (n,):
    the longest cross product of two rows of ``a - value I``."""
    rows = a - value[:, None, None] * np.eye(3)
    crosses = np.stack([np.cross(rows[:, 0], rows[:, 1]), np.cross(rows[:, 0], rows[:, 2]),
                        np.cross(rows[:, 1], rows[:, 2])], 1)
    lengths = np.einsum("nij,nij->ni", crosses, crosses)
    best = np.zeros(len(a), dtype=np.int64)
    best[lengths[:, 1] > lengths[:, 0]] = 1
    best[lengths[:, 2] > np.maximum(lengths[:, 0], lengths[:, 1])] = 2
    take = np.arange(len(a))
    return crosses[take, best] / np.sqrt(lengths[take, best])[:, None]


def _eigenvector1(a: np.ndarray, v0: np.ndarray, value: np.ndarray) -> np.ndarray:
    """Unit eigenvectors (n, 3) of ``a`` (n, 3, 3) for ``value`` (n,), orthogonal to the unit
    eigenvectors ``v0`` (n, 3): solved in the plane orthogonal to ``v0``."""
    x_major = np.abs(v0[:, 0]) > np.abs(v0[:, 1])
    inv_x = 1 / np.sqrt(v0[:, 0] * v0[:, 0] + v0[:, 2] * v0[:, 2])
    inv_y = 1 / np.sqrt(v0[:, 1] * v0[:, 1] + v0[:, 2] * v0[:, 2])
    zero = np.zeros(len(a))
    u = np.where(x_major[:, None], np.stack([-v0[:, 2] * inv_x, zero, v0[:, 0] * inv_x], 1),
                 np.stack([zero, v0[:, 2] * inv_y, -v0[:, 1] * inv_y], 1))
    v = np.cross(v0, u)
    au, av = _symmetric_times(a, u), _symmetric_times(a, v)
    m00 = _dot3(u, au) - value
    m01 = _dot3(u, av)
    m11 = _dot3(v, av) - value
    return _plane_eigenvector(u, v, m00, m01, m11)


def _symmetric_times(a: np.ndarray, u: np.ndarray) -> np.ndarray:
    """``a @ u`` (n, 3) from the upper triangle of ``a`` (n, 3, 3), summed as Open3D does."""
    return np.stack([a[:, 0, 0] * u[:, 0] + a[:, 0, 1] * u[:, 1] + a[:, 0, 2] * u[:, 2],
                     a[:, 0, 1] * u[:, 0] + a[:, 1, 1] * u[:, 1] + a[:, 1, 2] * u[:, 2],
                     a[:, 0, 2] * u[:, 0] + a[:, 1, 2] * u[:, 1] + a[:, 2, 2] * u[:, 2]], 1)


def _dot3(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    return u[:, 0] * v[:, 0] + u[:, 1] * v[:, 1] + u[:, 2] * v[:, 2]


def _plane_eigenvector(u: np.ndarray, v: np.ndarray, m00: np.ndarray, m01: np.ndarray,
                       m11: np.ndarray) -> np.ndarray:
    """The null vector (n, 3) of the 2x2 system [[m00, m01], [m01, m11]] in the basis ``u``,
    ``v`` (n, 3), normalised by its largest entry as Open3D does; ``u`` when the system is 0."""
    with np.errstate(divide="ignore", invalid="ignore"):
        # |m00| >= |m11|: solve from the first row, else from the second
        first = np.abs(m00) >= np.abs(m11)
        big = np.where(first, m00, m11)
        big_wins = np.abs(big) >= np.abs(m01)
        ratio = np.where(big_wins, m01 / big, big / m01)
        inv = 1 / np.sqrt(1 + ratio * ratio)
        big_n = np.where(big_wins, inv, ratio * inv)
        m01_n = np.where(big_wins, ratio * inv, inv)
        result = np.where(first[:, None], m01_n[:, None] * u - big_n[:, None] * v,
                          big_n[:, None] * u - m01_n[:, None] * v)
    degenerate = np.maximum(np.abs(big), np.abs(m01)) == 0
    return np.where(degenerate[:, None], u, result)


def dbscan_labels(points: np.ndarray, eps: float, min_points: int) -> np.ndarray:
    """DBSCAN cluster labels (n,) int64 of ``points`` (n, 3); -1 marks noise.

    Neighbours are the points closer than ``eps`` (itself included); a core point has at least
    ``min_points``. Clusters are the connected groups of core points, numbered by their
    lowest point index; a non-core point next to core points joins the lowest-numbered cluster
    among theirs (Open3D labels clusters in that order and grows them in turn).
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    points = np.ascontiguousarray(points, dtype=np.float64)
    n = len(points)
    if n == 0 or eps <= 0:
        return np.full(n, -1, dtype=np.int64)
    i, j = _pairs_closer_than(points, eps)
    core = np.bincount(i, minlength=n) + np.bincount(j, minlength=n) + 1 >= min_points
    both = core[i] & core[j]
    graph = coo_matrix((np.ones(both.sum()), (i[both], j[both])), shape=(n, n))
    _, component = connected_components(graph, directed=False)
    labels = np.full(n, -1, dtype=np.int64)
    labels[core] = _numbered_by_first_index(component[core], np.flatnonzero(core))
    return _attach_border_points(labels, core, i, j)


def _pairs_closer_than(points: np.ndarray, eps: float) -> tuple[np.ndarray, np.ndarray]:
    """The pairs (i, j), i < j, of ``points`` (n, 3) whose squared distance is below ``eps``²."""
    from scipy.spatial import cKDTree

    tree = cKDTree(points, balanced_tree=False, compact_nodes=False)
    i, j = tree.query_pairs(eps * (1 + 1e-9), output_type="ndarray").astype(np.int64).T.copy()
    distance2 = np.zeros(len(i))
    for coordinate in points.T.copy():  # x, y, z in order, as _distance2
        step = coordinate[i] - coordinate[j]
        distance2 = distance2 + step * step
    keep = distance2 < eps * eps
    return i[keep], j[keep]


def _numbered_by_first_index(component: np.ndarray, index: np.ndarray) -> np.ndarray:
    """``component`` ids (m,) of points at ``index`` (m,) ascending, renumbered 0, 1, ... in the
    order of each component's first point."""
    _, first = np.unique(component, return_index=True)
    order = np.argsort(first, kind="stable")
    rank = np.empty(len(order), dtype=np.int64)
    rank[order] = np.arange(len(order))
    return rank[np.searchsorted(np.unique(component), component)]


def _attach_border_points(labels: np.ndarray, core: np.ndarray, i: np.ndarray, j: np.ndarray) -> np.ndarray:
    """``labels`` (n,) with each non-core point next to a core point (pairs ``i``, ``j``) given
    the lowest label among its core neighbours."""
    source = np.concatenate([i, j])
    target = np.concatenate([j, i])
    edge = core[source] & ~core[target]
    best = np.full(len(labels), np.iinfo(np.int64).max)
    np.minimum.at(best, target[edge], labels[source[edge]])
    border = best < np.iinfo(np.int64).max
    labels = labels.copy()
    labels[border] = best[border]
    return labels
