"""Ray backend: one task per scan on a Ray cluster, the model in the object store once.

Every node needs jsrte installed (the tasks import it); no shared file system is needed: scans
travel in the tasks' arguments and the result files come back in their return values.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from typing import Any

from jsrte.batch.worker import JobOutcome, ModelBlob, ScanJob, failed_outcome, ray_task
from jsrte.errors import JsrteError

IN_FLIGHT_PER_CPU = 2
LOCAL = "local"
"""``--ray local`` starts a Ray instance on this machine for the run (``--workers`` CPUs)."""


def import_ray() -> Any:
    """The ``ray`` module, or a one-line error saying how to install it."""
    try:
        import ray
    except ImportError:
        raise JsrteError("--ray needs Ray, which is not installed: pip install 'jsrte[ray]'") from None
    return ray


def run_ray(jobs: Iterable[ScanJob], blob: ModelBlob, *, address: str, workers: int | None, retries: int,
            on_done: Callable[[JobOutcome], None]) -> None:
    """Fit ``jobs`` as Ray tasks on the cluster at ``address`` (``auto``, ``HOST:6379``,
    ``ray://HOST:10001``, or ``local``), calling ``on_done`` in this process as each ends.

    A task whose worker dies is retried by Ray up to ``retries`` times; a task that still
    fails becomes a failed outcome. Uses the Ray runtime already started in this process,
    if any, and leaves it running.
    """
    ray = import_ray()
    started = not ray.is_initialized()
    if started:
        _connect(ray, address, workers)
    try:
        model_ref = ray.put(blob)  # the model's bytes, once for the whole cluster
        task = ray.remote(num_cpus=1, max_retries=retries)(ray_task)
        capacity = IN_FLIGHT_PER_CPU * max(1, int(ray.cluster_resources().get("CPU", 1)))
        source = iter(jobs)
        in_flight: dict[Any, ScanJob] = {}
        while True:
            while len(in_flight) < capacity and (job := next(source, None)) is not None:
                in_flight[task.remote(model_ref, job)] = job
            if not in_flight:
                return
            ready, _ = ray.wait(list(in_flight), num_returns=1)
            for ref in ready:
                job = in_flight.pop(ref)
                try:
                    outcome = ray.get(ref)
                except ray.exceptions.RayError as exc:
                    first = (str(exc).strip().splitlines() or [""])[0]
                    outcome = failed_outcome(job, f"Ray {type(exc).__name__}: {first}")
                on_done(outcome)
    finally:
        if started:
            ray.shutdown()


def _connect(ray: Any, address: str, workers: int | None) -> None:
    try:
        if address == LOCAL:
            ray.init(address=LOCAL, num_cpus=workers, include_dashboard=False, log_to_driver=False)
        else:
            ray.init(address=address, log_to_driver=False)
    except (ConnectionError, RuntimeError, ValueError) as exc:
        raise JsrteError(f"cannot connect to the Ray cluster at {address!r} ({exc})") from exc
