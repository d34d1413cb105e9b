"""Helpers shared by the CLI modules."""

from __future__ import annotations

import torch


def set_threads(threads: int | None) -> None:
    """Use ``threads`` CPU threads for PyTorch (None: all cores)."""
    import os

    torch.set_num_threads(threads or os.cpu_count() or 1)
