"""From fits to shape codes and from shape codes back to meshes, with the model identity checked.

A code only means something with the decoder it was made with, so every path from a code to
a mesh goes through :func:`model_for_code`, which refuses a model whose SHA-256 does not start
with the 16 bytes the code stores.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import trimesh

from jsrte.codec.format import HASH_BYTES, ShapeCode, decode, model_hash_prefix
from jsrte.errors import JsrteError
from jsrte.geometry.sim3 import Sim3
from jsrte.model.checkpoint import DeepSdfModel, file_hash, read_metadata
from jsrte.result import FitResult


def read_code(path: str | Path) -> ShapeCode:
    """Read and check a ``.jsrte`` file (``JsrteError`` naming it if missing or invalid)."""
    path = Path(path)
    if path.is_dir():
        raise JsrteError("is a folder; give a shape code file (.jsrte)", path)
    if not path.is_file():
        raise JsrteError("no such shape code file", path)
    return decode(path.read_bytes(), source=str(path))


def model_identity(name_or_path: str | Path) -> tuple[str, str]:
    """(name, SHA-256 hex) of a shipped model or model file, without loading its weights."""
    from jsrte.model.registry import resolve_model_path

    path = resolve_model_path(name_or_path)
    meta = read_metadata(path)
    return str(meta.get("name", name_or_path)), file_hash(path)


def code_from_result(result: FitResult, *, model_name: str, model_sha256: str) -> ShapeCode:
    """The shape code of a fit made with the model ``model_name`` / ``model_sha256``."""
    if result.latent is None:
        raise JsrteError(f"the {result.method} result has no latent code to encode")
    return ShapeCode(latent=np.asarray(result.latent, np.float32), transform=result.transform,
                     model_name=model_name, model_hash=model_hash_prefix(model_sha256))


def code_from_fit_dir(folder: str | Path, *, model: str | Path | None = None) -> ShapeCode:
    """The shape code of a folder written by ``jsrte fit`` (its ``fit.json``).

    ``model`` (a shipped name or a file), when given, must be the model the fit used (same
    SHA-256 as ``fit.json`` records); otherwise the model recorded in ``fit.json`` is named.
    """
    from jsrte.fit.outputs import RESULT_NAME

    path = Path(folder) / RESULT_NAME
    fit = _read_fit_json(path)
    latent = _fit_latent(fit, path)
    transform = _fit_transform(fit, path)
    recorded_hash = fit.get("model_sha256")
    if recorded_hash is not None and not isinstance(recorded_hash, str):
        raise JsrteError(f"bad model_sha256 {recorded_hash!r}", path)
    if model is not None:
        name, sha256 = model_identity(model)
        if recorded_hash is not None and recorded_hash != sha256:
            fitted = fit.get("model")
            raise JsrteError(f"this fit was made with model {fitted!r} (hash {recorded_hash[:32]}); "
                             f"the model given ({model}) has hash {sha256[:32]}", path)
    else:
        if not isinstance(recorded_hash, str) or not isinstance(fit.get("model"), str):
            raise JsrteError("does not record the model (model, model_sha256); pass --model", path)
        name, sha256 = fit["model"], recorded_hash
    return ShapeCode(latent=latent, transform=transform, model_name=name,
                     model_hash=model_hash_prefix(sha256))


def _read_fit_json(path: Path) -> dict:
    if not path.is_file():
        raise JsrteError(f"no {path.name} here; give a scan file or a folder written by 'jsrte fit'",
                         path.parent)
    try:
        fit = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise JsrteError(f"not a readable fit result ({exc})", path) from exc
    if not isinstance(fit, dict):
        raise JsrteError("not a fit result (expected a JSON object)", path)
    return fit


def _fit_latent(fit: dict, path: Path) -> np.ndarray:
    if fit.get("latent") is None:
        raise JsrteError(f"the {fit.get('method', 'fit')} result has no latent code to encode", path)
    try:
        latent = np.asarray(fit["latent"], dtype=np.float32)
    except (TypeError, ValueError) as exc:
        raise JsrteError(f"bad latent ({exc})", path) from exc
    if latent.ndim != 1 or latent.size == 0 or not np.all(np.isfinite(latent)):
        raise JsrteError(f"bad latent (shape {latent.shape}, must be a finite vector)", path)
    return latent


def _fit_transform(fit: dict, path: Path) -> Sim3:
    try:
        if "scale" in fit and "rotation" in fit and "translation" in fit:
            return Sim3(fit["scale"], np.array(fit["rotation"], float), np.array(fit["translation"], float))
        return Sim3.from_matrix(np.array(fit["matrix"], float).reshape(4, 4))
    except (KeyError, TypeError, ValueError) as exc:
        raise JsrteError(f"bad transform (scale/rotation/translation or matrix: {exc})", path) from exc


def model_for_code(code: ShapeCode, *, model: str | Path | None = None,
                   source: str | Path | None = None) -> DeepSdfModel:
    """The model to decode ``code`` with: ``model`` (name or file) or the shipped model named
    in the code; refused unless its SHA-256 starts with the code's 16 stored bytes."""
    from jsrte.model.checkpoint import load_model
    from jsrte.model.registry import resolve_model, shipped_models

    stored = code.model_hash_hex
    if model is None:  # a shipped model only: the name in a file never becomes a path to open
        shipped = shipped_models().get(code.model_name)
        if shipped is None:
            raise JsrteError(f"this code was made with model {code.model_name!r} (hash {stored}), which is "
                             "not shipped with this jsrte; pass --model PATH", source)
        loaded = load_model(shipped)
        loaded.meta.setdefault("name", code.model_name)
    else:
        loaded = resolve_model(model)
    sha = loaded.meta.get("sha256") or file_hash(loaded.meta["path"])
    if bytes.fromhex(sha)[:HASH_BYTES] != code.model_hash:
        given = loaded.meta.get("path", model or code.model_name)
        raise JsrteError(f"this code was made with model {code.model_name!r} (hash {stored}); "
                         f"the model given ({given}) has hash {sha[: 2 * HASH_BYTES]}", source)
    if loaded.latent_size != code.latent.size:
        raise JsrteError(f"the code's latent has {code.latent.size} values; model {loaded.name!r} expects "
                         f"{loaded.latent_size}", source)
    return loaded


def mesh_from_code(code: ShapeCode, model: DeepSdfModel, *, resolution: int = 128,
                   canonical: bool = False) -> trimesh.Trimesh | None:
    """Decode the surface (marching cubes at ``resolution``); in the scan's frame (the code's
    transform applied) unless ``canonical``. None when the level set is empty."""
    from jsrte.model.meshing import decode_mesh

    mesh = decode_mesh(model.decoder, code.latent, resolution=resolution).mesh
    if mesh is None or canonical:
        return mesh
    mesh.vertices = code.transform.apply(mesh.vertices)
    return mesh
