"""The scene experiment: virtual rooms of several held-out objects, each room fitted whole
(``jsrte fit --scene``: every object found, its class chosen among the models) and scored
against its truth (:mod:`jsrte.experiments.scene_scoring`).

A room (:func:`draw_room`) holds ``OBJECTS`` objects: furniture of the four shipped classes,
drawn uniformly, and now and then a box (``BOX_SHARE``) that no model covers; each furniture
shape is a held-out one (evaluation set, seed 1, index ``1000 + 10 * room + k``), at its own
size. The room scanner's room mode (:class:`jsrte.scans.scene.SceneSettings` ``frame_all``)
places them side by side, the first touching the first, puts one to three walls behind and
beside them and sweeps the camera past them all. Room ``i`` of seed ``s`` is drawn from the
seed ``s * 100003 + i`` alone: the same room index and seed always give the same room.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import trimesh

from jsrte.atomic import read_csv_rows, write_bytes_atomic, write_csv_atomic, write_json_atomic
from jsrte.errors import JsrteError
from jsrte.experiments.scene_scoring import (
    BOX,
    FURNITURE,
    HIT,
    FoundObject,
    TrueObject,
    confusion,
    detection,
    fit_quality,
    object_rows,
)
from jsrte.presets import SCENE_PRESET
from jsrte.scans.scene import SceneSettings, VirtualRoom

ROOM_SETTINGS = SceneSettings(frame_all=True, front_clearance_deg=60.0, behind_clearance_deg=60.0,
                              wall_length_m=14.0)
"""The rooms' scanner: room mode; the other objects stand beside the first (60–120° from the
cameras' direction, either side: a row the camera walks past), walls long enough for a row."""
OBJECTS = (3, 6)
"""Objects per room, drawn uniformly in this range (fewer when one fits nowhere)."""
BOX_SHARE = 0.15
"""Each object after the first is a box with this probability (the first is always furniture)."""
BOX_SIZE_M = (0.25, 0.7)
SHAPE_INDEX_BASE = 1000
"""Object k of room i is evaluation-set shape ``SHAPE_INDEX_BASE + 10 * i + k``."""

OBJECTS_NAME, ROOMS_NAME, SUMMARY_MD, SUMMARY_CSV, CONFIG_NAME = (
    "objects.csv", "rooms.csv", "summary.md", "summary.csv", "config.json")
Log = Callable[[str], None]


@dataclass(frozen=True)
class ScenesConfig:
    """Everything that decides a scene run's numbers (recorded in config.json)."""

    rooms: int = 20
    first: int = 0
    seed: int = 0
    preset: str = SCENE_PRESET
    dtype: str | None = None
    """The decoder's arithmetic while the fits move (None: the preset's, ``FitSettings.decoder_dtype``)."""
    model: str = "auto"
    objects: tuple[int, int] = OBJECTS
    box_share: float = BOX_SHARE
    leftovers: bool = False
    """Also fit what the found objects' fits leave unexplained (``jsrte.fit.scene.fit_scene``)."""
    cameras: bool = True
    """Fit each room's scan with its cameras (the JSON sidecar); False: as a scan from another tool
    without them, the up axis given (``--up``), its file ``rooms/NNN/scan_without_cameras.ply``."""

    @property
    def indices(self) -> list[int]:
        """The room indices run: ``first`` ... ``first + rooms - 1``."""
        return list(range(self.first, self.first + self.rooms))

    def to_json(self) -> dict:
        """config.json's record."""
        return json.loads(json.dumps(asdict(self)))


@dataclass
class ScenesReport:
    """What a run wrote: every object row, the summary and the files."""

    rows: list[dict]
    summary: dict
    confusion: dict
    files: list[Path] = field(default_factory=list)


# --- the rooms --------------------------------------------------------------------------------


def room_rng(room: int, seed: int = 0) -> np.random.Generator:
    """The only randomness of room ``room`` of seed ``seed``."""
    return np.random.default_rng(seed * 100_003 + room)


def draw_room(room: int, *, seed: int = 0, objects: tuple[int, int] = OBJECTS, box_share: float = BOX_SHARE,
              settings: SceneSettings = ROOM_SETTINGS) -> VirtualRoom:
    """Room ``room`` of seed ``seed``: ``objects`` objects (furniture of the shipped classes, held
    out, at their own size; boxes with probability ``box_share`` after the first), scanned by
    the room scanner with ``settings`` (metres, a random world frame)."""
    from jsrte.scans.scene import scan_room
    from jsrte.shapes import EVAL_SET_SEED, generate_shape, shape_seed

    rng = room_rng(room, seed)
    n = int(rng.integers(objects[0], objects[1] + 1))
    drawn = []
    for k in range(n):
        kind = "box" if k > 0 and rng.random() < box_share else str(rng.choice(FURNITURE))
        if kind == "box":
            size = rng.uniform(*BOX_SIZE_M, size=3)
            mesh = trimesh.creation.box(extents=size)
            mesh.apply_translation([0.0, size[1] / 2.0, 0.0])
            drawn.append((kind, mesh, "box"))
        else:
            shape = generate_shape(kind, shape_seed(EVAL_SET_SEED, SHAPE_INDEX_BASE + 10 * room + k))
            drawn.append((kind, shape.mesh, shape.style))
    (kind, target, _), others = drawn[0], drawn[1:]
    return scan_room(target, rng=rng, settings=settings, target_kind=kind, others=others)


def true_objects(room: VirtualRoom) -> list[TrueObject]:
    """Every object of ``room`` as a :class:`TrueObject` (scan frame)."""
    objects = []
    for k, obj in enumerate(room.objects):
        centre, radius = _sphere(obj.scan_from_mesh.apply(np.asarray(obj.mesh.vertices)))
        objects.append(TrueObject(k, obj.kind, centre, radius))
    return objects


# --- one room ---------------------------------------------------------------------------------


def run_room(room: int, config: ScenesConfig, out: Path) -> list[dict]:
    """Draw, write (``out/rooms/NNN``), fit (``out/fits/NNN``) and score room ``room``; one row per
    true or found object (:func:`jsrte.experiments.scene_scoring.object_rows` plus the room,
    F@5% and pose errors of each furniture hit, the fit's points, time and quality)."""
    from jsrte.fit.scene import fit_scene
    from jsrte.fit.scene_outputs import write_scene_outputs
    from jsrte.scans.scene import write_room

    drawn = draw_room(room, seed=config.seed, objects=config.objects, box_share=config.box_share,
                      settings=ROOM_SETTINGS)
    scan = write_room(drawn, out / "rooms" / f"{room:03d}", seed=config.seed)
    up = None
    if not config.cameras:
        scan, up = _without_cameras(scan), tuple(float(v) for v in drawn.scan.up)
    truth = true_objects(drawn)
    started = time.perf_counter()
    try:
        scene = fit_scene(scan, model=config.model, preset=config.preset, seed=config.seed, dtype=config.dtype,
                          leftovers=config.leftovers, up=up)
    except JsrteError as exc:  # no object left: every true object is missed
        scene, failure = None, str(exc)
    seconds = time.perf_counter() - started
    found_objects = [] if scene is None else scene.found  # unexplained objects are no detections
    if scene is not None:
        write_scene_outputs(scene, out / "fits" / f"{room:03d}", extra={"input": str(scan.resolve())})
        failure = "; ".join(f"object {o.index}: {o.reason}" for o in scene.objects if o.status == "failed")
    found = [FoundObject(o.index, o.model, _found_centre(o), o.result.flag) for o in found_objects]
    found += [] if scene is None else [FoundObject(o.index, BOX, o.box.cuboid.centre) for o in scene.boxes]
    rows = object_rows(truth, found)
    by_index = {o.index: o for o in found_objects}
    rng = np.random.default_rng(config.seed)
    for row in rows:
        obj = by_index.get(row["found_index"])
        if obj is not None:
            row.update(_found_columns(obj))
        if row["outcome"] == HIT:
            row.update(_truth_columns(obj.result, drawn.objects[row["true_index"]], rng))
    for row in rows:
        row.update(room=room, seed=config.seed, scene_seconds=round(seconds, 2),
                   quick_fit_seconds=None if scene is None else scene.timing.get("quick fits"),
                   objects_found=len(found_objects), scene_error=failure)
    return [_ordered(r) for r in rows]


def _without_cameras(scan: Path) -> Path:
    """A copy of the room's ``scan`` (PLY) without its JSON sidecar, so without its cameras."""
    import shutil

    copy = scan.with_name(f"{scan.stem}_without_cameras.ply")
    shutil.copyfile(scan, copy)
    return copy


def _found_centre(obj: object) -> np.ndarray:
    """The bounding-box centre (3,) of a fitted object's retrieved mesh (its points' when empty)."""
    mesh = obj.result.mesh
    if mesh is not None and len(mesh.vertices):
        return _sphere(np.asarray(mesh.vertices))[0]
    return np.asarray(obj.centre, float)


def _found_columns(obj: object) -> dict:
    r = obj.result
    margin = None if obj.class_choice is None else obj.class_choice.get("margin")
    quality = {f"quality_{k}": v for k, v in r.quality.items() if isinstance(v, (int, float)) or v is None}
    return {"points": len(obj.points), "class_margin": margin, "fit_seconds": r.timing.get("total"),
            "scale_m": float(r.transform.s), "leftover_of": obj.leftover_of,
            "part_of": obj.part_of} | quality


def _truth_columns(result: object, true: object, rng: np.random.Generator) -> dict:
    """F@5% against the complete true shape and the pose errors (as the scan experiment)."""
    from jsrte.experiments.truth import score_against_truth, truth_of

    scores = score_against_truth(result, truth_of(true.mesh, true.scan_from_mesh), rng=rng)
    return {k: scores[k] for k in ("fscore", "precision", "recall", "rotation_error_deg", "scale_error_rel",
                                   "translation_error")}


COLUMNS = ("room", "seed", "outcome", "true_index", "true_class", "found_index", "found_class", "flag",
           "distance_rel", "fscore", "precision", "recall", "rotation_error_deg", "scale_error_rel",
           "translation_error", "class_margin", "points", "scale_m", "fit_seconds", "scene_seconds",
           "quick_fit_seconds", "objects_found", "scene_error")


def _ordered(row: dict) -> dict:
    """``row`` with the known columns first (missing ones empty), numbers rounded."""
    out = {k: row.get(k) for k in COLUMNS} | {k: v for k, v in row.items() if k not in COLUMNS}
    return {k: round(float(v), 5) if isinstance(v, (float, np.floating)) else v for k, v in out.items()}


def _sphere(vertices: np.ndarray) -> tuple[np.ndarray, float]:
    centre = (vertices.min(0) + vertices.max(0)) / 2.0
    return centre, float(np.linalg.norm(vertices - centre, axis=1).max())


# --- the run ----------------------------------------------------------------------------------


def run_scenes(config: ScenesConfig, out: Path, *, jobs: int = 1, threads: int | None = None,
               resume: bool = False, report: bool = True, log: Log = lambda _: None) -> ScenesReport:
    """Every room of ``config`` into ``out``: rooms/NNN, fits/NNN, objects.csv (rewritten after
    each room), rooms.csv, summary.md/.csv, a figure of the first room, report.html (with
    ``report``). With ``resume``, rooms already in objects.csv are kept and not run again (the
    settings must match config.json). ``jobs`` > 1 runs rooms in that many spawned processes."""
    config_path = out / CONFIG_NAME
    rows = _resumed_rows(config, out) if resume else []
    write_json_atomic(config_path, config.to_json())
    done = {r["room"] for r in rows}
    todo = [i for i in config.indices if i not in done]
    if done:
        log(f"resuming: {len(done)} room(s) done, {len(todo)} to run")
    for room, room_rows in _rooms(todo, config, out, jobs, threads):
        rows = [r for r in rows if r["room"] != room] + room_rows
        rows.sort(key=lambda r: r["room"])
        write_csv_atomic(out / OBJECTS_NAME, rows)
        log(_room_line(room, room_rows))
    rows = [r for r in rows if r["room"] in set(config.indices)]
    summary = summarize(rows)
    table = confusion(rows)
    files = [out / OBJECTS_NAME, *_write_summary(rows, summary, table, config, out)]
    figure = room_figure(out, config.indices[0])
    files += [figure] if figure is not None else []
    if report:
        page = write_scenes_report(out, config.indices, rows)
        files += [page] if page is not None else []
    return ScenesReport(rows, summary, table, files)


def _rooms(todo: list[int], config: ScenesConfig, out: Path, jobs: int, threads: int | None):  # noqa: ANN202
    """(room, rows) for each room of ``todo``, here or in ``jobs`` spawned processes."""
    if jobs <= 1 or len(todo) <= 1:
        for room in todo:
            yield room, run_room(room, config, out)
        return
    import multiprocessing
    import os
    from concurrent.futures import ProcessPoolExecutor

    per_job = max(1, (threads or os.cpu_count() or 1) // jobs)
    with ProcessPoolExecutor(max_workers=jobs, mp_context=multiprocessing.get_context("spawn"),
                             initializer=_init_worker, initargs=(per_job, os.getpid())) as pool:
        yield from zip(todo, pool.map(run_room, todo, [config] * len(todo), [out] * len(todo)), strict=True)


def _init_worker(threads: int, parent_pid: int) -> None:
    import torch

    from jsrte.model.decoder import flush_denormals
    from jsrte.processes import die_with_parent

    die_with_parent(parent_pid)
    flush_denormals()
    torch.set_num_threads(threads)


def _room_line(room: int, rows: list[dict]) -> str:
    d = detection(rows)
    seconds = rows[0]["scene_seconds"] if rows else 0.0
    return (f"room {room:03d}: {d['hits']} of {d['true_furniture']} found, {d['false_positives']} false "
            f"positive(s), {d['boxes_found']} of {d['boxes']} boxes reported, {d['found_on_boxes']} fitted, "
            f"{seconds:.0f} s")


def summarize(rows: list[dict]) -> dict:
    """Detection, fit quality and time over every room of ``rows``: seconds per scene (mean over
    rooms), of them in the quick fits (where every room recorded them), and per found object
    (all rooms' seconds over all objects found)."""
    rooms = {r["room"]: r for r in rows}
    seconds = [float(r["scene_seconds"]) for r in rooms.values()]
    quick = [r.get("quick_fit_seconds") for r in rooms.values()]
    found = sum(int(r["objects_found"]) for r in rooms.values())
    return {"rooms": len(rooms), **detection(rows), **fit_quality(rows),
            "seconds_per_scene": round(float(np.mean(seconds)), 1) if seconds else None,
            "quick_fit_seconds_per_scene": round(float(np.mean([float(q) for q in quick])), 1)
            if quick and all(q not in (None, "") for q in quick) else None,
            "seconds_per_object": round(sum(seconds) / found, 1) if found else None}


SUMMARY_LABELS = (
    ("rooms", "rooms"), ("true furniture objects", "true_furniture"), ("objects found", "found"),
    ("detection recall", "recall"), ("detection precision", "precision"), ("missed", "missed"),
    ("false positives", "false_positives"), ("boxes / reported as boxes / fitted as furniture", None),
    ("furniture reported as a box / boxes reported where none stands", None),
    ("share of box detections flagged doubtful", "boxes_flagged_doubtful"),
    ("class accuracy (matched objects)", "class_accuracy"),
    ("mean F@5% vs complete true shape (matched)", "fscore_mean"), ("median F@5% (matched)", "fscore_median"),
    ("mean F@5%, missed objects as 0", "fscore_mean_misses_zero"),
    ("matched fits with F@5% < 0.7 / ≥ 0.85", None),
    ("median rotation error (°, class right)", "rotation_error_deg_median"),
    ("median relative scale error (class right)", "scale_error_rel_median"),
    ("flag precision (doubtful fits with F < 0.7)", "flag_precision"),
    ("flag recall (fits with F < 0.7 flagged)", "flag_recall"),
    ("fits with F ≥ 0.85 flagged doubtful", "good_fits_flagged"),
    ("seconds per scene (wall)", "seconds_per_scene"),
    ("of which quick fits of the candidates (wall)", "quick_fit_seconds_per_scene"),
    ("seconds per found object (wall)", "seconds_per_object"))


def summary_markdown(summary: dict, table: dict, config: ScenesConfig) -> str:
    """summary.md: the metrics table and the confusion matrix (rows: true class; columns: found)."""
    def cell(value: object) -> str:
        return "–" if value is None else str(value)

    first, last = config.indices[0], config.indices[-1]
    lines = [f"Scene experiment: rooms {first}–{last} of seed {config.seed}, {config.objects[0]}–"
             f"{config.objects[1]} held-out objects each (evaluation set), model {config.model}, preset "
             f"{config.preset}{'' if config.cameras else ', scans without their cameras (up axis given)'}. "
             "A found object matches a true one within 0.3 of its bounding-sphere radius; "
             "found objects on boxes are neither hits nor false positives.", "", "| | |", "|---|---|"]
    for label, key in SUMMARY_LABELS:
        if key is None and label.startswith("boxes"):
            value = f"{summary['boxes']} / {summary['boxes_found']} / {summary['found_on_boxes']}"
        elif key is None and label.startswith("furniture"):
            value = f"{summary['furniture_as_boxes']} / {summary['false_boxes']}"
        elif key is None:
            value = f"{summary['fits_below_0.7']} / {summary['fits_at_least_0.85']} of {summary['scored']}"
        else:
            value = cell(summary[key])
        lines.append(f"| {label} | {value} |")
    columns = list(next(iter(table.values())))
    lines += ["", "Confusion matrix (rows: true class, columns: class found):", "",
              "| true \\ found | " + " | ".join(columns) + " |", "|---|" + "---|" * len(columns)]
    lines += [f"| {kind} | " + " | ".join(str(counts[c]) for c in columns) + " |" for kind, counts in table.items()]
    return "\n".join(lines) + "\n"


def _write_summary(rows: list[dict], summary: dict, table: dict, config: ScenesConfig, out: Path) -> list[Path]:
    keys = ("room", "seed", "scene_seconds", "quick_fit_seconds", "objects_found", "scene_error")
    rooms = list({r["room"]: {k: r.get(k) for k in keys} for r in rows}.values())
    write_csv_atomic(out / ROOMS_NAME, rooms)
    write_csv_atomic(out / SUMMARY_CSV, [summary])
    write_bytes_atomic(out / SUMMARY_MD, summary_markdown(summary, table, config).encode())
    return [out / ROOMS_NAME, out / SUMMARY_CSV, out / SUMMARY_MD]


def _resumed_rows(config: ScenesConfig, out: Path) -> list[dict]:
    """The rows of objects.csv in ``out`` (typed), after checking config.json matches ``config``
    (a setting config.json does not record, from before the setting existed, had its default)."""
    path = out / CONFIG_NAME
    if path.is_file():
        try:
            recorded = json.loads(path.read_text())
        except (OSError, UnicodeDecodeError, json.JSONDecodeError) as error:
            raise JsrteError(f"unreadable ({error})", path) from error
        if not isinstance(recorded, dict):
            raise JsrteError("unreadable (not a JSON object)", path)
        recorded = ScenesConfig().to_json() | recorded
        keep = {k: v for k, v in recorded.items() if k not in ("rooms", "first")}
        mine = {k: v for k, v in config.to_json().items() if k not in ("rooms", "first")}
        if keep != mine:
            changed = ", ".join(sorted(k for k in mine if keep.get(k) != mine[k]))
            raise JsrteError(f"was run with other settings ({changed}); resume with the same ones or pass "
                             "--overwrite", out)
    if not (out / OBJECTS_NAME).is_file():
        return []
    return read_csv_rows(out / OBJECTS_NAME)


# --- figure and report ------------------------------------------------------------------------


def room_figure(out: Path, room: int) -> Path | None:
    """``figure_room_NNN.png``: the room's object points with the true meshes, then with the
    retrieved ones (one camera; none where no object was found); None when the room was not
    fitted."""
    from jsrte.scans.io import load_scan, read_scan_info
    from jsrte.viz import render_panels

    room_dir, fit_dir = out / "rooms" / f"{room:03d}", out / "fits" / f"{room:03d}"
    if not (fit_dir / "scene.json").is_file():
        return None
    scan = room_dir / "scan.ply"
    points = load_scan(scan).points
    labels = np.load(room_dir / "labels.npy")
    objects = points[labels >= 0] if len(labels) == len(points) else points
    objects = objects[np.random.default_rng(0).choice(len(objects), min(len(objects), 8000), replace=False)]
    truth = _true_scene_mesh(room_dir)
    fitted = trimesh.load(fit_dir / "scene.ply", process=False) if (fit_dir / "scene.ply").is_file() else None
    info = read_scan_info(scan)
    path = out / f"figure_room_{room:03d}.png"
    render_panels([("true objects", truth, objects), ("found (jsrte fit --scene)", fitted, objects)], path,
                  up=(0.0, 1.0, 0.0) if info is None else tuple(info.up))
    return path


def _true_scene_mesh(room_dir: Path) -> trimesh.Trimesh:
    """Every true mesh of a written room (scene.json, meshes/) in the scan frame, as one mesh."""
    return trimesh.util.concatenate(list(_true_meshes(room_dir).values()))


def _true_meshes(room_dir: Path) -> dict[int, trimesh.Trimesh]:
    from jsrte.geometry.sim3 import Sim3

    record = json.loads((room_dir / "scene.json").read_text())
    meshes = {}
    for entry in record["objects"]:
        mesh = trimesh.load(room_dir / entry["mesh"], process=False)
        mesh.vertices = Sim3.from_dict(entry["scan_from_mesh"]).apply(np.asarray(mesh.vertices))
        meshes[entry["index"]] = mesh
    return meshes


def write_scenes_report(out: Path, rooms: list[int], rows: list[dict]) -> Path | None:
    """report.html: a 3D view of every fitted object of every room (the room's points, the
    retrieved mesh and the matched true mesh), with its class, outcome and F@5%."""
    from jsrte.view.loading import find_fits, load_items
    from jsrte.view.report import write_report

    items = []
    for room in rooms:
        fit_dir = out / "fits" / f"{room:03d}"
        try:
            room_items = load_items(find_fits(fit_dir), max_scan_points=5_000)
        except JsrteError:
            continue
        truth = _true_meshes(out / "rooms" / f"{room:03d}")
        by_found = {r["found_index"]: r for r in rows if r["room"] == room and r["found_index"] is not None}
        for item in room_items:
            row = by_found.get(int(item.name)) if item.name.isdigit() else None
            item.name = f"room {room:03d} object {item.name}"
            item.truth = None if row is None or row["true_index"] is None else truth.get(row["true_index"])
            if row is not None:
                item.numbers = {"class found": str(row["found_class"]), "true class": str(row["true_class"]),
                                "outcome": str(row["outcome"])} | (
                    {"F@5% vs truth": f"{row['fscore']:.3f}"} if row.get("fscore") is not None else {}) | item.numbers
            items.append(item)
    if not items:
        return None
    path = out / "report.html"
    write_report(items, path, title=f"jsrte experiment scenes: {out.resolve().name}", overwrite=True)
    return path
