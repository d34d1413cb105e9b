"""``jsrte score PRED_MESH TRUE_MESH``: F-score (the paper's F@5%) and Chamfer of two meshes."""

from __future__ import annotations

import json
import math
from pathlib import Path

import typer

from jsrte.cli import app
from jsrte.errors import JsrteError
from jsrte.presets import FitSettings


@app.command("score")
def score(
    pred_mesh: Path = typer.Argument(..., help="Predicted mesh (OBJ/PLY/OFF/STL/GLB)."),
    true_mesh: Path = typer.Argument(..., help="Ground-truth mesh, same frame and units."),
    fraction: float = typer.Option(
        FitSettings.fscore_fraction,
        help="Threshold as a fraction of the ground truth's bounding-sphere radius."),
    points: int = typer.Option(FitSettings.fscore_points, help="Points sampled on each surface."),
    seed: int = typer.Option(0, help="Seed of the surface sampling."),
) -> None:
    """Print {fscore, precision, recall, threshold, chamfer} as one JSON line."""
    import numpy as np

    from jsrte.geometry.mesh import load_mesh
    from jsrte.metrics.surface import fscore

    if not (fraction > 0 and math.isfinite(fraction)):
        raise JsrteError(f"--fraction must be a positive number, got {fraction}")
    if points < 1:
        raise JsrteError(f"--points must be at least 1, got {points}")
    pred = load_mesh(pred_mesh)
    truth = load_mesh(true_mesh)
    result = fscore(pred, truth, fraction=fraction, n_points=points,
                    rng=np.random.default_rng(seed))
    values = {k: (v if math.isfinite(v) else None) for k, v in result.as_dict().items()}
    typer.echo(json.dumps(values))
