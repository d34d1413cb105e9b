"""Where a fit spends its time: named stages, their seconds and their decoder evaluations.

The library marks its stages with :func:`stage` (a context manager) or :func:`timed_stage` (a
decorator); the decoder reports every batch of points it evaluates with
:func:`count_evaluations`. Nothing is recorded unless a caller collects a profile::

    with profiling() as profile:
        result = jsrte.fit("scan.ply")
    profile.seconds, profile.evaluations   # {"floor and cleaning": 0.41, ...}, {"solve": 150000, ...}

Stages nest: time spent in an inner stage counts for the inner one only (exclusive times), and
each evaluation counts for the innermost stage running. Work outside every stage is "other".
This module imports nothing heavy.
"""

from __future__ import annotations

import functools
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from contextvars import ContextVar
from dataclasses import dataclass, field
from typing import Any, TypeVar

OTHER = "other"
"""The stage of work done while no named stage runs."""

F = TypeVar("F", bound=Callable[..., Any])


@dataclass
class StageProfile:
    """Per stage, in first-seen order: seconds (exclusive, wall clock), CPU seconds (exclusive,
    every thread of the process: about twice the wall time when two cores are busy, and less
    sensitive than it to other processes' load) and decoder evaluations."""

    seconds: dict[str, float] = field(default_factory=dict)
    cpu_seconds: dict[str, float] = field(default_factory=dict)
    evaluations: dict[str, int] = field(default_factory=dict)
    _stack: list[list[Any]] = field(default_factory=list, repr=False)  # name, starts, time in children

    @property
    def total_seconds(self) -> float:
        return sum(self.seconds.values())

    @property
    def total_evaluations(self) -> int:
        return sum(self.evaluations.values())

    def as_dict(self) -> dict[str, dict[str, float]]:
        """{stage: {"seconds": s, "cpu_seconds": c, "evaluations": n}} (JSON-ready)."""
        names = list(dict.fromkeys([*self.seconds, *self.evaluations]))
        return {n: {"seconds": round(self.seconds.get(n, 0.0), 4),
                    "cpu_seconds": round(self.cpu_seconds.get(n, 0.0), 4),
                    "evaluations": self.evaluations.get(n, 0)} for n in names}

    def _enter(self, name: str) -> None:
        self._stack.append([name, time.perf_counter(), time.process_time(), 0.0, 0.0])

    def _exit(self) -> None:
        name, start, cpu_start, children, cpu_children = self._stack.pop()
        total = time.perf_counter() - start
        cpu_total = time.process_time() - cpu_start
        self.seconds[name] = self.seconds.get(name, 0.0) + total - children
        self.cpu_seconds[name] = self.cpu_seconds.get(name, 0.0) + cpu_total - cpu_children
        if self._stack:
            self._stack[-1][3] += total
            self._stack[-1][4] += cpu_total

    def _count(self, n: int) -> None:
        name = self._stack[-1][0] if self._stack else OTHER
        self.evaluations[name] = self.evaluations.get(name, 0) + n


_ACTIVE: ContextVar[StageProfile | None] = ContextVar("jsrte_stage_profile", default=None)


@contextmanager
def profiling() -> Iterator[StageProfile]:
    """Collect the stages run inside the block into a new :class:`StageProfile`.

    The time inside the block but outside every stage is recorded as :data:`OTHER`.
    """
    profile = StageProfile()
    token = _ACTIVE.set(profile)
    profile._enter(OTHER)
    try:
        yield profile
    finally:
        while profile._stack:  # an exception may leave inner stages open
            profile._exit()
        _ACTIVE.reset(token)


@contextmanager
def stage(name: str) -> Iterator[None]:
    """Attribute the block's time and decoder evaluations to ``name`` (no cost without a profile)."""
    profile = _ACTIVE.get()
    if profile is None:
        yield
        return
    profile._enter(name)
    try:
        yield
    finally:
        profile._exit()


def timed_stage(name: str) -> Callable[[F], F]:
    """Decorator: every call of the function is the stage ``name``."""

    def decorate(fn: F) -> F:
        @functools.wraps(fn)
        def wrapper(*args: Any, **kwargs: Any) -> Any:
            with stage(name):
                return fn(*args, **kwargs)

        return wrapper  # type: ignore[return-value]

    return decorate


def count_evaluations(n: int) -> None:
    """Record ``n`` points passed through the decoder (called by ``Decoder.forward``)."""
    profile = _ACTIVE.get()
    if profile is not None:
        profile._count(int(n))
