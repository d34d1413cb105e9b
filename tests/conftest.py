"""Fixtures shared by several test modules."""

import pytest


@pytest.fixture
def run_cli(monkeypatch, capsys):
    """Run ``jsrte ARGS`` in this process: (exit status, stdout, stderr)."""
    import sys

    from jsrte.cli import main

    def run(args: list[str]) -> tuple[int, str, str]:
        monkeypatch.setattr(sys, "argv", ["jsrte", *args])
        try:
            main()
            code = 0
        except SystemExit as exc:
            code = int(exc.code or 0)
        captured = capsys.readouterr()
        return code, captured.out, captured.err

    return run
