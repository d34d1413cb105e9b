"""``jsrte distill``: teach a cheaper decoder a trained model's SDF, keeping its latent space."""

from __future__ import annotations

from pathlib import Path

import typer

from jsrte.cli import app
from jsrte.cli.common import check_out_file, set_threads
from jsrte.errors import JsrteError
from jsrte.model.config import ARCHITECTURES

LOG_SUFFIX = ".log.csv"


@app.command("distill")
def distill(
    teacher: str = typer.Option(..., "--teacher", help="The model to copy: a shipped name or a .safetensors file."),
    out: Path = typer.Option(..., "--out", help="The student's model file (.safetensors); its loss log "
                                                  f"goes beside it ({LOG_SUFFIX})."),
    arch: str = typer.Option("tiny", help=f"The student's architecture: {', '.join(ARCHITECTURES)}."),
    steps: int = typer.Option(20000, help="Adam steps."),
    seconds: float = typer.Option(None, help="Stop after this much wall time instead (the learning-rate "
                                             "schedule runs over it)."),
    name: str = typer.Option(None, help="The student's model name (default: the teacher's and the "
                                        "architecture's)."),
    seed: int = typer.Option(0, help="Draws of codes and points."),
    device: str = typer.Option("cpu", help="Torch device: cpu, cuda or cuda:N."),
    threads: int = typer.Option(0, help="CPU threads (0: all cores)."),
    overwrite: bool = typer.Option(False, help="Replace --out if it exists."),
    progress: bool = typer.Option(True, help="Show a progress bar."),
) -> None:
    """Distil a model into a cheaper decoder with the same latent codes (docs/models.md).

    Written beside the model as MODEL.distilled.safetensors, it does the search of ``jsrte fit
    --preset express`` and the model finishes the fit. A GPU (``--device cuda``) takes minutes; a
    CPU, seconds a step.
    """
    if arch not in ARCHITECTURES:
        raise JsrteError(f"unknown architecture {arch!r}; known: {', '.join(ARCHITECTURES)}")
    if steps < 1 or (seconds is not None and seconds <= 0):
        raise JsrteError("--steps and --seconds must be positive")
    check_out_file(out, overwrite=overwrite, suffixes=(".safetensors",))
    set_threads(threads)
    _distill(teacher, out, arch, steps, seconds, name, seed, device, progress)


def _distill(teacher: str, out: Path, arch: str, steps: int, seconds: float | None, name: str | None, seed: int,
             device: str, progress: bool) -> None:
    """The distillation of :func:`distill`, its arguments checked: the student, its error on
    fresh draws, its file and its loss log."""
    import torch

    from jsrte.cli.common import resolve_device
    from jsrte.model.checkpoint import save_model
    from jsrte.model.distill import DistillSettings, student_error
    from jsrte.model.distill import distill as run_distill
    from jsrte.model.registry import resolve_model

    model = resolve_model(teacher)
    if ARCHITECTURES[arch].latent_size != model.latent_size:
        raise JsrteError(f"--arch {arch} has latent size {ARCHITECTURES[arch].latent_size}, the teacher "
                         f"{model.latent_size}", teacher)
    if torch.cuda.is_available():
        torch.backends.cuda.matmul.allow_tf32 = True
    settings = DistillSettings(steps=steps, max_seconds=seconds, seed=seed)
    rows: list[dict[str, float]] = []
    target = resolve_device(device)
    student = run_distill(model, ARCHITECTURES[arch], settings, device=target, name=name, progress=progress,
                          log=rows)
    error = student_error(student, model, settings, device=target)
    student.decoder.cpu()
    student.meta["distillation"].update(error)
    save_model(student, out)
    _write_log(out.with_suffix(LOG_SUFFIX), rows)
    typer.echo(f"wrote {out} ({student.meta['distillation']['steps_done']} steps, mean |error| "
               f"{error['mean_abs']:.4f}, near the surface {error['near_surface_mean_abs']:.4f})")


def _write_log(path: Path, rows: list[dict[str, float]]) -> None:
    import csv

    with open(path, "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=["step", "seconds", "lr", "loss"])
        writer.writeheader()
        writer.writerows(rows)
