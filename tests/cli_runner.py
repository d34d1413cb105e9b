"""Run the ``jsrte`` command line in the test's own process."""

import sys


def run_cli(monkeypatch, capsys, *args) -> tuple[int, str, str]:
    """``jsrte ARGS`` (each turned into a string): (exit status, stdout, stderr)."""
    from jsrte.cli import main

    monkeypatch.setattr(sys, "argv", ["jsrte", *[str(a) for a in args]])
    try:
        main()
        code = 0
    except SystemExit as exc:
        code = int(exc.code or 0)
    captured = capsys.readouterr()
    return code, captured.out, captured.err
