"""Fixtures shared by several test modules."""

import pytest

from cli_runner import run_cli as _run_cli


@pytest.fixture(autouse=True)
def ieee_denormals():
    """Every test starts and ends with denormal floats computed, as IEEE 754 says: a command run
    in this process flushes them for the rest of its process (``jsrte.model.decoder``)."""
    import torch

    torch.set_flush_denormal(False)
    yield
    torch.set_flush_denormal(False)


@pytest.fixture
def run_cli(monkeypatch, capsys):
    """Run ``jsrte ARGS`` in this process: (exit status, stdout, stderr)."""

    def run(args: list[str]) -> tuple[int, str, str]:
        return _run_cli(monkeypatch, capsys, *args)

    return run


@pytest.fixture
def short_fits(monkeypatch):
    """Shorten fits to 3 iterations of each stage, a few hundred samples and 16³ meshes, and record
    one setting of each: ``short_fits("init_scale")`` returns the list each full fit's
    ``FitSettings.init_scale`` is appended to. The screen's quick fits are shortened too, and
    recorded with ``quick=True``."""
    import importlib
    from dataclasses import replace

    def short(settings):  # noqa: ANN001, ANN202
        return replace(settings, iterations=3, extract_resolution=16,
                       adam_stage_iterations=min(3, settings.adam_stage_iterations),
                       polish_iterations=min(3, settings.polish_iterations),
                       refine_iterations=min(3, settings.refine_iterations),
                       samples_per_iteration=min(500, settings.samples_per_iteration),
                       eval_samples=min(2000, settings.eval_samples),
                       selection_resolution=min(24, settings.selection_resolution),
                       fscore_points=min(500, settings.fscore_points),
                       yaw_screen_samples=min(100, settings.yaw_screen_samples),
                       polish_samples=min(300, settings.polish_samples),
                       adam_stage_samples=min(300, settings.adam_stage_samples),
                       judge_samples=min(500, settings.judge_samples))

    def spy(setting: str, *, quick: bool = False) -> list:
        fitting, solve = importlib.import_module("jsrte.fit"), importlib.import_module("jsrte.fit.solve")
        seen, original = [], solve.fit_query

        def shortened(record: bool):  # noqa: ANN202
            def short_fit(model, query, settings, **kw):  # noqa: ANN001, ANN202
                if record:
                    seen.append(getattr(settings, setting))
                return original(model, query, short(settings), **kw)
            return short_fit

        monkeypatch.setattr(fitting, "fit_with_retry", shortened(True))  # the full fits (never fitted again)
        monkeypatch.setattr(solve, "fit_query", shortened(quick))  # the screen's quick fits
        return seen

    return spy
