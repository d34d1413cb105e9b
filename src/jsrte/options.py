"""The options of one fit, in one object shared by ``jsrte fit``, ``prepare``, ``fit-many`` and
``jsrte.fit()``: every option works wherever a fit runs, and is checked in one place.

Only the standard library is imported here: fit-many's workers unpickle these options before
they limit their threads and start PyTorch.
"""

from __future__ import annotations

import math
import numbers
from collections.abc import Iterable
from dataclasses import asdict, dataclass, fields, replace
from typing import TYPE_CHECKING

from jsrte.errors import JsrteError
from jsrte.presets import DECODER_DTYPES, DEFAULT_PRESET, PRESETS

if TYPE_CHECKING:
    from jsrte.presets import Preset

Vector = tuple[float, float, float]


@dataclass(frozen=True)
class FitOptions:
    """How to fit a query (what to fit it with, the model, is given beside it).

    Attributes
    ----------
    preset : fit settings by name (``jsrte.presets.PRESETS``)
    up : the rotation axis if known (any length; made unit); default: the floor normal of a scan,
        +y for a mesh
    viewpoints : sensor positions in the scan's frame (scan units); default: the cameras of the
        scan's JSON sidecar, if any
    line_of_sight : free-space samples on the lines of sight from the viewpoints: True adds them,
        False leaves them out, None follows the preset
    free_axis : let the rotation axis move away from ``up`` (default: held, the paper's known-axis mode)
    at : in a scan of several objects, fit the one nearest this point (scan units)
    hypotheses : number of θ starts (None: the preset's grid, every 30°)
    seed : seeds every random choice (the same seed gives the same fit)
    device : where the decoder runs ("cpu", "cuda", "cuda:1"; None: where the model is)
    units_check : refuse a scan whose object is implausibly large or small for metres
    dtype : the decoder's arithmetic while the hypotheses move ("auto", "float32", "bfloat16";
        None: the preset's, ``FitSettings.decoder_dtype``)
    float32_retry : fit a bfloat16 fit flagged doubtful again in float32 and keep the one with
        more inliers (None: the preset's, ``FitSettings.float32_retry``; a whole scene's default
        is False)
    floor_contact : hold the fitted shape to the floor under the object with this weight
        (``FitSettings.floor_contact``, whatever the class; None: the preset's): a table seen by
        its top alone otherwise ends with its legs in the air. Adam's fits only (not ``fast-gn``)
    """

    preset: str = DEFAULT_PRESET
    up: Vector | None = None
    viewpoints: tuple[Vector, ...] | None = None
    line_of_sight: bool | None = None
    free_axis: bool = False
    at: Vector | None = None
    hypotheses: int | None = None
    seed: int = 0
    device: str | None = None
    units_check: bool = True
    dtype: str | None = None
    float32_retry: bool | None = None
    floor_contact: float | None = None

    def __post_init__(self) -> None:
        """Check every option once: vectors (any sequence or array) become finite float tuples,
        the number of starts a positive int, the device a string, the preset a known one."""
        for name in ("up", "at"):
            value = getattr(self, name)
            if value is not None:
                object.__setattr__(self, name, _vector(value, name))
        if self.up is not None and not any(self.up):
            raise JsrteError(f"up must be a non-zero vector X,Y,Z, got {self.up}")
        if self.viewpoints is not None:
            points = tuple(_vector(p, "viewpoints") for p in _rows(self.viewpoints))
            object.__setattr__(self, "viewpoints", points or None)
        if self.hypotheses is not None:
            if not (isinstance(self.hypotheses, numbers.Integral) and self.hypotheses >= 1):
                raise JsrteError(f"hypotheses must be a positive whole number, got {self.hypotheses}")
            object.__setattr__(self, "hypotheses", int(self.hypotheses))  # a NumPy integer too
        if self.device is not None:
            object.__setattr__(self, "device", str(self.device))  # a torch.device is welcome too
        if self.preset not in PRESETS:
            raise JsrteError(f"unknown preset {self.preset!r}; known: {', '.join(PRESETS)}")
        if why := floor_contact_error(self.floor_contact, self.preset):
            raise JsrteError(f"floor_contact {why}")
        if self.dtype is not None and self.dtype not in DECODER_DTYPES:
            raise JsrteError(f"unknown dtype {self.dtype!r}; known: {', '.join(DECODER_DTYPES)}")

    def settings(self) -> Preset:
        """The preset with these options applied (line of sight, free axis, dtype, float32 retry,
        floor contact)."""
        from jsrte.presets import get_preset, with_line_of_sight

        preset = get_preset(self.preset)
        preset = replace(preset, scan_sdf=with_line_of_sight(preset.scan_sdf, self.line_of_sight))
        if self.free_axis:
            preset = replace(preset, fit=replace(preset.fit, hold_axis=False))
        if self.dtype is not None:
            preset = replace(preset, fit=replace(preset.fit, decoder_dtype=self.dtype))
        if self.float32_retry is not None:
            preset = replace(preset, fit=replace(preset.fit, float32_retry=bool(self.float32_retry)))
        if self.floor_contact is not None:
            preset = replace(preset, fit=replace(preset.fit, floor_contact=float(self.floor_contact),
                                                 floor_contact_classes=None))
        return preset

    def record(self) -> dict[str, object]:
        """The options as fit.json records them (JSON types: tuples become lists)."""
        import json

        return json.loads(json.dumps(asdict(self)))

    def changed(self, **changes: object) -> FitOptions:
        """A copy with ``changes`` (option names as keywords); a one-line error for an unknown name."""
        unknown = sorted(set(changes) - {f.name for f in fields(self)})
        if unknown:
            raise JsrteError(f"unknown fit option {', '.join(unknown)}; known: "
                             f"{', '.join(f.name for f in fields(self))}")
        return replace(self, **changes)


def floor_contact_error(weight: object, preset: str) -> str | None:
    """Why ``weight`` cannot be the floor-contact weight of a fit by the known ``preset`` (None:
    it can, or it is None, the preset's own)."""
    if weight is None:
        return None
    if not (isinstance(weight, numbers.Real) and math.isfinite(weight) and weight >= 0):
        return f"must be a finite number 0 or more, got {weight!r}"
    solver = PRESETS[preset].fit.solver
    if weight and solver != "adam":
        return f"holds Adam's fits only; preset {preset} fits by {solver}"
    return None


def _rows(value: object) -> Iterable[object]:
    """The rows of a (k, 3) array or a sequence of points."""
    return value.tolist() if hasattr(value, "tolist") else value  # type: ignore[union-attr,return-value]


def _vector(value: object, name: str) -> Vector:
    """(3,) finite floats from any sequence or array, or a one-line error naming the option."""
    try:
        items = value.tolist() if hasattr(value, "tolist") else list(value)  # type: ignore[union-attr,call-overload]
        vector = tuple(float(x) for x in items)
    except (TypeError, ValueError):
        vector = ()
    if len(vector) != 3 or not all(math.isfinite(x) for x in vector):
        raise JsrteError(f"{name} must be three finite numbers X,Y,Z, got {value!r}")
    return vector  # type: ignore[return-value]
