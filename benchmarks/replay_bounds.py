"""The command line that the benches replaying a bound on ``jsrte experiment scenes`` rows share:
``OBJECTS.csv [OBJECTS.csv ...] [--bounds B,B,...]``."""

from __future__ import annotations

import argparse
from pathlib import Path


def rows_and_bounds(doc: str, default_bounds: tuple[float, ...]) -> tuple[list[Path], list[float]]:
    """The objects.csv paths and the bounds to replay, from the command line of a bench whose
    module docstring is ``doc``."""
    parser = argparse.ArgumentParser(description=doc.splitlines()[0])
    parser.add_argument("objects", nargs="+", type=Path, help="objects.csv of a scenes experiment")
    parser.add_argument("--bounds", default=",".join(map(str, default_bounds)),
                        help="comma-separated coverage bounds to replay")
    args = parser.parse_args()
    return args.objects, [float(b) for b in args.bounds.split(",")]
