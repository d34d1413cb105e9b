"""The fit options of the command line, declared once: ``jsrte fit``, ``prepare`` and ``fit-many``
take the same flags (each a typer default below) and turn them into one
:class:`jsrte.options.FitOptions` with :func:`fit_options`."""

from __future__ import annotations

from typing import TYPE_CHECKING

import typer

from jsrte.errors import JsrteError
from jsrte.options import FitOptions, floor_contact_error
from jsrte.presets import CLASS_PRESET, DECODER_DTYPES, DEFAULT_PRESET, PRESETS, SCENE_PRESET

if TYPE_CHECKING:  # numpy is imported by the functions that run, never for --help
    import numpy as np

MODEL = typer.Option("chair", help="Shipped model name or model file; several separated by commas (chair,table), "
                                   "or auto (every shipped model): the class whose quick fit explains the object "
                                   "best is fitted.")
QUERY_PRESET = typer.Option(DEFAULT_PRESET, help=f"Fit settings: {', '.join(PRESETS)} (docs/presets.md).")
PRESET = typer.Option(None, help=f"Fit settings: {', '.join(PRESETS)} (docs/presets.md). "
                                 f"Default: {DEFAULT_PRESET}; {CLASS_PRESET} where the class is unknown.")
SCENE_OR_FIT_PRESET = typer.Option(None, help=f"Fit settings: {', '.join(PRESETS)} (docs/presets.md). "
                                              f"Default: {DEFAULT_PRESET}; {CLASS_PRESET} where the class is "
                                              f"unknown (--model auto or a list); {SCENE_PRESET} with --scene.")
UP = typer.Option(None, help="Known up axis X,Y,Z (default: the floor normal; +y for meshes).")
VIEWPOINT = typer.Option(
    None, help="Sensor position X,Y,Z in the scan's frame (metres), repeatable; 0,0,0 for a depth frame in "
               "camera coordinates. Default: the cameras of the scan's JSON sidecar, if any.")
LINE_OF_SIGHT = typer.Option(
    None, "--line-of-sight/--no-line-of-sight",
    help="Free-space samples on the lines of sight from the viewpoints (beyond the paper; default: the "
         "preset's, on in fast, off in paper; docs/presets.md).")
FREE_AXIS = typer.Option(False, "--free-axis", help="Let the rotation axis move away from the up axis (default: "
                                                    "held at the floor normal / --up, the paper's known-axis mode).")
AT = typer.Option(None, "--at", help="In a scan of several objects, fit the one nearest X,Y,Z (scan frame, "
                                     "metres); default: the one most like the model's class.")
DTYPE = typer.Option(None, help="The decoder's arithmetic while the fit moves: auto (bfloat16 where the CPU or "
                                 "GPU has it natively, about twice as fast), float32 or bfloat16. Default: the "
                                 "preset's (auto; float32 in paper).")
FLOAT32_RETRY = typer.Option(
    None, "--float32-retry/--no-float32-retry",
    help="Fit a bfloat16 fit flagged doubtful again in float32 and keep the one with more inliers (default: the "
         "preset's: on in every preset but paper and smoke; off with --scene; docs/presets.md).")
FLOOR_CONTACT = typer.Option(
    None, "--floor-contact",
    help="Hold the fitted shape to the floor under the object with this weight, whatever its class: a table "
         "seen by its top alone otherwise ends with its legs in the air (default: the preset's; 0.3 for tables "
         "in fast-scales-floor; Adam presets only, not fast-gn; docs/presets.md).")
LEFTOVERS = typer.Option(
    False, "--leftovers/--no-leftovers",
    help="Whole scenes (fit --scene): also fit, as objects of their own, the points the found objects' fits "
         "leave unexplained (a chair segmented with the bed it touches; docs/clutter.md). Slower.")
HYPOTHESES = typer.Option(None, help="Number of θ starts (default: every 30°, 12).")
SEED = typer.Option(0, help="Random seed.")
DEVICE = typer.Option("cpu", help="Torch device: cpu, cuda or cuda:N (where PyTorch sees a GPU).")
UNITS_CHECK = typer.Option(
    True, "--units-check/--no-units-check",
    help="Refuse a scan whose object is implausibly large or small for metres (over 10 m or under 2 cm across: "
         "millimetres?); --no-units-check fits it anyway.")


def fit_options(*, preset: str = DEFAULT_PRESET, up: str | None = None, viewpoint: list[str] | None = None,
                line_of_sight: bool | None = None, free_axis: bool = False, at: str | None = None,
                hypotheses: int | None = None, seed: int = 0, device: str = "cpu",
                units_check: bool = True, dtype: str | None = None, float32_retry: bool | None = None,
                floor_contact: float | None = None) -> FitOptions:
    """The flags' values (as typed) as checked :class:`FitOptions`; a one-line error naming the
    flag for a bad value."""
    from jsrte.cli.common import resolve_device

    check_preset(preset)
    check_dtype(dtype)
    if hypotheses is not None and hypotheses < 1:
        raise JsrteError(f"--hypotheses must be positive, got {hypotheses}")
    if why := floor_contact_error(floor_contact, preset):
        raise JsrteError(f"--floor-contact {why}")
    points = parse_points(viewpoint)
    return FitOptions(preset=preset, up=parse_vector(up), viewpoints=None if points is None else points,
                      line_of_sight=line_of_sight, free_axis=free_axis,
                      at=None if at is None else three_numbers(at, "--at"), hypotheses=hypotheses, seed=seed,
                      device=str(resolve_device(device)), units_check=units_check, dtype=dtype,
                      float32_retry=float32_retry, floor_contact=floor_contact)


def check_preset(preset: str) -> str:
    """``preset`` if it names a preset, else a one-line error listing the known ones."""
    if preset not in PRESETS:
        raise JsrteError(f"unknown preset {preset!r}; known: {', '.join(PRESETS)}")
    return preset


def parse_vector(text: str | None, name: str = "--up") -> np.ndarray | None:
    """'X,Y,Z' -> unit (3,) vector; None stays None."""
    import numpy as np

    if text is None:
        return None
    v = three_numbers(text, name)
    if np.linalg.norm(v) == 0:
        raise JsrteError(f"{name} must be a non-zero vector X,Y,Z, got {text!r}")
    return v / np.linalg.norm(v)


def parse_points(texts: list[str] | None, name: str = "--viewpoint") -> np.ndarray | None:
    """['X,Y,Z', ...] -> (k, 3) positions (scan units); None or empty stays None."""
    import numpy as np

    return np.stack([three_numbers(text, name) for text in texts]) if texts else None


def three_numbers(text: str, name: str) -> np.ndarray:
    """'X,Y,Z' -> (3,) finite floats, or a one-line error naming the option."""
    import numpy as np

    try:
        v = np.array([float(x) for x in text.split(",")])
    except ValueError:
        v = np.array([])
    if v.shape != (3,) or not np.all(np.isfinite(v)):
        raise JsrteError(f"{name} must be three finite numbers X,Y,Z, got {text!r}")
    return v


def check_dtype(dtype: str | None) -> None:
    """A one-line error for a ``--dtype`` that is none of ``DECODER_DTYPES`` (None: the preset's)."""
    if dtype is not None and dtype not in DECODER_DTYPES:
        raise JsrteError(f"--dtype must be one of {', '.join(DECODER_DTYPES)}, got {dtype!r}")
