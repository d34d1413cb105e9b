"""JSRTE: joint latent code and similarity transform (the paper's section 3, Algorithm 1)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from jsrte.fit.query import SdfQuery
from jsrte.fit.solve import fit_query
from jsrte.model.checkpoint import DeepSdfModel
from jsrte.options import FitOptions
from jsrte.result import FitResult


def fit(query: str | Path | SdfQuery, *, model: str | Path | DeepSdfModel = "chair",
        options: FitOptions | None = None, progress: bool = False, **changes: object) -> FitResult:
    """Find the shape and the similarity transform that explain ``query``.

    Parameters
    ----------
    query : a scan (PLY/PCD/XYZ, metres, any pose, floor optional with ``up``), a complete
        mesh (OBJ/OFF/STL/GLB), an SDF-sample ``.npz`` (``jsrte sample``), a query file
        (``jsrte prepare``), or an ``SdfQuery`` (formats: ``jsrte.formats``)
    model : a shipped model's name, a model file, or a loaded model
    options : how to fit (:class:`jsrte.options.FitOptions`: preset, up, viewpoints,
        line_of_sight, free_axis, at, hypotheses, seed, device, units_check); default: the
        defaults of ``jsrte fit``
    progress : show a progress bar
    changes : options by name, applied over ``options`` (``fit(scan, up=(0, 0, 1), seed=3)``);
        ``device`` moves a loaded ``model`` there (None: a loaded model stays where it is, a
        named one runs on the CPU)
    """
    from jsrte.model.decoder import decoder_device
    from jsrte.model.registry import resolve_model
    from jsrte.timing import stage

    options = (options or FitOptions()).changed(**changes)
    settings = options.settings()
    with stage("load"):
        loaded = model if isinstance(model, DeepSdfModel) else resolve_model(model)
        if options.device is not None:
            loaded.to(options.device)
        sdf_query = query if isinstance(query, SdfQuery) else fit_query_of(query, options, model=loaded)
    result = fit_query(loaded, sdf_query, settings.fit, n_hypotheses=options.hypotheses, seed=options.seed,
                       progress=progress)
    result.query_points = sdf_query.surface
    result.info.update(options=options.record(), preset=settings.name, model=loaded.name,
                       model_sha256=loaded.meta.get("sha256"), query=sdf_query.info,
                       device=str(decoder_device(loaded.decoder)),
                       up=None if sdf_query.up is None else np.asarray(sdf_query.up).tolist())
    return result


def fit_query_of(path: str | Path, options: FitOptions, *, model: DeepSdfModel | None = None) -> SdfQuery:
    """The SDF query of the file at ``path`` as the fit with ``options`` sees it (``jsrte prepare``
    saves it). In a scan of several objects the object is the one nearest ``options.at``, else the
    one most like ``model``'s class, else the largest."""
    from jsrte.fit.query import load_query

    return load_query(path, rng=np.random.default_rng(options.seed), up=_array(options.up),
                      viewpoints=_array(options.viewpoints), scan_settings=options.settings().scan_sdf,
                      units_check=options.units_check, at=_array(options.at),
                      shape=None if model is None else _shape_if_scan(path, model))


def _array(value: tuple | None) -> np.ndarray | None:
    """A tuple option as a float64 array (None stays None)."""
    return None if value is None else np.asarray(value, dtype=np.float64)


def _shape_if_scan(query: str | Path, model: DeepSdfModel) -> object:
    """The class's proportions when ``query`` is a scan (segmentation needs them), else None."""
    from jsrte.fit.query import class_shape
    from jsrte.formats import input_kind

    return class_shape(model) if input_kind(query) == "scan" else None


__all__ = ["FitOptions", "FitResult", "SdfQuery", "fit", "fit_query", "fit_query_of"]
