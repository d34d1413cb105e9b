"""``jsrte fit-many``: fit every scan of a folder (or list) locally or on a Ray cluster."""

from __future__ import annotations

from pathlib import Path

import typer

from jsrte.cli import app
from jsrte.cli import fit_options as opt
from jsrte.cli.common import check_out_folder, check_threads
from jsrte.errors import JsrteError


@app.command("fit-many")
def fit_many_command(
    source: Path = typer.Argument(..., help="Folder of scans (PLY/PCD/XYZ/PTS, OBJ/OFF/STL/GLB, NPZ) or a "
                                            ".txt list of scan paths, one a line."),
    out: Path = typer.Option(..., "--out", help="Output folder: one result folder per scan, summary.csv."),
    model: str = typer.Option("chair", help="Shipped model name or model file."),
    preset: str = opt.PRESET,
    up: str = typer.Option(None, help="Known up axis X,Y,Z for every scan (default: each floor's normal)."),
    viewpoint: list[str] = opt.VIEWPOINT, line_of_sight: bool = opt.LINE_OF_SIGHT,
    free_axis: bool = opt.FREE_AXIS, at: str = opt.AT, hypotheses: int = opt.HYPOTHESES,
    seed: int = typer.Option(0, help="Random seed (the same for every scan, as jsrte fit)."),
    device: str = opt.DEVICE, units_check: bool = opt.UNITS_CHECK, dtype: str = opt.DTYPE,
    float32_retry: bool = opt.FLOAT32_RETRY, floor_contact: float = opt.FLOOR_CONTACT,
    workers: int = typer.Option(0, help="Parallel fits on this machine (0: all cores); with --ray local, "
                                        "the CPUs of that Ray instance."),
    ray: str = typer.Option(None, "--ray", help="Run on the Ray cluster at this address (auto, HOST:6379, "
                                                "ray://HOST:10001) or 'local' (start one here)."),
    retries: int = typer.Option(2, help="Times a scan is sent again after its worker process died."),
    progress: bool = typer.Option(True, help="Show a progress bar."),
    html_report: bool = typer.Option(True, "--report/--no-report",
                                     help="Also write report.html beside summary.csv (as jsrte report)."),
    overwrite: bool = typer.Option(False, help="Fit every scan again, replacing the results in --out (needed "
                                               "when they were made with another model or preset)."),
) -> None:
    """Fit every scan; skip those already done in --out; a failed scan is recorded and the rest go on.

    Exit status 0 when every scan is done, 1 when some failed (see summary.csv), 2 on bad input.
    """
    from jsrte.batch import fit_many
    from jsrte.presets import default_preset, names_several_models

    preset = preset or default_preset(class_unknown=names_several_models(model))
    options = opt.fit_options(preset=preset, up=up, viewpoint=viewpoint, line_of_sight=line_of_sight,
                              free_axis=free_axis, at=at, hypotheses=hypotheses, seed=seed, device=device,
                              units_check=units_check, dtype=dtype, float32_retry=float32_retry,
                              floor_contact=floor_contact)
    check_threads(workers, "--workers")
    if retries < 0:
        raise JsrteError(f"--retries must be 0 or more, got {retries}")
    check_out_folder(out)
    report = fit_many(source, out=out, model=model, options=options, workers=workers or None, ray_address=ray,
                      retries=retries, progress=progress, overwrite=overwrite)
    typer.echo(f"{len(report.rows)} scans: {report.fitted} fitted now, {report.skipped} done before, "
               f"{report.failed} failed; wrote {report.summary}")
    if html_report:
        from jsrte.view.report import write_batch_report

        write_batch_report(out, say=typer.echo)
    if report.failed:
        raise typer.Exit(1)
