"""Helpers shared by the CLI modules."""

from __future__ import annotations

from typing import TYPE_CHECKING

if TYPE_CHECKING:  # torch is imported by the commands that run, never for --help
    import torch


def set_threads(threads: int | None) -> None:
    """Use ``threads`` CPU threads for PyTorch (None: all cores)."""
    import os

    import torch

    torch.set_num_threads(threads or os.cpu_count() or 1)


def resolve_device(name: str) -> torch.device:
    """The torch device called ``name`` ("cpu", "cuda", "cuda:1", ...); JsrteError if this machine lacks it."""
    import torch

    from jsrte.errors import JsrteError

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
