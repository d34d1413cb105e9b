"""The ``jsrte`` command: one Typer app; each subcommand lives in its own module here.

Every subcommand is a thin call into the library. A ``JsrteError`` becomes one line on
stderr and exit status 2.
"""

from __future__ import annotations

import sys

import typer

from jsrte.errors import JsrteError

app = typer.Typer(
    name="jsrte",
    help="Find the shape (DeepSDF latent code) and similarity transform that explain a 3D scan.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
    rich_markup_mode=None,  # plain help: option text wraps to the terminal's full width
)



@app.callback()
def _root() -> None:
    """Find the shape (DeepSDF latent code) and similarity transform that explain a 3D scan."""


def _register() -> None:
    """Import every ``jsrte.cli.*_cmd`` module; importing one registers its commands on ``app``."""
    import importlib
    import pkgutil

    import jsrte.cli as package

    for info in sorted(pkgutil.iter_modules(package.__path__), key=lambda m: m.name):
        if info.name.endswith("_cmd"):
            importlib.import_module(f"jsrte.cli.{info.name}")


def main() -> None:
    """Console-script entry point."""
    _register()
    try:
        app()
    except JsrteError as exc:
        print(f"jsrte: error: {exc}", file=sys.stderr)
        sys.exit(2)
