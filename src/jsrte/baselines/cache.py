"""The user cache folder of the baselines (databases, descriptors, trained classifiers).

``$JSRTE_CACHE`` when set, else ``$XDG_CACHE_HOME/jsrte``, else ``~/.cache/jsrte``. Everything
in it can be deleted at any time: it is rebuilt on demand. Files are written atomically.
"""

from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path
from typing import Any

import numpy as np

from jsrte.atomic import write_with


def cache_dir(*parts: str) -> Path:
    """The cache folder (or a sub-folder of it named by ``parts``); created on demand."""
    root = os.environ.get("JSRTE_CACHE")
    if root:
        base = Path(root)
    else:
        xdg = os.environ.get("XDG_CACHE_HOME")
        base = (Path(xdg) if xdg else Path.home() / ".cache") / "jsrte"
    folder = base.joinpath(*parts)
    folder.mkdir(parents=True, exist_ok=True)
    return folder


def digest(obj: Any) -> str:
    """A short stable hash (16 hex digits) of a JSON-able object."""
    text = json.dumps(obj, sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def save_arrays(path: Path, arrays: dict[str, np.ndarray]) -> None:
    """Write ``arrays`` as an uncompressed ``.npz`` atomically."""
    write_with(path, lambda tmp: np.savez(tmp, **arrays))


def load_arrays(path: Path) -> dict[str, np.ndarray] | None:
    """Read an ``.npz`` written by :func:`save_arrays`; None if absent or unreadable."""
    if not path.is_file():
        return None
    try:
        with np.load(path, allow_pickle=False) as data:
            return {k: data[k] for k in data.files}
    except (OSError, ValueError, EOFError):
        return None
