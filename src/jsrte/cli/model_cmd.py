"""``jsrte reconstruct`` (latent-only, DeepSDF) and ``jsrte evaluate-model`` (model card figures)."""

from __future__ import annotations

from pathlib import Path

import typer

from jsrte.cli import app
from jsrte.cli.common import check_out_file, check_out_folder, check_threads, resolve_device, set_threads
from jsrte.errors import JsrteError


@app.command("reconstruct")
def reconstruct(
    mesh: Path = typer.Argument(..., help="Mesh in canonical orientation (+y up, front -z), any position/scale."),
    out: Path = typer.Option(..., "--out", help="Output folder (shape.ply, reconstruct.json)."),
    model: str = typer.Option("chair", help="Shipped model name or model file."),
    resolution: int = typer.Option(128, help="Marching-cubes resolution."),
    seed: int = typer.Option(0, help="Random seed."),
    threads: int = typer.Option(0, help="CPU threads (0: all cores)."),
    overwrite: bool = typer.Option(False, help="Replace results already in --out."),
    progress: bool = typer.Option(True, help="Show a progress bar."),
) -> None:
    """DeepSDF latent-only reconstruction; the mesh is written in the input's own frame."""
    import numpy as np

    from jsrte.atomic import output_dir, write_json_atomic
    from jsrte.fit.reconstruct import reconstruct_mesh
    from jsrte.geometry.mesh import load_mesh, save_mesh
    from jsrte.metrics.surface import fscore
    from jsrte.model.registry import resolve_model

    if not 8 <= resolution <= 1024:
        raise JsrteError(f"--resolution must be in 8..1024, got {resolution}")
    check_out_folder(out, marker="reconstruct.json", overwrite=overwrite)
    set_threads(threads)
    source = load_mesh(mesh)
    loaded = resolve_model(model)
    result, latent = reconstruct_mesh(loaded, source, rng=np.random.default_rng(seed), resolution=resolution,
                                      progress=progress)
    if result is None:
        raise JsrteError("the reconstructed surface is empty (the model cannot represent this shape)", mesh)
    score = fscore(result, source, rng=np.random.default_rng(seed))
    with output_dir(out, overwrite=overwrite, marker="reconstruct.json") as folder:
        save_mesh(result, folder / "shape.ply")
        write_json_atomic(folder / "reconstruct.json", {
            "input": str(mesh), "model": loaded.name, "model_sha256": loaded.meta.get("sha256"),
            "latent": latent.tolist(), "fscore_vs_input": score.as_dict(), "resolution": resolution})
    typer.echo(f"F@5% against the input: {score.fscore:.3f}; wrote {out}/shape.ply, reconstruct.json")


@app.command("evaluate-model")
def evaluate_model_command(
    model: str = typer.Option("chair", help="Shipped model name or model file."),
    n_train: int = typer.Option(20, help="Training shapes decoded from their codes."),
    n_heldout: int = typer.Option(20, help="Held-out shapes (evaluation seed set) reconstructed latent-only."),
    resolution: int = typer.Option(96, help="Marching-cubes resolution."),
    out: Path = typer.Option(None, help="Write the per-shape rows and means as JSON here."),
    seed: int = typer.Option(0, help="Random seed."),
    threads: int = typer.Option(0, help="CPU threads (0: all cores)."),
    device: str = typer.Option("cpu", help="Torch device: cpu, cuda or cuda:N."),
    overwrite: bool = typer.Option(False, help="Replace the file given by --out if it exists."),
) -> None:
    """Model-card figures: F@5% / Chamfer of training and held-out procedural shapes."""
    import json

    from jsrte.atomic import write_json_atomic
    from jsrte.fit.reconstruct import evaluate_model
    from jsrte.model.registry import resolve_model
    from jsrte.shapes import EVAL_SET_SEED, generate_set

    if out is not None:
        check_out_file(out, overwrite=overwrite)
    check_threads(threads)
    set_threads(threads)
    loaded = resolve_model(model).to(resolve_device(device))
    data = loaded.meta.get("data", {})
    if data.get("source") != "procedural":
        raise JsrteError("evaluate-model needs a model trained on procedural shapes (its data is regenerated)")
    category, set_seed = data["category"], int(data["set_seed"])
    n_train = min(n_train, int(loaded.codes.shape[0]))
    train = [s.mesh for s in generate_set(category, n_train, set_seed)]
    held = [s.mesh for s in generate_set(category, n_heldout, EVAL_SET_SEED)]
    report = evaluate_model(loaded, train, held, resolution=resolution, seed=seed)
    if out is not None:
        write_json_atomic(out, report)
    typer.echo(json.dumps(report["summary"]))
