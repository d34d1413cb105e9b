"""Classes left close by the screen are decided by their final fits (jsrte.fit.classes)."""

from __future__ import annotations

import importlib
import json

import numpy as np
import pytest
import torch

from analytic import BallAndBlobDecoder, SphereDecoder
from jsrte.fit.classes import decide, final_terms, fit_contenders
from jsrte.fit.query import SdfQuery
from jsrte.fit.screen import ScreenSettings, contending
from jsrte.geometry.sim3 import Sim3
from jsrte.model.checkpoint import DeepSdfModel
from jsrte.result import FitResult

CENTRE = np.array([2.0, 0.5, -1.0])


def _sphere_points(rng: np.random.Generator, n: int, centre: np.ndarray, radius: float) -> np.ndarray:
    v = rng.normal(size=(n, 3))
    return centre + radius * v / np.linalg.norm(v, axis=1, keepdims=True)


def _fit(scale: float, code: float) -> FitResult:
    """A fit of scale ``scale`` centred at CENTRE whose code's ratio is ``code``."""
    return FitResult("jsrte", Sim3(scale, np.eye(3), CENTRE), np.zeros(2, np.float32), None, 0.0, {},
                     timing={"total": 1.0}, info={"decoder_evaluations": 100},
                     quality={"latent_mahalanobis_ratio": code})


def test_contending_classes_are_the_best_and_those_within_the_margin():
    classes = {"bed": 0.030, "chair": None, "sofa": 0.035, "table": 0.050}
    assert contending(classes, ScreenSettings(final_margin=0.01)) == ["bed", "sofa"]
    assert contending(classes, ScreenSettings(final_margin=0.004)) == ["bed"]
    assert contending(classes, ScreenSettings(final_margin=0.0)) == ["bed"]
    assert contending(classes, ScreenSettings(final_margin=0.03)) == ["bed", "sofa"]  # at most two
    assert contending(classes, ScreenSettings(final_margin=0.03, final_classes=3)) == ["bed", "sofa", "table"]
    assert contending({"bed": None, "sofa": None}, ScreenSettings()) == []


def test_the_final_score_adds_the_codes_typicality_to_the_class_score():
    settings = ScreenSettings(final_code_weight=0.02)
    screen = {"bed": 0.030, "sofa": 0.032}
    chosen, scores = decide(screen, {"bed": 1.5, "sofa": 0.6}, settings)  # the bed model stretched far
    assert chosen == "sofa" and scores == pytest.approx({"bed": 0.060, "sofa": 0.044})
    chosen, _ = decide(screen, {"bed": 0.7, "sofa": 0.7}, settings)  # alike codes: the screen decides
    assert chosen == "bed"
    chosen, _ = decide(screen, {"bed": 0.9, "sofa": 0.85}, settings)  # 0.002 of the screen outweighs 0.05
    assert chosen == "bed"


def _stub_full_fits(monkeypatch, fits: dict[str, FitResult]) -> list[tuple[str, SdfQuery]]:
    """Make every full fit return ``fits[model name]``; the list of (model name, query) fitted."""
    fitted = []

    def fit_recorded(model, query, options, *, class_choice=None, progress=False):
        fitted.append((model.meta["name"], query))
        return fits[model.meta["name"]]

    monkeypatch.setattr(importlib.import_module("jsrte.fit"), "fit_recorded", fit_recorded)
    return fitted


def _ball_and_blob() -> tuple[SdfQuery, dict[str, DeepSdfModel]]:
    rng = np.random.default_rng(0)
    points = np.concatenate([_sphere_points(rng, 700, CENTRE, 1.0),
                             _sphere_points(rng, 300, CENTRE + [1.5, 0.0, 0.0], 0.5)])
    models = {"ball": DeepSdfModel(SphereDecoder(), torch.zeros(1, 2), {"name": "ball"}),
              "pair": DeepSdfModel(BallAndBlobDecoder(), torch.zeros(1, 2), {"name": "pair"})}
    return SdfQuery(points, np.zeros(len(points)), points), models


def test_final_terms_measure_each_fit_on_the_same_points():
    query, models = _ball_and_blob()
    settings = ScreenSettings()
    pair = final_terms(models["pair"], _fit(2.0, 0.5), {"pair": query, "ball": query}, settings)
    assert pair["residual"] < 1e-6 and pair["unexplained"] == 0.0 and pair["code"] == 0.5
    ball = final_terms(models["ball"], _fit(2.0, 0.5), {"ball": query}, settings)
    assert ball["residual"] > 0.02 and 0.25 < ball["unexplained"] <= 0.3  # the blob, less where it touches


@pytest.mark.parametrize("ball_code", [0.6, 1.6])
def test_the_runner_up_is_fitted_only_where_the_best_fit_needs_an_atypical_code(monkeypatch, ball_code):
    """The screen ranks "ball" 0.002 ahead of "pair": the screen alone takes "ball". Its full fit
    comes first; with a typical code (0.6) it stands and nothing else is fitted. With an atypical
    one (1.6, above ``final_code_max``) "pair" is fitted too, and its typical code (0.5) makes it
    the class: fit.json's ``class`` records what was compared."""
    query, models = _ball_and_blob()
    fits = {"ball": _fit(2.0, ball_code), "pair": _fit(2.0, 0.5)}
    fitted = _stub_full_fits(monkeypatch, fits)
    screen_record = {"chosen": "ball", "chosen_by": "fit", "scores": {"ball": 0.030, "pair": 0.032},
                     "margin": 0.002, "refitted": []}
    settings = ScreenSettings(final_code_max=0.9, final_code_weight=0.02)
    options = type("Options", (), {"seed": 0})()
    result = fit_contenders({"ball": query, "pair": query}, models, options, screen_record, settings=settings)
    record = json.loads(json.dumps(result.to_json()))["class"]
    assert record["scores"] == screen_record["scores"]  # the screen's record is kept
    final = record["final"]
    if ball_code < 0.9:
        assert [n for n, _ in fitted] == ["ball"] and result is fits["ball"]
        assert record["chosen"] == "ball" and record["chosen_by"] == "fit"
        assert final["compared"] == ["ball"] and final["margin"] is None
        return
    assert [n for n, _ in fitted] == ["ball", "pair"] and result is fits["pair"]
    assert record["chosen"] == "pair" and record["chosen_by"] == "final fit"
    assert final["compared"] == ["ball", "pair"]
    assert final["scores"] == pytest.approx({"ball": 0.030 + 0.02 * 1.6, "pair": 0.032 + 0.02 * 0.5})
    assert final["margin"] == pytest.approx(0.02 * 1.1 - 0.002, abs=1e-5)
    assert final["terms"]["ball"]["unexplained"] > 0.25 and final["terms"]["pair"]["residual"] < 1e-5
    assert final["decoder_evaluations"] == {"ball": 100, "pair": 100}


@pytest.mark.parametrize(("ball_scale", "above"), [(1.0, 1.1), (0.72, 1.1), (1.3, None), (1.3, 1.1), (2.0, None)])
def test_a_fit_outside_its_class_sizes_calls_the_runner_up_and_loses_to_a_fit_within(monkeypatch, ball_scale,
                                                                                     above):
    """"ball" leads the screen and its full fit needs a typical code; where that fit's radius
    lies outside the ball model's sizes (0.9-1.1 m, widened by 1.3 below and by ``above`` above:
    0.69-1.21 m, or 0.69-1.43 m with 1.3 both ways) "pair" is fitted too and wins, though its
    final score is higher: a size none of its class's is no evidence for the class."""
    query, models = _ball_and_blob()
    models["ball"].meta["sizes_m"] = {"smallest": 0.9, "median": 1.0, "largest": 1.1, "shapes": 10}
    fits = {"ball": _fit(ball_scale, 0.6), "pair": _fit(1.0, 0.8)}
    fitted = _stub_full_fits(monkeypatch, fits)
    screen_record = {"chosen": "ball", "chosen_by": "fit", "scores": {"ball": 0.030, "pair": 0.032},
                     "margin": 0.002, "refitted": []}
    settings = ScreenSettings(final_code_max=0.9, final_code_weight=0.02, final_size_margin=1.3,
                              final_size_margin_above=above)
    options = type("Options", (), {"seed": 0})()
    result = fit_contenders({"ball": query, "pair": query}, models, options, screen_record, settings=settings)
    final = result.info["class"]["final"]
    assert final["size_margin"] == 1.3 and final["size_margin_above"] == above
    if ball_scale < 1.1 or (ball_scale == 1.3 and above is None):
        assert [n for n, _ in fitted] == ["ball"] and result is fits["ball"] and final["in_sizes"] == {"ball": True}
        return
    assert [n for n, _ in fitted] == ["ball", "pair"] and result is fits["pair"]
    assert result.info["class"]["chosen"] == "pair"
    assert final["in_sizes"] == {"ball": False, "pair": None}  # the pair model records no sizes
    assert final["scores"]["pair"] > final["scores"]["ball"]
    off = ScreenSettings(final_code_max=0.9, final_code_weight=0.02, final_size_margin=None)
    fitted.clear()
    assert fit_contenders({"ball": query, "pair": query}, models, options, screen_record, settings=off) is fits["ball"]
    assert [n for n, _ in fitted] == ["ball"]


def test_where_both_compared_fits_lie_outside_their_sizes_the_third_class_is_fitted_on_the_best_object(monkeypatch):
    """A bed scan whose screen ranks sofa, table, bed within the margin: the sofa and the table
    fits both end at a bed's size, outside their classes' sizes; the bed, third, is fitted on the
    sofa's object and wins."""
    query, models = _ball_and_blob()
    sizes = {"smallest": 0.9, "median": 1.0, "largest": 1.1, "shapes": 10}
    models = {name: DeepSdfModel(SphereDecoder(), torch.zeros(1, 2), {"name": name, "sizes_m": sizes})
              for name in ("sofa", "table", "bed", "chair")}
    models["bed"].meta["sizes_m"] = {"smallest": 1.8, "median": 2.0, "largest": 2.2, "shapes": 10}
    fits = {"sofa": _fit(2.0, 0.5), "table": _fit(2.0, 0.5), "bed": _fit(2.0, 0.5)}
    fitted = _stub_full_fits(monkeypatch, fits)
    other = SdfQuery(query.surface[:10], np.zeros(10), query.surface[:10])
    screen_record = {"chosen": "sofa", "chosen_by": "fit", "margin": 0.002, "refitted": [],
                     "scores": {"sofa": 0.030, "table": 0.032, "bed": 0.034, "chair": 0.09}}
    options = type("Options", (), {"seed": 0})()
    result = fit_contenders({"sofa": query, "table": other}, models, options, screen_record)
    assert [name for name, _ in fitted] == ["sofa", "table", "bed"] and fitted[2][1] is query
    assert result is fits["bed"] and result.info["class"]["final"]["in_sizes"] == {
        "sofa": False, "table": False, "bed": True}


@pytest.mark.parametrize("table_scale", [1.5, 3.0])
def test_where_every_contending_fit_lies_outside_its_sizes_the_class_whose_sizes_hold_it_is_fitted(monkeypatch,
                                                                                                   table_scale):
    """A bed scan whose screen ranks table and sofa within the margin and the bed far behind:
    the table fits it at 1.5 m, past the table's largest size times 1.1 (1.21 m), and the sofa
    larger still. The bed, whose sizes (1.3-2.0 m, widened: 1.0-2.2 m) hold 1.5 m, is fitted too,
    though far behind at the screen, and wins; the chair's sizes hold no such radius. A table fit
    at 3.0 m, which no class's sizes hold, calls no further fit."""
    query, _ = _ball_and_blob()
    sizes = {"table": (0.4, 1.1), "sofa": (0.7, 1.2), "bed": (1.3, 2.0), "chair": (0.4, 0.7)}
    models = {name: DeepSdfModel(SphereDecoder(), torch.zeros(1, 2),
                                 {"name": name, "sizes_m": {"smallest": lo, "median": (lo + hi) / 2, "largest": hi,
                                                            "shapes": 10}})
              for name, (lo, hi) in sizes.items()}
    fits = {"table": _fit(table_scale, 0.5), "sofa": _fit(3.5, 0.5), "bed": _fit(1.55, 0.5)}
    fitted = _stub_full_fits(monkeypatch, fits)
    screen_record = {"chosen": "table", "chosen_by": "fit", "margin": 0.008, "refitted": [],
                     "scores": {"table": 0.023, "sofa": 0.031, "bed": 0.068, "chair": 0.085}}
    settings = ScreenSettings(final_code_max=0.9, final_size_margin=1.3, final_size_margin_above=1.1)
    options = type("Options", (), {"seed": 0})()
    result = fit_contenders({"table": query, "sofa": query}, models, options, screen_record, settings=settings)
    final = result.info["class"]["final"]
    if table_scale == 3.0:
        assert [name for name, _ in fitted] == ["table", "sofa"] and result is fits["table"]
        return
    assert [name for name, _ in fitted] == ["table", "sofa", "bed"] and fitted[2][1] is query
    assert result is fits["bed"] and final["in_sizes"] == {"table": False, "sofa": False, "bed": True}


@pytest.mark.parametrize("far_code", [None, 1.1])
def test_where_both_compared_fits_need_a_far_code_the_third_class_is_fitted_on_the_best_object(monkeypatch,
                                                                                              far_code):
    """A sofa scan whose screen ranks bed, table, sofa within the margin: the bed and the table
    fits both need codes far out among their training codes (1.9, 1.35). With ``final_far_code``
    1.1 neither is the object's class: the sofa, third, is fitted on the bed's object, needs a
    typical code (0.6) and wins; without it the table stays."""
    query, _ = _ball_and_blob()
    models = {name: DeepSdfModel(SphereDecoder(), torch.zeros(1, 2), {"name": name})
              for name in ("bed", "table", "sofa", "chair")}
    fits = {"bed": _fit(1.0, 1.9), "table": _fit(1.0, 1.35), "sofa": _fit(1.0, 0.6)}
    fitted = _stub_full_fits(monkeypatch, fits)
    other = SdfQuery(query.surface[:10], np.zeros(10), query.surface[:10])
    screen_record = {"chosen": "bed", "chosen_by": "fit", "margin": 0.0003, "refitted": [],
                     "scores": {"bed": 0.0194, "table": 0.0197, "sofa": 0.0235, "chair": 0.063}}
    settings = ScreenSettings(final_code_max=0.9, final_code_weight=0.02, final_size_margin=None,
                              final_far_code=far_code)
    options = type("Options", (), {"seed": 0})()
    result = fit_contenders({"bed": query, "table": other}, models, options, screen_record, settings=settings)
    if far_code is None:
        assert [name for name, _ in fitted] == ["bed", "table"] and result is fits["table"]
        return
    assert [name for name, _ in fitted] == ["bed", "table", "sofa"] and fitted[2][1] is query
    final = result.info["class"]["final"]
    assert result is fits["sofa"] and final["compared"] == ["bed", "table", "sofa"] and final["first_all_far"]
    assert final["scores"]["sofa"] == pytest.approx(0.0235 + 0.02 * 0.6)


def test_after_every_first_fit_needed_a_far_code_only_a_typical_one_can_win(monkeypatch):
    """As above, but the sofa's screen score (0.035) puts its final score (0.047) above the
    table's (0.0467): the table's far code rules it out all the same. Where the first two were
    not both far (the table's code 1.05), the table wins on its final score and no third class
    is fitted."""
    query, _ = _ball_and_blob()
    models = {name: DeepSdfModel(SphereDecoder(), torch.zeros(1, 2), {"name": name})
              for name in ("bed", "table", "sofa")}
    screen_record = {"chosen": "bed", "chosen_by": "fit", "margin": 0.0003, "refitted": [],
                     "scores": {"bed": 0.0194, "table": 0.0197, "sofa": 0.035}}
    settings = ScreenSettings(final_code_max=0.9, final_code_weight=0.02, final_size_margin=None,
                              final_far_code=1.1, final_margin=0.035)
    options = type("Options", (), {"seed": 0})()
    fits = {"bed": _fit(1.0, 1.9), "table": _fit(1.0, 1.35), "sofa": _fit(1.0, 0.6)}
    _stub_full_fits(monkeypatch, fits)
    result = fit_contenders({"bed": query, "table": query}, models, options, screen_record, settings=settings)
    assert result is fits["sofa"] and result.info["class"]["final"]["scores"]["sofa"] > 0.0197 + 0.02 * 1.35
    fits["table"] = _fit(1.0, 1.05)
    fitted = _stub_full_fits(monkeypatch, fits)
    result = fit_contenders({"bed": query, "table": query}, models, options, screen_record, settings=settings)
    assert [name for name, _ in fitted] == ["bed", "table"] and result is fits["table"]
