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

import re
import struct
from pathlib import Path
from typing import BinaryIO, Literal

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
    return sum(count for name, count, *_ in ply_header(path)[1] if name == "face")


PLY_SIZES = {"char": 1, "uchar": 1, "int8": 1, "uint8": 1, "short": 2, "ushort": 2, "int16": 2, "uint16": 2,
             "int": 4, "uint": 4, "int32": 4, "uint32": 4, "float": 4, "float32": 4, "double": 8, "float64": 8}
"""Bytes of each PLY scalar type."""
MAX_HEADER_LINES = 500


PlyElement = tuple[str, int, int | None, list[str], list[str | None]]
"""An element of a PLY header: name, count, bytes per item (None when it has a list property),
property names, and their scalar types (None for a list property)."""


def ply_header(path: Path) -> tuple[str, list[PlyElement], int]:
    """(format, elements, header bytes) of a PLY file (:data:`PlyElement`). JsrteError naming the
    file if malformed, or if its vertices lack x, y or z or have only some of nx, ny, nz."""
    elements: list[PlyElement] = []
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
                elements.append((words[1], _element_count(words[2], path), 0, [], []))
            elif words[0] == "property" and elements and len(words) >= 3:
                name, count, size, names, types = elements[-1]
                scalar = words[1] if len(words) == 3 else None
                item = PLY_SIZES.get(scalar) if scalar else None
                if scalar and item is None:
                    raise JsrteError(f"malformed PLY header (unknown property type {words[1]!r})", path)
                elements[-1] = (name, count, None if size is None or item is None else size + item,
                                names + [words[-1]], types + [scalar])
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
    for name, count, item_bytes, *_ in elements:
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
"""Bytes of a PCD field by its SIZE entry."""
MAX_PCD_COUNT = 4096
"""Largest COUNT of a PCD field (descriptors have tens to hundreds; Open3D allocates what it says)."""
PCD_POINT_FIELDS = ("x", "y", "z", "normal_x", "normal_y", "normal_z")
PCD_BINARY_READABLE = {("F", 4), ("I", 1), ("I", 2), ("I", 4), ("U", 1), ("U", 2), ("U", 4)}
"""(TYPE, SIZE) of the binary fields Open3D decodes (it returns 0 for the others, e.g. 8-byte floats)."""
PCD_KEYWORDS = ("VERSION", "FIELDS", "SIZE", "TYPE", "COUNT", "WIDTH", "HEIGHT", "VIEWPOINT", "POINTS", "DATA")
"""PCD header entries, in the order the format requires."""
PCD_DATA = ("ascii", "binary", "binary_compressed")
PCD_LINE_BYTES = 1023
"""Longest line of a PCD file Open3D reads at once (it reads a longer one as several lines)."""
MAX_PCD_INT = 2**31 - 1
"""Largest WIDTH, HEIGHT or POINTS Open3D holds (a C int)."""
LZF_MAX_RATIO = 88
"""LZF (binary_compressed) expands data at most 88-fold (3 bytes into 264)."""
_PCD_TEXT = re.compile(rb"[\t\n\r\x20-\x7e]*")
_PCD_WORD = re.compile(rb"[^\t\n\r ]+")
"""A word of a PCD data line, as Open3D splits it."""


def pcd_header(f: BinaryIO, path: Path) -> dict[str, list[str]]:
    """Entries (keyword -> values) of the header of the PCD file ``f``, open at its start; ``f`` is
    left at the first byte of data. Lines are read as Open3D reads them.

    JsrteError naming the file for a header Open3D would read otherwise than it is written (it
    matches keywords by prefix and case, stops at the first line starting ``DATA``, and leaves an
    entry it cannot read unset, then sizes its arrays from whatever number that memory held): an
    unknown, repeated or out-of-order entry, a control or non-ASCII byte, no DATA line.
    """
    entries: dict[str, list[str]] = {}
    for _ in range(MAX_HEADER_LINES):
        line = f.readline(PCD_LINE_BYTES)
        if not line:
            break
        words = line.split()
        if not words or words[0].startswith(b"#"):
            continue
        text = line.decode("ascii", errors="replace").strip()
        if not _PCD_TEXT.fullmatch(line):
            raise JsrteError(f"malformed PCD header (a control or non-ASCII byte in line {text[:20]!r})", path)
        key = words[0].decode()
        if key not in PCD_KEYWORDS:
            raise JsrteError(f"malformed PCD header (line {text[:40]!r})", path)
        last = next(reversed(entries), None)
        if last is not None and PCD_KEYWORDS.index(key) <= PCD_KEYWORDS.index(last):
            raise JsrteError(f"malformed PCD header ({key} after {last}; the order is {' '.join(PCD_KEYWORDS)})",
                             path)
        entries[key] = [w.decode() for w in words[1:]]
        if key == "DATA":
            return entries
    raise JsrteError("malformed PCD header (no DATA line)", path)


def _pcd_int(text: str) -> int:
    """A WIDTH, HEIGHT, POINTS or COUNT value: decimal digits only (as Open3D reads them), at most a C int."""
    if not text.isascii() or not text.isdigit() or int(text) > MAX_PCD_INT:
        raise ValueError(text)
    return int(text)


def _pcd_layout(entries: dict[str, list[str]], path: Path) -> tuple[int, int, int, str]:
    """(points, values per point, bytes per point, data kind) of a PCD header; JsrteError naming the
    file if absurd."""
    try:
        points = _pcd_int(entries["POINTS"][0])
        width, height = _pcd_int(entries["WIDTH"][0]), _pcd_int(entries["HEIGHT"][0])
        sizes = [PCD_ITEM[s] for s in entries["SIZE"]]
        counts = [_pcd_int(c) for c in entries.get("COUNT", ["1"] * len(sizes))]
        types = entries["TYPE"]
        names = entries["FIELDS"]
        data = entries["DATA"][0]
    except (KeyError, IndexError, ValueError):
        raise JsrteError("malformed PCD header (FIELDS, SIZE, TYPE, COUNT, WIDTH, HEIGHT, POINTS or DATA)",
                         path) from None
    if not len(names) == len(types) == len(counts) == len(sizes):
        raise JsrteError("malformed PCD header (FIELDS, SIZE, TYPE and COUNT disagree)", path)
    if width * height != points:
        raise JsrteError(f"malformed PCD header (WIDTH {width} x HEIGHT {height} is not POINTS {points})", path)
    if any(not 1 <= c <= MAX_PCD_COUNT for c in counts) or any(
            c != 1 for n, c in zip(names, counts, strict=True) if n in PCD_POINT_FIELDS):
        raise JsrteError(f"malformed PCD header (COUNT {' '.join(map(str, counts))[:60]})", path)
    if any(t not in ("F", "I", "U") for t in types):
        raise JsrteError(f"malformed PCD header (TYPE {' '.join(types)[:40]})", path)
    if data not in PCD_DATA:
        raise JsrteError(f"malformed PCD header (DATA {data[:30]!r}; use {', '.join(PCD_DATA)})", path)
    _check_fields(names, ("normal_x", "normal_y", "normal_z"), path)
    unreadable = [f"{n} ({t} {s})" for n, t, s in zip(names, types, sizes, strict=True)
                  if n in PCD_POINT_FIELDS and (t, s) not in PCD_BINARY_READABLE]
    if data != "ascii" and unreadable:
        raise JsrteError(f"binary PCD fields {', '.join(unreadable)[:60]} are not readable (Open3D reads them as "
                         "0); store coordinates and normals as 4-byte floats (TYPE F, SIZE 4)", path)
    return points, sum(counts), sum(s * c for s, c in zip(sizes, counts, strict=True)), data


def check_pcd_complete(path: Path) -> None:
    """JsrteError naming the file if a PCD file's header is malformed or read otherwise by Open3D
    (see :func:`pcd_header`), or the file holds fewer points than its header declares: Open3D
    allocates the declared points before reading them and leaves those it does not find as
    whatever the memory held."""
    with path.open("rb") as f:
        points, values, point_bytes, data = _pcd_layout(pcd_header(f, path), path)
        header_bytes = f.tell()
        if data == "ascii":
            rows = _pcd_text_rows(f, values)
            if rows < points:
                raise JsrteError(f"truncated: the header declares {points} points of {values} values, the file "
                                 f"has {rows} lines with {values} values", path)
            return
        actual = path.stat().st_size - header_bytes
        if data == "binary":
            if actual < points * point_bytes:
                raise JsrteError(f"truncated: the header declares {points} points ({points * point_bytes} bytes), "
                                 f"the file has {actual}", path)
            return
        _check_pcd_compressed(f.read(8), actual - 8, points * point_bytes, path)


def _pcd_text_rows(f: BinaryIO, values: int) -> int:
    """Lines of ASCII PCD data that Open3D reads as points: lines (of at most 1023 bytes, up to a
    zero byte) holding at least ``values`` words; it skips the others."""
    rows = 0
    while line := f.readline(PCD_LINE_BYTES):
        rows += len(_PCD_WORD.findall(line.split(b"\0", 1)[0])) >= values
    return rows


def _check_pcd_compressed(sizes: bytes, actual: int, need: int, path: Path) -> None:
    """JsrteError unless the 8 bytes ``sizes`` opening binary_compressed data (compressed and
    uncompressed bytes, little-endian uint32) fit ``actual`` bytes of compressed data and hold the
    ``need`` bytes the header declares."""
    if len(sizes) < 8:
        raise JsrteError("truncated: binary_compressed data without its sizes", path)
    compressed, uncompressed = struct.unpack("<II", sizes)
    if compressed > actual:
        raise JsrteError(f"truncated: the compressed data is {compressed} bytes, the file has {actual}", path)
    if uncompressed < need or uncompressed > LZF_MAX_RATIO * compressed:
        raise JsrteError(f"malformed PCD data ({compressed} compressed bytes cannot hold the {need} bytes the "
                         f"header declares, or the {uncompressed} bytes they claim)", path)
