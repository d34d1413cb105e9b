"""Helpers shared by the CLI modules."""

from __future__ import annotations

import os
from pathlib import Path
from typing import TYPE_CHECKING

from jsrte.errors import JsrteError

if TYPE_CHECKING:  # torch is imported by the commands that run, never for --help
    import torch


def set_threads(threads: int | None) -> None:
    """Use ``threads`` CPU threads for PyTorch (None or 0: all cores), denormal floats flushed to
    zero (``jsrte.model.decoder.flush_denormals``); JsrteError if negative."""
    import torch

    from jsrte.model.decoder import flush_denormals

    check_threads(threads)
    flush_denormals()
    torch.set_num_threads(threads or os.cpu_count() or 1)


def check_threads(threads: int | None, option: str = "--threads") -> None:
    """A one-line error unless ``threads`` is None, 0 (all cores) or positive."""
    if threads is not None and threads < 0:
        raise JsrteError(f"{option} must be 0 (all cores) or a positive number, got {threads}")


def check_out_folder(out: Path, *, marker: str | None = None, overwrite: bool = False) -> Path:
    """Check, before any work, that ``out`` can be an output folder: not a file, not under a file,
    writable where it will be created, and not holding a result ``marker`` unless ``overwrite``."""
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise JsrteError("is a file, not a folder; give --out a folder", out)
    _check_creatable(out)
    if marker is not None and (out / marker).exists() and not overwrite:
        raise JsrteError(f"already holds a result ({marker}); pass --overwrite to replace it", out)
    return out


def check_out_file(out: Path, *, overwrite: bool = False, suffixes: tuple[str, ...] | None = None) -> Path:
    """Check, before any work, that ``out`` can be written as a file: not a folder, its folder not a
    file and writable, a known suffix (when ``suffixes`` are given), and absent unless ``overwrite``."""
    out = Path(out)
    if out.is_dir():
        raise JsrteError("is a folder; give --out a file name", out)
    if suffixes is not None and out.suffix.lower() not in suffixes:
        raise JsrteError(f"--out must end in {' or '.join(suffixes)}", out)
    _check_creatable(out.parent)
    if out.exists() and not overwrite:
        raise JsrteError("already exists; pass --overwrite to replace it", out)
    return out


def _check_creatable(folder: Path) -> None:
    """``folder`` exists as a writable folder, or can be made: its nearest existing ancestor is a
    writable folder (not a file)."""
    folder = Path(os.path.abspath(folder))
    existing = folder
    while not existing.exists() and existing != existing.parent:
        existing = existing.parent
    if not existing.is_dir():
        raise JsrteError(f"cannot be created: {existing} is a file, not a folder", folder)
    if not os.access(existing, os.W_OK | os.X_OK):
        raise JsrteError(f"cannot write there: {existing} is not writable", folder)


def resolve_device(name: str) -> torch.device:
    """The torch device called ``name`` ("cpu", "cuda", "cuda:1", ...); JsrteError if this machine lacks it."""
    import torch

    try:
        device = torch.device(name)
    except (RuntimeError, ValueError):
        raise JsrteError(f"unknown device {name!r} (use cpu, cuda or cuda:N)") from None
    if device.type == "cpu":
        return device
    if device.type != "cuda":
        raise JsrteError(f"device {name!r} is not supported (use cpu, cuda or cuda:N)")
    if not torch.cuda.is_available():
        raise JsrteError(f"device {name!r} asked for, but this PyTorch build sees no CUDA GPU; use --device cpu")
    if device.index is not None and device.index >= torch.cuda.device_count():
        raise JsrteError(f"device {name!r} asked for, but there are {torch.cuda.device_count()} CUDA GPUs")
    return device
