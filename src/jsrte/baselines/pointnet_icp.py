"""PointNet + ICP: a PointNet classifier names the database shape, then the supplementary's
registration (:func:`jsrte.baselines.registration.register`) places it.

The paper's third and strongest baseline (section 4.2, F@5% 0.452 on Redwood chairs). The
classifier (:mod:`jsrte.baselines.pointnet`) is trained on the database shapes the first time it
is needed and cached per database; 1024 points of the query, canonicalized with the known up
axis, are classified, and the most probable shape is registered.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from jsrte.baselines.database import ShapeDatabase
from jsrte.baselines.pointnet import (
    PointNetSettings,
    TrainedClassifier,
    canonicalize,
    classifier_path,
    load_classifier,
    save_classifier,
    train_classifier,
)
from jsrte.baselines.protocol import Stopwatch, baseline_result, check_query
from jsrte.baselines.registration import IcpSettings, register
from jsrte.result import FitResult

CANONICAL_UP = np.array([0.0, 1.0, 0.0])


class PointNetIcp:
    """The ``pointnet-icp`` baseline (see the module docstring).

    Parameters
    ----------
    settings : the classifier and its training
    icp : the registration
    cache : folder of trained classifiers (default ``<cache>/pointnet``)
    progress : print training progress
    """

    name = "pointnet-icp"

    def __init__(self, settings: PointNetSettings = PointNetSettings(),  # noqa: B008 (frozen)
                 icp: IcpSettings = IcpSettings(), *, cache: Path | None = None,  # noqa: B008 (frozen)
                 progress: bool = False) -> None:
        self.settings, self.icp, self.cache, self.progress = settings, icp, cache, progress
        self._trained: dict[str, TrainedClassifier] = {}

    def classifier(self, database: ShapeDatabase) -> TrainedClassifier:
        """The classifier of ``database``: from memory, the cache, or trained now (and cached)."""
        path = classifier_path(database.key, self.settings, self.cache)
        if database.key in self._trained:
            return self._trained[database.key]
        trained = load_classifier(path, len(database), self.settings)
        if trained is None:
            pools = [canonicalize(database.points(i), CANONICAL_UP) for i in range(len(database))]
            trained = train_classifier(pools, self.settings, progress=self.progress)
            save_classifier(trained, path)
        self._trained[database.key] = trained
        return trained

    def fit(self, query_points: np.ndarray, query_normals: np.ndarray, up: np.ndarray,
            database: ShapeDatabase, *, rng: np.random.Generator) -> FitResult:
        clock = Stopwatch()
        points, _, up = check_query(query_points, query_normals, up)
        trained = self.classifier(database)
        clock.lap("database")
        n = self.settings.points
        cloud = canonicalize(points[rng.choice(len(points), n, replace=len(points) < n)], up)
        probs = trained.predict(cloud[None])[0]
        best = int(np.argmax(probs))
        clock.lap("recognize")
        reg = register(points, database.points(best), up, rng=rng, settings=self.icp)
        clock.lap("register")
        return baseline_result(self.name, database, best, reg.transform, loss=reg.rmse,
                               criterion={"name": "pointnet_probability", "value": float(probs[best])},
                               timing=clock.done(), info=reg.to_json() | {"classifier": trained.report})
