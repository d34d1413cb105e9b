"""Local backend: a pool of worker processes (spawned, one PyTorch thread each)."""

from __future__ import annotations

import multiprocessing
import os
from collections import deque
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from contextlib import contextmanager
from dataclasses import replace

from jsrte.batch.worker import (
    THREAD_VARIABLES,
    JobOutcome,
    ModelBlob,
    ScanJob,
    failed_outcome,
    init_local_worker,
    local_task,
)

IN_FLIGHT_PER_WORKER = 2
"""Jobs queued per worker: enough to keep it busy, few enough that scans are read lazily."""


def run_local(jobs: Iterable[ScanJob], blob: ModelBlob, *, workers: int, retries: int,
              on_done: Callable[[JobOutcome], None]) -> None:
    """Fit ``jobs`` on ``workers`` processes, calling ``on_done`` (in this process) as each ends.

    A worker process that dies (a crash in native code, the OOM killer) breaks the pool: the
    jobs it held are sent again, up to ``retries`` times each, to a fresh pool; after that
    they are failed outcomes. Which job killed the worker cannot be told, so every job in
    flight counts one attempt.
    """
    source = iter(jobs)
    again: deque[ScanJob] = deque()
    context = multiprocessing.get_context("spawn")  # the driver may already run PyTorch threads
    while True:
        with _one_thread_children(), ProcessPoolExecutor(workers, mp_context=context,
                                                         initializer=init_local_worker,
                                                         initargs=(blob, os.getpid())) as pool:
            lost = _drain(pool, source, again, workers * IN_FLIGHT_PER_WORKER, on_done)
        if lost is None:
            return
        for job in lost:
            if job.attempt < retries:
                again.append(replace(job, attempt=job.attempt + 1))
            else:
                on_done(failed_outcome(job, f"worker process died ({lost_reason(job)})"))


@contextmanager
def _one_thread_children() -> Iterator[None]:
    """Worker processes started meanwhile inherit one-thread settings for OpenMP and BLAS
    (read when those libraries load, before any code of ours runs in the child)."""
    saved = {name: os.environ.get(name) for name in THREAD_VARIABLES}
    os.environ.update({name: "1" for name in THREAD_VARIABLES})
    try:
        yield
    finally:
        for name, value in saved.items():
            if value is None:
                os.environ.pop(name, None)
            else:
                os.environ[name] = value


def lost_reason(job: ScanJob) -> str:
    """How many times ``job`` was tried, for the error of a scan whose worker died each time."""
    return f"{job.attempt + 1} attempt{'s' if job.attempt else ''}"


def _drain(pool: ProcessPoolExecutor, source: Iterator[ScanJob], again: deque[ScanJob], capacity: int,
           on_done: Callable[[JobOutcome], None]) -> list[ScanJob] | None:
    """Run jobs until none are left (None) or the pool breaks (the jobs it lost)."""
    in_flight: dict[Future, ScanJob] = {}

    def fill() -> None:
        while len(in_flight) < capacity:
            job = again.popleft() if again else next(source, None)
            if job is None:
                return
            in_flight[pool.submit(local_task, job)] = job

    try:
        fill()
        while in_flight:
            done, _ = wait(in_flight, return_when=FIRST_COMPLETED)
            lost = []
            for future in done:
                job = in_flight.pop(future)
                if not _report(future, job, on_done):
                    lost.append(job)
            if lost:  # the pool is broken: keep what finished, hand back the rest
                wait(in_flight)
                return lost + [job for future, job in in_flight.items() if not _report(future, job, on_done)]
            fill()
    except KeyboardInterrupt:
        pool.shutdown(wait=False, cancel_futures=True)
        raise
    return None


def _report(future: Future, job: ScanJob, on_done: Callable[[JobOutcome], None]) -> bool:
    """Pass a finished job's outcome to ``on_done``; False if its worker died."""
    try:
        outcome = future.result()
    except BrokenProcessPool:
        return False
    except Exception as exc:  # e.g. an outcome that could not be sent back
        outcome = failed_outcome(job, f"{type(exc).__name__}: {exc}")
    on_done(outcome)
    return True
