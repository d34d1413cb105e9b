"""Atomic file writing: a crash never leaves a half-written file that looks whole; and reading
back, typed, the CSV tables written here."""

from __future__ import annotations

import json
import os
import shutil
import tempfile
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from jsrte.errors import JsrteError


@contextmanager
def atomic_path(path: str | Path) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; rename it onto ``path`` only on success.

    The temporary name keeps the suffix of ``path`` so writers that pick a format by
    extension (trimesh, numpy, matplotlib) behave as for the final name.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.stem}.", suffix=f".tmp{path.suffix}", dir=path.parent)
    os.close(fd)
    tmp_path = Path(tmp)
    try:
        yield tmp_path
        # mkstemp makes 0600 (and some writers recreate the file so): follow the umask instead
        os.chmod(tmp_path, 0o666 & ~_umask())
        os.replace(tmp_path, path)
    finally:
        if tmp_path.exists():
            tmp_path.unlink()


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def write_bytes_atomic(path: str | Path, data: bytes) -> None:
    """Write ``data`` to ``path`` atomically."""
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)


def write_json_atomic(path: str | Path, obj: Any) -> None:
    """Write ``obj`` as indented JSON to ``path`` atomically."""
    write_bytes_atomic(path, (json.dumps(obj, indent=2, default=_json_default) + "\n").encode())


def write_with(path: str | Path, writer: Callable[[Path], None]) -> None:
    """Call ``writer(tmp_path)`` and move the result onto ``path`` atomically."""
    with atomic_path(path) as tmp:
        writer(tmp)


def write_csv_atomic(path: str | Path, rows: list[dict]) -> None:
    """Write ``rows`` (dicts) as a CSV file with a header, atomically; the columns are every
    key of the rows, in first-seen order."""
    import csv

    keys = list(dict.fromkeys(k for row in rows for k in row))

    def write(tmp: Path) -> None:
        with open(tmp, "w", newline="") as f:
            writer = csv.DictWriter(f, fieldnames=keys)
            writer.writeheader()
            writer.writerows(rows)

    write_with(path, write)


def read_csv_rows(path: str | Path) -> list[dict]:
    """The rows of a CSV file written by :func:`write_csv_atomic`, each cell typed back by
    :func:`csv_cell`; an unreadable file is a JsrteError naming it."""
    import csv

    try:
        with open(path, newline="") as f:
            return [{k: csv_cell(v) for k, v in row.items()} for row in csv.DictReader(f)]
    except (OSError, UnicodeDecodeError, csv.Error) as error:
        raise JsrteError(f"unreadable table ({error})", path) from error


def csv_cell(text: str | None) -> object:
    """A CSV cell back as written: None (empty or missing), bool, int, float or text."""
    if text is None or text == "":
        return None
    if text in ("True", "False"):
        return text == "True"
    for kind in (int, float):
        try:
            return kind(text)
        except ValueError:
            pass
    return text


def _json_default(obj: Any) -> Any:
    import numpy as np

    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, Path):
        return str(obj)
    raise TypeError(f"not JSON serializable: {type(obj).__name__}")


@contextmanager
def output_dir(path: str | Path, *, overwrite: bool = False, marker: str | None = None,
               keep: Callable[[Path], bool] | None = None) -> Iterator[Path]:
    """Prepare an output folder and remove it again if the work inside fails.

    Refuses a folder that already holds ``marker`` (a previous result) unless ``overwrite``.
    A folder created here is deleted on failure, unless ``keep(folder)`` says its partial
    results are worth keeping (a resumable run); an existing one keeps what it had.
    """
    path = Path(path)
    if marker and (path / marker).exists() and not overwrite:
        raise JsrteError(f"already holds a result ({marker}); pass --overwrite to replace it", path)
    created = not path.exists()
    path.mkdir(parents=True, exist_ok=True)
    try:
        yield path
    except BaseException:
        if created and not (keep is not None and keep(path)):
            shutil.rmtree(path, ignore_errors=True)
        raise
