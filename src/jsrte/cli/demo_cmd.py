"""``jsrte demo``: the main job on the embedded default data and the shipped chair model."""

from __future__ import annotations

import time
from pathlib import Path

import typer

from jsrte.cli import app
from jsrte.cli.common import check_out_folder, check_threads, set_threads
from jsrte.cli.fit_options import check_preset


@app.command("demo")
def demo(
    out: Path = typer.Option(Path("demo_out"), "--out", help="Output folder."),
    seed: int = typer.Option(0, help="Which held-out chair (index in the evaluation set) and scan pose."),
    preset: str = typer.Option("fast", help="Fit settings (fast or paper)."),
    model: str = typer.Option("chair", help="Shipped model name or model file."),
    overwrite: bool = typer.Option(True, help="Replace an earlier demo's files in --out."),
    threads: int = typer.Option(0, help="CPU threads (0: all cores)."),
) -> None:
    """Scan a held-out generated chair in a random pose, fit it, and score the result."""
    import numpy as np

    from jsrte.atomic import output_dir
    from jsrte.experiments.truth import score_against_truth, truth_of
    from jsrte.fit import fit
    from jsrte.fit.outputs import RESULT_NAME, write_fit_outputs
    from jsrte.geometry.mesh import save_mesh
    from jsrte.scans.scanner import scan_mesh, write_scan
    from jsrte.shapes import EVAL_SET_SEED, generate_shape, shape_seed

    check_preset(preset)
    check_threads(threads)
    check_out_folder(out, marker=RESULT_NAME, overwrite=overwrite)
    set_threads(threads)
    category = "chair"
    shape = generate_shape(category, shape_seed(EVAL_SET_SEED, seed))
    typer.echo(f"held-out {category} #{seed} of the evaluation set (style {shape.style}); "
               "never seen in training (training uses set seed 0)")
    with output_dir(out, overwrite=True) as folder:
        scan = scan_mesh(shape.mesh, rng=np.random.default_rng(seed))
        scan_path = write_scan(scan, folder / "scan.ply", seed=seed)
        save_mesh(shape.mesh, folder / "true_shape_mesh_frame.ply")
        typer.echo(f"virtual scan: {len(scan.points)} points ({int(scan.is_object.sum())} on the object) "
                   f"-> {scan_path}")
        started = time.perf_counter()
        result = fit(scan_path, model=model, preset=preset, seed=seed, progress=True)
        elapsed = time.perf_counter() - started
        truth = truth_of(shape.mesh, scan.scan_from_mesh)
        score = score_against_truth(result, truth, rng=np.random.default_rng(seed))
        save_mesh(truth.mesh, folder / "true_shape.ply")
        write_fit_outputs(result, folder, query_points=scan.points[scan.is_object], up=scan.up,
                          extra={"input": str(scan_path), "against_truth": score})
    typer.echo(f"F@5% against the complete true shape: {score['fscore']:.3f} "
               f"(precision {score['precision']:.3f}, recall {score['recall']:.3f})")
    typer.echo(f"transform error: scale {100 * score['scale_error_rel']:.1f}%, rotation "
               f"{score['rotation_error_deg']:.1f}°, translation {100 * score['translation_error']:.1f} cm")
    typer.echo(f"fit time {elapsed:.1f} s (preset {preset}); outputs in {out}/: fit.json, shape.ply, "
               "overlay.png, scan.ply, true_shape.ply")
