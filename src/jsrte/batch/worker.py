"""The work of one scan, the same in a local worker process and in a Ray task.

A job carries the scan's bytes (and its JSON sidecar, whose camera positions ``jsrte fit``
uses), the truth mesh's bytes when there is one, and the fit options; the outcome carries the
summary row and the result files' bytes. Nothing is read from or written to the driver's disk,
so Ray workers need no shared file system. The model travels once per worker (a local pool's
initializer, Ray's object store) and is loaded once per worker process.

Only the standard library is imported at module level: a worker limits its threads before
PyTorch and NumPy start theirs.
"""

from __future__ import annotations

import os
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from jsrte.options import FitOptions

THREAD_VARIABLES = ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS")
_MODEL_CACHE: dict[str, Any] = {}


@dataclass(frozen=True)
class ModelBlob:
    """A model file's bytes and what the workers need besides.

    Attributes
    ----------
    name : the model's name (as ``resolve_model`` gives it)
    path : where the driver read it (recorded, never opened by the workers)
    sha256 : hex digest of ``data`` (the workers' cache key)
    data : the ``.safetensors`` file
    geometry : canonical height and radius of the class, computed once by the driver
    """

    name: str
    path: str
    sha256: str
    data: bytes
    geometry: dict[str, float]


@dataclass(frozen=True)
class ScanJob:
    """One scan to fit.

    Attributes
    ----------
    index : position in the run's scan list
    name : result folder name
    scan : the scan's path as the driver knows it (recorded, and used in error messages)
    files : file name -> bytes: the scan first, then its ``<stem>.json`` if any
    truth_mesh : (file name, bytes) of the true mesh, or None
    truth_pose : ``Sim3.to_dict()`` of the true scan_from_mesh, or None
    options : fit options
    attempt : 0, then 1, 2, ... when re-sent after a worker died
    """

    index: int
    name: str
    scan: str
    files: dict[str, bytes]
    options: FitOptions
    truth_mesh: tuple[str, bytes] | None = None
    truth_pose: dict | None = None
    attempt: int = 0


@dataclass
class JobOutcome:
    """What comes back: the summary row and, for a success, the result files (fit.json last)."""

    index: int
    name: str
    row: dict[str, Any]
    files: dict[str, bytes] = field(default_factory=dict)

    @property
    def ok(self) -> bool:
        return self.row["status"] == "ok"


def failed_outcome(job: ScanJob, error: str, seconds: float = 0.0) -> JobOutcome:
    """The outcome of a scan that could not be fitted."""
    return JobOutcome(job.index, job.name, summary_row(job.scan, job.name, "failed", error=error,
                                                        seconds=seconds))


def summary_row(scan: str, name: str, status: str, *, error: str = "", fscore: float | None = None,
                scale: float | None = None, seconds: float = 0.0, flag: str | None = None,
                inlier_share: float | None = None) -> dict[str, Any]:
    """A row of summary.csv (empty cells for what is unknown)."""
    return {"scan": scan, "result": name, "status": status, "error": error,
            "fscore": "" if fscore is None else round(float(fscore), 4),
            "scale": "" if scale is None else round(float(scale), 5), "time_s": round(seconds, 2),
            "flag": flag or "", "inlier_share": "" if inlier_share is None else round(float(inlier_share), 4)}


# -- worker set-up --------------------------------------------------------------------------

_LOCAL_BLOB: ModelBlob | None = None

def limit_threads() -> None:
    """One thread per worker (the workers are the parallelism)."""
    for name in THREAD_VARIABLES:
        os.environ[name] = "1"
    import torch

    torch.set_num_threads(1)


def init_local_worker(blob: ModelBlob, parent_pid: int | None = None) -> None:
    """Process-pool initializer: end with the driver ``parent_pid`` (no orphans after a kill), and
    keep the model for every job of this process."""
    global _LOCAL_BLOB
    if parent_pid is not None:
        from jsrte.processes import die_with_parent

        die_with_parent(parent_pid)
    limit_threads()
    _LOCAL_BLOB = blob


def local_task(job: ScanJob) -> JobOutcome:
    """A process-pool task."""
    assert _LOCAL_BLOB is not None, "init_local_worker did not run"
    return fit_job(job, _LOCAL_BLOB)


def ray_task(blob: ModelBlob, job: ScanJob) -> JobOutcome:
    """A Ray task (``blob`` arrives from the object store, put there once)."""
    limit_threads()
    return fit_job(job, blob)


def cached_model(blob: ModelBlob) -> Any:
    """The DeepSdfModel in ``blob``, loaded once per process."""
    if blob.sha256 not in _MODEL_CACHE:
        from jsrte.model.checkpoint import load_model

        _MODEL_CACHE.clear()
        with tempfile.TemporaryDirectory(prefix="jsrte-model-") as tmp:
            path = Path(tmp) / "model.safetensors"
            path.write_bytes(blob.data)
            model = load_model(path)
        model.meta.setdefault("name", blob.name)
        model.meta.update(blob.geometry, path=blob.path)
        _MODEL_CACHE[blob.sha256] = model
    return _MODEL_CACHE[blob.sha256]


# -- one scan -------------------------------------------------------------------------------

def fit_job(job: ScanJob, blob: ModelBlob) -> JobOutcome:
    """Fit one scan; any error becomes a failed outcome (the run goes on)."""
    started = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="jsrte-fit-many-") as tmp:
        try:
            return _fit(job, cached_model(blob), Path(tmp), started)
        except Exception as exc:  # one scan's failure, whatever it is, is reported and the run goes on
            message = str(exc) if type(exc).__name__ == "JsrteError" else f"{type(exc).__name__}: {exc}"
            message = message.replace(str(Path(tmp) / "in"), str(Path(job.scan).parent))
            return failed_outcome(job, " ".join(message.split()), time.perf_counter() - started)


def _fit(job: ScanJob, model: Any, tmp: Path, started: float) -> JobOutcome:

    from jsrte.fit import fit
    from jsrte.fit.outputs import write_fit_outputs

    inputs = tmp / "in"
    inputs.mkdir()
    for file_name, data in job.files.items():
        (inputs / Path(file_name).name).write_bytes(data)
    scan = inputs / Path(next(iter(job.files))).name
    result = fit(scan, model=model, options=job.options)
    scores, note = _score(job, result, tmp)
    seconds = time.perf_counter() - started
    out = tmp / "out"
    out.mkdir()
    written = write_fit_outputs(result, out, query_points=result.query_points, up=result.info.get("up"),
                                extra={"input": job.scan, "truth": scores, "wall_time_s": round(seconds, 2)})
    files = {p.name: p.read_bytes() for p in written}
    row = summary_row(job.scan, job.name, "ok", error=note, scale=result.transform.s, seconds=seconds,
                      fscore=None if scores is None else scores["fscore"], flag=result.flag,
                      inlier_share=result.quality.get("inlier_share"))
    return JobOutcome(job.index, job.name, row, files)


def _score(job: ScanJob, result: Any, tmp: Path) -> tuple[dict | None, str]:
    """F@5% and transform errors against the truth, or None (and why, if the truth is bad)."""
    if job.truth_mesh is None or job.truth_pose is None:
        return None, ""
    import numpy as np

    from jsrte.errors import JsrteError
    from jsrte.experiments.truth import score_against_truth, truth_of
    from jsrte.geometry.mesh import load_mesh
    from jsrte.geometry.sim3 import Sim3
    from jsrte.presets import get_preset

    name, data = job.truth_mesh
    path = tmp / "truth" / Path(name).name
    path.parent.mkdir()
    path.write_bytes(data)
    try:
        truth = truth_of(load_mesh(path), Sim3.from_dict(job.truth_pose))
    except (JsrteError, KeyError, TypeError, ValueError) as exc:
        return None, f"truth not scored: {str(exc).replace(str(path.parent), '(truth)')}"
    scores = score_against_truth(result, truth, rng=np.random.default_rng(job.options.seed),
                                 settings=get_preset(job.options.preset).fit)
    return {k: float(v) for k, v in scores.items()}, ""

