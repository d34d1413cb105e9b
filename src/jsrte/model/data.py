"""Training data for the auto-decoder: procedural shapes of a class, or the user's meshes."""

from __future__ import annotations

from pathlib import Path

from jsrte.errors import JsrteError
from jsrte.model.train import TrainingData
from jsrte.presets import SdfSampling
from jsrte.sdf.dataset import build_sdf_dataset
from jsrte.sdf.mesh_sdf import SdfSamples


def procedural_training_data(category: str, n_shapes: int, work_dir: Path, *,
                             settings: SdfSampling = SdfSampling(), set_seed: int | None = None,
                             workers: int | None = None, progress: bool = True) -> TrainingData:
    """Generate ``n_shapes`` shapes of ``category`` (the training seed set) and sample their SDF.

    Meshes go to ``work_dir/meshes``, samples to ``work_dir/samples`` (cached by mesh hash).
    """
    from jsrte.shapes import TRAIN_SET_SEED, write_set

    set_seed = TRAIN_SET_SEED if set_seed is None else set_seed
    if n_shapes < 1:
        raise JsrteError(f"--shapes must be positive, got {n_shapes}")
    meshes = write_set(category, n_shapes, set_seed, work_dir / "meshes")
    summary = {"source": "procedural", "category": category, "n_shapes": n_shapes,
               "set_seed": set_seed, "samples_per_shape": settings.n_points}
    return _sampled(meshes, work_dir / "samples", settings, summary, workers, progress)


def folder_training_data(folder: Path, work_dir: Path, *, category: str | None = None,
                         settings: SdfSampling = SdfSampling(), limit: int | None = None,
                         workers: int | None = None, progress: bool = True) -> TrainingData:
    """The meshes of ``folder`` (a ShapeNetCore v2 root/synset when ``category`` is given,
    else any folder of meshes), sampled into ``work_dir/samples``."""
    from jsrte.shapes.shapenet import iter_mesh_folder, iter_shapenet

    if not Path(folder).is_dir():
        raise JsrteError("no such data folder", folder)
    if category is not None and _looks_like_shapenet(Path(folder)):
        meshes = [p for _, p in iter_shapenet(folder, category)]
    else:
        meshes = list(iter_mesh_folder(folder))
    if limit:
        meshes = meshes[:limit]
    if not meshes:
        raise JsrteError("holds no meshes to train on", folder)
    summary = {"source": "folder", "folder": str(folder), "category": category,
               "n_shapes": len(meshes), "samples_per_shape": settings.n_points}
    return _sampled(meshes, work_dir / "samples", settings, summary, workers, progress)


def _looks_like_shapenet(folder: Path) -> bool:
    return any(folder.glob("*/models/model_normalized.obj")) or any(
        folder.glob("*/*/models/model_normalized.obj"))


def _sampled(meshes: list[Path], sample_dir: Path, settings: SdfSampling, summary: dict,
             workers: int | None, progress: bool = True) -> TrainingData:
    paths = build_sdf_dataset(meshes, sample_dir, settings=settings, workers=workers, progress=progress)
    summary["meshes"] = [Path(m).name for m in meshes]
    return TrainingData.from_samples([_cached_samples(p) for p in paths], summary)


def _cached_samples(path: Path) -> SdfSamples:
    """A sample file of the cache; a damaged one is named with what to do about it."""
    try:
        return SdfSamples.load(path)
    except JsrteError as exc:
        raise JsrteError(f"{exc} (a cached sample file: delete it and run again to sample that mesh anew)") \
            from None
