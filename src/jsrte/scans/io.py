"""Loading real scans: point clouds (PLY/PCD/XYZ/PTS) and Redwood-style meshes (PLY/OBJ).

A mesh gives its vertices and vertex normals; a sparse mesh is also sampled densely on its
surface (the paper builds its SDF samples from "the set of vertices on the densely sampled
meshes"). The JSON a virtual scan writes beside its PLY is read by :func:`read_scan_info`.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from jsrte.errors import JsrteError
from jsrte.formats import (
    SCAN_CLOUD_SUFFIXES,
    SCAN_MESH_SUFFIXES,
    check_pcd_complete,
    check_ply_complete,
    ply_face_count,
)

if TYPE_CHECKING:
    from jsrte.geometry.sim3 import Sim3



@dataclass(frozen=True)
class ScanCloud:
    """A scan as read from disk (scan units, normally metres).

    Attributes
    ----------
    points : (n, 3) float64
    normals : (n, 3) float64 unit vectors, or None when the file has none
    path : the file it came from (None when built in memory)
    view : (n,) int64 index of the camera (depth image) that saw each point, an index into
        the scan's cameras (the PLY vertex property ``view``), or None when unknown
    """

    points: np.ndarray
    normals: np.ndarray | None = None
    path: Path | None = None
    view: np.ndarray | None = None


@dataclass(frozen=True)
class ScanInfo:
    """What a virtual scan's JSON records (ground truth for experiments).

    Attributes
    ----------
    scan_from_mesh : Sim3, input-mesh coordinates to scan metres
    up : (3,) float64, the floor normal
    floor_offset : float, the floor is ``up . x = floor_offset``
    cameras : (k, 3) float64, camera centres
    raw : the whole JSON object
    """

    scan_from_mesh: Sim3
    up: np.ndarray
    floor_offset: float
    cameras: np.ndarray
    raw: dict[str, Any]


def load_scan(
    path: str | Path, *, dense_points: int = 50_000, rng: np.random.Generator | None = None
) -> ScanCloud:
    """Read a point cloud or a mesh as a :class:`ScanCloud`.

    Parameters
    ----------
    path : a PLY/PCD/XYZ/XYZN/PTS point cloud, or a PLY/OBJ/OFF/STL mesh
    dense_points : a mesh with fewer vertices than this is also sampled on its surface
        until it has this many points (face normals at the samples)
    rng : randomness of that sampling (default: seeded 0, so loading is reproducible)

    Raises ``JsrteError`` naming the file when it is missing, of an unknown format,
    unreadable, empty, or holds NaN/infinite coordinates.
    """
    path = Path(path)
    if path.is_dir():
        raise JsrteError("is a folder, not a scan file", path)
    if not path.is_file():
        raise JsrteError("no such file", path)
    if path.stat().st_size == 0:
        raise JsrteError("file is empty", path)
    suffix = path.suffix.lower()
    if suffix not in SCAN_CLOUD_SUFFIXES + SCAN_MESH_SUFFIXES:
        known = ", ".join(SCAN_CLOUD_SUFFIXES + SCAN_MESH_SUFFIXES)
        raise JsrteError(f"unsupported scan format {path.suffix!r} (use {known})", path)
    rng = rng if rng is not None else np.random.default_rng(0)
    if suffix == ".ply":
        check_ply_complete(path)
    elif suffix == ".pcd":
        check_pcd_complete(path)
    view = None
    if suffix in SCAN_MESH_SUFFIXES or (suffix == ".ply" and ply_face_count(path) > 0):
        points, normals = _read_mesh(path, dense_points, rng)
    else:
        points, normals, view = _read_cloud(path)
    return _checked(points, normals, path, view)


def read_scan_info(ply_path: str | Path) -> ScanInfo | None:
    """The JSON a virtual scan wrote beside ``ply_path`` (``<stem>.json``), or None if absent."""
    from jsrte.geometry.sim3 import Sim3

    json_path = Path(ply_path).with_suffix(".json")
    if not json_path.is_file():
        return None
    try:
        raw = json.loads(json_path.read_text())
        return ScanInfo(
            scan_from_mesh=Sim3.from_dict(raw["scan_from_mesh"]),
            up=np.asarray(raw["up"], dtype=np.float64),
            floor_offset=float(raw["floor"]["offset"]),
            cameras=np.asarray(raw["cameras"], dtype=np.float64).reshape(-1, 3),
            raw=raw,
        )
    except (ValueError, KeyError, TypeError) as exc:
        raise JsrteError(f"not a scan description ({type(exc).__name__}: {exc})", json_path) from exc


def _read_cloud(path: Path) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]:
    """Points (n, 3), normals (n, 3) or None and camera indices (n,) or None of a point-cloud
    file: PLY by :func:`jsrte.scans.ply.read_ply_scan`, the other formats (and PLY layouts it
    leaves) by Open3D, imported only for them (no camera indices)."""
    if path.suffix.lower() == ".ply":
        from jsrte.scans.ply import read_ply_scan

        read = read_ply_scan(path)
        if read is not None:
            return read
    import open3d as o3d

    with o3d.utility.VerbosityContextManager(o3d.utility.VerbosityLevel.Error):
        try:
            cloud = o3d.io.read_point_cloud(str(path))
        except Exception as exc:  # Open3D raises RuntimeError on some broken files
            raise JsrteError(f"cannot read point cloud ({exc})", path) from exc
    points = np.asarray(cloud.points, dtype=np.float64)
    normals = np.asarray(cloud.normals, dtype=np.float64) if cloud.has_normals() else None
    if len(points) == 0 and path.suffix.lower() in (".xyz", ".xyzn", ".pts"):
        return _read_text_rows(path), None, None  # e.g. a PTS file without its count line
    return points, normals, None


def _read_text_rows(path: Path, prefix: str | None = None) -> np.ndarray:
    """x y z of every text line holding at least three numbers (after ``prefix``, if given)."""
    rows = []
    with path.open("r", errors="replace") as f:
        for line in f:
            words = line.split()
            if prefix is not None:
                if not words or words[0] != prefix:
                    continue
                words = words[1:]
            if len(words) < 3:
                continue
            try:
                rows.append([float(w) for w in words[:3]])
            except ValueError:
                continue
    return np.array(rows, dtype=np.float64).reshape(-1, 3)


def _read_mesh(path: Path, dense_points: int, rng: np.random.Generator
               ) -> tuple[np.ndarray, np.ndarray | None]:
    import trimesh

    try:
        loaded = trimesh.load(path, force="mesh", process=False)
    except Exception as exc:  # trimesh raises many types for broken files
        raise JsrteError(f"cannot read mesh ({type(exc).__name__}: {exc})", path) from exc
    if isinstance(loaded, trimesh.PointCloud):
        return np.asarray(loaded.vertices, dtype=np.float64), None
    if not isinstance(loaded, trimesh.Trimesh) or len(loaded.faces) == 0:
        if path.suffix.lower() == ".obj":  # vertices only: a point cloud
            return _read_text_rows(path, prefix="v"), None
        raise JsrteError("holds no triangles and no points", path)
    from jsrte.geometry.mesh import check_face_indices

    check_face_indices(loaded, path)
    vertices = np.asarray(loaded.vertices, dtype=np.float64)
    if not np.all(np.isfinite(vertices)):
        raise JsrteError("has NaN or infinite coordinates", path)
    used = np.unique(loaded.faces)  # unreferenced vertices have no normal
    points, normals = vertices[used], np.asarray(loaded.vertex_normals, dtype=np.float64)[used]
    missing = dense_points - len(points)
    if missing > 0 and loaded.area > 0:
        seed = int(rng.integers(2**31))
        samples, face = trimesh.sample.sample_surface(loaded, missing, seed=seed)
        points = np.concatenate([points, samples])
        normals = np.concatenate([normals, loaded.face_normals[face]])
    return points, normals


def _checked(points: np.ndarray, normals: np.ndarray | None, path: Path,
             view: np.ndarray | None = None) -> ScanCloud:
    points = np.asarray(points, dtype=np.float64)
    if points.size == 0:
        points = points.reshape(0, 3)
    if points.ndim != 2 or points.shape[1] != 3:
        raise JsrteError(f"holds points of shape {points.shape}, not 3D points", path)
    if len(points) == 0:
        raise JsrteError("holds no points (empty or unreadable point cloud)", path)
    bad = ~np.all(np.isfinite(points), axis=1)
    if bad.any():
        raise JsrteError(f"has {int(bad.sum())} points with NaN or infinite coordinates", path)
    if normals is not None:
        normals = _unit_normals(np.asarray(normals, dtype=np.float64).reshape(-1, 3), len(points))
    if view is not None and (len(view) != len(points) or (len(view) and view.min() < 0)):
        raise JsrteError(f"has {len(view)} camera indices ('view') for {len(points)} points, "
                         "or a negative one", path)
    return ScanCloud(points=points, normals=normals, path=path, view=view)


def _unit_normals(normals: np.ndarray, count: int) -> np.ndarray | None:
    """(count, 3) unit normals, or None where they are unusable (re-estimated downstream): another
    count, a NaN or infinite component, or a length that is zero or too large to compute."""
    if len(normals) != count or not np.all(np.isfinite(normals)):
        return None
    with np.errstate(over="ignore"):
        length = np.linalg.norm(normals, axis=1)
    if not np.all(np.isfinite(length)) or np.any(length < 1e-9):
        return None
    return normals / length[:, None]
