"""``jsrte train``: learn a DeepSDF auto-decoder on one class of shapes."""

from __future__ import annotations

from pathlib import Path

import typer

from jsrte.cli import app
from jsrte.cli.common import check_out_folder, check_threads, set_threads
from jsrte.errors import JsrteError
from jsrte.model.config import ARCHITECTURES, MODEL_NAME, PREVIOUS_STATE_NAME, STATE_NAME, TrainSettings
from jsrte.presets import SdfSampling

_DEFAULT = TrainSettings()


@app.command("train")
def train(
    out: Path = typer.Option(..., "--out", help="Run folder: checkpoints, log, model.safetensors."),
    category: str = typer.Option("chair", help="Shape class (procedural data, or the ShapeNet synset "
                                                "with --data)."),
    shapes: int = typer.Option(100, "--shapes", help="Number of procedural training shapes."),
    data: Path = typer.Option(None, "--data", help="Train on this folder of meshes / ShapeNet root instead."),
    arch: str = typer.Option("cpu", help=f"Decoder architecture: {', '.join(ARCHITECTURES)}."),
    steps: int = typer.Option(_DEFAULT.steps, help="Optimizer steps."),
    batch_shapes: int = typer.Option(_DEFAULT.shapes_per_batch, help="Shapes per step."),
    points: int = typer.Option(_DEFAULT.points_per_shape, help="SDF samples per shape per step."),
    samples: int = typer.Option(SdfSampling.n_points, help="SDF samples drawn per training shape."),
    lr_net: float = typer.Option(_DEFAULT.lr_net, help="Decoder learning rate."),
    lr_codes: float = typer.Option(_DEFAULT.lr_codes, help="Latent-code learning rate."),
    checkpoint_every: int = typer.Option(_DEFAULT.checkpoint_every, help="Steps between checkpoints."),
    seed: int = typer.Option(0, help="Training seed."),
    name: str = typer.Option(None, help="Model name stored in the file (default: the category)."),
    resume: bool = typer.Option(False, help="Continue the run in --out after an interruption."),
    threads: int = typer.Option(0, help="CPU threads (0: all cores)."),
    progress: bool = typer.Option(True, help="Show a progress bar."),
) -> None:
    """Train decoder weights and per-shape latent codes (clamped L1, code regularization).

    Under ``torchrun --nproc_per_node=N`` the same command trains data-parallel: each step's
    batch of shapes is split across the N processes (docs/scale.md).
    """
    if arch not in ARCHITECTURES:
        raise JsrteError(f"unknown architecture {arch!r}; known: {', '.join(ARCHITECTURES)}")
    _check_numbers(steps=steps, batch_shapes=batch_shapes, points=points, samples=samples, shapes=shapes,
                   checkpoint_every=checkpoint_every, lr_net=lr_net, lr_codes=lr_codes)
    check_threads(threads)
    check_out_folder(out)
    started = (out / STATE_NAME).exists() or (out / PREVIOUS_STATE_NAME).exists()
    if started and not resume:
        raise JsrteError("already holds a training run; pass --resume to continue it", out)
    if resume and not started:
        raise JsrteError(f"nothing to resume ({STATE_NAME} missing)", out)
    if resume:
        from jsrte.model.train import readable_state

        readable_state(out)  # a damaged state is reported before the data is sampled
    try:
        _train(out, category, shapes, data, arch, name, resume, threads, progress,
               TrainSettings(steps=steps, shapes_per_batch=batch_shapes, points_per_shape=points, lr_net=lr_net,
                             lr_codes=lr_codes, checkpoint_every=checkpoint_every, seed=seed),
               SdfSampling(n_points=samples))
    except KeyboardInterrupt:
        saved = (out / STATE_NAME).exists()
        typer.echo("stopped; " + ("resume with --resume (from the last checkpoint)" if saved
                                  else "no checkpoint was written yet: run the same command again to start "
                                       "over (sampled shapes are kept)"), err=True)
        raise typer.Exit(130) from None


def _check_numbers(**values: float) -> None:
    """One-line errors for counts and rates that must be positive."""
    for name, value in values.items():
        if not value > 0:
            raise JsrteError(f"--{name.replace('_', '-')} must be positive, got {value}")


def _train(out: Path, category: str, shapes: int, data: Path | None, arch: str, name: str | None, resume: bool,
           threads: int, progress: bool, settings: TrainSettings, sampling: SdfSampling) -> None:
    """The training run of :func:`train`, its arguments checked."""
    from jsrte.model.distributed import init_from_env, main_process_first, shutdown
    from jsrte.model.train import Trainer

    ctx = init_from_env()
    set_threads(threads or (None if ctx is None else _threads_per_process()))
    with main_process_first(ctx):  # rank 0 samples the data, the others read its cache
        training_data = _load_data(out, category, shapes, data, sampling, progress and (ctx is None or ctx.is_main))
    meta = {"name": name or category, "category": category, "arch": arch}
    trainer = Trainer(ARCHITECTURES[arch], settings, training_data, out, meta, dist=ctx)
    if resume:
        trainer.load_checkpoint()
        if trainer.is_main:
            if trainer.resumed_from is not None and trainer.resumed_from.name != STATE_NAME:
                typer.echo(f"{STATE_NAME} is unreadable; resuming from the checkpoint before it", err=True)
            typer.echo(f"resuming at step {trainer.step} of {settings.steps}")
    trainer.run(progress=progress)
    is_main, steps, minutes = trainer.is_main, trainer.step, trainer.elapsed / 60
    del trainer  # its DDP wrapper holds the process group: freed now, not at interpreter exit
    shutdown(ctx)
    if is_main:
        typer.echo(f"wrote {out / MODEL_NAME} ({training_data.n_shapes} shapes, {steps} steps, {minutes:.1f} min)")


def _threads_per_process() -> int:
    """The node's cores shared by the processes torchrun started on it."""
    import os

    return max(1, (os.cpu_count() or 1) // int(os.environ.get("LOCAL_WORLD_SIZE", "1")))


def _load_data(out: Path, category: str, shapes: int, data: Path | None, sampling: SdfSampling,  # noqa: ANN202
               progress: bool):
    from jsrte.model.data import folder_training_data, procedural_training_data

    if data is not None:
        return folder_training_data(data, out / "data", category=category, settings=sampling, progress=progress)
    return procedural_training_data(category, shapes, out / "data", settings=sampling, progress=progress)

