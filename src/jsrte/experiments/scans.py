"""The scan experiment (the paper's Table 2 and Fig. 3): held-out shapes scanned on a floor,
every method on every scan, F@5% against the complete true shape and against the scan.

Scans come from the virtual depth scanner (partial views, noise, a floor, a random world
frame), or from a folder of real scans (Redwood-style PLY; no truth, so only F@5% against the
scan is reported). Shapes are from the evaluation seed set: never trained on.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from jsrte.atomic import write_bytes_atomic, write_csv_atomic
from jsrte.errors import JsrteError
from jsrte.metrics.surface import fscore
from jsrte.result import FitResult

PAPER_TABLE2 = {"harris3d-shot": 0.273, "ourcvfh-icp": 0.367, "pointnet-icp": 0.452, "jsrte": 0.902}
"""The paper's mean F@5% on 58 Redwood chair scans (Table 2); FPFH+RANSAC+ICP is ours only."""
SCALES = {"quick": 4, "paper": 58}
"""Scans per class: quick (minutes here) and the paper's 58 test scans."""
PAPER_VALIDATION_SCANS = 31
"""The paper held out 31 further scans to validate the baselines (index 58.. of our set)."""


@dataclass
class ScanCase:
    """One query: the scan file and, for virtual scans, the truth."""

    name: str
    path: Path
    truth: object | None = None  # jsrte.experiments.truth.Truth
    info: dict = field(default_factory=dict)


CLUTTER_KINDS = ("table", "box")
"""What stands beside the object in a cluttered scan (``--clutter``): a table and boxes, as in
a room; never a second object of the class (which one would be "the" object?)."""


SIZES = ("drawn", "own")
"""How big a clean scan's shape stands: ``drawn``, scaled to a height drawn from the scanner's
0.6-1.2 m whatever its class (Table 2's protocol, as for meshes in arbitrary units); ``own``, at
its own size in metres (the procedural shapes are metric: a bed is a bed's size)."""


def check_sizes(sizes: str, clutter: bool) -> None:
    """A one-line error for ``sizes`` none of :data:`SIZES`, or ``own`` in a room (``clutter``)."""
    if sizes not in SIZES:
        raise JsrteError(f"unknown --sizes {sizes!r} (known: {', '.join(SIZES)})")
    if clutter and sizes != "drawn":
        raise JsrteError("--sizes own is for clean scans: in a room (--clutter) the shape stands at a drawn height")


def virtual_cases(category: str, n: int, folder: Path, *, seed: int = 0, first: int = 0,
                  clutter: bool = False, sizes: str = "drawn") -> list[ScanCase]:
    """Scan ``n`` held-out shapes of ``category`` (evaluation set indices ``first``...) into
    ``folder`` (category_000.ply + .json), each at the size ``sizes`` says (:data:`SIZES`;
    the pose and the views are drawn alike either way). With ``clutter``, each shape is scanned in a room
    instead (:func:`jsrte.scans.scene.scan_room`: walls, a table and boxes beside it, one of
    them touching it) into ``folder/category_000/`` (scan.ply, scan.json, scene.json,
    labels.npy, meshes/); the room is drawn from the same seed, so the same index always
    gives the same room."""
    from jsrte.experiments.truth import truth_of
    from jsrte.geometry.mesh import save_mesh
    from jsrte.scans.scanner import ScannerSettings, at_own_size, scan_mesh, write_scan
    from jsrte.shapes import EVAL_SET_SEED, generate_shape, shape_seed

    check_sizes(sizes, clutter)
    if clutter:
        return _cluttered_cases(category, n, folder, seed=seed, first=first)
    cases = []
    for i in range(first, first + n):
        shape = generate_shape(category, shape_seed(EVAL_SET_SEED, i))
        settings = at_own_size(shape.mesh, ScannerSettings()) if sizes == "own" else ScannerSettings()
        scan = scan_mesh(shape.mesh, rng=np.random.default_rng(seed * 100_003 + i), settings=settings)
        mesh_path = folder / f"{category}_{i:03d}_true_mesh_frame.ply"
        save_mesh(shape.mesh, mesh_path)
        path = write_scan(scan, folder / f"{category}_{i:03d}.ply", seed=seed, mesh=mesh_path)
        cases.append(ScanCase(path.stem, path, truth_of(shape.mesh, scan.scan_from_mesh),
                              {"style": shape.style, "points": len(scan.points)}))
    return cases


def _cluttered_cases(category: str, n: int, folder: Path, *, seed: int, first: int) -> list[ScanCase]:
    from dataclasses import replace

    from jsrte.experiments.truth import truth_of
    from jsrte.scans.scene import SceneSettings, scan_room, write_room
    from jsrte.shapes import EVAL_SET_SEED, generate_shape, shape_seed

    settings = replace(SceneSettings(), other_kinds=CLUTTER_KINDS)
    cases = []
    for i in range(first, first + n):
        shape = generate_shape(category, shape_seed(EVAL_SET_SEED, i))
        room = scan_room(shape.mesh, rng=np.random.default_rng(seed * 100_003 + i), settings=settings,
                         target_kind=category)
        path = write_room(room, folder / f"{category}_{i:03d}", seed=seed)
        cases.append(ScanCase(f"{category}_{i:03d}", path, truth_of(shape.mesh, room.scan.scan_from_mesh),
                              {"style": shape.style, "points": len(room.scan.points),
                               "others": ",".join(o.kind for o in room.objects[1:]),
                               "walls": len(room.walls)}))
    return cases


def folder_cases(folder: Path) -> list[ScanCase]:
    """Real scans: every scan file in ``folder`` (no truth; formats: ``jsrte.formats.SCAN_SUFFIXES``)."""
    from jsrte.formats import SCAN_SUFFIXES

    paths = sorted(p for p in Path(folder).iterdir() if p.suffix.lower() in SCAN_SUFFIXES)
    if not paths:
        raise JsrteError(f"holds no scans ({', '.join(SCAN_SUFFIXES)})", folder)
    return [ScanCase(p.stem, p) for p in paths]


def run_method(method: str, case: ScanCase, *, model: object, database: object, preset: str,
               seed: int, dtype: str | None = None) -> FitResult:
    """One method on one scan (``dtype``: jsrte's decoder arithmetic, None: the preset's).
    Baselines see the scan prepared exactly as the fit does."""
    if method == "jsrte":
        from jsrte.fit import fit

        return fit(case.path, model=model, preset=preset, seed=seed, dtype=dtype)
    from jsrte.baselines import get_baseline
    from jsrte.scans.io import load_scan, read_scan_info
    from jsrte.scans.preprocess import prepare_scan

    rng = np.random.default_rng(seed)
    info = read_scan_info(case.path)
    viewpoints = info.cameras if info is not None else None
    prepared = prepare_scan(load_scan(case.path, rng=rng), rng=rng, viewpoints=viewpoints)
    return get_baseline(method).fit(prepared.points, prepared.normals, prepared.up, database, rng=rng)


def run_scan_experiment(cases: list[ScanCase], methods: list[str], out: Path, *, model: object,
                        preset: str = "fast", seed: int = 0, figure_scans: int = 4,
                        progress: bool = True, jobs: int = 1, threads: int | None = None,
                        report: bool = True, category: str | None = None, dtype: str | None = None) -> list[dict]:
    """Every method on every scan; writes results.csv, table.md, table.csv, figure PNGs and, with
    ``report``, report.html (a 3D view of each scan's jsrte fit, as ``jsrte report``).

    With ``jobs`` > 1 the first scan runs here (it builds the baselines' database, descriptors
    and PointNet classifier into the on-disk cache), the others in ``jobs`` worker processes
    (spawned, ``threads`` // ``jobs`` torch threads each) that read that cache.
    """
    from tqdm import tqdm

    database = _database(model) if any(m != "jsrte" for m in methods) else None
    context = _CaseContext(methods, model, database, preset, seed, dtype)
    rows: list[dict] = []
    figures: list[Path] = []
    html = _HtmlReport() if report else None

    def record(case: ScanCase, case_rows: list[dict], results: dict) -> None:
        rows.extend(case_rows)
        if len(figures) < figure_scans:
            figures.append(_figure(case, _scan_points(case), results, methods, out))
        if html is not None:
            html.add(case, case_rows, results)
        write_csv_atomic(out / "results.csv", rows)

    bar = tqdm(total=len(cases), desc="scans", disable=not progress)
    serial = cases if jobs <= 1 else cases[:1]
    for case in serial:
        record(case, *context.run(case))
        bar.update(1)
    if len(cases) > len(serial):
        for case, (case_rows, results) in _in_workers(cases[len(serial):], context, jobs, threads):
            record(case, case_rows, results)
            bar.update(1)
    bar.close()
    _write_table(rows, methods, out, n_scans=len(cases), category=category)
    if html is not None:
        html.write(out / "report.html", title=f"jsrte experiment scans: {out.resolve().name}")
    return rows


class _HtmlReport:
    """report.html of a scan experiment: per scan, jsrte's fit (else the first method's) with the
    scan, the true mesh and floor, every method's F@5% among the numbers, an overlay thumbnail."""

    def __init__(self) -> None:
        self.items: list = []
        self.thumbnails: dict[str, bytes] = {}

    def add(self, case: ScanCase, case_rows: list[dict], results: dict) -> None:
        from jsrte.scans.io import read_scan_info
        from jsrte.view.loading import Plane, item_from_result
        from jsrte.view.report import overlay_png

        if not results:
            return
        method = "jsrte" if "jsrte" in results else next(iter(results))
        by_method = {r["method"]: r for r in case_rows}
        info = read_scan_info(case.path)
        floor = None if info is None else Plane(info.up, info.floor_offset)
        item = item_from_result(case.name, results[method], scan=_scan_points(case),
                                truth=None if case.truth is None else case.truth.mesh, floor=floor,
                                fscore=by_method[method].get("truth_fscore"))
        for other, row in by_method.items():
            if other != method and row.get("truth_fscore") is not None:
                item.numbers[f"F@5% {other}"] = f"{row['truth_fscore']:.3f}"
        self.items.append(item)
        points = _object_points(case, item.scan)
        self.thumbnails[case.name] = overlay_png(item.mesh, points, None if info is None else info.up)

    def write(self, path: Path, *, title: str) -> None:
        from jsrte.view.report import write_report

        if self.items:
            write_report(self.items, path, title=title, overwrite=True, thumbnails=self.thumbnails)


@dataclass
class _CaseContext:
    """What every scan's runs need (pickled once into each worker process)."""

    methods: list[str]
    model: object
    database: object
    preset: str
    seed: int
    dtype: str | None = None

    def run(self, case: ScanCase) -> tuple[list[dict], dict]:
        """Rows (one per method) and the results by method, for one scan."""
        from jsrte.experiments.truth import score_against_truth
        from jsrte.fit.quality import quality_columns

        scan_points = _scan_points(case)
        rows, results = [], {}
        for method in self.methods:
            row = {"scan": case.name, "method": method, "status": "ok", "error": ""}
            started = time.perf_counter()
            try:
                result = run_method(method, case, model=self.model, database=self.database,
                                    preset=self.preset, seed=self.seed, dtype=self.dtype)
            except JsrteError as exc:
                row.update(status="failed", error=str(exc))
                result = None
            row["seconds"] = round(time.perf_counter() - started, 2)
            if result is not None:
                results[method] = result
                row.update(_scores(result, case, scan_points, self.seed, score_against_truth))
                row.update(quality_columns(result))
                if "class" in result.info:
                    row.update(fitted_class=result.info["class"]["chosen"],
                               class_margin=result.info["class"]["margin"])
            rows.append(row)
        return rows, results


_WORKER_CONTEXT: _CaseContext | None = None


def _init_worker(context: _CaseContext, threads: int, parent_pid: int | None = None) -> None:
    import torch

    from jsrte.model.decoder import flush_denormals

    if parent_pid is not None:  # no orphan keeps running after the experiment is killed
        from jsrte.processes import die_with_parent

        die_with_parent(parent_pid)

    global _WORKER_CONTEXT
    _WORKER_CONTEXT = context
    flush_denormals()
    torch.set_num_threads(threads)


def _run_in_worker(case: ScanCase) -> tuple[list[dict], dict]:
    assert _WORKER_CONTEXT is not None
    return _WORKER_CONTEXT.run(case)


def _in_workers(cases: list[ScanCase], context: _CaseContext, jobs: int, threads: int | None):  # noqa: ANN202
    """(case, run output) in the order of ``cases``, computed by ``jobs`` spawned processes."""
    import multiprocessing
    import os
    from concurrent.futures import ProcessPoolExecutor

    per_job = max(1, (threads or os.cpu_count() or 1) // jobs)
    with ProcessPoolExecutor(max_workers=jobs, mp_context=multiprocessing.get_context("spawn"),
                             initializer=_init_worker, initargs=(context, per_job, os.getpid())) as pool:
        yield from zip(cases, pool.map(_run_in_worker, cases), strict=True)


def _scan_points(case: ScanCase) -> np.ndarray:
    from jsrte.scans.io import load_scan

    return load_scan(case.path).points


def _database(model: object) -> object:
    from jsrte.baselines.database import ShapeDatabase

    return ShapeDatabase.from_model(model)


def _scores(result: FitResult, case: ScanCase, scan_points: np.ndarray, seed: int, score_fn) -> dict:  # noqa: ANN001
    out = {}
    if case.truth is not None:
        truth = score_fn(result, case.truth, rng=np.random.default_rng(seed))
        out.update({f"truth_{k}": v for k, v in truth.items()})
    object_points = _object_points(case, scan_points)
    vs_scan = fscore(result.mesh, object_points, rng=np.random.default_rng(seed))
    out.update(scan_fscore=vs_scan.fscore, scan_precision=vs_scan.precision, scan_recall=vs_scan.recall)
    return out


def _object_points(case: ScanCase, scan_points: np.ndarray) -> np.ndarray:
    """The object's points of a scan (the floor removed by the truth's plane when known; a
    room's object by its labels)."""
    from jsrte.scans.io import read_scan_info
    from jsrte.scans.scene import read_room_labels

    labels = read_room_labels(case.path)
    if labels is not None and len(labels) == len(scan_points):
        return scan_points[labels == 0]
    info = read_scan_info(case.path)
    if info is None:
        return scan_points
    height = scan_points @ info.up - info.floor_offset
    return scan_points[height > 0.02]


def _figure(case: ScanCase, scan_points: np.ndarray, results: dict, methods: list[str], out: Path) -> Path:
    from jsrte.scans.io import read_scan_info
    from jsrte.viz import render_panels

    info = read_scan_info(case.path)
    up = (0.0, 1.0, 0.0) if info is None else tuple(info.up)
    points = _object_points(case, scan_points)
    truth_mesh = None if case.truth is None else case.truth.mesh
    panels = [("test shape", truth_mesh, points)]
    panels += [(m, results[m].mesh if m in results else None, points) for m in methods]
    path = out / f"figure_{case.name}.png"
    render_panels(panels, path, up=up)
    return path


def summarize(rows: list[dict], methods: list[str], category: str | None = None) -> list[dict]:
    """Per method: mean F@5% vs truth and vs scan (failures count as 0), failures, mean time,
    and with the class left to the fit (``fitted_class``), the share of scans given ``category``."""
    table = []
    for m in methods:
        mine = [r for r in rows if r["method"] == m]
        truth_f = [r.get("truth_fscore", 0.0) if r["status"] == "ok" else 0.0 for r in mine]
        scan_f = [r.get("scan_fscore", 0.0) if r["status"] == "ok" else 0.0 for r in mine]
        has_truth = any("truth_fscore" in r for r in mine)
        table.append({
            "method": m, "scans": len(mine), "failed": sum(r["status"] != "ok" for r in mine),
            "fscore_vs_truth": round(float(np.mean(truth_f)), 3) if has_truth and mine else None,
            "fscore_vs_scan": round(float(np.mean(scan_f)), 3) if mine else None,
            "rotation_error_deg_median": _median(mine, "truth_rotation_error_deg"),
            "scale_error_rel_median": _median(mine, "truth_scale_error_rel"),
            "seconds_mean": round(float(np.mean([r["seconds"] for r in mine])), 1) if mine else None,
            "class_accuracy": _class_accuracy(mine, category),
            "paper_fscore": PAPER_TABLE2.get(m),
        })
    return table


def _class_accuracy(rows: list[dict], category: str | None) -> float | None:
    """Share of ``rows`` whose fitted class is ``category`` (failures count as wrong); None when
    no row chose its class."""
    if category is None or not any("fitted_class" in r for r in rows):
        return None
    return round(float(np.mean([r.get("fitted_class") == category for r in rows])), 3)


def _median(rows: list[dict], key: str) -> float | None:
    values = [r[key] for r in rows if r["status"] == "ok" and key in r]
    return round(float(np.median(values)), 3) if values else None


def _write_table(rows: list[dict], methods: list[str], out: Path, *, n_scans: int,
                 category: str | None = None) -> None:
    table = summarize(rows, methods, category)
    write_csv_atomic(out / "table.csv", table)
    lines = [f"Scan experiment: {n_scans} scans of held-out shapes (evaluation seed set, never trained on). "
             "Failures count as F = 0.", "",
             "| | " + " | ".join(t["method"] for t in table) + " |",
             "|---|" + "---|" * len(table)]
    def cell(v: object) -> str:
        return "–" if v is None else str(v)
    for label, key in [("F@5% vs complete true shape (ours)", "fscore_vs_truth"),
                       ("F@5% vs scan (ours)", "fscore_vs_scan"),
                       ("F@5% (paper, Redwood chairs)", "paper_fscore"),
                       ("median rotation error (°)", "rotation_error_deg_median"),
                       ("median relative scale error", "scale_error_rel_median"),
                       ("failed scans", "failed"), ("mean time per scan (s)", "seconds_mean")] + (
                          [(f"class chosen = {category}", "class_accuracy")]
                          if any(t["class_accuracy"] is not None for t in table) else []):
        lines.append(f"| {label} | " + " | ".join(cell(t[key]) for t in table) + " |")
    write_bytes_atomic(out / "table.md", ("\n".join(lines) + "\n").encode())
