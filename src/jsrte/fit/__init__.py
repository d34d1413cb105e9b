"""JSRTE: joint latent code and similarity transform (the paper's section 3, Algorithm 1)."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import torch

from jsrte.fit.api import fit_query
from jsrte.fit.optimize import SdfQuery
from jsrte.fit.result import FitResult
from jsrte.model.checkpoint import DeepSdfModel


def fit(query: str | Path | SdfQuery, *, model: str | Path | DeepSdfModel | list = "chair", preset: str = "fast",
        up: np.ndarray | None = None, viewpoints: np.ndarray | None = None, line_of_sight: bool | None = None,
        free_axis: bool = False, at: np.ndarray | None = None,
        hypotheses: int | None = None, seed: int = 0, progress: bool = False,
        device: str | torch.device | None = None, units_check: bool = True) -> FitResult:
    """Find the shape and the similarity transform that explain ``query``.

    Parameters
    ----------
    query : a scan (PLY/PCD/XYZ, metres, any pose, floor optional with ``up``), a complete
        mesh (OBJ/OFF/STL/GLB), an SDF-sample ``.npz`` (``jsrte sample``), a query file
        (``jsrte prepare``), or an ``SdfQuery``
    model : a shipped model's name, a model file, or a loaded model; or several (a list, or
        names separated by commas), or "auto" (every shipped model): each is fitted quickly to
        the scan's candidate objects and the class that explains its best candidate best is
        kept (``jsrte.fit.screen``; fit.json's ``class`` records every class's score)
    preset : "fast" (default) or "paper" (jsrte.presets)
    up : (3,) the rotation axis if known; else the floor normal (scans) or +y (meshes)
    viewpoints : (k, 3) sensor positions of a scan (scan units), if known; default: the
        cameras of the scan's JSON sidecar (hidden-point removal, normal orientation)
    line_of_sight : free-space samples on the lines of sight from the viewpoints (beyond the
        paper): True adds them, False leaves them out, None follows the preset (``fast``: on,
        ``paper``: off; docs/presets.md). Without viewpoints there are none either way
    free_axis : let the rotation axis move from the up axis too (default: held, the paper's
        known-axis mode, whenever the up axis is known)
    at : (3,) in a scan of several objects, fit the one nearest this point (scan units);
        default: of the candidates whose proportions match the model's class best, the one a
        quick fit of the model explains best (fit.json's ``query.segmentation`` records the
        choice, the other candidates and their screen scores)
    hypotheses : number of θ starts (default: every 30°, 12)
    device : where the decoder runs ("cpu", "cuda", ...); a loaded ``model`` is moved there
        (None: a loaded model stays where it is, a named one runs on the CPU)
    units_check : refuse a scan whose object is implausibly large or small for metres (default);
        False skips that check
    """
    from jsrte.fit.query import SCAN_SUFFIXES, load_query
    from jsrte.model.decoder import decoder_device
    from jsrte.presets import get_preset, with_line_of_sight
    from jsrte.timing import stage

    settings = get_preset(preset)
    settings = replace(settings, scan_sdf=with_line_of_sight(settings.scan_sdf, line_of_sight))
    if free_axis:
        settings = replace(settings, fit=replace(settings.fit, hold_axis=False))
    class_choice = None
    with stage("load"):
        models = load_models(model, device)
        rng = np.random.default_rng(seed)
        is_scan = (not isinstance(query, SdfQuery) and Path(query).suffix.lower() in SCAN_SUFFIXES
                   and Path(query).is_file())
    if is_scan and at is None:
        sdf_query, loaded, class_choice = _choose_in_scan(query, models, rng=rng, up=up, viewpoints=viewpoints,
                                                          settings=settings, units_check=units_check, seed=seed)
    else:
        if at is not None and len(models) > 1:
            from jsrte.errors import JsrteError

            raise JsrteError("--at picks an object for one model; name a single --model with it")
        loaded = next(iter(models.values()))
        with stage("load"):
            sdf_query = query if isinstance(query, SdfQuery) else load_query(
                query, rng=rng, up=up, viewpoints=viewpoints, scan_settings=settings.scan_sdf,
                units_check=units_check, shape=_shape_if_scan(query, loaded), at=at)
        if len(models) > 1:
            from jsrte.fit.screen import choose_class

            choice = choose_class(sdf_query, models, seed=seed)
            loaded, class_choice = choice.model, choice.class_json()
    result = fit_query(loaded, sdf_query, settings.fit, n_hypotheses=hypotheses, seed=seed, progress=progress)
    result.query_points = sdf_query.surface
    result.info.update(preset=settings.name, model=loaded.name, model_sha256=loaded.meta.get("sha256"),
                       query=sdf_query.info, device=str(decoder_device(loaded.decoder)),
                       up=None if sdf_query.up is None else np.asarray(sdf_query.up).tolist())
    if class_choice is not None:
        result.info["class"] = class_choice
    return result


def model_names(model: str | Path | DeepSdfModel | list) -> list:
    """The models ``model`` names: "auto" is every shipped model (JsrteError when none is
    shipped), "a,b" a list of names, a list stays a list, anything else is one model."""
    from jsrte.errors import JsrteError
    from jsrte.model.registry import shipped_models

    if isinstance(model, (list, tuple)):
        names = list(model)
    elif isinstance(model, str) and model == "auto":
        names = list(shipped_models())
        if not names:
            raise JsrteError("--model auto: no shipped model in this installation (pass a model file)")
    elif isinstance(model, str) and "," in model:
        names = [m.strip() for m in model.split(",") if m.strip()]
    else:
        names = [model]
    if not names:
        raise JsrteError(f"no model named in {model!r}")
    return names


def load_models(model: str | Path | DeepSdfModel | list, device: str | torch.device | None) -> dict:
    """Name -> loaded ``DeepSdfModel`` of every model ``model`` names (:func:`model_names`),
    moved to ``device`` if given."""
    from jsrte.model.registry import resolve_model

    models = {}
    for m in model_names(model):
        loaded = m if isinstance(m, DeepSdfModel) else resolve_model(m)
        if device is not None:
            loaded.to(device)
        models[loaded.name if isinstance(m, DeepSdfModel) else str(m)] = loaded
    return models


def _choose_in_scan(query: str | Path, models: dict, *, rng: np.random.Generator, up: np.ndarray | None,
                    viewpoints: np.ndarray | None, settings: object, units_check: bool,
                    seed: int) -> tuple[SdfQuery, DeepSdfModel, dict | None]:
    """The scan's object (and class, with several models) chosen by quick fits
    (``jsrte.fit.screen.choose_in_scan``): its query, its model and the class record (None
    with one model)."""
    from jsrte.fit.query import class_shape, scan_candidates
    from jsrte.fit.screen import choose_in_scan
    from jsrte.timing import stage

    single = len(models) == 1

    def segment(model: DeepSdfModel) -> object:
        with stage("load"):
            return scan_candidates(query, rng=rng if single else np.random.default_rng(seed), up=up,
                                   viewpoints=viewpoints, settings=settings.scan_sdf, units_check=units_check,
                                   shape=class_shape(model))

    choice = choose_in_scan(query, models, segment=segment, seed=seed, final_rng=rng)
    return choice.query, choice.model, None if single else choice.class_json()


def _shape_if_scan(query: str | Path | SdfQuery, model: DeepSdfModel) -> object:
    """The class's proportions when ``query`` is a scan (segmentation needs them), else None."""
    from jsrte.fit.query import SCAN_SUFFIXES, class_shape

    return class_shape(model) if Path(query).suffix.lower() in SCAN_SUFFIXES else None


__all__ = ["FitResult", "SdfQuery", "fit", "fit_query", "load_models", "model_names"]
