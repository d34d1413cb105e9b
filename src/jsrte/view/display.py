"""Drawing-ready data: scan points subsampled and coloured by distance to the fitted surface,
meshes decimated for display only (the fit's files are never changed)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

NEAR_COLOUR = np.array([40, 90, 220], dtype=np.float64)
MID_COLOUR = np.array([250, 200, 40], dtype=np.float64)
FAR_COLOUR = np.array([220, 40, 40], dtype=np.float64)
FAR_FRACTION = 0.10
"""A point this far from the surface, as a fraction of the mesh's bounding-sphere radius, is
drawn fully red (twice the paper's F@5% threshold)."""
SURFACE_SAMPLES = 30_000


@dataclass(frozen=True)
class ColouredPoints:
    """Scan points for display.

    Attributes
    ----------
    points : (m, 3) float32, scan units
    colours : (m, 3) uint8 RGB
    distances : (m,) float32 distance to the fitted surface (scan units; NaN without a mesh)
    far : the distance drawn fully red (scan units; NaN without a mesh)
    """

    points: np.ndarray
    colours: np.ndarray
    distances: np.ndarray
    far: float


def subsample(points: np.ndarray, max_points: int, *, seed: int = 0) -> np.ndarray:
    """At most ``max_points`` of ``points`` (n, 3), chosen uniformly at random (seeded), in order."""
    if len(points) <= max_points:
        return np.asarray(points)
    keep = np.sort(np.random.default_rng(seed).choice(len(points), max_points, replace=False))
    return np.asarray(points)[keep]


def distance_to_surface(points: np.ndarray, mesh: Any, *, samples: int = SURFACE_SAMPLES, candidates: int = 6,
                        seed: int = 0) -> np.ndarray:
    """(n,) distance of each point (n, 3) to ``mesh``'s surface, scan units.

    The triangles under each point's ``candidates`` nearest of ``samples`` points spread over
    the surface by area are measured exactly; the distance is the least of them: exact unless
    the nearest triangle holds none of those samples, then too large by at most about their
    spacing ``sqrt(area / samples)`` (a few points in a thousand).
    """
    import trimesh
    from pykdtree.kdtree import KDTree

    points = np.ascontiguousarray(points, dtype=np.float64).reshape(-1, 3)
    surface, face_of_sample = trimesh.sample.sample_surface(mesh, samples, seed=seed)
    _, nearest = KDTree(np.asarray(surface)).query(points, k=candidates)
    faces = np.asarray(face_of_sample)[np.asarray(nearest).reshape(len(points), candidates)]
    triangles = np.asarray(mesh.triangles)[faces.ravel()]
    closest = trimesh.triangles.closest_point(triangles, np.repeat(points, candidates, axis=0))
    gaps = np.linalg.norm(closest - np.repeat(points, candidates, axis=0), axis=1).reshape(len(points), candidates)
    return gaps.min(axis=1)


def colour_by_distance(distances: np.ndarray, far: float) -> np.ndarray:
    """(n, 3) uint8 RGB: blue on the surface, yellow at ``far / 2``, red at ``far`` and beyond."""
    x = np.clip(np.asarray(distances, dtype=np.float64) / far, 0.0, 1.0)[:, None]
    low = NEAR_COLOUR + (MID_COLOUR - NEAR_COLOUR) * np.clip(2 * x, 0, 1)
    high = MID_COLOUR + (FAR_COLOUR - MID_COLOUR) * np.clip(2 * x - 1, 0, 1)
    return np.where(x < 0.5, low, high).round().astype(np.uint8)


def coloured_scan(scan: np.ndarray, mesh: Any, max_points: int, *, seed: int = 0) -> ColouredPoints:
    """The scan subsampled to ``max_points``, coloured by distance to ``mesh`` (grey without one)."""
    points = subsample(scan, max_points, seed=seed)
    if mesh is None:
        grey = np.full((len(points), 3), 150, dtype=np.uint8)
        return ColouredPoints(points.astype(np.float32), grey, np.full(len(points), np.nan, np.float32), np.nan)
    vertices = np.asarray(mesh.vertices)
    centre = (vertices.min(axis=0) + vertices.max(axis=0)) / 2
    far = FAR_FRACTION * float(np.linalg.norm(vertices - centre, axis=1).max())
    distances = distance_to_surface(points, mesh, seed=seed)
    return ColouredPoints(points.astype(np.float32), colour_by_distance(distances, far),
                          distances.astype(np.float32), far)


def decimated(mesh: Any, max_faces: int) -> Any:
    """A copy of ``mesh`` with at most about ``max_faces`` triangles (quadric decimation with
    fast-simplification); the mesh itself when it is already small enough."""
    import trimesh

    faces = np.asarray(mesh.faces)
    if len(faces) <= max_faces:
        return mesh
    import fast_simplification

    vertices, faces = fast_simplification.simplify(
        np.asarray(mesh.vertices, dtype=np.float32), faces.astype(np.int32), 1.0 - max_faces / len(faces))
    return trimesh.Trimesh(vertices, faces, process=False)
