"""What fit-many works on: the scans of a folder or a list file, their result-folder names, and
the ground truth a virtual scan's JSON points to."""

from __future__ import annotations

import json
from collections import Counter
from dataclasses import dataclass
from pathlib import Path

from jsrte.errors import JsrteError
from jsrte.formats import INPUT_SUFFIXES

LIST_SUFFIX = ".txt"


@dataclass(frozen=True)
class TruthRef:
    """Where the truth of a virtual scan lies.

    Attributes
    ----------
    mesh : the true mesh file (its own frame)
    scan_from_mesh : the ``Sim3.to_dict()`` of the true pose, mesh frame to scan metres
    """

    mesh: Path
    scan_from_mesh: dict


def list_scans(source: str | Path) -> list[Path]:
    """The scans to fit: a folder's scan files (not its subfolders; sorted by name), or the
    paths in a ``.txt`` list, one a line (relative to the list's folder; blank lines and ``#``
    comments skipped; listed files need not exist: a missing one is a failed scan)."""
    source = Path(source)
    if source.is_dir():
        scans = sorted(p for p in source.iterdir() if p.is_file() and p.suffix.lower() in INPUT_SUFFIXES)
        if not scans:
            raise JsrteError(f"holds no scans ({', '.join(INPUT_SUFFIXES)})", source)
        return scans
    if not source.is_file():
        raise JsrteError("no such folder or list file", source)
    if source.suffix.lower() != LIST_SUFFIX:
        raise JsrteError(f"give a folder of scans or a {LIST_SUFFIX} list of scan paths", source)
    try:
        lines = source.read_text().splitlines()
    except (OSError, UnicodeDecodeError) as exc:
        raise JsrteError(f"cannot read the list ({exc})", source) from exc
    scans = []
    for line in lines:
        text = line.strip()
        if text and not text.startswith("#"):
            path = Path(text).expanduser()
            scans.append(path if path.is_absolute() else source.parent / path)
    if not scans:
        raise JsrteError("lists no scans", source)
    return scans


def result_names(scans: list[Path]) -> list[str]:
    """One result-folder name per scan: its stem; stems that collide get the suffix appended
    (``a.ply`` -> ``a_ply``), then a counter. Deterministic in the order of ``scans``."""
    stems = Counter(p.stem for p in scans)
    names = [p.stem if stems[p.stem] == 1 else f"{p.stem}_{p.suffix.lstrip('.').lower()}" for p in scans]
    counts, seen = Counter(names), Counter()
    unique = []
    for name in names:
        seen[name] += 1
        unique.append(name if counts[name] == 1 else f"{name}_{seen[name]}")
    return unique


def find_truth(scan: Path) -> TruthRef | None:
    """The truth of a virtual scan: its ``<stem>.json`` (true pose) and the mesh its ``"mesh"``
    field names (absolute, else relative to the JSON's folder or the working folder); None when
    either is missing or the JSON is not a scan description."""
    info_path = scan.with_suffix(".json")
    if not info_path.is_file():
        return None
    try:
        raw = json.loads(info_path.read_text())
        pose, mesh_field = raw["scan_from_mesh"], raw.get("mesh")
    except (OSError, ValueError, KeyError, TypeError):
        return None
    if not isinstance(mesh_field, str) or not isinstance(pose, dict):
        return None
    mesh = Path(mesh_field).expanduser()
    candidates = [mesh] if mesh.is_absolute() else [info_path.parent / mesh, Path.cwd() / mesh]
    for candidate in candidates:
        if candidate.is_file():
            return TruthRef(mesh=candidate, scan_from_mesh=pose)
    return None
