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

if TYPE_CHECKING:
    from jsrte.geometry.sim3 import Sim3

CLOUD_SUFFIXES = (".ply", ".pcd", ".xyz", ".xyzn", ".pts")
MESH_SUFFIXES = (".obj", ".off", ".stl")
"""Formats that are always meshes; a PLY is a mesh when its header declares faces."""


@dataclass(frozen=True)
class ScanCloud:
    """A scan as read from disk (scan units, normally metres).

    Attributes
    ----------
    points : (n, 3) float64
    normals : (n, 3) float64 unit vectors, or None when the file has none
    path : the file it came from (None when built in memory)
    """

    points: np.ndarray
    normals: np.ndarray | None = None
    path: Path | None = None


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
    if suffix not in CLOUD_SUFFIXES + MESH_SUFFIXES:
        known = ", ".join(CLOUD_SUFFIXES + MESH_SUFFIXES)
        raise JsrteError(f"unsupported scan format {path.suffix!r} (use {known})", path)
    rng = rng if rng is not None else np.random.default_rng(0)
    if suffix == ".ply":
        check_ply_complete(path)
    elif suffix == ".pcd":
        check_pcd_complete(path)
    if suffix in MESH_SUFFIXES or (suffix == ".ply" and _ply_face_count(path) > 0):
        points, normals = _read_mesh(path, dense_points, rng)
    else:
        points, normals = _read_cloud(path)
    return _checked(points, normals, path)


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


def _ply_face_count(path: Path) -> int:
    """Number of faces a PLY header declares (0 for a point cloud)."""
    return sum(count for name, count, _, _ in ply_header(path)[1] if name == "face")


PLY_SIZES = {"char": 1, "uchar": 1, "int8": 1, "uint8": 1, "short": 2, "ushort": 2, "int16": 2, "uint16": 2,
             "int": 4, "uint": 4, "int32": 4, "uint32": 4, "float": 4, "float32": 4, "double": 8, "float64": 8}
"""Bytes of each PLY scalar type."""
MAX_HEADER_LINES = 500


def ply_header(path: Path) -> tuple[str, list[tuple[str, int, int | None, list[str]]], int]:
    """(format, elements, header bytes) of a PLY file; each element is (name, count, bytes per
    item or None when it has a list property, property names). JsrteError naming the file if
    malformed, or if its vertices lack x, y or z or have only some of nx, ny, nz."""
    elements: list[tuple[str, int, int | None, list[str]]] = []
    fmt = None
    with path.open("rb") as f:
        if f.readline().strip() != b"ply":
            raise JsrteError("not a PLY file (no 'ply' magic line)", path)
        for _ in range(MAX_HEADER_LINES):
            line = f.readline()
            if not line:
                break
            words = line.decode("ascii", errors="replace").split()
            if words == ["end_header"]:
                if fmt is None:
                    raise JsrteError("malformed PLY header (no format line)", path)
                _check_fields(dict((e[0], e[3]) for e in elements).get("vertex"), ("nx", "ny", "nz"), path)
                return fmt, elements, f.tell()
            if not words or words[0] in ("comment", "obj_info"):
                continue
            if words[0] == "format" and len(words) >= 2:
                fmt = words[1]
            elif words[0] == "element" and len(words) == 3:
                elements.append((words[1], _element_count(words[2], path), 0, []))
            elif words[0] == "property" and elements and len(words) >= 3:
                name, count, size, names = elements[-1]
                item = PLY_SIZES.get(words[1]) if len(words) == 3 else None
                if len(words) == 3 and item is None:
                    raise JsrteError(f"malformed PLY header (unknown property type {words[1]!r})", path)
                elements[-1] = (name, count, None if size is None or item is None else size + item,
                                names + [words[-1]])
            else:
                raise JsrteError(f"malformed PLY header (line {' '.join(words)[:40]!r})", path)
    raise JsrteError("malformed PLY header (no end_header)", path)


def _check_fields(names: list[str] | None, normals: tuple[str, str, str], path: Path) -> None:
    """JsrteError unless the point fields ``names`` hold x, y and z, and all or none of ``normals``."""
    if names is None:
        return
    missing = [axis for axis in ("x", "y", "z") if axis not in names]
    if missing:
        raise JsrteError(f"the points have no {', '.join(missing)} coordinate (fields: {' '.join(names)[:80]})",
                         path)
    present = [n for n in normals if n in names]
    if present and len(present) != 3:
        raise JsrteError(f"the points have normal components {', '.join(present)} but not all three", path)


def _element_count(text: str, path: Path) -> int:
    try:
        count = int(text)
    except ValueError:
        count = -1
    if count < 0:
        raise JsrteError(f"malformed PLY header (element count {text[:20]!r})", path)
    return count


def check_ply_complete(path: Path) -> None:
    """JsrteError if the PLY file is shorter than its header declares (a truncated download or
    copy): Open3D would return the missing points as zeros or garbage.

    Elements up to the first one with a list property (faces) are counted exactly: bytes for a
    binary file, data lines for an ASCII one.
    """
    fmt, elements, header_bytes = ply_header(path)
    counted, items, size = [], 0, 0
    for name, count, item_bytes, _ in elements:
        if item_bytes is None:
            break
        counted.append(f"{count} {name}")
        items += count
        size += count * item_bytes
    if fmt not in ("ascii", "binary_little_endian", "binary_big_endian"):
        raise JsrteError(f"malformed PLY header (unknown format {fmt[:30]!r})", path)
    if not counted:
        return
    if fmt == "ascii":
        with path.open("rb") as f:
            f.seek(header_bytes)
            lines = sum(1 for line in f if line.strip())
        if lines < items:
            raise JsrteError(f"truncated: the header declares {', '.join(counted)} ({items} data lines), the "
                             f"file has {lines}", path)
        return
    actual = path.stat().st_size - header_bytes
    if actual < size:
        raise JsrteError(f"truncated: the header declares {', '.join(counted)} ({size} bytes of data), the "
                         f"file has {actual}", path)


PCD_ITEM = {"1": 1, "2": 2, "4": 4, "8": 8}
MAX_PCD_COUNT = 4096
"""Largest COUNT of a PCD field (descriptors have tens to hundreds; Open3D allocates what it says)."""
PCD_POINT_FIELDS = ("x", "y", "z", "normal_x", "normal_y", "normal_z")
"""Bytes of a PCD field by its SIZE entry."""


def check_pcd_complete(path: Path) -> None:
    """JsrteError if an uncompressed PCD file is shorter than its header's POINTS declare."""
    fields: dict[str, list[str]] = {}
    with path.open("rb") as f:
        for _ in range(MAX_HEADER_LINES):
            line = f.readline()
            if not line:
                return  # no DATA line: Open3D finds no points, reported as such
            words = line.decode("ascii", errors="replace").split()
            if words and not words[0].startswith("#"):
                fields[words[0].upper()] = words[1:]
                if words[0].upper() == "DATA":
                    break
        header_bytes = f.tell()
        try:
            points = int(fields["POINTS"][0])
            width, height = int(fields["WIDTH"][0]), int(fields["HEIGHT"][0])
            sizes = [PCD_ITEM[s] for s in fields["SIZE"]]
            counts = [int(c) for c in fields.get("COUNT", ["1"] * len(sizes))]
            types = fields["TYPE"]
            names = fields["FIELDS"]
            data = fields["DATA"][0].lower()
        except (KeyError, IndexError, ValueError):
            raise JsrteError("malformed PCD header (FIELDS, SIZE, TYPE, COUNT, WIDTH, HEIGHT, POINTS or DATA)",
                             path) from None
        if not len(names) == len(types) == len(counts) == len(sizes) or points < 0 or min(counts, default=1) < 0:
            raise JsrteError("malformed PCD header (FIELDS, SIZE, TYPE and COUNT disagree)", path)
        if width < 0 or height < 0 or width * height != points:
            raise JsrteError(f"malformed PCD header (WIDTH {width} x HEIGHT {height} is not POINTS {points})", path)
        if any(not 1 <= c <= MAX_PCD_COUNT for c in counts) or any(
                c != 1 for n, c in zip(names, counts, strict=True) if n in PCD_POINT_FIELDS):
            raise JsrteError(f"malformed PCD header (COUNT {' '.join(map(str, counts))[:60]})", path)
        if any(t not in ("F", "I", "U") for t in types):
            raise JsrteError(f"malformed PCD header (TYPE {' '.join(types)[:40]})", path)
        _check_fields(names, ("normal_x", "normal_y", "normal_z"), path)
        if data == "ascii":
            lines = sum(1 for line in f if line.strip())
            if lines < points:
                raise JsrteError(f"truncated: the header declares {points} points, the file has {lines} lines",
                                 path)
        elif data == "binary":
            need = points * sum(s * c for s, c in zip(sizes, counts, strict=True))
            actual = path.stat().st_size - header_bytes
            if actual < need:
                raise JsrteError(f"truncated: the header declares {points} points ({need} bytes), the file has "
                                 f"{actual}", path)


def _read_cloud(path: Path) -> tuple[np.ndarray, np.ndarray | None]:
    import open3d as o3d

    with o3d.utility.VerbosityContextManager(o3d.utility.VerbosityLevel.Error):
        try:
            cloud = o3d.io.read_point_cloud(str(path))
        except Exception as exc:  # Open3D raises RuntimeError on some broken files
            raise JsrteError(f"cannot read point cloud ({exc})", path) from exc
    points = np.asarray(cloud.points, dtype=np.float64)
    normals = np.asarray(cloud.normals, dtype=np.float64) if cloud.has_normals() else None
    if len(points) == 0 and path.suffix.lower() in (".xyz", ".xyzn", ".pts"):
        return _read_text_rows(path), None  # e.g. a PTS file without its count line
    return points, normals


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


def _checked(points: np.ndarray, normals: np.ndarray | None, path: Path) -> ScanCloud:
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
        normals = np.asarray(normals, dtype=np.float64).reshape(-1, 3)
        length = np.linalg.norm(normals, axis=1)
        if len(normals) != len(points) or not np.all(np.isfinite(normals)) or np.any(length < 1e-9):
            normals = None  # unusable normals are re-estimated downstream
        else:
            normals = normals / length[:, None]
    return ScanCloud(points=points, normals=normals, path=path)
