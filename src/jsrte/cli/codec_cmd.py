"""``jsrte encode`` and ``jsrte decode``: a shape as a few hundred bytes, and back to a mesh."""

from __future__ import annotations

from pathlib import Path

import typer

from jsrte.cli import app
from jsrte.cli.common import check_out_file, check_threads, set_threads
from jsrte.errors import JsrteError
from jsrte.formats import MESH_OUTPUT_SUFFIXES
from jsrte.presets import DEFAULT_PRESET, PRESETS


def _refuse_existing(out: Path, overwrite: bool) -> None:
    check_out_file(out, overwrite=overwrite)


@app.command("encode")
def encode_command(
    source: Path = typer.Argument(..., help="A scan to fit (as 'jsrte fit' takes), or a folder written by "
                                            "'jsrte fit' (holding fit.json)."),
    out: Path = typer.Option(..., "--out", help="Shape code file to write (.jsrte)."),
    model: str = typer.Option(None, help="Shipped model name or model file (default: the fit's model for a "
                                         "fit folder, 'chair' for a scan)."),
    latent: str = typer.Option("fp32", "--latent", help="Latent encoding: fp32 (exact), fp16 or int8."),
    preset: str = typer.Option(DEFAULT_PRESET, help=f"Fit settings for a scan: {', '.join(PRESETS)}."),
    up: str = typer.Option(None, help="Known up axis X,Y,Z for a scan (default: the floor normal)."),
    seed: int = typer.Option(0, help="Random seed of the fit."),
    threads: int = typer.Option(0, help="CPU threads (0: all cores)."),
    overwrite: bool = typer.Option(False, help="Replace --out if it exists."),
) -> None:
    """Store a shape as its latent code and similarity transform (the paper's compression)."""
    from jsrte.atomic import write_bytes_atomic
    from jsrte.cli.fit_options import check_preset, parse_vector
    from jsrte.codec.convert import code_from_fit_dir, code_from_result
    from jsrte.codec.format import ENCODINGS, encode

    if latent not in ENCODINGS:
        raise JsrteError(f"unknown --latent {latent!r}; known: {', '.join(ENCODINGS)}")
    check_preset(preset)
    check_threads(threads)
    if not source.exists():
        raise JsrteError("no such file or folder", source)
    _refuse_existing(out, overwrite)
    if source.is_dir():
        code = code_from_fit_dir(source, model=model)
    else:
        from jsrte.fit import fit
        from jsrte.model.registry import resolve_model

        set_threads(threads)
        loaded = resolve_model(model or "chair")
        result = fit(source, model=loaded, preset=preset, up=parse_vector(up), seed=seed)
        code = code_from_result(result, model_name=loaded.name, model_sha256=loaded.meta["sha256"])
    data = encode(code, latent_format=latent)
    write_bytes_atomic(out, data)
    typer.echo(f"wrote {out} ({len(data)} bytes: {latent} latent d={code.latent.size}, "
               f"model {code.model_name!r} {code.model_hash_hex[:12]}…, scale {code.transform.s:.4f})")


@app.command("decode")
def decode_command(
    code_file: Path = typer.Argument(..., help="Shape code (.jsrte) written by 'jsrte encode'."),
    out: Path = typer.Option(..., "--out", help=f"Mesh to write ({', '.join(MESH_OUTPUT_SUFFIXES)})."),
    model: str = typer.Option(None, help="Model file (default: the shipped model named in the code)."),
    resolution: int = typer.Option(128, help="Marching-cubes grid resolution."),
    canonical: bool = typer.Option(False, help="Write the mesh in the canonical frame (no transform)."),
    threads: int = typer.Option(0, help="CPU threads (0: all cores)."),
    overwrite: bool = typer.Option(False, help="Replace --out if it exists."),
) -> None:
    """Turn a shape code back into a mesh, in the scan's frame (or canonical with --canonical)."""
    from jsrte.codec.convert import mesh_from_code, model_for_code, read_code
    from jsrte.geometry.mesh import save_mesh

    if out.suffix.lower() not in MESH_OUTPUT_SUFFIXES:
        known = ", ".join(MESH_OUTPUT_SUFFIXES)
        raise JsrteError(f"unsupported mesh format {out.suffix!r}; use one of {known}", out)
    if not 8 <= resolution <= 1024:
        raise JsrteError(f"--resolution must be in 8..1024, got {resolution}")
    check_threads(threads)
    _refuse_existing(out, overwrite)
    code = read_code(code_file)
    loaded = model_for_code(code, model=model, source=code_file)
    set_threads(threads)
    mesh = mesh_from_code(code, loaded, resolution=resolution, canonical=canonical)
    if mesh is None:
        raise JsrteError(f"the decoded surface is empty (model {loaded.name!r}); nothing written", code_file)
    save_mesh(mesh, out)
    frame = "canonical" if canonical else "scan"
    typer.echo(f"wrote {out} ({len(mesh.vertices)} vertices, {len(mesh.faces)} faces, {frame} frame)")
