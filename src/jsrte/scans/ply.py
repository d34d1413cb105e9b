"""Reading and writing a PLY point cloud's vertices with NumPy (ASCII or binary, any numeric
property type).

Open3D reads the same, but importing it costs about half a second of a fit's start-up. A
layout this reader does not handle (a list property among or before the vertices of a binary
file) is left to Open3D: :func:`read_ply_cloud` returns None.

A scan may carry, per point, the index of the depth image (camera) that saw it: the integer
vertex property ``view`` (:data:`VIEW_PROPERTY`), an index into the cameras of the scan's JSON
sidecar. Readers that do not know it (Open3D, MeshLab) skip it.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from jsrte.errors import JsrteError
from jsrte.formats import ply_header

PLY_TYPES = {"char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1", "short": "i2", "int16": "i2",
             "ushort": "u2", "uint16": "u2", "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
             "float": "f4", "float32": "f4", "double": "f8", "float64": "f8"}
"""NumPy type of each PLY scalar type."""

VIEW_PROPERTY = "view"
"""Name of the optional per-point camera index (a PLY vertex property of integer type)."""

Element = tuple[str, int, list[tuple[str, str | None]]]
"""An element of a PLY header: name, count, and (name, NumPy type, None for a list) per property."""


def read_ply_cloud(path: Path) -> tuple[np.ndarray, np.ndarray | None] | None:
    """x, y, z (n, 3) float64 of the vertices of the PLY file ``path`` and their nx, ny, nz
    (n, 3) float64 when it has all three (else None); no vertex element: no points.

    None when a list property comes among the vertices, or before them in a binary file (left
    to Open3D). JsrteError naming the file if it cannot be read.
    """
    columns = read_ply_vertices(path)
    if columns is None:
        return None
    return _cloud_of(columns)


def read_ply_scan(path: Path) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None] | None:
    """As :func:`read_ply_cloud`, plus each point's camera index (n,) int64 when the vertices
    have the integer property ``view`` (else None)."""
    columns = read_ply_vertices(path)
    if columns is None:
        return None
    points, normals = _cloud_of(columns)
    view = columns.get(VIEW_PROPERTY)
    if view is None or not np.issubdtype(view.dtype, np.integer):
        return points, normals, None
    return points, normals, view.astype(np.int64)


def _cloud_of(columns: dict[str, np.ndarray]) -> tuple[np.ndarray, np.ndarray | None]:
    """Points (n, 3) and normals (n, 3) or None, float64, from a PLY's vertex columns."""
    if not columns:
        return np.zeros((0, 3)), None
    points = np.column_stack([columns[axis].astype(np.float64) for axis in ("x", "y", "z")])
    if not all(axis in columns for axis in ("nx", "ny", "nz")):
        return points, None
    return points, np.column_stack([columns[axis].astype(np.float64) for axis in ("nx", "ny", "nz")])


def read_ply_vertices(path: Path) -> dict[str, np.ndarray] | None:
    """Every vertex property of the PLY file ``path`` by name, each (n,) in its own NumPy type;
    {} when there is no vertex element. None when a list property
    comes among the vertices, or before them in a binary file. JsrteError naming the file if it
    cannot be read, or when the vertices lack x, y or z."""
    fmt, elements, header_bytes = _header(path)
    names = [name for name, _, _ in elements]
    if "vertex" not in names:
        return {}
    at = names.index("vertex")
    vertex_names = [name for name, _ in elements[at][2]]
    if any(kind is None for _, kind in elements[at][2]):
        return None  # a list property among the vertices
    try:
        if fmt == "ascii":
            columns = _ascii_vertices(path, header_bytes, elements, at)
        else:
            columns = _binary_vertices(path, header_bytes, elements, at, "<" if "little" in fmt else ">")
    except (ValueError, OSError) as exc:
        raise JsrteError(f"cannot read point cloud ({type(exc).__name__}: {exc})", path) from exc
    if columns is None:
        return None
    if not all(axis in vertex_names for axis in ("x", "y", "z")):
        raise JsrteError("the PLY vertices have no x, y, z", path)
    return dict(zip(vertex_names, columns, strict=True))


def write_ply_scan(path: Path, points: np.ndarray, normals: np.ndarray, colors: np.ndarray,
                   view: np.ndarray | None = None) -> None:
    """Write a binary little-endian PLY point cloud at ``path`` (not atomic: give a temporary
    path): x, y, z and nx, ny, nz as double ((n, 3) each), red, green, blue as uchar ((n, 3)
    uint8) and, if given, the camera index ``view`` (n,) as the int property ``view``."""
    fields = [(name, "<f8") for name in ("x", "y", "z", "nx", "ny", "nz")]
    fields += [(name, "u1") for name in ("red", "green", "blue")]
    if view is not None:
        fields.append((VIEW_PROPERTY, "<i4"))
    data = np.empty(len(points), dtype=np.dtype(fields))
    for k, axis in enumerate("xyz"):
        data[axis] = points[:, k]
        data["n" + axis] = normals[:, k]
    for k, channel in enumerate(("red", "green", "blue")):
        data[channel] = colors[:, k]
    if view is not None:
        data[VIEW_PROPERTY] = view
    types = {"<f8": "double", "u1": "uchar", "<i4": "int"}
    header = ["ply", "format binary_little_endian 1.0", "comment Created by jsrte",
              f"element vertex {len(points)}"]
    header += [f"property {types[kind]} {name}" for name, kind in fields]
    header.append("end_header")
    with open(path, "wb") as f:
        f.write(("\n".join(header) + "\n").encode("ascii"))
        f.write(data.tobytes())


def _header(path: Path) -> tuple[str, list[Element], int]:
    """(format, elements, header bytes) of a PLY file (:func:`jsrte.formats.ply_header`), each
    property with its NumPy type."""
    fmt, elements, header_bytes = ply_header(path)
    typed = [(name, count, [(p, PLY_TYPES[t] if t else None) for p, t in zip(names, types, strict=True)])
             for name, count, _, names, types in elements]
    return fmt, typed, header_bytes


def _ascii_vertices(path: Path, header_bytes: int, elements: list[Element], at: int) -> list[np.ndarray]:
    """The vertex properties' columns (each (n,): float64, integers in their own type) of an ASCII PLY file:
    one line per item of every element, the vertices after the items of the elements before them."""
    name, count, properties = elements[at]
    if count == 0:
        return [np.zeros(0, dtype=kind) for _, kind in properties]
    skip = sum(c for _, c, _ in elements[:at])
    with path.open("rb") as f:
        f.seek(header_bytes)
        rows = np.loadtxt(f, dtype=np.float64, comments=None, skiprows=skip, max_rows=count, ndmin=2)
    if rows.shape != (count, len(properties)):
        raise ValueError(f"{len(rows)} vertex lines of {rows.shape[1]} values, not {count} of {len(properties)}")
    return [column.astype(kind) if np.dtype(kind).kind in "iu" else column  # floats stay float64
            for column, (_, kind) in zip(rows.T, properties, strict=True)]


def _binary_vertices(path: Path, header_bytes: int, elements: list[Element], at: int,
                     order: str) -> list[np.ndarray] | None:
    """The vertex properties' columns (each (n,) in its file's type) of a binary PLY file, or
    None when a list property comes before them (items of varying size)."""
    before = [kind for _, _, properties in elements[: at + 1] for _, kind in properties]
    if None in before:
        return None
    skip = sum(c * np.dtype([(f"p{i}", order + k) for i, (_, k) in enumerate(p)]).itemsize
               for _, c, p in elements[:at])
    name, count, properties = elements[at]
    dtype = np.dtype([(f"p{i}", order + kind) for i, (_, kind) in enumerate(properties)])
    data = np.fromfile(path, dtype=dtype, count=count, offset=header_bytes + skip)
    if len(data) < count:
        raise ValueError(f"{len(data)} of {count} vertices")
    return [data[field].astype(data.dtype[field].newbyteorder("=")) for field in dtype.names]
