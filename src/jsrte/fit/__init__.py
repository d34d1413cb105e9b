"""JSRTE: joint latent code and similarity transform (the paper's section 3, Algorithm 1)."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from jsrte.fit.query import SdfQuery
from jsrte.fit.solve import fit_query, fit_with_retry
from jsrte.model.checkpoint import DeepSdfModel
from jsrte.options import FitOptions
from jsrte.presets import Preset
from jsrte.result import FitResult

if TYPE_CHECKING:
    from jsrte.fit.screen import ScreenSettings


def fit(query: str | Path | SdfQuery, *, model: str | Path | DeepSdfModel | list = "chair",
        options: FitOptions | None = None, progress: bool = False, **changes: object) -> FitResult:
    """Find the shape and the similarity transform that explain ``query``.

    Parameters
    ----------
    query : a scan (PLY/PCD/XYZ, metres, any pose, floor optional with ``up``), a complete
        mesh (OBJ/OFF/STL/GLB), an SDF-sample ``.npz`` (``jsrte sample``), a query file
        (``jsrte prepare``), or an ``SdfQuery`` (formats: ``jsrte.formats``)
    model : a shipped model's name, a model file, or a loaded model; or several (a list, or
        names separated by commas), or "auto" (every shipped model): each is fitted quickly to
        the scan's candidate objects, and the class whose fits explain the whole cluster of
        its best candidate best is kept (``jsrte.fit.screen.class_scores``; fit.json's
        ``class`` records every class's score)
    options : how to fit (:class:`jsrte.options.FitOptions`: preset, up, viewpoints,
        line_of_sight, free_axis, at, hypotheses, seed, device, units_check); default: the
        defaults of ``jsrte fit`` (preset ``fast``; ``fast-scales`` where ``model`` names several).
        In a scan of several objects the object is the one nearest ``at``, else, of the
        candidates whose proportions match the class best, the one a quick fit explains best
        (fit.json's ``query.segmentation`` records the choice and the others)
    progress : show a progress bar
    changes : options by name, applied over ``options`` (``fit(scan, up=(0, 0, 1), seed=3)``);
        ``device`` moves a loaded ``model`` there (None: a loaded model stays where it is, a
        named one runs on the CPU)
    """
    from jsrte.formats import input_kind
    from jsrte.presets import default_preset, names_several_models
    from jsrte.timing import stage

    options = (options or FitOptions(preset=default_preset(class_unknown=names_several_models(model)))
               ).changed(**changes)
    class_choice = None
    with stage("load"):
        models = load_models(model, options.device)
        is_scan = not isinstance(query, SdfQuery) and input_kind(query) == "scan"
    if is_scan and options.at is None:
        choice = _choose_in_scan(query, models, options)
        if len(choice.objects) > 1:
            from jsrte.fit.classes import fit_contenders

            return fit_contenders(choice.objects, models, options, choice.class_json(), progress=progress)
        sdf_query, loaded = choice.query, choice.model
        class_choice = None if len(models) == 1 else choice.class_json()
    else:
        if options.at is not None and len(models) > 1:
            from jsrte.errors import JsrteError

            raise JsrteError("--at picks an object for one model; name a single --model with it")
        loaded = next(iter(models.values()))
        with stage("load"):
            sdf_query = query if isinstance(query, SdfQuery) else fit_query_of(query, options, model=loaded)
        if len(models) > 1:
            from jsrte.fit.screen import choose_class

            choice = choose_class(sdf_query, models, settings=_screen_settings(options), seed=options.seed)
            loaded, class_choice = choice.model, choice.class_json()
    return fit_recorded(loaded, sdf_query, options, class_choice=class_choice, progress=progress)


def fit_recorded(model: DeepSdfModel, query: SdfQuery, options: FitOptions, *, class_choice: dict | None = None,
                 progress: bool = False, settings: Preset | None = None) -> FitResult:
    """``fit_with_retry`` (``fit_query``, again in float32 where a bfloat16 fit is doubtful and
    the preset asks) with ``options`` (its preset's settings, or ``settings`` where given), the
    result carrying what fit.json records of how it was made (options, preset, model and its
    hash, the query's record, device, up, the class choice if any)."""
    from jsrte.model.decoder import decoder_device

    settings = settings or options.settings()
    result = fit_with_retry(model, query, settings.fit, n_hypotheses=options.hypotheses, seed=options.seed,
                            progress=progress)
    result.query_points = query.surface
    result.info.update(options=options.record(), preset=settings.name, model=model.name,
                       model_sha256=model.meta.get("sha256"), query=query.info,
                       device=str(decoder_device(model.decoder)),
                       up=None if query.up is None else np.asarray(query.up).tolist())
    if class_choice is not None:
        result.info["class"] = class_choice
    return result


def fit_query_of(path: str | Path, options: FitOptions, *, model: DeepSdfModel | None = None) -> SdfQuery:
    """The SDF query of the file at ``path`` as a fit with ``options`` and one ``model`` sees it
    without the quick-fit screen (``jsrte prepare`` saves it). In a scan of several objects the
    object is the one nearest ``options.at``, else the one most like ``model``'s class, else the
    largest."""
    from jsrte.fit.query import load_query

    return load_query(path, rng=np.random.default_rng(options.seed), up=_array(options.up),
                      viewpoints=_array(options.viewpoints), scan_settings=options.settings().scan_sdf,
                      units_check=options.units_check, at=_array(options.at),
                      shape=None if model is None else _shape_if_scan(path, model))


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


def load_models(model: str | Path | DeepSdfModel | list, device: str | None) -> dict:
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


def _choose_in_scan(query: str | Path, models: dict, options: FitOptions) -> object:
    """The scan's object (and class, with several models) chosen by quick fits: the
    ``jsrte.fit.screen.Choice`` (its ``objects``: the contending classes' objects, more than one
    where the classes' final fits decide)."""
    from jsrte.fit.query import class_shape, scan_candidates
    from jsrte.fit.screen import choose_in_scan
    from jsrte.timing import stage

    single = len(models) == 1
    rng = np.random.default_rng(options.seed)
    settings = options.settings()

    def segment(model: DeepSdfModel) -> object:
        with stage("load"):
            return scan_candidates(query, rng=rng if single else np.random.default_rng(options.seed),
                                   up=_array(options.up), viewpoints=_array(options.viewpoints),
                                   settings=settings.scan_sdf, units_check=options.units_check,
                                   shape=class_shape(model))

    return choose_in_scan(query, models, segment=segment, settings=_screen_settings(options), seed=options.seed,
                          final_rng=rng)


def _screen_settings(options: FitOptions) -> ScreenSettings:
    """The quick fits' ``jsrte.fit.screen.ScreenSettings``, in the arithmetic ``options`` ask for,
    searched by the distilled decoders where the preset's full fit is."""
    from jsrte.fit.screen import ScreenSettings

    return ScreenSettings().in_arithmetic(options.dtype).searched_as(options.settings().fit)


def _array(value: tuple | None) -> np.ndarray | None:
    """A tuple option as a float64 array (None stays None)."""
    return None if value is None else np.asarray(value, dtype=np.float64)


def _shape_if_scan(query: str | Path | SdfQuery, model: DeepSdfModel) -> object:
    """The class's proportions when ``query`` is a scan (segmentation needs them), else None."""
    from jsrte.fit.query import class_shape
    from jsrte.formats import input_kind

    return class_shape(model) if input_kind(query) == "scan" else None


__all__ = ["FitOptions", "FitResult", "SdfQuery", "fit", "fit_query", "fit_query_of", "fit_recorded", "load_models",
           "model_names"]
