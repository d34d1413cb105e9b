"""``jsrte experiment scans``: the paper's Table 2 on virtual (or real) scans."""

from __future__ import annotations

from pathlib import Path

import typer

from jsrte.cli import fit_options as opt
from jsrte.cli.common import check_out_folder, check_threads, set_threads
from jsrte.cli.experiment_cmd import experiment_app, split_names
from jsrte.errors import JsrteError


@experiment_app.command("scans")
def scans_command(
    out: Path = typer.Option(..., "--out", help="Output folder (results.csv, table.md, figures)."),
    category: str = typer.Option("chair", help="Shape class of the held-out shapes."),
    model: str = typer.Option(None, help="Model file or shipped name (default: the category's shipped model); "
                                         "auto or a comma-separated list lets jsrte choose the class (the table "
                                         "gives the class accuracy; jsrte only)."),
    scale: str = typer.Option("quick", help="quick (4 scans) or paper (58 scans)."),
    scans: int = typer.Option(None, help="Number of virtual scans (overrides --scale)."),
    folder: Path = typer.Option(None, help="Use the real scans in this folder instead (no truth)."),
    methods: str = typer.Option("jsrte,harris3d-shot,ourcvfh-icp,pointnet-icp,fpfh-ransac-icp",
                                help="Methods, comma-separated."),
    preset: str = typer.Option(None, help="Fit preset for jsrte (default: fast; fast-scales with --model auto "
                                          "or a list)."),
    seed: int = typer.Option(0, help="Random seed (scan poses)."),
    overwrite: bool = typer.Option(False, help="Replace results already in --out."),
    threads: int = typer.Option(0, help="CPU threads (0: all cores)."),
    jobs: int = typer.Option(1, help="Scans run in this many processes at once (threads shared among them)."),
    html_report: bool = typer.Option(True, "--report/--no-report",
                                     help="Also write report.html beside results.csv (3D view of each fit)."),
    clutter: bool = typer.Option(False, "--clutter", help="Scan each shape in a room: walls, a table and boxes "
                                                          "beside it, one touching it (docs/clutter.md)."),
    first: int = typer.Option(0, help="First evaluation-set index of the virtual scans (0: Table 2's)."),
    dtype: str = opt.DTYPE,
    sizes: str = typer.Option("drawn", help="drawn: each shape scaled to a height drawn from 0.6-1.2 m, whatever "
                                            "its class (Table 2's protocol); own: each at its own size in metres "
                                            "(clean scans only)."),
) -> None:
    """Every method on every scan; F@5% against the true shape and the scan, times, figures."""
    from jsrte.atomic import output_dir
    from jsrte.baselines import BASELINE_NAMES
    from jsrte.experiments.scans import SCALES, check_sizes, folder_cases, run_scan_experiment, virtual_cases
    from jsrte.fit import model_names
    from jsrte.model.registry import resolve_model
    from jsrte.presets import default_preset, names_several_models

    chosen = split_names(methods, ("jsrte",) + BASELINE_NAMES, "method")
    if scale not in SCALES:
        raise JsrteError(f"unknown scale {scale!r} (known: {', '.join(SCALES)})")
    check_sizes(sizes, clutter)
    opt.check_dtype(dtype)
    if jobs < 1:
        raise JsrteError(f"--jobs must be positive, got {jobs}")
    check_threads(threads)
    check_out_folder(out, marker="table.md", overwrite=overwrite)
    several = names_several_models(model)
    if several and any(m != "jsrte" for m in chosen):
        raise JsrteError(f"--model {model}: only jsrte chooses the class; pass --methods jsrte")
    loaded = model_names(model) if several else resolve_model(model or category)
    preset = preset or default_preset(class_unknown=several)
    set_threads(threads)
    with output_dir(out, overwrite=overwrite, marker="table.md") as folder_out:
        cases = (folder_cases(folder) if folder is not None
                 else virtual_cases(category, scans or SCALES[scale], folder_out / "scans", seed=seed,
                                    first=first, clutter=clutter, sizes=sizes))
        run_scan_experiment(cases, list(chosen), folder_out, model=loaded, preset=preset, seed=seed,
                            jobs=jobs, threads=threads or None, report=html_report, category=category,
                            dtype=dtype)
    typer.echo((out / "table.md").read_text())
