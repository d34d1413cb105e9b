"""``jsrte fit``, ``jsrte reconstruct`` and ``jsrte models``."""

from __future__ import annotations

import json
from pathlib import Path
from typing import TYPE_CHECKING

import typer

from jsrte.cli import app
from jsrte.cli.common import check_out_file, check_out_folder, check_threads, resolve_device, set_threads
from jsrte.errors import JsrteError
from jsrte.presets import DEFAULT_PRESET, PRESETS

if TYPE_CHECKING:  # numpy is imported by the functions that run, never for --help
    import numpy as np


def parse_vector(text: str | None, name: str = "--up") -> np.ndarray | None:
    """'X,Y,Z' -> unit (3,) vector; None stays None."""
    import numpy as np

    if text is None:
        return None
    v = _three_numbers(text, name)
    if np.linalg.norm(v) == 0:
        raise JsrteError(f"{name} must be a non-zero vector X,Y,Z, got {text!r}")
    return v / np.linalg.norm(v)


def parse_points(texts: list[str] | None, name: str = "--viewpoint") -> np.ndarray | None:
    """['X,Y,Z', ...] -> (k, 3) positions (scan units); None or empty stays None."""
    import numpy as np

    return np.stack([_three_numbers(text, name) for text in texts]) if texts else None


def _three_numbers(text: str, name: str) -> np.ndarray:
    """'X,Y,Z' -> (3,) finite floats, or a one-line error naming the option."""
    import numpy as np

    try:
        v = np.array([float(x) for x in text.split(",")])
    except ValueError:
        v = np.array([])
    if v.shape != (3,) or not np.all(np.isfinite(v)):
        raise JsrteError(f"{name} must be three finite numbers X,Y,Z, got {text!r}")
    return v


UNITS_HELP = ("Refuse a scan whose object is implausibly large or small for metres (over 10 m or under 2 cm "
              "across: millimetres?); --no-units-check fits it anyway.")


def check_hypotheses(hypotheses: int | None) -> None:
    """A one-line error unless ``hypotheses`` is None (the default grid) or positive."""
    if hypotheses is not None and hypotheses < 1:
        raise JsrteError(f"--hypotheses must be positive, got {hypotheses}")


def check_preset(preset: str) -> str:
    """``preset`` if it names a preset, else a one-line error listing the known ones."""
    if preset not in PRESETS:
        raise JsrteError(f"unknown preset {preset!r}; known: {', '.join(PRESETS)}")
    return preset


@app.command("fit")
def fit_command(
    scan: Path = typer.Argument(..., help="Scan (PLY/PCD/XYZ, metres), complete mesh (OBJ/OFF/STL/GLB) "
                                          "or SDF samples (.npz)."),
    out: Path = typer.Option(..., "--out", help="Output folder (fit.json, shape.ply, overlay.png)."),
    model: str = typer.Option("chair", help="Shipped model name or model file."),
    up: str = typer.Option(None, help="Known up axis X,Y,Z (default: the floor normal; +y for meshes)."),
    viewpoint: list[str] = typer.Option(
        None, help="Sensor position X,Y,Z in the scan's frame (metres), repeatable; 0,0,0 for a depth "
                   "frame in camera coordinates. Default: the cameras of the scan's JSON sidecar, if any."),
    line_of_sight: bool = typer.Option(
        None, "--line-of-sight/--no-line-of-sight",
        help="Free-space samples on the lines of sight from the viewpoints (beyond the paper; default: the "
             "preset's, on in fast, off in paper; docs/presets.md)."),
    free_axis: bool = typer.Option(
        False, "--free-axis", help="Let the rotation axis move away from the up axis (default: held at the "
                                   "floor normal / --up, the paper's known-axis mode)."),
    at: str = typer.Option(None, "--at", help="In a scan of several objects, fit the one nearest X,Y,Z (scan "
                                              "frame, metres); default: the one most like the model's class."),
    preset: str = typer.Option(DEFAULT_PRESET, help=f"Fit settings: {', '.join(PRESETS)}."),
    hypotheses: int = typer.Option(None, help="Number of θ starts (default: every 30°, 12)."),
    seed: int = typer.Option(0, help="Random seed."),
    device: str = typer.Option("cpu", help="Torch device: cpu, cuda or cuda:N (where PyTorch sees a GPU)."),
    threads: int = typer.Option(0, help="CPU threads (0: all cores)."),
    overwrite: bool = typer.Option(False, help="Replace results already in --out."),
    progress: bool = typer.Option(True, help="Show a progress bar."),
    units_check: bool = typer.Option(True, "--units-check/--no-units-check", help=UNITS_HELP),
) -> None:
    """Fit the model to a scan: latent code + similarity transform (the paper's JSRTE)."""
    from jsrte.fit import fit
    from jsrte.fit.outputs import RESULT_NAME, write_fit_outputs
    from jsrte.io import output_dir

    check_preset(preset)
    check_threads(threads)
    check_hypotheses(hypotheses)
    torch_device = resolve_device(device)
    if not scan.exists():
        raise JsrteError("no such file", scan)
    check_out_folder(out, marker=RESULT_NAME, overwrite=overwrite)
    viewpoints = parse_points(viewpoint)
    set_threads(threads)
    result = fit(scan, model=model, preset=preset, up=parse_vector(up), viewpoints=viewpoints,
                 line_of_sight=line_of_sight, free_axis=free_axis, at=_three_numbers(at, "--at") if at else None,
                 hypotheses=hypotheses, seed=seed, progress=progress, device=torch_device, units_check=units_check)
    with output_dir(out, overwrite=overwrite, marker=RESULT_NAME) as folder:
        write_fit_outputs(result, folder, query_points=result.query_points, up=result.info.get("up"),
                          extra={"input": str(scan)})
    _report(result, out)


@app.command("prepare")
def prepare_command(
    scan: Path = typer.Argument(..., help="Scan (PLY/PCD/XYZ, metres) or complete mesh (OBJ/OFF/STL/GLB)."),
    out: Path = typer.Option(..., "--out", help="Query file to write (.npz), for `jsrte fit QUERY.npz`."),
    up: str = typer.Option(None, help="Known up axis X,Y,Z (default: the floor normal; +y for meshes)."),
    viewpoint: list[str] = typer.Option(None, help="Sensor position X,Y,Z (metres), repeatable."),
    line_of_sight: bool = typer.Option(
        None, "--line-of-sight/--no-line-of-sight",
        help=f"Line-of-sight free-space samples (default: as the {DEFAULT_PRESET} preset)."),
    seed: int = typer.Option(0, help="Random seed."),
    overwrite: bool = typer.Option(False, help="Replace an existing query file."),
    units_check: bool = typer.Option(True, "--units-check/--no-units-check", help=UNITS_HELP),
) -> None:
    """Preprocess a scan once into the fit's SDF query (floor, outliers, normals, samples): fit it
    later or on another machine (a GPU box without Open3D) with `jsrte fit QUERY.npz`."""
    import numpy as np

    from jsrte.fit.query import load_query, save_query
    from jsrte.presets import get_preset, with_line_of_sight

    check_out_file(out, overwrite=overwrite, suffixes=(".npz",))
    settings = with_line_of_sight(get_preset(DEFAULT_PRESET).scan_sdf, line_of_sight)
    query = load_query(scan, rng=np.random.default_rng(seed), up=parse_vector(up), viewpoints=parse_points(viewpoint),
                       scan_settings=settings, units_check=units_check)
    query.info["source"] = scan.name
    save_query(query, out)
    typer.echo(f"wrote {out}: {len(query.sdf)} SDF samples, {len(query.surface)} surface points"
               + ("" if query.up is None else f", up {np.round(query.up, 3).tolist()}"))


def _report(result, out: Path) -> None:  # noqa: ANN001
    import numpy as np

    t = result.transform
    typer.echo(f"scale {t.s:.4f}  yaw θ {np.degrees(result.angles['theta']) % 360:.1f}°  "
               f"translation {np.round(t.t, 3).tolist()}")
    typer.echo(f"winner by {result.criterion['name']}: {result.criterion['value']:.4f}; "
               f"time {result.timing['total']:.1f} s")
    if result.flag is not None:
        typer.echo(_quality_line(result.flag, result.quality))
    typer.echo(f"wrote {out}/fit.json, shape.ply, shape_canonical.ply, overlay.png")


def _quality_line(flag: str, quality: dict) -> str:
    """One line: the flag and the measures it rests on (docs/confidence.md)."""
    def number(key: str, text: str) -> str:
        value = quality.get(key)
        return f"{text} –" if value is None else f"{text} {value:.2f}"

    return (f"flag {flag}: " + number("inlier_share", "inliers") + ", "
            + number("free_space_violation", "free-space violation") + ", "
            + number("loss_margin_rel", "loss margin") + ", "
            + number("latent_mahalanobis_ratio", "code distance") + " (docs/confidence.md)")


@app.command("models")
def models_command(as_json: bool = typer.Option(False, "--json", help="Print JSON.")) -> None:
    """List the shipped models."""
    from jsrte.model.registry import describe_models

    rows = describe_models()
    if as_json:
        typer.echo(json.dumps(rows, indent=2))
        return
    if not rows:
        typer.echo("no shipped models")
    for r in rows:
        f = r["metrics"].get("train_fscore_mean")
        h = r["metrics"].get("heldout_fscore_mean")
        typer.echo(f"{r['name']:8s} {r['category'] or '?':6s} {r['shapes']} shapes, latent {r['latent_size']}, "
                   f"{r['size_kb']} KB, F@5% train {f if f is not None else '-'} held-out "
                   f"{h if h is not None else '-'}")
