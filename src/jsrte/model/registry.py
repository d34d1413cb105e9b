"""Shipped models, selectable by name anywhere a model path is accepted."""

from __future__ import annotations

from pathlib import Path

from jsrte.errors import JsrteError
from jsrte.model.checkpoint import DeepSdfModel, file_hash, load_model, read_metadata

PRETRAINED_DIR = Path(__file__).parent / "pretrained"


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
        sizes = model_sizes(meta | {"name": name, "sha256": file_hash(path)})
        rows.append({"name": name, "category": meta.get("category"), "shapes": meta.get("n_shapes"),
                     "architecture": meta.get("arch"), "latent_size": meta["architecture"]["latent_size"],
                     "size_kb": round(path.stat().st_size / 1024, 1),
                     "sizes_m": None if sizes is None else asdict(sizes),
                     "metrics": meta.get("metrics", {}), "path": str(path)})
    return rows
