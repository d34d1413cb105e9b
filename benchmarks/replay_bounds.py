"""The command line that the benches replaying a bound on ``jsrte experiment scenes`` rows share:
``OBJECTS.csv [OBJECTS.csv ...] [--bounds B,B,...]``, and for some a switch to another bound."""

from __future__ import annotations

import argparse
from pathlib import Path


def rows_and_bounds(doc: str, default_bounds: tuple[float, ...],
                    alternative: tuple[str, tuple[float, ...], str] | None = None
                    ) -> tuple[list[Path], list[float], bool]:
    """The objects.csv paths, the bounds to replay and whether ``alternative``'s switch was given,
    from the command line of a bench whose module docstring is ``doc``. ``alternative``: a switch,
    its default bounds (in place of ``default_bounds`` when it is given) and its help."""
    parser = argparse.ArgumentParser(description=doc.splitlines()[0])
    parser.add_argument("objects", nargs="+", type=Path, help="objects.csv of a scenes experiment")
    parser.add_argument("--bounds", help="comma-separated bounds to replay (default: "
                        f"{','.join(map(str, default_bounds))})")
    if alternative is not None:
        parser.add_argument(alternative[0], action="store_true", help=alternative[2])
    args = parser.parse_args()
    switched = alternative is not None and getattr(args, alternative[0].lstrip("-").replace("-", "_"))
    defaults = alternative[1] if switched else default_bounds
    bounds = [float(b) for b in args.bounds.split(",")] if args.bounds else list(defaults)
    return args.objects, bounds, bool(switched)
