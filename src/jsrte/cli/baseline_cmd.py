"""``jsrte baseline``: a recognize-then-register baseline of the paper's Table 2 on one scan."""

from __future__ import annotations

from pathlib import Path

import typer

from jsrte.baselines import BASELINE_NAMES
from jsrte.cli import app
from jsrte.cli.common import check_out_folder, check_threads, set_threads
from jsrte.cli.fit_options import parse_vector
from jsrte.errors import JsrteError

NAME_HELP = (
    "Baseline: harris3d-shot (Harris3D keypoints + SHOT, PCL), ourcvfh-icp (OUR-CVFH, PCL, + ICP), "
    "pointnet-icp (PointNet classifier + ICP), fpfh-ransac-icp (Open3D FPFH + RANSAC + ICP)."
)


@app.command("baseline")
def baseline_command(
    name: str = typer.Argument(..., help=NAME_HELP, metavar="NAME"),
    scan: Path = typer.Argument(..., help="Scan (PLY/PCD/XYZ, metres) or complete mesh (OBJ/OFF/STL/GLB)."),
    out: Path = typer.Option(..., "--out", help="Output folder (fit.json, shape.ply, overlay.png)."),
    model: str = typer.Option("chair", help="Shipped model name or model file: its training shapes are "
                                            "the database."),
    up: str = typer.Option(None, help="Known up axis X,Y,Z (default: the floor normal; +y for meshes)."),
    seed: int = typer.Option(0, help="Random seed."),
    threads: int = typer.Option(0, help="CPU threads (0: all cores)."),
    overwrite: bool = typer.Option(False, help="Replace results already in --out."),
    progress: bool = typer.Option(True, help="Show progress (PointNet training, the first time)."),
) -> None:
    """Retrieve a training shape of the model and its similarity transform with a baseline."""
    import numpy as np

    from jsrte.atomic import output_dir
    from jsrte.baselines.database import ShapeDatabase
    from jsrte.baselines.run import load_baseline_query, run_baseline
    from jsrte.fit.outputs import RESULT_NAME, write_fit_outputs
    from jsrte.model.registry import resolve_model

    if name not in BASELINE_NAMES:
        raise JsrteError(f"unknown baseline {name!r} (known: {', '.join(BASELINE_NAMES)})")
    if not scan.exists():
        raise JsrteError("no such file", scan)
    check_threads(threads)
    check_out_folder(out, marker=RESULT_NAME, overwrite=overwrite)
    set_threads(threads)
    query = load_baseline_query(scan, rng=np.random.default_rng(seed), up=parse_vector(up))
    loaded = resolve_model(model)
    database = ShapeDatabase.from_model(loaded)
    result = run_baseline(name, query, database, seed=seed, progress=progress)
    result.info.update(model=loaded.name, model_sha256=loaded.meta.get("sha256"))
    with output_dir(out, overwrite=overwrite, marker=RESULT_NAME) as folder:
        write_fit_outputs(result, folder, query_points=query.points, up=query.up, extra={"input": str(scan)})
    t = result.transform
    typer.echo(f"{name}: retrieved {result.info['retrieved_name']} (#{result.info['retrieved_index']}) by "
               f"{result.criterion['name']} {result.criterion['value']:.4g}")
    typer.echo(f"scale {t.s:.4f}  translation {np.round(t.t, 3).tolist()}  "
               f"time {result.timing['total']:.1f} s")
    typer.echo(f"wrote {out}/fit.json, shape.ply, shape_canonical.ply, overlay.png")
