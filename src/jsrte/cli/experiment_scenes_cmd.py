"""``jsrte experiment scenes``: virtual rooms of several objects, each fitted whole and scored."""

from __future__ import annotations

from pathlib import Path

import typer

from jsrte.cli import fit_options as opt
from jsrte.cli.common import check_out_folder, check_threads, set_threads
from jsrte.cli.experiment_cmd import experiment_app
from jsrte.errors import JsrteError
from jsrte.presets import PRESETS, SCENE_PRESET


@experiment_app.command("scenes", short_help="Rooms of 3-6 held-out objects and 1-3 walls, each fitted whole "
                                             "(class unknown) and scored: detection, class, F@5%, flag, time.")
def scenes_command(
    out: Path = typer.Option(..., "--out", help="Output folder (rooms/NNN, fits/NNN, objects.csv, rooms.csv, "
                                                "summary.md/.csv, figure_room_NNN.png, report.html)."),
    rooms: int = typer.Option(20, help="Number of rooms."),
    first: int = typer.Option(0, help="Index of the first room (rooms FIRST ... FIRST+ROOMS-1; the reported set "
                                      "is 0-19 of seed 0: tune on others, e.g. --first 100)."),
    seed: int = typer.Option(0, help="Room seed: room i of seed s is drawn from s * 100003 + i alone."),
    objects: str = typer.Option("3,6", help="Objects per room 'LO,HI' (drawn uniformly; 2 to 9: a room of one "
                                            "object gives too few views to find its floor)."),
    model: str = typer.Option("auto", help="The models each object's class is chosen among: auto (every shipped "
                                           "model) or a comma-separated list."),
    preset: str = typer.Option(SCENE_PRESET, help=f"Fit preset: {', '.join(PRESETS)}."),
    dtype: str = opt.DTYPE, leftovers: bool = opt.LEFTOVERS,
    cameras: bool = typer.Option(True, "--cameras/--without-cameras",
                                 help="Fit each scan with its cameras (its JSON sidecar), or without them and "
                                      "with the up axis given, as a scan from another tool with --up."),
    threads: int = typer.Option(0, help="CPU threads (0: all cores)."),
    jobs: int = typer.Option(1, help="Rooms run in this many processes at once (threads shared among them)."),
    overwrite: bool = typer.Option(False, help="Replace results already in --out."),
    resume: bool = typer.Option(False, help="Continue a stopped run in --out (same settings): rooms already in "
                                            "objects.csv are kept."),
    html_report: bool = typer.Option(True, "--report/--no-report",
                                     help="Also write report.html (a 3D view of every fitted object)."),
) -> None:
    """N virtual rooms: furniture of the four shipped classes (held out) and boxes, walls, a sweep of
    views; every room fitted by `jsrte fit --scene` and scored against its truth."""
    from jsrte.atomic import output_dir
    from jsrte.experiments.scenes import CONFIG_NAME, OBJECTS_NAME, SUMMARY_MD, ScenesConfig, run_scenes
    from jsrte.fit import model_names

    if rooms < 1:
        raise JsrteError(f"--rooms must be at least 1, got {rooms}")
    if first < 0:
        raise JsrteError(f"--first must be 0 or more, got {first}")
    if jobs < 1:
        raise JsrteError(f"--jobs must be positive, got {jobs}")
    if preset not in PRESETS:
        raise JsrteError(f"unknown preset {preset!r}; known: {', '.join(PRESETS)}")
    opt.check_dtype(dtype)
    if resume and overwrite:
        raise JsrteError("--resume continues the run in --out, --overwrite replaces it: give one")
    check_threads(threads)
    if not resume:
        check_out_folder(out, marker=SUMMARY_MD, overwrite=overwrite)
        if (out / OBJECTS_NAME).exists() and not overwrite:
            raise JsrteError(f"holds an unfinished run ({OBJECTS_NAME}); pass --resume to continue it or "
                             "--overwrite to replace it", out)
    elif not (out / CONFIG_NAME).is_file():
        raise JsrteError(f"holds no run to resume ({CONFIG_NAME} is missing)", out)
    model_names(model)  # "auto" without any shipped model is an error now, not after the first room
    config = ScenesConfig(rooms=rooms, first=first, seed=seed, preset=preset, dtype=dtype, model=model,
                          objects=_count_range(objects, "objects", 2, 9), leftovers=leftovers,
                          cameras=cameras)
    set_threads(threads)
    with output_dir(out, overwrite=True, keep=lambda folder: (folder / OBJECTS_NAME).is_file()) as folder:
        if overwrite:
            _clear(folder)
        report = run_scenes(config, folder, jobs=jobs, threads=threads or None, resume=resume,
                            report=html_report, log=typer.echo)
    typer.echo((out / SUMMARY_MD).read_text())
    typer.echo(f"wrote {', '.join(str(p) for p in report.files)}")


def _count_range(text: str, name: str, least: int, most: int) -> tuple[int, int]:
    """'LO,HI' as (LO, HI), with least <= LO <= HI <= most (JsrteError otherwise)."""
    try:
        lo, hi = (int(v) for v in text.split(","))
    except ValueError:
        raise JsrteError(f"--{name} must be two whole numbers 'LO,HI', got {text!r}") from None
    if not least <= lo <= hi <= most:
        raise JsrteError(f"--{name} must satisfy {least} <= LO <= HI <= {most}, got {text!r}")
    return lo, hi


def _clear(folder: Path) -> None:
    """Remove a former run's files from ``folder`` (only what this command writes)."""
    import shutil

    from jsrte.experiments.scenes import CONFIG_NAME, OBJECTS_NAME, ROOMS_NAME, SUMMARY_CSV, SUMMARY_MD

    for name in ("rooms", "fits"):
        shutil.rmtree(folder / name, ignore_errors=True)
    for name in (OBJECTS_NAME, ROOMS_NAME, SUMMARY_CSV, SUMMARY_MD, CONFIG_NAME, "report.html"):
        (folder / name).unlink(missing_ok=True)
    for figure in folder.glob("figure_room_*.png"):
        figure.unlink()
