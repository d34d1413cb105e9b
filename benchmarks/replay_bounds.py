"""The command line that the benches replaying a bound on ``jsrte experiment scenes`` rows share:
``OBJECTS.csv [OBJECTS.csv ...] [--bounds B,B,...]``, and for some a switch to another bound."""

from __future__ import annotations

import argparse
import csv
from pathlib import Path

Alternative = tuple[str, tuple[float, ...], str]
"""A switch to another bound: the switch (``--seen-through``), its default bounds and its help."""


def rows_and_bounds(doc: str, default_bounds: tuple[float, ...],
                    alternatives: tuple[Alternative, ...] = ()) -> tuple[list[Path], list[float], str | None]:
    """The objects.csv paths, the bounds to replay and which of ``alternatives``' switches was
    given (None: none), from the command line of a bench whose module docstring is ``doc``. A
    switch's default bounds stand in for ``default_bounds`` when it is given; at most one may be."""
    parser = argparse.ArgumentParser(description=doc.splitlines()[0])
    parser.add_argument("objects", nargs="+", type=Path, help="objects.csv of a scenes experiment")
    parser.add_argument("--bounds", help="comma-separated bounds to replay (default: "
                        f"{','.join(map(str, default_bounds))})")
    switches = parser.add_mutually_exclusive_group()
    for switch, _, help_text in alternatives:
        switches.add_argument(switch, action="store_true", help=help_text)
    args = parser.parse_args()
    given = next((a for a in alternatives if getattr(args, a[0].lstrip("-").replace("-", "_"))), None)
    defaults = given[1] if given is not None else default_bounds
    bounds = [float(b) for b in args.bounds.split(",")] if args.bounds else list(defaults)
    return args.objects, bounds, None if given is None else given[0]


def read_hits(paths: list[Path], columns: dict[str, str]) -> list[dict]:
    """The found furniture (hits) of every objects.csv in ``paths``: each row's ``room``,
    ``class`` (found), ``fscore`` and whether it was flagged ``doubtful``, and each of ``columns``
    (key: CSV column) as a number (None where not recorded)."""
    hits = []
    for path in paths:
        with open(path, newline="") as f:
            for row in csv.DictReader(f):
                if row["outcome"] == "hit" and row["fscore"]:
                    hits.append({"room": row["room"], "class": row["found_class"], "fscore": float(row["fscore"]),
                                 "doubtful": row["flag"] == "doubtful"}
                                | {key: float(row[c]) if row.get(c) else None for key, c in columns.items()})
    return hits
