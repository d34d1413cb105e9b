"""Whole scenes: every object standing on the floor of a scan, each with its class and its fit.

The scan is segmented once (``jsrte.fit.query.scan_candidates``: floor, walls, clusters). Every
candidate that may be an object (not too small, too flat or too big) is then fitted in turn:

1. its class, when several models are given (``--model auto``): each model is fitted quickly
   to the candidate and the lowest screen score wins (``jsrte.fit.screen.choose_class``, the
   same scale-free score that picks the class of a single object);
2. the full fit with that model and the preset's settings (``jsrte.fit.solve.fit_query``).

A candidate whose fit fails (too few points, a degenerate cluster) is recorded as failed with
the reason and the others go on; candidates the segmentation rejected are listed as skipped with
their point counts. ``jsrte.fit.scene_outputs`` writes the files.
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from jsrte.errors import JsrteError
from jsrte.fit.screen import ScreenSettings
from jsrte.options import FitOptions
from jsrte.result import FitResult


@dataclass
class SceneObject:
    """One candidate object of a scene and what became of it.

    Attributes
    ----------
    index : its number in the scene (objects/NN/), in the order fitted
    candidate : its position in the segmentation's candidates
    points : (m, 3) float64 its scan points (scan units)
    status : "ok" (fitted) or "failed"
    reason : why it failed ("" when fitted)
    model : the name of the model fitted (the class), None when it failed before the choice
    class_choice : every class's screen score and the margin (None with one model)
    result : the fit (None when it failed)
    """

    index: int
    candidate: int
    points: np.ndarray = field(repr=False)
    status: str = "ok"
    reason: str = ""
    model: str | None = None
    class_choice: dict[str, Any] | None = None
    result: FitResult | None = None

    @property
    def centre(self) -> list[float]:
        """The centre of its points' bounding box (3,), scan units."""
        return ((self.points.min(0) + self.points.max(0)) / 2.0).tolist()

    def to_json(self) -> dict[str, Any]:
        """scene.json's record of the object."""
        entry: dict[str, Any] = {"index": self.index, "folder": f"objects/{self.index:02d}", "status": self.status,
                                 "candidate": self.candidate, "points": len(self.points),
                                 "candidate_centre": [round(v, 5) for v in self.centre], "class": self.model}
        if self.class_choice is not None:
            entry["class_scores"] = self.class_choice.get("scores")
            entry["class_margin"] = self.class_choice.get("margin")
        if self.reason:
            entry["reason"] = self.reason
        r = self.result
        if r is not None:
            mesh = r.mesh
            entry.update(transform=r.transform.to_dict(),
                         latent=None if r.latent is None else np.asarray(r.latent, float).round(6).tolist(),
                         fitted_centre=None if mesh is None else _box_centre(np.asarray(mesh.vertices)),
                         flag=r.flag, quality=json_ready(r.quality), loss=json_ready({"loss": r.loss})["loss"],
                         time_s=r.timing.get("total"))
        return entry


@dataclass
class SceneResult:
    """Every object of a scan, fitted.

    Attributes
    ----------
    objects : the candidates fitted (or failed), best class rank first
    skipped : the candidates the segmentation rejected: position, points, reason
    segmentation : the segmentation's record (walls, removed points, candidates)
    scan_points : (n, 3) float64 the scan's points (scan units), for figures
    up : (3,) the up axis (floor normal)
    floor_offset : the floor plane is {x : up·x = floor_offset}; None without a floor
    options : the fit options as recorded
    models : the names of the models the classes were chosen among
    """

    objects: list[SceneObject]
    skipped: list[dict[str, Any]]
    segmentation: dict[str, Any]
    scan_points: np.ndarray = field(repr=False)
    up: np.ndarray | None = None
    floor_offset: float | None = None
    options: dict[str, Any] = field(default_factory=dict)
    models: list[str] = field(default_factory=list)

    @property
    def fitted(self) -> list[SceneObject]:
        """The objects whose fit succeeded."""
        return [o for o in self.objects if o.result is not None]

    def to_json(self) -> dict[str, Any]:
        """scene.json: the objects, the skipped candidates, walls, floor and options."""
        seg = self.segmentation
        return {"format": "jsrte-scene", "models": self.models, "options": self.options,
                "floor": {"up": None if self.up is None else np.asarray(self.up, float).tolist(),
                          "offset": self.floor_offset},
                "walls": seg.get("walls", []), "removed": seg.get("removed", {}),
                "objects": [o.to_json() for o in self.objects], "skipped": self.skipped,
                "counts": {"fitted": len(self.fitted), "failed": len(self.objects) - len(self.fitted),
                           "skipped": len(self.skipped)}}


def fit_scene(path: str | Path, *, model: object = "auto", options: FitOptions | None = None,
              screen: ScreenSettings = ScreenSettings(), progress: bool = False, workers: int = 1,
              **changes: object) -> SceneResult:
    """Fit every object standing on the floor of the scan at ``path``.

    Parameters
    ----------
    path : a scan (PLY/PCD/XYZ, metres, floor found or ``up`` given)
    model : the models the class is chosen among (as ``jsrte.fit.fit``: "auto" for every
        shipped model, "chair,table", a list, or one model: then no class is chosen)
    options : how to fit (``FitOptions``; ``at`` is refused: a scene fits every object)
    screen : how the class of each object is screened
    progress : show each fit's progress bar (one object at a time only)
    workers : objects fitted at once, each in a thread of its own with one PyTorch thread (the
        fits' PyTorch and NumPy work runs outside Python's interpreter lock); 1: one after the
        other, with PyTorch's threads as they are set
    changes : options by name, applied over ``options``

    Raises ``JsrteError`` when the scan holds no object (saying what segmentation removed).
    """
    from jsrte.fit import _array, load_models
    from jsrte.fit.query import class_shape, scan_candidates
    from jsrte.timing import stage

    options = (options or FitOptions()).changed(**changes)
    if options.at is not None:
        raise JsrteError("--scene fits every object; --at picks one (give one or the other)", path)
    with stage("load"):
        models = load_models(model, options.device)
        settings = options.settings()
        shape = class_shape(next(iter(models.values()))) if len(models) == 1 else None
        cands = scan_candidates(path, rng=np.random.default_rng(options.seed), up=_array(options.up),
                                viewpoints=_array(options.viewpoints), settings=settings.scan_sdf,
                                units_check=options.units_check, shape=shape)
    segmented = cands.segmented
    seg = cands.segmentation
    cloud_points = np.asarray(segmented.cloud.points, float)
    objects = [SceneObject(number, k, cloud_points[segmented.index[seg.candidates[k].index]])
               for number, k in enumerate(cands.valid())]
    _fit_objects(objects, cands, models, options, screen, progress, workers)
    skipped = [{"candidate": k, "points": len(c.index), "reason": c.rejected}
               for k, c in enumerate(seg.candidates) if c.rejected]
    floor = segmented.floor
    return SceneResult(objects, skipped, seg.to_json(), cloud_points, up=np.asarray(segmented.up, float),
                       floor_offset=None if floor is None else float(floor.offset),
                       options=options.record(), models=list(models))


def _fit_objects(objects: list[SceneObject], cands: object, models: dict, options: FitOptions,
                 screen: ScreenSettings, progress: bool, workers: int) -> None:
    """Fit every one of ``objects`` (in ``workers`` threads when more than one); a failed fit is
    recorded in its object and the others go on."""
    def fit_one(obj: SceneObject) -> None:
        try:
            _fit_object(obj, cands, models, options, screen, progress and workers == 1)
        except JsrteError as exc:
            obj.status, obj.reason, obj.result = "failed", str(exc), None

    workers = max(1, min(workers, len(objects)))
    if workers == 1:
        for obj in objects:
            fit_one(obj)
        return
    import torch

    before = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        with ThreadPoolExecutor(workers) as pool:
            list(pool.map(fit_one, objects))
    finally:
        torch.set_num_threads(before)


def _fit_object(obj: SceneObject, cands: object, models: dict, options: FitOptions, screen: ScreenSettings,
                progress: bool) -> None:
    """Choose ``obj``'s class and fit it (fills ``obj.model``, ``class_choice``, ``result``)."""
    from jsrte.fit import fit_recorded
    from jsrte.fit.screen import choose_class

    query = cands.query(obj.candidate, rng=np.random.default_rng(options.seed))
    query.info["segmentation"] |= {"chosen": obj.candidate, "chosen_by": "scene"}
    if len(models) > 1:
        choice = choose_class(query, models, settings=screen, seed=options.seed)
        model, obj.class_choice = choice.model, choice.class_json()
        obj.model = next(name for name, m in models.items() if m is model)
    else:
        (obj.model, model), = models.items()
    obj.result = fit_recorded(model, query, options, class_choice=obj.class_choice, progress=progress)


def _box_centre(points: np.ndarray) -> list[float]:
    """The centre (3,) of the bounding box of ``points`` (n, 3)."""
    return [round(float(v), 5) for v in (points.min(0) + points.max(0)) / 2.0]


def json_ready(values: dict[str, Any]) -> dict[str, Any]:
    """``values`` with NumPy numbers as Python ones and non-finite floats as None."""
    out: dict[str, Any] = {}
    for key, value in values.items():
        if isinstance(value, (np.floating, float)):
            value = float(value) if np.isfinite(value) else None
        elif isinstance(value, np.integer):
            value = int(value)
        out[key] = value
    return out
