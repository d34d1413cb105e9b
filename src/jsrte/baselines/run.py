"""Run a baseline on a file, prepared exactly as ``jsrte fit`` prepares it."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from jsrte.baselines import get_baseline
from jsrte.baselines.database import ShapeDatabase
from jsrte.result import FitResult

MESH_SURFACE_POINTS = 20_000
"""Points sampled on a complete-mesh query (``jsrte fit`` uses as many surface points)."""


@dataclass(frozen=True)
class BaselineQuery:
    """A query's object points as the baselines take them.

    Attributes
    ----------
    points : (n, 3) float64, scan units (metres)
    normals : (n, 3) float64, outward unit normals
    up : (3,) float64, the known up axis
    info : what it came from (JSON-ready)
    """

    points: np.ndarray
    normals: np.ndarray
    up: np.ndarray
    info: dict[str, Any] = field(default_factory=dict)


def load_baseline_query(path: str | Path, *, rng: np.random.Generator, up: np.ndarray | None = None
                        ) -> BaselineQuery:
    """Read a scan or a complete mesh as ``jsrte fit`` does.

    Scans (PLY/PCD/XYZ/XYZN/PTS point clouds or scan meshes): :func:`jsrte.scans.io.load_scan`
    then :func:`jsrte.scans.preprocess.prepare_scan` (floor removal, clustering, outliers, hidden
    points from the cameras a virtual scan records; the floor normal is the up axis unless ``up``
    is given). Complete meshes (OBJ/OFF/STL/GLB/GLTF): surface samples with face normals, up
    ``up`` or +y.
    """
    from jsrte.formats import input_kind

    path = Path(path)
    if input_kind(path, accept=("scan", "mesh")) == "mesh":
        return _mesh_query(path, rng, up)
    return _scan_query(path, rng, up)


def _scan_query(path: Path, rng: np.random.Generator, up: np.ndarray | None) -> BaselineQuery:
    from jsrte.scans.io import load_scan, read_scan_info
    from jsrte.scans.preprocess import prepare_scan

    cloud = load_scan(path, rng=rng)
    info = read_scan_info(path) if path.suffix.lower() == ".ply" else None
    viewpoints = info.cameras if info is not None and len(info.cameras) else None
    prepared = prepare_scan(cloud, rng=rng, up=up, viewpoints=viewpoints)
    return BaselineQuery(prepared.points, prepared.normals, np.asarray(prepared.up, dtype=np.float64),
                         {"input": "scan", "scan_points": len(cloud.points),
                          "object_points": len(prepared.points), "floor_found": prepared.floor is not None})


def _mesh_query(path: Path, rng: np.random.Generator, up: np.ndarray | None) -> BaselineQuery:
    import trimesh

    from jsrte.geometry.mesh import load_mesh

    mesh = load_mesh(path)
    points, faces = trimesh.sample.sample_surface(mesh, MESH_SURFACE_POINTS, seed=int(rng.integers(2**31)))
    axis = np.array([0.0, 1.0, 0.0]) if up is None else np.asarray(up, dtype=np.float64)
    return BaselineQuery(np.asarray(points, dtype=np.float64), np.asarray(mesh.face_normals[faces]),
                         axis / np.linalg.norm(axis), {"input": "mesh", "object_points": len(points)})


def run_baseline(name: str, query: BaselineQuery, database: ShapeDatabase, *, seed: int = 0,
                 progress: bool = False) -> FitResult:
    """Run baseline ``name`` on a prepared query against ``database``; raises ``BaselineFailed``."""
    options: dict[str, Any] = {"progress": progress} if name == "pointnet-icp" else {}
    baseline = get_baseline(name, **options)
    result = baseline.fit(query.points, query.normals, query.up, database, rng=np.random.default_rng(seed))
    result.info.update(query=query.info, up=query.up.tolist(), seed=seed)
    return result
