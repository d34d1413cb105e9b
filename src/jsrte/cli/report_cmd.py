"""``jsrte report``: one self-contained HTML file (offline) with an interactive 3D view per fit."""

from __future__ import annotations

import sys
from pathlib import Path

import typer

from jsrte.cli import app


@app.command("report")
def report_command(
    path: Path = typer.Argument(..., help="A fit folder (fit.json), a fit-many output, a scene folder "
                                          "(scene.json, objects/NN/) or a .jsrte shape code."),
    out: Path = typer.Option(..., "--out", help="HTML file to write (e.g. report.html)."),
    overwrite: bool = typer.Option(False, help="Replace --out if it exists."),
) -> None:
    """Write one HTML page that works offline: a 3D view of each fit (mesh, scan points, truth, floor) and,
    for several fits, a summary table with each fit's overlay thumbnail."""
    from jsrte.errors import JsrteError
    from jsrte.view.loading import find_fits, load_items
    from jsrte.view.report import write_report

    if out.is_dir():
        raise JsrteError("is a folder; give a file name such as report.html", out)
    if out.exists() and not overwrite:
        raise JsrteError("already exists; pass --overwrite to replace it", out)
    collection = find_fits(path)
    items = load_items(collection)
    for item in items:
        for problem in item.problems:
            print(f"jsrte: warning: {problem}", file=sys.stderr)
    size = write_report(items, out, title=f"jsrte: {collection.path.resolve().name}", overwrite=overwrite)
    typer.echo(f"wrote {out} ({size / 1e6:.2f} MB, {len(items)} fit{'s' * (len(items) != 1)})")
