"""Shipped models, selectable by name anywhere a model path is accepted."""

from __future__ import annotations

from pathlib import Path

from jsrte.errors import JsrteError
from jsrte.model.checkpoint import DeepSdfModel, file_hash, load_model, read_metadata

PRETRAINED_DIR = Path(__file__).parent / "pretrained"
DISTILLED_DIR = PRETRAINED_DIR / "distilled"
"""The shipped models' distilled decoders (``jsrte distill``), each naming its teacher."""
DISTILLED_SUFFIX = ".distilled.safetensors"
"""A model file's own distilled decoder lies beside it under this suffix (``model.safetensors``:
``model.distilled.safetensors``)."""


def shipped_models() -> dict[str, Path]:
    """Name -> file of every model shipped in the package."""
    return {p.stem: p for p in sorted(PRETRAINED_DIR.glob("*.safetensors"))}


def resolve_model_path(name_or_path: str | Path) -> Path:
    """A shipped model's name, or a path to a ``.safetensors`` model (or a training run folder)."""
    path = Path(name_or_path)
    if path.is_dir() and (path / "model.safetensors").is_file():
        return path / "model.safetensors"
    if path.is_file():
        return path
    shipped = shipped_models()
    if str(name_or_path) in shipped:
        return shipped[str(name_or_path)]
    known = ", ".join(shipped) or "none shipped"
    raise JsrteError(f"no model file or shipped model called {str(name_or_path)!r} (shipped: {known})")


def resolve_model(name_or_path: str | Path) -> DeepSdfModel:
    """Load a model by shipped name or path."""
    model = load_model(resolve_model_path(name_or_path))
    model.meta.setdefault("name", str(name_or_path))
    return model


def describe_models() -> list[dict]:
    """Metadata summaries of the shipped models (for ``jsrte models``)."""
    from dataclasses import asdict

    from jsrte.model.sizes import model_sizes

    rows = []
    for name, path in shipped_models().items():
        meta = read_metadata(path)
        sha256 = file_hash(path)
        sizes = model_sizes(meta | {"name": name, "sha256": sha256})
        student = shipped_distilled(sha256)
        rows.append({"name": name, "category": meta.get("category"), "shapes": meta.get("n_shapes"),
                     "architecture": meta.get("arch"), "latent_size": meta["architecture"]["latent_size"],
                     "size_kb": round(path.stat().st_size / 1024, 1),
                     "sizes_m": None if sizes is None else asdict(sizes),
                     "metrics": meta.get("metrics", {}), "path": str(path),
                     "distilled": None if student is None else {
                         "architecture": read_metadata(student).get("arch"),
                         "size_kb": round(student.stat().st_size / 1024, 1), "path": str(student)}})
    return rows


def distilled_decoder(model: DeepSdfModel) -> DeepSdfModel:
    """The distilled decoder of ``model`` (``jsrte distill``), on the model's device: the one it
    holds (``model.distilled``), else the file beside the model's own (:data:`DISTILLED_SUFFIX`),
    else the shipped one whose teacher is ``model`` (the same SHA-256); it is kept in
    ``model.distilled``. JsrteError if there is none."""
    from jsrte.model.decoder import decoder_device

    if model.distilled is None:
        sha256, own = model.meta.get("sha256"), model.meta.get("path")
        beside = [Path(own).parent / (Path(own).stem + DISTILLED_SUFFIX)] if own else []
        found = next((path for path in beside if path.is_file() and _teacher_sha256(path) == sha256),
                     None) or shipped_distilled(sha256)
        if found is None:
            hint = f"jsrte distill --teacher {own} --out {beside[0]}" if own else "jsrte distill"
            raise JsrteError(f"model {model.name!r} has no distilled decoder; make one with `{hint}`")
        model.distilled = load_model(found)
    model.distilled.decoder.to(decoder_device(model.decoder))
    return model.distilled


def shipped_distilled(sha256: str | None) -> Path | None:
    """The shipped distilled decoder taught by the model whose file has this SHA-256, if any."""
    return next((path for path in sorted(DISTILLED_DIR.glob("*.safetensors")) if _teacher_sha256(path) == sha256),
                None)


def _teacher_sha256(path: Path) -> str | None:
    """The SHA-256 of the model a distilled decoder was taught by (None: not a distilled decoder)."""
    return (read_metadata(path).get("distilled_from") or {}).get("sha256")
