"""``fit_many``: fit every scan of a folder or list, locally or on Ray; resumable, one failure at a time.

Layout of the output folder ``out``::

    out/<name>/fit.json, shape.ply, shape_canonical.ply, overlay.png   (as ``jsrte fit``)
    out/summary.csv                                                     (one row per scan)

A scan is done when ``out/<name>/fit.json`` exists (it is written last, atomically): a rerun
skips it, so an interrupted run loses nothing that finished and fits nothing twice; failed
scans are tried again. ``summary.csv`` is rewritten atomically after every scan. Results are
reused only when made with the same model (by SHA-256) and preset: a run with another model
or preset is refused unless ``overwrite`` (then every scan is fitted again).
"""

from __future__ import annotations

import csv
import io
import json
import os
import socket
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from jsrte.atomic import write_bytes_atomic
from jsrte.batch.inputs import find_truth, list_scans, result_names
from jsrte.batch.worker import JobOutcome, ModelBlob, ScanJob, failed_outcome, summary_row
from jsrte.errors import JsrteError
from jsrte.fit.outputs import RESULT_NAME
from jsrte.options import FitOptions

SUMMARY_NAME = "summary.csv"
COLUMNS = ("scan", "result", "status", "error", "fscore", "scale", "time_s", "flag", "inlier_share", "model",
           "model_sha256", "preset")
"""summary.csv: the scan's path, its result folder, ok/failed, the error, F@5% against the truth
(virtual scans whose JSON names a findable mesh; else empty), the estimated scale, seconds, the
flag and inlier share (docs/confidence.md), and the model (name, SHA-256 of its file) and preset of the run."""
LOCK_NAME = ".fit-many.lock"


@dataclass
class BatchReport:
    """What a run did.

    Attributes
    ----------
    summary : path of summary.csv
    rows : one summary row per scan, in the order of the scan list
    fitted : scans fitted by this run
    skipped : scans already done before it
    failed : scans that failed in this run
    """

    summary: Path
    rows: list[dict[str, Any]]
    fitted: int
    skipped: int
    failed: int


def fit_many(source: str | Path, *, out: str | Path, model: str | Path = "chair", options: FitOptions | None = None,
             workers: int | None = None, ray_address: str | None = None, retries: int = 2,
             progress: bool = True, overwrite: bool = False) -> BatchReport:
    """Fit every scan of ``source`` (a folder, or a ``.txt`` list) into ``out``.

    Parameters
    ----------
    model, options : as ``jsrte.fit.fit``, the same for every scan
    workers : local worker processes (default: all cores); with ``ray_address="local"`` the
        CPUs of the Ray instance started here; ignored for another Ray cluster
    ray_address : None (local process pool) or a Ray address (see ``run_ray``)
    retries : times a scan is sent again after its worker process died
    overwrite : fit every scan again, replacing the results already in ``out`` (needed when they
        were made with another model, preset or options)
    """
    options = options or FitOptions()
    if ray_address is not None:
        from jsrte.batch.ray_backend import import_ray

        import_ray()  # before anything is written: say how to install it
    scans = list_scans(source)
    names = result_names(scans)
    out = Path(out)
    workers = workers or os.cpu_count() or 1
    identity = model_identity(model, options.preset)  # a bad model stops the run before anything is written
    if not overwrite:
        _check_same_identity(out, names, identity)
        _check_same_options(out, names, options)
    blob = None
    if overwrite or any(not (out / name / RESULT_NAME).is_file() for name in names):
        blob = load_blob(model)
    with _locked(out):
        rows = {} if overwrite else {i: row for i, (scan, name) in enumerate(zip(scans, names, strict=True))
                                     if (row := _done_row(scan, out / name)) is not None}
        todo = [i for i in range(len(scans)) if i not in rows]
        summary = _Summary(out / SUMMARY_NAME, rows, identity)
        summary.write()
        counts = {"fitted": 0, "failed": 0}
        if todo:
            blob = blob or load_blob(model)
            bar = _bar(len(scans), len(rows), progress)

            def on_done(outcome: JobOutcome) -> None:
                if outcome.ok:
                    _write_result(out / outcome.name, outcome.files)
                counts["fitted" if outcome.ok else "failed"] += 1
                summary.add(outcome.index, outcome.row)
                bar.update(1)
                bar.set_postfix(failed=counts["failed"])

            jobs = _jobs(todo, scans, names, options, on_done)
            try:
                if ray_address is None:
                    from jsrte.batch.local import run_local

                    run_local(jobs, blob, workers=min(workers, len(todo)), retries=retries, on_done=on_done)
                else:
                    from jsrte.batch.ray_backend import run_ray

                    run_ray(jobs, blob, address=ray_address, workers=workers, retries=retries,
                            on_done=on_done)
            finally:
                bar.close()
    return BatchReport(out / SUMMARY_NAME, summary.ordered(), counts["fitted"], len(scans) - len(todo),
                       counts["failed"])


# -- inputs and outputs -----------------------------------------------------------------------

def load_blob(model: str | Path) -> ModelBlob:
    """Read the model once; compute its class geometry here rather than in every worker."""
    from jsrte.fit.solve import class_geometry
    from jsrte.model.checkpoint import file_hash
    from jsrte.model.registry import resolve_model, resolve_model_path

    path = resolve_model_path(model)
    loaded = resolve_model(path)
    geometry = class_geometry(loaded)
    name = loaded.meta.get("name") or str(model)
    return ModelBlob(name=str(name), path=str(path), sha256=file_hash(path), data=path.read_bytes(),
                     geometry={"canonical_height": geometry.height, "canonical_radius": geometry.radius})


def model_identity(model: str | Path, preset: str) -> dict[str, str]:
    """What makes results comparable: the model's name and file SHA-256, and the preset."""
    from jsrte.model.checkpoint import file_hash, read_metadata
    from jsrte.model.registry import resolve_model_path

    path = resolve_model_path(model)
    name = read_metadata(path).get("name") or str(path)
    return {"model": str(name), "model_sha256": file_hash(path), "preset": preset}


def _check_same_identity(out: Path, names: list[str], identity: dict[str, str]) -> None:
    """JsrteError if ``out`` holds results of these scans made with another model or preset."""
    others: dict[tuple[str, str, str], int] = {}
    for name in names:
        try:
            result = json.loads((out / name / RESULT_NAME).read_text())
            made = (str(result.get("model")), str(result.get("model_sha256")), str(result.get("preset")))
        except (OSError, ValueError, AttributeError):
            continue  # no result (or an unreadable one, fitted again)
        if made[1:] != (identity["model_sha256"], identity["preset"]):
            others[made] = others.get(made, 0) + 1
    if others:
        (model, sha, preset), count = next(iter(others.items()))
        raise JsrteError(f"holds {sum(others.values())} result(s) made with model {model!r} ({sha[:12]}), preset "
                         f"{preset!r}; this run uses model {identity['model']!r} "
                         f"({identity['model_sha256'][:12]}), preset {identity['preset']!r}: pass --overwrite to "
                         "fit every scan again, or give another --out", out)


def _check_same_options(out: Path, names: list[str], options: FitOptions) -> None:
    """JsrteError if ``out`` holds results of these scans made with other fit options (the device aside)."""
    wanted = {k: v for k, v in options.record().items() if k != "device"}
    for name in names:
        try:
            made = json.loads((out / name / RESULT_NAME).read_text()).get("options")
        except (OSError, ValueError, AttributeError):
            continue
        if not isinstance(made, dict):
            continue  # recorded before options were: the model and preset checks stand
        differ = [f"{k} {made.get(k)!r} there, {v!r} now" for k, v in wanted.items() if made.get(k) != v]
        if differ:
            raise JsrteError(f"{name} was fitted with other options ({'; '.join(differ)[:200]}): pass --overwrite "
                             "to fit every scan again, or give another --out", out)


def make_job(index: int, name: str, scan: Path, options: FitOptions) -> ScanJob:
    """Read a scan (and its JSON sidecar, and its truth mesh) into a job; JsrteError if unreadable."""
    if not scan.is_file():
        raise JsrteError("no such file", scan)
    try:
        files = {scan.name: scan.read_bytes()}
        sidecar = scan.with_suffix(".json")
        if sidecar.is_file() and sidecar != scan:
            files[sidecar.name] = sidecar.read_bytes()
        truth = find_truth(scan)
        truth_mesh = None if truth is None else (truth.mesh.name, truth.mesh.read_bytes())
    except OSError as exc:
        raise JsrteError(f"cannot read ({exc.strerror or exc})", scan) from exc
    return ScanJob(index=index, name=name, scan=str(scan), files=files, options=options,
                   truth_mesh=truth_mesh, truth_pose=None if truth is None else truth.scan_from_mesh)


def _jobs(todo: list[int], scans: list[Path], names: list[str], options: FitOptions,
          on_done: Any) -> Iterator[ScanJob]:
    """Jobs read lazily, as the backend asks for them; an unreadable scan fails right here."""
    for i in todo:
        try:
            yield make_job(i, names[i], scans[i], options)
        except JsrteError as exc:
            on_done(failed_outcome(ScanJob(i, names[i], str(scans[i]), {}, options), str(exc)))


def _done_row(scan: Path, folder: Path) -> dict[str, Any] | None:
    """The summary row of a scan fitted by an earlier run (None if not done)."""
    path = folder / RESULT_NAME
    if not path.is_file():
        return None
    try:
        result = json.loads(path.read_text())
        truth = result.get("truth") or {}
        seconds = result.get("wall_time_s", (result.get("timing_s") or {}).get("total", 0.0))
        return summary_row(str(scan), folder.name, "ok", fscore=truth.get("fscore"), scale=result["scale"],
                           seconds=float(seconds), flag=result.get("flag"),
                           inlier_share=(result.get("quality") or {}).get("inlier_share"))
    except (OSError, ValueError, KeyError, TypeError, AttributeError):
        return None  # not a result after all: fit it again


def _write_result(folder: Path, files: dict[str, bytes]) -> None:
    """The worker's files, each atomically, fit.json last (it marks the scan done)."""
    folder.mkdir(parents=True, exist_ok=True)
    for name in sorted(files, key=lambda n: n == RESULT_NAME):
        write_bytes_atomic(folder / Path(name).name, files[name])


class _Summary:
    """summary.csv, rewritten atomically whenever a row is added."""

    def __init__(self, path: Path, rows: dict[int, dict[str, Any]], identity: dict[str, str]) -> None:
        self.path, self.rows, self.identity = path, dict(rows), identity

    def add(self, index: int, row: dict[str, Any]) -> None:
        self.rows[index] = row
        self.write()

    def ordered(self) -> list[dict[str, Any]]:
        return [self.rows[i] for i in sorted(self.rows)]

    def write(self) -> None:
        text = io.StringIO()
        writer = csv.DictWriter(text, fieldnames=COLUMNS, lineterminator="\n")
        writer.writeheader()
        writer.writerows(row | self.identity for row in self.ordered())
        write_bytes_atomic(self.path, text.getvalue().encode())


def _bar(total: int, initial: int, progress: bool) -> Any:
    from tqdm import tqdm

    return tqdm(total=total, initial=initial, desc="fitting", unit="scan", disable=not progress)


@contextmanager
def _locked(out: Path) -> Iterator[None]:
    """Refuse a second fit-many writing into the same folder at the same time."""
    out.mkdir(parents=True, exist_ok=True)
    lock = out / LOCK_NAME
    me = f"{socket.gethostname()} {os.getpid()}"
    for _ in range(2):
        try:
            fd = os.open(lock, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644)
            break
        except FileExistsError:
            if not _stale(lock):
                raise JsrteError(f"another fit-many is writing here ({_owner(lock)}); if it is gone, "
                                 f"delete {LOCK_NAME}", out) from None
            lock.unlink(missing_ok=True)
    else:
        raise JsrteError(f"cannot take {LOCK_NAME}", out)
    with os.fdopen(fd, "w") as f:
        f.write(me + "\n")
    try:
        yield
    finally:
        lock.unlink(missing_ok=True)


def _owner(lock: Path) -> str:
    try:
        return "host and process " + lock.read_text().strip()
    except OSError:
        return "unknown process"


def _stale(lock: Path) -> bool:
    """A lock gone, or left by a process of this host that no longer runs."""
    try:
        host, pid = lock.read_text().split()
        if host != socket.gethostname():
            return False
        os.kill(int(pid), 0)
    except (ProcessLookupError, FileNotFoundError):
        return True
    except (OSError, ValueError):
        return False
    return False
