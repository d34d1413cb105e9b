"""``jsrte shapes``: write a set of procedural furniture meshes (and a contact sheet)."""

from __future__ import annotations

import re
from collections import Counter
from pathlib import Path

import typer

from jsrte.cli import app
from jsrte.cli.common import check_out_folder
from jsrte.errors import JsrteError


@app.command("shapes")
def shapes(
    category: str = typer.Option(..., "--category", help="chair, table, sofa or bed."),
    n: int = typer.Option(..., "--n", help="Number of shapes."),
    seed: int = typer.Option(0, "--seed", help="Set seed: 0 for training sets, 1 for evaluation sets."),
    out: Path = typer.Option(..., "--out", help="Output folder ({category}_{i:04d}.ply + .json)."),
    sheet: bool = typer.Option(False, "--sheet", help="Also render the first 16 shapes to sheet.png."),
    overwrite: bool = typer.Option(False, "--overwrite",
                                   help="Replace meshes already in the folder (stale ones are removed)."),
) -> None:
    """Generate shapes 0..n-1 of a procedural set, reproducibly from the set seed."""
    from tqdm import tqdm

    from jsrte.atomic import output_dir
    from jsrte.formats import MESH_FILE_SUFFIXES
    from jsrte.shapes import check_category, generate_shape, shape_seed, write_shape
    from jsrte.shapes.sheet import MAX_SHEET_SHAPES, render_sheet

    check_category(category)
    if n < 1:
        raise JsrteError(f"--n must be at least 1, got {n}")
    if seed < 0:
        raise JsrteError(f"--seed must be non-negative, got {seed}")
    check_out_folder(out)
    existing = [p for p in out.iterdir() if p.suffix.lower() in MESH_FILE_SUFFIXES] if out.is_dir() else []
    if existing and not overwrite:
        raise JsrteError(f"already holds {len(existing)} mesh file(s); pass --overwrite to replace them",
                         out)
    styles: Counter[str] = Counter()
    shown = []
    with output_dir(out) as folder:
        for i in tqdm(range(n), desc=f"{category}s", unit="shape", disable=n < 20):
            shape = generate_shape(category, shape_seed(seed, i))
            write_shape(shape, folder, i)
            styles[shape.style] += 1
            if i < MAX_SHEET_SHAPES:
                shown.append(shape)
        _remove_stale(folder, category, n)
        if sheet:
            render_sheet([s.mesh for s in shown], [f"#{i} {s.style}" for i, s in enumerate(shown)],
                         folder / "sheet.png")
    summary = ", ".join(f"{style} {count}" for style, count in sorted(styles.items()))
    typer.echo(f"wrote {n} {category} meshes to {out} ({summary})"
               + (f"; sheet {out / 'sheet.png'}" if sheet else ""))


def _remove_stale(folder: Path, category: str, n: int) -> None:
    """Delete ``{category}_{i:04d}.ply/.json`` left from an earlier, larger set (i >= n)."""
    pattern = re.compile(rf"{re.escape(category)}_(\d{{4,}})\.(ply|json)")
    for path in folder.iterdir():
        match = pattern.fullmatch(path.name)
        if match and int(match.group(1)) >= n:
            path.unlink()
