"""The input formats jsrte reads, in one place, and how a file is told to be one of them.

Every command that takes a scan, a mesh or SDF samples asks :func:`input_kind` what the file
is, so the lists below are the only lists of supported formats:

- **scans** (:data:`SCAN_SUFFIXES`): point clouds (PLY/PCD/XYZ/XYZN/PTS) or scan meshes (a PLY
  whose header declares faces); metres, any pose, a floor usually in view;
- **complete meshes** (:data:`MESH_SUFFIXES`): OBJ/OFF/STL/GLB/GLTF, a whole object's surface;
- **npz** files: SDF samples (``jsrte sample``) or prepared queries (``jsrte prepare``).

Also here: the header checks that refuse a truncated or malformed PLY/PCD file before a reader
library returns zeros or garbage for the points it never read.
"""

from __future__ import annotations

from pathlib import Path
from typing import Literal

from jsrte.errors import JsrteError

SCAN_CLOUD_SUFFIXES = (".ply", ".pcd", ".xyz", ".xyzn", ".pts")
"""Point-cloud scans (a PLY with faces is a scan mesh)."""
SCAN_MESH_SUFFIXES = (".obj", ".off", ".stl")
"""Meshes ``jsrte.scans.io.load_scan`` reads as a scan (Redwood-style); ``jsrte fit`` takes them as complete meshes."""
SCAN_SUFFIXES = SCAN_CLOUD_SUFFIXES
"""Files ``jsrte fit`` treats as scans."""
MESH_SUFFIXES = (".obj", ".off", ".stl", ".glb", ".gltf")
"""Files ``jsrte fit`` treats as complete meshes."""
MESH_FILE_SUFFIXES = (".obj", ".ply", ".off", ".stl", ".glb", ".gltf")
"""Files :func:`jsrte.geometry.mesh.load_mesh` reads (training meshes, truth meshes)."""
MESH_OUTPUT_SUFFIXES = (".ply", ".obj", ".off", ".stl", ".glb")
"""Mesh files jsrte writes (``decode --out``)."""
NPZ_SUFFIX = ".npz"
INPUT_SUFFIXES = SCAN_SUFFIXES + MESH_SUFFIXES + (NPZ_SUFFIX,)
"""Everything ``jsrte fit``, ``prepare`` and ``fit-many`` take."""

InputKind = Literal["scan", "mesh", "npz"]


def input_kind(path: str | Path, *, accept: tuple[InputKind, ...] = ("scan", "mesh", "npz")) -> InputKind:
    """What ``path`` is by its suffix; JsrteError naming the file when it is missing, a folder,
    or of a format not in ``accept``."""
    path = Path(path)
    if path.is_dir():
        raise JsrteError("is a folder; give a scan, mesh or .npz file (fit-many fits a folder)", path)
    if not path.exists():
        raise JsrteError("no such file", path)
    suffix = path.suffix.lower()
    kind: InputKind | None = ("scan" if suffix in SCAN_SUFFIXES else "mesh" if suffix in MESH_SUFFIXES
                              else "npz" if suffix == NPZ_SUFFIX else None)
    if kind not in accept:
        known = ", ".join(s for k, group in (("scan", SCAN_SUFFIXES), ("mesh", MESH_SUFFIXES),
                                             ("npz", (NPZ_SUFFIX,))) if k in accept for s in group)
        raise JsrteError(f"unsupported input {path.suffix!r} (use {known})", path)
    return kind


def ply_face_count(path: Path) -> int:
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
