"""jsrte: joint 3D shape retrieval and similarity-transform estimation (DeepSDF-based).

Conventions (see docs/conventions.md):
- canonical frame of ShapeNetCore v2: +y up, front towards -z, DeepSDF unit-sphere normalization;
- SDF negative inside, positive outside;
- a similarity ``scan_from_canonical`` maps canonical x to ``s * R @ x + t`` (scan units, metres),
  and ``sdf_scan(g(x)) = s * sdf_canonical(x)``.
"""

from jsrte.errors import JsrteError

__version__ = "0.1.0"


def fit(*args, **kwargs):  # noqa: ANN002, ANN003, ANN201
    """``jsrte.fit.fit``: see its docstring (imported lazily to keep ``import jsrte`` light)."""
    from jsrte.fit import fit as _fit

    return _fit(*args, **kwargs)


__all__ = ["JsrteError", "__version__", "fit"]
