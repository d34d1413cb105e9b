"""What there is to look at: fit folders, ``fit-many`` outputs, scenes and ``.jsrte`` codes.

:func:`find_fits` says what a path holds (cheaply: no mesh is read), :func:`load_item` reads one
fit's geometry and numbers. A fit whose files are partly missing or corrupt still loads: what
could not be read is left out and named in :attr:`FitItem.problems`, one line each, so the
others can still be shown.

Layouts understood::

    FIT/fit.json, shape.ply, overlay.png                      (jsrte fit)
    OUT/<name>/fit.json ..., OUT/summary.csv                  (jsrte fit-many: a batch)
    SCENE/scene.json, SCENE/objects/<NN>/fit.json ...         (a scene: one fit per object, and
                                                              its boxes' cuboids in scene.json)
    CODE.jsrte                                                (jsrte encode: a shape code)

Only NumPy, trimesh and pykdtree are imported here; PyTorch only to decode a ``.jsrte`` code.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np

from jsrte.errors import JsrteError

RESULT_NAME = "fit.json"
MESH_NAME = "shape.ply"
OVERLAY_NAME = "overlay.png"
SCENE_NAME = "scene.json"
SCENE_OBJECTS = "objects"
CODE_SUFFIX = ".jsrte"
CODE_RESOLUTION = 96
"""Marching-cubes resolution a ``.jsrte`` code is decoded at for display."""

Kind = Literal["fit", "batch", "scene", "code"]


@dataclass(frozen=True)
class Pose:
    """A similarity transform ``x -> scale * rotation @ x + translation`` (canonical -> scan units).

    Attributes
    ----------
    scale : float, > 0
    rotation : (3, 3) float64 rotation matrix
    translation : (3,) float64, scan units
    label : what it is ("winner", "hypothesis 3")
    loss : the fit's loss at this pose (None if unknown)
    winner : whether it is the pose the fit returned
    """

    scale: float
    rotation: np.ndarray
    translation: np.ndarray
    label: str
    loss: float | None = None
    winner: bool = False


@dataclass(frozen=True)
class Plane:
    """The floor ``normal . x = offset`` (unit normal pointing up, scan units)."""

    normal: np.ndarray
    offset: float


@dataclass(frozen=True)
class FitEntry:
    """One fit to show, before anything is read.

    Attributes
    ----------
    name : its name in lists (the result folder's name, the object's number, the code's stem)
    folder : the fit folder (None for a code or a box)
    code : the ``.jsrte`` file (None for a fit folder or a box)
    box : a box of a scene: its scene.json entry (``cuboid``, ``points``, ``box_evidence``) and
        the scene folder in ``folder``
    """

    name: str
    folder: Path | None = None
    code: Path | None = None
    box: dict | None = None


@dataclass(frozen=True)
class Collection:
    """What a path holds: its kind and its fits, in display order."""

    kind: Kind
    path: Path
    entries: list[FitEntry]


@dataclass
class FitItem:
    """One fit, read for display (every array in the scan's frame, scan units).

    Attributes
    ----------
    name : as the entry
    fit_read : whether its fit.json (or code) could be read at all
    numbers : label -> value shown beside it (class, scale, yaw, loss, F@5%, ...)
    mesh : the retrieved surface, or None
    scan : (n, 3) float64 scan points, or None
    truth : the true surface, or None
    floor : the floor plane, or None
    poses : the winner and the other hypotheses' end poses
    overlay : the fit's overlay.png, if it has one
    problems : one line for each thing that could not be read
    """

    name: str
    fit_read: bool = True
    numbers: dict[str, str] = field(default_factory=dict)
    mesh: Any = None  # trimesh.Trimesh
    scan: np.ndarray | None = None
    truth: Any = None  # trimesh.Trimesh
    floor: Plane | None = None
    poses: list[Pose] = field(default_factory=list)
    overlay: Path | None = None
    problems: list[str] = field(default_factory=list)

    @property
    def up(self) -> np.ndarray | None:
        """(3,) unit up axis (the floor's normal), or None."""
        return None if self.floor is None else self.floor.normal


# -- what a path holds --------------------------------------------------------------------------

def find_fits(path: str | Path) -> Collection:
    """The fits under ``path``: a fit folder, a ``fit-many`` output, a scene or a ``.jsrte`` code.

    Raises ``JsrteError`` naming ``path`` when it does not exist or holds no fit.
    """
    path = Path(path)
    if not path.exists():
        raise JsrteError("no such file or folder", path)
    if path.is_file():
        if path.suffix.lower() == CODE_SUFFIX:
            return Collection("code", path, [FitEntry(path.stem, code=path)])
        if path.name == RESULT_NAME:
            return find_fits(path.parent)
        raise JsrteError(f"not a fit: give a fit folder (holding {RESULT_NAME}), a fit-many output, a scene "
                         f"folder ({SCENE_NAME}) or a {CODE_SUFFIX} shape code", path)
    if (path / RESULT_NAME).is_file():
        return Collection("fit", path, [FitEntry(path.name, folder=path)])
    if (path / SCENE_NAME).is_file():
        entries = [FitEntry(f.name, folder=f) for f in _fit_folders(path / SCENE_OBJECTS)] + _scene_boxes(path)
        if entries:
            return Collection("scene", path, sorted(entries, key=lambda e: e.name))
    folders = _fit_folders(path)
    if folders:
        return Collection("batch", path, [FitEntry(f.name, folder=f) for f in folders])
    raise JsrteError(f"holds no fit: expected {RESULT_NAME} (jsrte fit), result folders holding it (jsrte "
                     f"fit-many), {SCENE_NAME} with {SCENE_OBJECTS}/<NN>/{RESULT_NAME} (a scene), or give a "
                     f"{CODE_SUFFIX} shape code", path)


def _scene_boxes(scene: Path) -> list[FitEntry]:
    """The boxes of the scene in folder ``scene`` (its scene.json's objects of status ``box``
    with a cuboid); none where scene.json cannot be read."""
    try:
        record = json.loads((scene / SCENE_NAME).read_text())
    except (OSError, ValueError):
        return []
    if not isinstance(record, dict) or not isinstance(record.get("objects"), list):
        return []
    objects = record["objects"]
    return [FitEntry(f"{o['index']:02d}", folder=scene, box=o | {"input": record.get("input"),
                                                                "floor": record.get("floor")})
            for o in objects if isinstance(o, dict) and o.get("status") == "box" and isinstance(o.get("cuboid"), dict)
            and isinstance(o.get("index"), int)]


def _fit_folders(parent: Path) -> list[Path]:
    """Subfolders of ``parent`` holding a fit.json, sorted by name."""
    if not parent.is_dir():
        return []
    return sorted((p for p in parent.iterdir() if p.is_dir() and (p / RESULT_NAME).is_file()),
                  key=lambda p: p.name)


# -- one fit --------------------------------------------------------------------------------------

def load_item(entry: FitEntry, *, max_scan_points: int = 200_000) -> FitItem:
    """Read one fit for display; what cannot be read is named in ``problems`` (never raises for it)."""
    if entry.code is not None:
        return _load_code(entry)
    assert entry.folder is not None
    if entry.box is not None:
        return _load_box(entry, max_scan_points)
    item = FitItem(entry.name)
    fit_json = entry.folder / RESULT_NAME
    try:
        fit = json.loads(fit_json.read_text())
        if not isinstance(fit, dict) or "scale" not in fit or "rotation" not in fit:
            raise ValueError("no scale and rotation")
        winner = _pose(fit, "winner", winner=True, loss=fit.get("loss"))
    except (OSError, ValueError, TypeError, KeyError) as exc:
        item.fit_read = False
        item.problems.append(f"{fit_json}: not a readable fit ({_reason(exc)})")
        return item
    item.poses = [winner] + _hypothesis_poses(fit)
    overlay = entry.folder / OVERLAY_NAME
    item.overlay = overlay if overlay.is_file() else None
    item.mesh = _fit_mesh(entry.folder, fit, item.problems)
    scan_path = _scan_path(fit.get("input"), entry.folder)
    if scan_path is None:
        if fit.get("input"):
            item.problems.append(f"{fit_json}: its scan {fit['input']} is not found; the scan is not shown")
    else:
        item.scan = _scan_points(scan_path, item.problems, max_scan_points)
    item.truth, truth_floor = _truth(scan_path, item.problems)
    item.floor = truth_floor or _floor_from_up(fit.get("up"), item.scan, item.mesh)
    item.numbers = _numbers(fit, item)
    return item


def _load_box(entry: FitEntry, max_scan_points: int) -> FitItem:
    """A box of a scene (``entry.box``): its cuboid as the mesh, the scene's scan and floor."""
    from jsrte.scans.boxes import Cuboid

    item = FitItem(entry.name)
    box = entry.box
    try:
        record = box["cuboid"]
        cuboid = Cuboid(np.asarray(record["centre"], float).reshape(3),
                        np.asarray(record["axes"], float).reshape(3, 3),
                        np.asarray(record["extents"], float).reshape(3))
        extents = cuboid.extents
        finite = np.all(np.isfinite(cuboid.centre)) and np.all(np.isfinite(cuboid.axes))
        if not (finite and np.all(extents > 0)):
            raise ValueError("its centre, axes or extents are not finite and positive")
        item.mesh = cuboid.mesh()
    except (KeyError, TypeError, ValueError) as exc:
        item.fit_read = False
        item.problems.append(f"{entry.folder / SCENE_NAME}: box {entry.name} is not readable ({_reason(exc)})")
        return item
    scan_path = _scan_path(box.get("input"), entry.folder)
    if scan_path is not None:
        item.scan = _scan_points(scan_path, item.problems, max_scan_points)
    floor = box.get("floor") or {}
    try:
        item.floor = Plane(_unit(floor["up"]), float(floor["offset"]))
    except (KeyError, TypeError, ValueError):
        item.floor = None
    evidence = box.get("box_evidence") or {}
    item.numbers = {"class": "box", "size (m)": " × ".join(f"{v:.2f}" for v in extents),
                    "points": str(box.get("points", "?"))}
    if isinstance(evidence.get("seen_through"), int | float):
        item.numbers["seen through"] = f"{evidence['seen_through']:.3f} per point"
    if isinstance(evidence.get("floor_seen_under"), int | float):
        item.numbers["floor seen under"] = f"{evidence['floor_seen_under']:.2f} of its footprint"
    return item


def load_items(collection: Collection, *, max_scan_points: int = 200_000) -> list[FitItem]:
    """Every fit of ``collection``; ``JsrteError`` when none could be read at all."""
    items = [load_item(e, max_scan_points=max_scan_points) for e in collection.entries]
    if not any(i.fit_read for i in items):
        raise JsrteError(f"no fit could be read ({items[0].problems[0]})", collection.path)
    return items


def _reason(exc: BaseException) -> str:
    if isinstance(exc, OSError):
        return exc.strerror or str(exc)
    return f"{type(exc).__name__}: {exc}"


def _pose(d: dict, label: str, *, winner: bool = False, loss: Any = None) -> Pose:
    """A Pose from ``{"scale", "rotation", "translation"}`` (fit.json or a hypothesis's transform)."""
    rotation = np.asarray(d["rotation"], dtype=np.float64).reshape(3, 3)
    translation = np.asarray(d["translation"], dtype=np.float64).reshape(3)
    scale = float(d["scale"])
    if not (scale > 0 and np.all(np.isfinite(rotation)) and np.all(np.isfinite(translation))):
        raise ValueError("scale, rotation or translation is not finite and positive")
    return Pose(scale, rotation, translation, label, None if loss is None else float(loss), winner)


def _hypothesis_poses(fit: dict) -> list[Pose]:
    """The end poses of the hypotheses other than the winner (those that have one)."""
    poses = []
    winner_index = fit.get("winner_hypothesis")
    for h in fit.get("hypotheses") or []:
        try:
            if h.get("transform") is None or h.get("index") == winner_index:
                continue
            poses.append(_pose(h["transform"], f"hypothesis {h['index']}", loss=h.get("loss")))
        except (KeyError, TypeError, ValueError, AttributeError):
            continue  # a malformed hypothesis is simply not drawn
    return poses


def _fit_mesh(folder: Path, fit: dict, problems: list[str]) -> Any:
    """The retrieved mesh in the scan frame (shape.ply), or None with the reason in ``problems``."""
    from jsrte.geometry.mesh import load_mesh

    path = folder / MESH_NAME
    if fit.get("empty_surface"):
        problems.append(f"{folder / RESULT_NAME}: the fit's surface is empty; no mesh to show")
        return None
    if not path.exists():
        problems.append(f"{path}: missing; the retrieved mesh is not shown")
        return None
    try:
        return load_mesh(path)
    except JsrteError as exc:
        problems.append(f"{exc}; the retrieved mesh is not shown")
        return None


def _scan_path(recorded: Any, folder: Path) -> Path | None:
    """Where the scan named in fit.json's ``input`` is: as recorded (absolute, or relative to the
    working folder), else relative to the fit folder or the folders above it."""
    if not isinstance(recorded, str) or not recorded:
        return None
    path = Path(recorded).expanduser()
    if path.is_absolute():
        return path if path.is_file() else None
    for base in (Path.cwd(), folder, *list(folder.resolve().parents)[:3]):
        if (base / path).is_file():
            return base / path
    return None


def _scan_points(path: Path, problems: list[str], max_points: int) -> np.ndarray | None:
    """(n, 3) points of a scan (a point cloud, a mesh's vertices, or SDF samples near the surface)."""
    try:
        from jsrte.formats import input_kind

        kind = input_kind(path)
        if kind == "npz":
            points = _npz_surface(path)
        elif kind == "mesh" or path.suffix.lower() == ".ply":
            points = _trimesh_points(path)
        else:
            from jsrte.scans.io import load_scan

            points = load_scan(path, dense_points=0).points
    except JsrteError as exc:
        problems.append(f"{exc}; the scan is not shown")
        return None
    if len(points) > max_points:
        points = points[np.random.default_rng(0).choice(len(points), max_points, replace=False)]
    return points


def _trimesh_points(path: Path) -> np.ndarray:
    """The vertices of a PLY/GLB point cloud or mesh, read with trimesh (no Open3D start-up)."""
    import trimesh

    try:
        loaded = trimesh.load(path, process=False)
        if isinstance(loaded, trimesh.Scene):
            loaded = loaded.to_geometry() if hasattr(loaded, "to_geometry") else loaded.dump(concatenate=True)
        points = np.asarray(loaded.vertices, dtype=np.float64).reshape(-1, 3)
    except Exception as exc:  # trimesh raises many types for broken files
        raise JsrteError(f"cannot read scan ({type(exc).__name__}: {exc})", path) from exc
    points = points[np.all(np.isfinite(points), axis=1)]
    if len(points) == 0:
        raise JsrteError("holds no points", path)
    return points


def _npz_surface(path: Path) -> np.ndarray:
    """Surface points of a query file or of SDF samples (those within 1% of the surface)."""
    from jsrte.fit.query import is_query_file, read_query_file

    if is_query_file(path):
        return read_query_file(path).surface
    from jsrte.sdf.mesh_sdf import SdfSamples

    s = SdfSamples.load(path)
    return s.points[np.abs(s.sdf) < 0.01] * s.scale + s.centre


def _truth(scan_path: Path | None, problems: list[str]) -> tuple[Any, Plane | None]:
    """The true mesh in the scan frame and the floor, from a virtual scan's ``<stem>.json``
    (its ``scan_from_mesh`` pose, ``floor`` and the ``mesh`` it names, found as ``fit-many``
    finds it: absolute, else beside the JSON, else in the working folder); None where absent."""
    if scan_path is None:
        return None, None
    info_path = scan_path.with_suffix(".json")
    if not info_path.is_file() or info_path == scan_path:
        return None, None
    try:
        raw = json.loads(info_path.read_text())
        floor = raw.get("floor") or {}
        plane = Plane(_unit(floor["normal"]), float(floor["offset"])) if "normal" in floor else None
        mesh_field, pose_field = raw.get("mesh"), raw.get("scan_from_mesh")
    except (OSError, ValueError, TypeError, KeyError, AttributeError):
        return None, None  # not a scan description: no truth, no floor
    if not isinstance(mesh_field, str) or not isinstance(pose_field, dict):
        return None, plane
    recorded = Path(mesh_field).expanduser()
    candidates = [recorded] if recorded.is_absolute() else [info_path.parent / recorded, Path.cwd() / recorded]
    mesh_path = next((c for c in candidates if c.is_file()), None)
    if mesh_path is None:
        problems.append(f"{info_path}: its true mesh {mesh_field} is not found; the true mesh is not shown")
        return None, plane
    from jsrte.geometry.mesh import load_mesh

    try:
        mesh = load_mesh(mesh_path)
        pose = _pose(pose_field, "truth")
    except JsrteError as exc:
        problems.append(f"{exc}; the true mesh is not shown")
        return None, plane
    except (KeyError, TypeError, ValueError) as exc:
        problems.append(f"{info_path}: cannot read the true pose ({_reason(exc)}); the true mesh is not shown")
        return None, plane
    mesh.vertices = pose.scale * np.asarray(mesh.vertices) @ pose.rotation.T + pose.translation
    return mesh, plane


def _unit(v: Any) -> np.ndarray:
    v = np.asarray(v, dtype=np.float64).reshape(3)
    n = np.linalg.norm(v)
    if not n > 0:
        raise ValueError("zero normal")
    return v / n


def _floor_from_up(up: Any, scan: np.ndarray | None, mesh: Any) -> Plane | None:
    """The floor from the fit's up axis: under the scan's lowest points (its 1st height percentile),
    else under the mesh's lowest vertex. None without an up axis."""
    try:
        normal = _unit(up)
    except (TypeError, ValueError):
        return None
    if scan is not None and len(scan):
        return Plane(normal, float(np.percentile(scan @ normal, 1.0)))
    if mesh is not None:
        return Plane(normal, float((np.asarray(mesh.vertices) @ normal).min()))
    return None


def _numbers(fit: dict, item: FitItem) -> dict[str, str]:
    """What the panel and the report list for a fit, formatted."""
    numbers = {"class": str(fit.get("model", "?"))}
    if fit.get("method", "jsrte") != "jsrte":
        numbers["method"] = str(fit["method"])
    numbers["scale"] = f"{float(fit['scale']):.4f}"
    if isinstance(fit.get("theta"), int | float):
        numbers["yaw"] = f"{np.degrees(fit['theta']) % 360:.1f}°"
    if isinstance(fit.get("loss"), int | float):
        numbers["loss"] = f"{fit['loss']:.4g}"
    for key in ("confident", "confidence", "low_confidence"):
        if key in fit and fit[key] is not None:
            value = fit[key]
            numbers[key.replace("_", " ")] = (("yes" if value else "no") if isinstance(value, bool)
                                              else f"{value:.3g}" if isinstance(value, float) else str(value))
    fscore = (fit.get("truth") or {}).get("fscore") if isinstance(fit.get("truth"), dict) else None
    if fscore is None and item.truth is not None and item.mesh is not None:
        fscore = truth_fscore(item.mesh, item.truth)
    if fscore is not None:
        numbers["F@5%"] = f"{float(fscore):.3f}"
    hypotheses = fit.get("hypotheses") or []
    if hypotheses and fit.get("winner_hypothesis") is not None:
        numbers["winner"] = f"hypothesis {fit['winner_hypothesis']} of {len(hypotheses)}"
    total = (fit.get("timing_s") or {}).get("total") if isinstance(fit.get("timing_s"), dict) else None
    if isinstance(fit.get("wall_time_s", total), int | float):
        numbers["time"] = f"{float(fit.get('wall_time_s', total)):.1f} s"
    return numbers


def truth_fscore(mesh: Any, truth: Any) -> float:
    """The paper's F@5% of ``mesh`` against the true mesh (3000 points each, seeded)."""
    from jsrte.metrics.surface import fscore

    return fscore(mesh, truth, rng=np.random.default_rng(0)).fscore


# -- a shape code ---------------------------------------------------------------------------------

def _load_code(entry: FitEntry) -> FitItem:
    """A ``.jsrte`` code decoded with its shipped model: the mesh and the pose (no scan)."""
    from jsrte.codec.convert import mesh_from_code, model_for_code, read_code

    assert entry.code is not None
    code = read_code(entry.code)  # a corrupt code is the whole input: a one-line error
    model = model_for_code(code, source=entry.code)
    t = code.transform
    item = FitItem(entry.name, poses=[Pose(float(t.s), np.asarray(t.R), np.asarray(t.t), "code", winner=True)])
    item.mesh = mesh_from_code(code, model, resolution=CODE_RESOLUTION)
    if item.mesh is None:
        item.problems.append(f"{entry.code}: the decoded surface is empty; no mesh to show")
    angle = np.degrees(np.arccos(np.clip((np.trace(np.asarray(t.R)) - 1) / 2, -1, 1)))
    item.numbers = {"class": code.model_name, "scale": f"{t.s:.4f}", "rotation": f"{angle:.1f}°",
                    "latent": f"{code.latent.size} values"}
    return item


# -- a result in memory ---------------------------------------------------------------------------

def item_from_result(name: str, result: Any, *, scan: np.ndarray | None = None, truth: Any = None,
                     floor: Plane | None = None, fscore: float | None = None,
                     max_scan_points: int = 20_000) -> FitItem:
    """A FitItem from a ``FitResult`` held in memory (the experiments'), with its scan (n, 3),
    true mesh, floor and F@5% against the truth where known."""
    t = result.transform
    poses = [Pose(float(t.s), np.asarray(t.R), np.asarray(t.t), "winner", float(result.loss), True)]
    winner_index = result.info.get("winner_hypothesis")
    poses += [Pose(float(h.transform.s), np.asarray(h.transform.R), np.asarray(h.transform.t),
                   f"hypothesis {h.index}", float(h.loss))
              for h in result.hypotheses if h.transform is not None and h.index != winner_index]
    item = FitItem(name, poses=poses, truth=truth, floor=floor, mesh=result.mesh)
    if scan is not None:
        item.scan = scan if len(scan) <= max_scan_points else scan[
            np.random.default_rng(0).choice(len(scan), max_scan_points, replace=False)]
    if item.mesh is None:
        item.problems.append(f"{name}: the {result.method} surface is empty; no mesh to show")
    fit = {"model": result.info.get("model", "?"), "method": result.method, "scale": t.s, "loss": result.loss,
           "winner_hypothesis": winner_index, "hypotheses": result.hypotheses,
           **({"theta": result.angles["theta"]} if result.angles else {}),
           **({"truth": {"fscore": fscore}} if fscore is not None else {})}
    item.numbers = _numbers(fit, item)
    return item
