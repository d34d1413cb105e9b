"""The one error type users see: a one-line message naming the file and what is wrong."""

from __future__ import annotations

from pathlib import Path


class JsrteError(Exception):
    """A user-facing error; the CLI prints ``str(error)`` on one line and exits non-zero."""

    def __init__(self, message: str, path: str | Path | None = None) -> None:
        text = f"{path}: {message}" if path is not None else message
        super().__init__(text.replace("\n", " "))
