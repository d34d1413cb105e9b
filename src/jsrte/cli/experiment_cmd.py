"""``jsrte experiment ...``: the paper's experiments (synthetic, compression; more may join
``experiment_app``)."""

from __future__ import annotations

from pathlib import Path

import typer

from jsrte.cli import app
from jsrte.cli.common import check_threads, resolve_device, set_threads
from jsrte.errors import JsrteError
from jsrte.experiments.settings import SCENARIOS, SYNTHETIC_SCALES, CompressionSettings
from jsrte.presets import PRESETS

experiment_app = typer.Typer(name="experiment", help="Run the paper's experiments and write their tables and "
                             "figures.", no_args_is_help=True)
app.add_typer(experiment_app, name="experiment")


def split_names(text: str, known: tuple[str, ...] | list[str], what: str) -> tuple[str, ...]:
    """'a,b' -> ('a', 'b'), each checked against ``known`` (JsrteError naming the bad one)."""
    names = tuple(dict.fromkeys(n.strip() for n in text.split(",") if n.strip()))
    if not names:
        raise JsrteError(f"no {what} given")
    bad = [n for n in names if n not in known]
    if bad:
        raise JsrteError(f"unknown {what} {', '.join(bad)} (known: {', '.join(known)})")
    return names


def load_models(categories: tuple[str, ...], model: str | None) -> dict:
    """Category -> loaded model, or None where there is none (the experiment skips it).

    With ``model`` (a path or shipped name) there must be exactly one category.
    """
    from jsrte.model.registry import resolve_model, shipped_models

    if model is not None:
        if len(categories) != 1:
            raise JsrteError(f"--model gives the model of one class; got --categories {','.join(categories)}")
        return {categories[0]: resolve_model(model)}
    shipped = shipped_models()
    return {c: resolve_model(c) if c in shipped else None for c in categories}


def _check_out(out: Path, marker: str, overwrite: bool) -> None:
    from jsrte.cli.common import check_out_folder

    check_out_folder(out, marker=marker, overwrite=overwrite)


@experiment_app.command("synthetic", short_help="Paper section 4.1 (Fig. 2): fits of held-out shapes under "
                                                "random transforms.")
def synthetic_command(
    out: Path = typer.Option(..., "--out", help="Output folder (runs.csv, summary.md/.csv, box plots)."),
    categories: str = typer.Option("chair,table,sofa,bed", help="Classes, comma-separated (those without a "
                                                                "shipped model are skipped)."),
    model: str = typer.Option(None, help="Model file (or shipped name) for a single class given by "
                                         "--categories."),
    scale: str = typer.Option("quick", help=f"Experiment size: {', '.join(SYNTHETIC_SCALES)} "
                                            "(quick: 3 shapes x 4 inits x 2 scenarios, fast preset, minutes; "
                                            "medium: 10 x 10 x 4 scenarios, fast preset, about an hour per "
                                            "class on 1 CPU core; paper: 30 x 50 x 4 scenarios, paper "
                                            "preset, GPU hours)."),
    shapes: int = typer.Option(None, help="Held-out shapes per class (overrides --scale)."),
    inits: int = typer.Option(None, help="Initializations per shape and scenario (overrides --scale)."),
    scenarios: str = typer.Option(None, help=f"Scenarios, comma-separated: {', '.join(SCENARIOS)} "
                                             "(overrides --scale)."),
    preset: str = typer.Option(None, help=f"Fit settings: {', '.join(PRESETS)} (overrides --scale)."),
    samples: int = typer.Option(None, help="SDF samples per query (overrides --scale)."),
    resolution: int = typer.Option(None, help="Marching-cubes resolution of scored surfaces (default: the "
                                              "preset's selection resolution)."),
    seed: int = typer.Option(0, help="Random seed."),
    threads: int = typer.Option(0, help="CPU threads (0: all cores)."),
    device: str = typer.Option("cpu", help="Torch device of the fits: cpu, cuda or cuda:N."),
    overwrite: bool = typer.Option(False, help="Replace results already in --out."),
    resume: bool = typer.Option(False, help="Continue an interrupted run in --out (same settings) where it "
                                            "stopped."),
) -> None:
    """Paper section 4.1 (Fig. 2) and the supplementary's wider ranges: fits of held-out shapes under
    random transforms from random initializations around the truth."""
    from dataclasses import replace

    from jsrte.atomic import output_dir
    from jsrte.experiments.synthetic import RUNS_NAME, SUMMARY_MD, SyntheticConfig, run_synthetic
    from jsrte.shapes import CATEGORIES

    if scale not in SYNTHETIC_SCALES:
        raise JsrteError(f"unknown scale {scale!r}; known: {', '.join(SYNTHETIC_SCALES)}")
    base = SYNTHETIC_SCALES[scale]
    preset_name = preset or base.preset
    if preset_name not in PRESETS:
        raise JsrteError(f"unknown preset {preset_name!r}; known: {', '.join(PRESETS)}")
    for name, value in (("--shapes", shapes), ("--inits", inits), ("--samples", samples),
                        ("--resolution", resolution)):
        if value is not None and value < (8 if name == "--resolution" else 1):
            raise JsrteError(f"{name} must be positive, got {value}")
    cats = split_names(categories, CATEGORIES, "categories")
    config = SyntheticConfig(
        categories=cats,
        scenarios=split_names(scenarios, tuple(SCENARIOS), "scenarios") if scenarios else base.scenarios,
        shapes=shapes or base.shapes, inits=inits or base.inits, fit=PRESETS[preset_name].fit,
        preset_name=preset_name, scale_name=scale if not (shapes or inits or scenarios or preset or samples)
        else f"{scale} (modified)",
        sampling=replace(PRESETS[preset_name].sampling, n_points=samples or base.query_samples),
        seed=seed, resolution=resolution)
    if resume and overwrite:
        raise JsrteError("--resume continues the run in --out, --overwrite replaces it: give one")
    if not resume:
        _check_out(out, SUMMARY_MD, overwrite)
        if (out / RUNS_NAME).exists() and not overwrite:
            raise JsrteError(f"holds an unfinished run ({RUNS_NAME}); pass --resume to continue it or "
                             "--overwrite to replace it", out)
    check_threads(threads)
    torch_device = resolve_device(device)
    models = {c: m if m is None else m.to(torch_device) for c, m in load_models(cats, model).items()}
    if all(m is None for m in models.values()):
        raise JsrteError(f"no model for any of {', '.join(cats)}: none is shipped; pass --model PATH "
                         "with one category")
    set_threads(threads)
    with output_dir(out, overwrite=overwrite or resume, marker=SUMMARY_MD,
                    keep=lambda folder: (folder / RUNS_NAME).is_file()) as folder:
        report = run_synthetic(config, models, folder, log=typer.echo, resume=resume)
    for row in report.summary:
        if row["status"] == "ok":
            typer.echo(f"{row['scenario']:12s} {row['category']:6s} median F@5% {row['median_fscore']:.3f}  "
                       f"mean {row['mean_fscore']:.3f}  >= 0.8: {row['fraction_ge_0.8']:.0%}")
    for category, why in report.skipped.items():
        typer.echo(f"skipped {category}: {why} (none shipped; pass --model PATH with this one category)")
    typer.echo(f"wrote {', '.join(str(p) for p in report.files)}")


@experiment_app.command("compression")
def compression_command(
    out: Path = typer.Option(..., "--out", help="Output folder (table3.md/.csv, objects.csv, "
                                                "rate_distortion.png, codes/, meshes/)."),
    category: str = typer.Option("chair", help="Class of the test objects."),
    model: str = typer.Option(None, help="Model file or shipped name (default: the shipped model of the "
                                         "class)."),
    n: int = typer.Option(5, "--n", help="Number of held-out test objects."),
    source: str = typer.Option("meshes", help="meshes: complete meshes in a random pose; scans: virtual "
                                              "scans of them (the fit sees the scan)."),
    preset: str = typer.Option("fast", help=f"Fit settings: {', '.join(PRESETS)}."),
    samples: int = typer.Option(None, help="SDF samples of a mesh query (default: the preset's)."),
    dense_faces: int = typer.Option(CompressionSettings.dense_faces, help="Faces targeted when re-meshing "
                                    "the low-poly procedural original densely, as a scan reconstruction."),
    seed: int = typer.Option(0, help="Random seed."),
    threads: int = typer.Option(0, help="CPU threads (0: all cores)."),
    overwrite: bool = typer.Option(False, help="Replace results already in --out."),
) -> None:
    """Paper section 4.3 (Table 3): our shape codes against mesh simplification (QE-100, QE-1000,
    VC-0.1, VC-0.2), file size and F@5% against the original."""
    from dataclasses import replace

    from jsrte.atomic import output_dir
    from jsrte.experiments.compression import SOURCES, TABLE_MD, CompressionConfig, run_compression
    from jsrte.shapes import check_category

    check_category(category)
    if source not in SOURCES:
        raise JsrteError(f"unknown source {source!r}; known: {', '.join(SOURCES)}")
    if preset not in PRESETS:
        raise JsrteError(f"unknown preset {preset!r}; known: {', '.join(PRESETS)}")
    if n < 1:
        raise JsrteError(f"--n must be positive, got {n}")
    if samples is not None and samples < 1:
        raise JsrteError(f"--samples must be positive, got {samples}")
    if dense_faces < 100:
        raise JsrteError(f"--dense-faces must be at least 100, got {dense_faces}")
    chosen = PRESETS[preset]
    if samples:
        chosen = replace(chosen, sampling=replace(chosen.sampling, n_points=samples))
    _check_out(out, TABLE_MD, overwrite)
    check_threads(threads)
    loaded = load_models((category,), model)[category]
    if loaded is None:
        raise JsrteError(f"no shipped model for {category!r}; pass --model PATH")
    config = CompressionConfig(category=category, n=n, source=source, preset=chosen, seed=seed,
                               settings=CompressionSettings(dense_faces=dense_faces))
    set_threads(threads)
    with output_dir(out, overwrite=overwrite, marker=TABLE_MD) as folder:
        report = run_compression(config, loaded, folder, log=typer.echo)
    for row in report.table:
        size = "" if row["mean_size_kb"] == "" else f"{row['mean_size_kb']:.3f} KB"
        typer.echo(f"{row['method']:12s} F@5% {row['mean_fscore']:.3f}  {size}")
    typer.echo(f"wrote {', '.join(str(p) for p in report.files)}")
