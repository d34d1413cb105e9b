"""JSRTE: joint latent code and similarity transform (the paper's section 3, Algorithm 1)."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import torch

from jsrte.fit.api import fit_query
from jsrte.fit.query import SdfQuery
from jsrte.fit.result import FitResult
from jsrte.model.checkpoint import DeepSdfModel


def fit(query: str | Path | SdfQuery, *, model: str | Path | DeepSdfModel = "chair", preset: str = "fast",
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
    model : a shipped model's name, a model file, or a loaded model
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
        default: the one whose proportions match the model's class best (fit.json's
        ``query.segmentation`` records the choice and the other candidates)
    hypotheses : number of θ starts (default: every 30°, 12)
    device : where the decoder runs ("cpu", "cuda", ...); a loaded ``model`` is moved there
        (None: a loaded model stays where it is, a named one runs on the CPU)
    units_check : refuse a scan whose object is implausibly large or small for metres (default);
        False skips that check
    """
    from jsrte.fit.query import load_query
    from jsrte.model.decoder import decoder_device
    from jsrte.model.registry import resolve_model
    from jsrte.presets import get_preset, with_line_of_sight
    from jsrte.timing import stage

    settings = get_preset(preset)
    settings = replace(settings, scan_sdf=with_line_of_sight(settings.scan_sdf, line_of_sight))
    if free_axis:
        settings = replace(settings, fit=replace(settings.fit, hold_axis=False))
    with stage("load"):
        loaded = model if isinstance(model, DeepSdfModel) else resolve_model(model)
        if device is not None:
            loaded.to(device)
        rng = np.random.default_rng(seed)
        sdf_query = query if isinstance(query, SdfQuery) else load_query(
            query, rng=rng, up=up, viewpoints=viewpoints, scan_settings=settings.scan_sdf,
            units_check=units_check, shape=_shape_if_scan(query, loaded), at=at)
    result = fit_query(loaded, sdf_query, settings.fit, n_hypotheses=hypotheses, seed=seed, progress=progress)
    result.query_points = sdf_query.surface
    result.info.update(preset=settings.name, model=loaded.name, model_sha256=loaded.meta.get("sha256"),
                       query=sdf_query.info, device=str(decoder_device(loaded.decoder)),
                       up=None if sdf_query.up is None else np.asarray(sdf_query.up).tolist())
    return result


def _shape_if_scan(query: str | Path, model: DeepSdfModel) -> object:
    """The class's proportions when ``query`` is a scan (segmentation needs them), else None."""
    from jsrte.fit.query import class_shape
    from jsrte.formats import input_kind

    return class_shape(model) if input_kind(query) == "scan" else None


__all__ = ["FitResult", "SdfQuery", "fit", "fit_query"]
