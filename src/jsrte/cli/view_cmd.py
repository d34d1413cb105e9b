"""``jsrte view``: look at fits in a browser (an interactive 3D viewer served locally)."""

from __future__ import annotations

import sys
from pathlib import Path

import typer

from jsrte.cli import app


@app.command("view")
def view_command(
    path: Path = typer.Argument(..., help="A fit folder (fit.json), a fit-many output, a scene folder "
                                          "(scene.json, objects/NN/) or a .jsrte shape code."),
    host: str = typer.Option("127.0.0.1", help="Address to serve on (0.0.0.0: every network interface)."),
    port: int = typer.Option(8080, help="Port to serve on (0: any free port)."),
) -> None:
    """Serve an interactive 3D view of the fits: scan points coloured by distance to the fitted surface,
    retrieved and true meshes, floor, hypotheses' poses. Open the printed URL; Ctrl-C stops it."""
    from jsrte.errors import JsrteError
    from jsrte.view.loading import find_fits
    from jsrte.view.server import serve

    if not 0 <= port <= 65535:
        raise JsrteError(f"--port must be in 0..65535, got {port}")
    collection = find_fits(path)
    serve(collection, host=host, port=port, say=lambda line: print(line, flush=True),
          warn=lambda line: print(f"jsrte: warning: {line}", file=sys.stderr, flush=True))
    typer.echo("jsrte view: stopped")
