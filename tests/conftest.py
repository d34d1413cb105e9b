"""Fixtures shared by several test modules."""

import pytest

from cli_runner import run_cli as _run_cli


@pytest.fixture
def run_cli(monkeypatch, capsys):
    """Run ``jsrte ARGS`` in this process: (exit status, stdout, stderr)."""

    def run(args: list[str]) -> tuple[int, str, str]:
        return _run_cli(monkeypatch, capsys, *args)

    return run


@pytest.fixture
def short_fits(monkeypatch):
    """Shorten fits to 3 iterations of each stage and 16³ meshes, and record one setting of each:
    ``short_fits("init_scale")`` returns the list each full fit's ``FitSettings.init_scale`` is
    appended to; ``quick=True`` shortens and records the screen's quick fits too."""
    import importlib
    from dataclasses import replace

    def short(settings):  # noqa: ANN001, ANN202
        return replace(settings, iterations=3, extract_resolution=16,
                       adam_stage_iterations=min(3, settings.adam_stage_iterations),
                       polish_iterations=min(3, settings.polish_iterations),
                       refine_iterations=min(3, settings.refine_iterations))

    def spy(setting: str, *, quick: bool = False) -> list:
        fitting, solve = importlib.import_module("jsrte.fit"), importlib.import_module("jsrte.fit.solve")
        seen, original = [], solve.fit_query

        def short_fit(model, query, settings, **kw):
            seen.append(getattr(settings, setting))
            return original(model, query, short(settings), **kw)

        monkeypatch.setattr(fitting, "fit_with_retry", short_fit)  # the full fits (never fitted again)
        if quick:
            monkeypatch.setattr(solve, "fit_query", short_fit)  # the screen's quick fits
        return seen

    return spy
