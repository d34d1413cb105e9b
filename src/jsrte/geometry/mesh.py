"""Mesh loading, validation, DeepSDF unit-sphere normalization and saving."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import trimesh

from jsrte.atomic import write_with
from jsrte.errors import JsrteError
from jsrte.formats import MESH_FILE_SUFFIXES, check_ply_complete
from jsrte.presets import SdfSampling


def load_mesh(path: str | Path) -> trimesh.Trimesh:
    """Read a triangle mesh (OBJ/PLY/OFF/STL/GLB); scenes are flattened into one mesh.

    Raises ``JsrteError`` naming the file when it is missing, unreadable, empty, has
    non-finite vertices or zero surface area.
    """
    path = Path(path)
    if path.is_dir():
        raise JsrteError("is a folder, not a mesh file", path)
    if not path.is_file():
        raise JsrteError("no such file", path)
    if path.stat().st_size == 0:
        raise JsrteError("file is empty", path)
    if path.suffix.lower() not in MESH_FILE_SUFFIXES:
        raise JsrteError(f"unsupported mesh format {path.suffix!r} (use {', '.join(MESH_FILE_SUFFIXES)})", path)
    if path.suffix.lower() == ".ply":
        check_ply_complete(path)
    try:
        loaded = trimesh.load(path, force="mesh", process=False)
    except Exception as exc:  # trimesh raises many types for broken files
        raise JsrteError(f"cannot read mesh ({type(exc).__name__}: {exc})", path) from exc
    if not isinstance(loaded, trimesh.Trimesh) or len(loaded.faces) == 0:
        raise JsrteError("holds no triangles", path)
    return validate_mesh(loaded, path)


def validate_mesh(mesh: trimesh.Trimesh, path: str | Path | None = None) -> trimesh.Trimesh:
    """Check a mesh is usable (finite vertices, faces on existing vertices, non-zero area); returns it."""
    if len(mesh.faces) == 0:
        raise JsrteError("mesh holds no triangles", path)
    check_face_indices(mesh, path)
    if not np.all(np.isfinite(mesh.vertices)):
        raise JsrteError("mesh has NaN or infinite vertex coordinates", path)
    if not mesh.area > 0:
        raise JsrteError("mesh has zero surface area", path)
    return mesh


def check_face_indices(mesh: trimesh.Trimesh, path: str | Path | None = None) -> None:
    """JsrteError unless the vertices are (n, 3), the faces (m, 3), and every face refers to an
    existing vertex (a damaged file can say otherwise)."""
    vertices, faces = np.asarray(mesh.vertices), np.asarray(mesh.faces)
    if vertices.ndim != 2 or vertices.shape[1] != 3 or faces.ndim != 2 or faces.shape[1] != 3:
        raise JsrteError(f"vertices {vertices.shape} and faces {faces.shape} are not 3D triangles", path)
    if faces.size and (faces.min() < 0 or faces.max() >= len(mesh.vertices)):
        raise JsrteError(f"faces refer to vertex {int(faces.max())}, but there are {len(mesh.vertices)} vertices",
                         path)


@dataclass(frozen=True)
class Normalization:
    """DeepSDF's unit-sphere normalization: ``canonical = (mesh - centre) / scale``.

    Attributes
    ----------
    centre : (3,) float64, the bounding-box centre (mesh units)
    scale : float, the largest vertex distance from the centre times the padding (mesh units)
    """

    centre: np.ndarray
    scale: float

    def to_canonical(self, points: np.ndarray) -> np.ndarray:
        """Mesh-frame points (n, 3) -> normalized canonical frame (n, 3)."""
        return (np.asarray(points, dtype=np.float64) - self.centre) / self.scale

    def to_mesh(self, points: np.ndarray) -> np.ndarray:
        """Canonical points (n, 3) -> mesh frame (n, 3)."""
        return np.asarray(points, dtype=np.float64) * self.scale + self.centre


def unit_sphere_normalization(
    mesh: trimesh.Trimesh, padding: float = SdfSampling.normalization_padding
) -> Normalization:
    """The DeepSDF normalization of ``mesh``: bounding-box centre, max distance × padding."""
    lo, hi = mesh.bounds
    centre = (lo + hi) / 2.0
    radius = float(np.linalg.norm(mesh.vertices - centre, axis=1).max())
    if radius <= 0:
        raise JsrteError("mesh is degenerate (all vertices coincide)")
    return Normalization(centre=centre, scale=radius * padding)


def normalized(mesh: trimesh.Trimesh, norm: Normalization | None = None) -> trimesh.Trimesh:
    """A copy of ``mesh`` in the normalized canonical frame."""
    norm = norm or unit_sphere_normalization(mesh)
    return trimesh.Trimesh(norm.to_canonical(mesh.vertices), mesh.faces.copy(), process=False)


def save_mesh(mesh: trimesh.Trimesh, path: str | Path) -> None:
    """Write ``mesh`` atomically; the format follows the suffix."""
    write_with(path, lambda tmp: mesh.export(tmp))
