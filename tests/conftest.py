"""Fixtures shared by several test modules."""

import pytest

from cli_runner import run_cli as _run_cli


@pytest.fixture
def run_cli(monkeypatch, capsys):
    """Run ``jsrte ARGS`` in this process: (exit status, stdout, stderr)."""

    def run(args: list[str]) -> tuple[int, str, str]:
        return _run_cli(monkeypatch, capsys, *args)

    return run
