"""``jsrte sample`` and ``jsrte dataset``: DeepSDF-style SDF samples of meshes."""

from __future__ import annotations

from pathlib import Path

import typer

from jsrte.cli import app
from jsrte.cli.common import check_out_file, check_out_folder, check_threads
from jsrte.errors import JsrteError
from jsrte.presets import SdfSampling


@app.command("sample")
def sample(
    mesh: Path = typer.Argument(..., help="Mesh file (OBJ/PLY/OFF/STL/GLB)."),
    out: Path = typer.Option(..., "--out", help="Output .npz (points, sdf, centre, scale)."),
    n: int = typer.Option(SdfSampling.n_points, "--n", help="Number of samples."),
    seed: int = typer.Option(0, help="Random seed."),
    overwrite: bool = typer.Option(False, help="Replace an existing output file."),
) -> None:
    """SDF samples of one mesh in the normalized canonical frame (negative inside)."""
    import numpy as np

    from jsrte.geometry.mesh import load_mesh
    from jsrte.sdf.mesh_sdf import sample_sdf

    if n < 1:
        raise JsrteError(f"--n must be positive, got {n}")
    check_out_file(out, overwrite=overwrite, suffixes=(".npz",))
    samples = sample_sdf(load_mesh(mesh), rng=np.random.default_rng(seed), settings=SdfSampling(n_points=n))
    samples.save(out)
    inside = float((samples.sdf < 0).mean())
    typer.echo(f"wrote {out}: {len(samples.sdf)} samples, {inside:.1%} inside, scale {samples.scale:.4g}")


@app.command("dataset")
def dataset(
    folder: Path = typer.Argument(..., help="Folder of meshes (searched recursively)."),
    out: Path = typer.Option(..., "--out", help="Output folder of .npz samples (a cache)."),
    n: int = typer.Option(SdfSampling.n_points, "--n", help="Samples per mesh."),
    seed: int = typer.Option(0, help="Random seed (mesh i uses seed + i)."),
    workers: int = typer.Option(0, help="Worker processes (0: all cores)."),
) -> None:
    """Sample every mesh of a folder in parallel; meshes already sampled are skipped."""
    from jsrte.formats import MESH_FILE_SUFFIXES
    from jsrte.sdf.dataset import build_sdf_dataset

    if not folder.is_dir():
        raise JsrteError("no such folder", folder)
    check_threads(workers, "--workers")
    check_out_folder(out)
    meshes = sorted(p for p in folder.rglob("*") if p.suffix.lower() in MESH_FILE_SUFFIXES)
    if not meshes:
        raise JsrteError("holds no mesh files", folder)
    paths = build_sdf_dataset(meshes, out, settings=SdfSampling(n_points=n), seed=seed,
                              workers=workers or None)
    typer.echo(f"wrote {len(paths)} sample files to {out}")
