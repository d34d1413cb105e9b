"""``jsrte version``."""

from __future__ import annotations

import typer

import jsrte
from jsrte.cli import app


@app.command("version")
def version() -> None:
    """Print the jsrte version."""
    typer.echo(jsrte.__version__)
