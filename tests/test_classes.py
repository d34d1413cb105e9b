"""Classes left close by the screen are decided by their final fits (jsrte.fit.classes)."""

from __future__ import annotations

import importlib
import json

import numpy as np
import pytest
import torch

from analytic import SphereDecoder
from jsrte.fit.classes import decide, final_terms, fit_contenders
from jsrte.fit.query import SdfQuery
from jsrte.fit.screen import ScreenSettings, contending
from jsrte.geometry.sim3 import Sim3
from jsrte.model.checkpoint import DeepSdfModel
from jsrte.result import FitResult

CENTRE = np.array([2.0, 0.5, -1.0])


class BallAndBlob(torch.nn.Module):
    """A ball of radius 0.5 at the origin and one of 0.25 beside it (+x): the fitted "pair" class."""

    def __init__(self) -> None:
        super().__init__()
        self.config = SphereDecoder().config

    def forward(self, points: torch.Tensor, codes: torch.Tensor) -> torch.Tensor:
        far = (points - torch.tensor([0.75, 0.0, 0.0], dtype=points.dtype)).norm(dim=-1) - 0.25
        return torch.minimum(points.norm(dim=-1) - 0.5, far)


def _sphere_points(rng: np.random.Generator, n: int, centre: np.ndarray, radius: float) -> np.ndarray:
    v = rng.normal(size=(n, 3))
    return centre + radius * v / np.linalg.norm(v, axis=1, keepdims=True)


def _fit(scale: float) -> FitResult:
    return FitResult("jsrte", Sim3(scale, np.eye(3), CENTRE), np.zeros(2, np.float32), None, 0.0, {},
                     timing={"total": 1.0}, info={"decoder_evaluations": 100})


def test_contending_classes_are_the_best_and_those_within_the_margin():
    classes = {"bed": 0.030, "chair": None, "sofa": 0.035, "table": 0.050}
    assert contending(classes, ScreenSettings(final_margin=0.01)) == ["bed", "sofa"]
    assert contending(classes, ScreenSettings(final_margin=0.004)) == ["bed"]
    assert contending(classes, ScreenSettings(final_margin=0.0)) == ["bed"]
    assert contending(classes, ScreenSettings(final_margin=0.03)) == ["bed", "sofa"]  # at most two
    assert contending(classes, ScreenSettings(final_margin=0.03, final_classes=3)) == ["bed", "sofa", "table"]
    assert contending({"bed": None, "sofa": None}, ScreenSettings()) == []


def test_decide_keeps_the_lowest_final_score_and_records_the_comparison():
    terms = {"sofa": {"residual": 0.020, "freespace": 0.004, "unexplained": 0.10},
             "bed": {"residual": 0.015, "freespace": 0.002, "unexplained": 0.02}}
    weights = {"residual": 1.0, "freespace": 1.0, "unexplained": 0.0}
    chosen, record = decide(terms, weights)
    assert chosen == "bed" and record["compared"] == ["sofa", "bed"]
    assert record["scores"] == {"sofa": 0.024, "bed": 0.017} and record["margin"] == pytest.approx(0.007)
    assert record["terms"]["sofa"]["unexplained"] == 0.1
    # the free space alone reverses it
    chosen, _ = decide(terms | {"bed": terms["bed"] | {"freespace": 0.02}}, weights)
    assert chosen == "sofa"


def test_final_fits_choose_the_class_the_screen_ranked_second(monkeypatch):
    """The screen ranks "ball" (a sphere model) 0.002 ahead of "pair" (ball and blob) on a
    ball-and-blob cluster, so the screen alone would take "ball". Fitted in full, the ball's fit
    leaves the blob's 30% of the points unexplained and the pair's fit explains them all: the
    final fits choose "pair", return its fit, and fit.json's ``class`` records the comparison."""
    fit_module = importlib.import_module("jsrte.fit")
    rng = np.random.default_rng(0)
    points = np.concatenate([_sphere_points(rng, 700, CENTRE, 1.0),
                             _sphere_points(rng, 300, CENTRE + [1.5, 0.0, 0.0], 0.5)])
    query = SdfQuery(points, np.zeros(len(points)), points)
    models = {"ball": DeepSdfModel(SphereDecoder(), torch.zeros(1, 2), {"name": "ball"}),
              "pair": DeepSdfModel(BallAndBlob(), torch.zeros(1, 2), {"name": "pair"})}
    fits = {"ball": _fit(2.0), "pair": _fit(2.0)}  # both exact on the ball
    fitted = []

    def fit_recorded(model, query, options, *, class_choice=None, progress=False):
        name = model.meta["name"]
        fitted.append(name)
        return fits[name]

    monkeypatch.setattr(fit_module, "fit_recorded", fit_recorded)
    screen_record = {"chosen": "ball", "chosen_by": "fit", "scores": {"ball": 0.030, "pair": 0.032},
                     "margin": 0.002, "refitted": []}
    settings = ScreenSettings()
    assert final_terms(models["pair"], fits["pair"], {"pair": query}, settings)["residual"] < 1e-6
    ball = final_terms(models["ball"], fits["ball"], {"ball": query}, settings)
    assert ball["residual"] > 0.02 and 0.25 < ball["unexplained"] <= 0.3  # the blob, less the points touching the ball
    options = type("Options", (), {"seed": 0})()
    result = fit_contenders({"ball": query, "pair": query}, models, options, screen_record, settings=settings)
    assert fitted == ["ball", "pair"] and result is fits["pair"]
    record = json.loads(json.dumps(result.to_json()))["class"]
    assert record["chosen"] == "pair" and record["chosen_by"] == "final fit"
    assert record["scores"] == screen_record["scores"]  # the screen's record is kept
    final = record["final"]
    assert final["compared"] == ["ball", "pair"] and final["margin"] > 0.02
    assert final["scores"]["pair"] < 1e-5 < final["scores"]["ball"]
    assert final["decoder_evaluations"] == {"ball": 100, "pair": 100}
