"""What every baseline shares: the ``Baseline`` protocol, its failure type, and result building."""

from __future__ import annotations

import time
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np

from jsrte.errors import JsrteError
from jsrte.geometry.sim3 import Sim3
from jsrte.result import FitResult

if TYPE_CHECKING:
    from jsrte.baselines.database import ShapeDatabase

MIN_QUERY_POINTS = 50
"""A query with fewer points than this is refused by every baseline (as ``prepare_scan`` does)."""


class BaselineFailed(JsrteError):
    """A baseline cannot handle this query (too few points, no keypoints, no matches, ...).

    The scan experiment records it as a failure for that scan; the CLI prints it as an error.
    """


class Baseline(Protocol):
    """A recognize-then-register method: retrieve a database shape, then estimate its pose.

    ``fit`` takes the query's points ``(n, 3)`` in scan units (metres) with outward unit normals
    ``(n, 3)`` and the known up axis ``(3,)`` (the floor normal), and returns a
    :class:`~jsrte.result.FitResult` whose ``transform`` is ``scan_from_canonical`` and whose
    ``mesh_canonical`` is the retrieved database shape in its normalized canonical frame.
    It raises :class:`BaselineFailed` when it cannot produce an answer.
    """

    name: str

    def fit(self, query_points: np.ndarray, query_normals: np.ndarray, up: np.ndarray,
            database: ShapeDatabase, *, rng: np.random.Generator) -> FitResult: ...


def check_query(points: np.ndarray, normals: np.ndarray | None, up: np.ndarray | None,
                *, min_points: int = MIN_QUERY_POINTS) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Validate a query: points (n, 3) finite, normals (n, 3) (unit length forced), up (3,) non-zero.

    Returns float64 copies ``(points, normals, up)``; ``up`` defaults to +y. Raises
    :class:`BaselineFailed` for too few points and ``JsrteError`` for malformed arrays.
    """
    p = np.asarray(points, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 3:
        raise JsrteError(f"query points must be an (n, 3) array, got shape {p.shape}")
    if len(p) < min_points:
        raise BaselineFailed(f"the query has only {len(p)} points (need at least {min_points})")
    if not np.all(np.isfinite(p)):
        raise JsrteError("the query has NaN or infinite coordinates")
    if normals is None:
        from jsrte.scans.preprocess import estimate_normals

        n = estimate_normals(p, up=up)
    else:
        n = np.asarray(normals, dtype=np.float64)
        if n.shape != p.shape:
            raise JsrteError(f"query normals {n.shape} do not match the points {p.shape}")
    length = np.linalg.norm(n, axis=1, keepdims=True)
    n = np.where(length > 0, n / np.maximum(length, 1e-12), np.array([0.0, 1.0, 0.0]))
    u = np.array([0.0, 1.0, 0.0]) if up is None else np.asarray(up, dtype=np.float64).reshape(3)
    if not np.linalg.norm(u) > 0:
        raise JsrteError("the up axis must be a non-zero vector")
    if np.ptp(p, axis=0).max() <= 0:
        raise BaselineFailed("the query's points all coincide")
    return p, n, u / np.linalg.norm(u)


class Stopwatch:
    """Named lap times in seconds (``laps``), plus ``total`` on :meth:`done`."""

    def __init__(self) -> None:
        self.start = self.last = time.perf_counter()
        self.laps: dict[str, float] = {}

    def lap(self, name: str) -> None:
        now = time.perf_counter()
        self.laps[name] = round(now - self.last, 4)
        self.last = now

    def done(self) -> dict[str, float]:
        return self.laps | {"total": round(time.perf_counter() - self.start, 4)}


def baseline_result(name: str, database: ShapeDatabase, index: int, transform: Sim3, *, loss: float,
                    criterion: dict[str, Any], timing: dict[str, float],
                    info: dict[str, Any] | None = None) -> FitResult:
    """The common result of a baseline: database shape ``index`` placed by ``transform``.

    Parameters
    ----------
    name : the baseline's name (``FitResult.method``)
    database : the database the shape was retrieved from
    index : the retrieved shape's index
    transform : ``scan_from_canonical``
    loss : the method's final registration residual (scan units)
    criterion : how the shape was retrieved and the winning score
    """
    return FitResult(
        method=name, transform=transform, latent=None, mesh_canonical=database.meshes[index].copy(),
        loss=float(loss), criterion=criterion, timing=timing,
        info={"retrieved_index": int(index), "retrieved_name": database.names[index],
              "database": database.describe()} | (info or {}),
    )
