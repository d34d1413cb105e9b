"""Write a fit's files: fit.json, shape.ply (scan frame), shape_canonical.ply, overlay.png."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from jsrte.atomic import write_json_atomic
from jsrte.geometry.mesh import save_mesh
from jsrte.result import FitResult
from jsrte.timing import timed_stage

RESULT_NAME = "fit.json"


@timed_stage("outputs")
def write_fit_outputs(result: FitResult, out_dir: Path, *, query_points: np.ndarray,
                      up: np.ndarray | None, extra: dict | None = None) -> list[Path]:
    """Write the result files into ``out_dir`` (each atomically; fit.json last)."""
    from jsrte.viz import render_overlay

    written = []
    if result.mesh_canonical is not None:
        save_mesh(result.mesh_canonical, out_dir / "shape_canonical.ply")
        save_mesh(result.mesh, out_dir / "shape.ply")
        written += [out_dir / "shape_canonical.ply", out_dir / "shape.ply"]
    overlay = out_dir / "overlay.png"
    up_axis = (0.0, 1.0, 0.0) if up is None else tuple(np.asarray(up, float))
    render_overlay(result.mesh, query_points, overlay, up=up_axis, title=result.method)
    written.append(overlay)
    write_json_atomic(out_dir / RESULT_NAME, result.to_json() | (extra or {}))
    written.append(out_dir / RESULT_NAME)
    return written
