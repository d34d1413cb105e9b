"""jsrte: joint 3D shape retrieval and similarity-transform estimation (DeepSDF-based).

Conventions (docs/conventions.md):
- canonical frame of ShapeNetCore v2: +y up, front towards -z, DeepSDF unit-sphere normalization;
- SDF negative inside, positive outside;
- a similarity ``scan_from_canonical`` maps canonical x to ``s * R @ x + t`` (scan units, metres),
  and ``sdf_scan(g(x)) = s * sdf_canonical(x)``.

``jsrte.fit(...)`` is the fit function (the README's Python API), also after the subpackage
``jsrte.fit`` has been imported (``from jsrte.fit import fit_query`` and the like still work).
"""

from __future__ import annotations

import sys
import types
from pathlib import Path
from typing import TYPE_CHECKING

from jsrte.errors import JsrteError

if TYPE_CHECKING:
    from jsrte.fit.query import SdfQuery
    from jsrte.model.checkpoint import DeepSdfModel
    from jsrte.options import FitOptions
    from jsrte.result import FitResult

__version__ = "0.1.0"


def fit(query: str | Path | SdfQuery, *, model: str | Path | DeepSdfModel | list = "chair",
        options: FitOptions | None = None, progress: bool = False, **changes: object) -> FitResult:
    """Find the shape and the similarity transform that explain ``query`` (a scan file, a mesh,
    SDF samples, a query file, or an ``SdfQuery``) with ``model`` (a shipped name, a file, a
    loaded model; or several, or "auto": the class is chosen by quick fits). Returns a
    ``FitResult`` (``.transform``, ``.latent``, ``.mesh``, ``.to_json()``).

    Fit options (``jsrte.options.FitOptions``: preset, up, viewpoints, line_of_sight, free_axis,
    at, hypotheses, seed, device, units_check) come as ``options``, or by name:
    ``jsrte.fit("scan.ply", model="chair", up=(0, 0, 1))``. The same function as
    ``from jsrte.fit import fit`` (imported on first call, to keep ``import jsrte`` light).
    """
    from jsrte.fit import fit as _fit

    return _fit(query, model=model, options=options, progress=progress, **changes)


class _Package(types.ModuleType):
    """The ``jsrte`` module: importing the subpackage ``jsrte.fit`` leaves ``jsrte.fit`` the function
    (the import system would otherwise bind the name to the subpackage)."""

    def __setattr__(self, name: str, value: object) -> None:
        if name == "fit" and isinstance(value, types.ModuleType):
            return
        super().__setattr__(name, value)


sys.modules[__name__].__class__ = _Package

__all__ = ["JsrteError", "__version__", "fit"]
