"""The scene experiment: matching found objects to true ones, the tallies, and a whole run."""

from __future__ import annotations

import csv
import importlib
import json
from dataclasses import replace

import numpy as np
import pytest

from jsrte.experiments.scene_scoring import (
    BOX_FOUND,
    BOX_UNFOUND,
    FALSE_BOX,
    FALSE_POSITIVE,
    HIT,
    MISS,
    ON_BOX,
    FoundObject,
    TrueObject,
    confusion,
    detection,
    fit_quality,
    match_objects,
    object_rows,
)


def true_room() -> list[TrueObject]:
    return [TrueObject(0, "chair", np.zeros(3), 1.0), TrueObject(1, "table", np.array([5.0, 0, 0]), 2.0),
            TrueObject(2, "sofa", np.array([10.0, 0, 0]), 1.0), TrueObject(3, "box", np.array([0.0, 5, 0]), 0.5)]


def found_room() -> list[FoundObject]:
    return [FoundObject(0, "chair", np.array([0.2, 0, 0]), "ok"),    # near the chair, but f4 is nearer
            FoundObject(1, "chair", np.array([5.5, 0, 0]), "ok"),    # the table (0.25 radius), class wrong
            FoundObject(2, "sofa", np.array([10.5, 0, 0]), "ok"),    # 0.5 radius from the sofa: no match
            FoundObject(3, "bed", np.array([0.0, 5.1, 0]), "doubtful"),  # on the box
            FoundObject(4, "chair", np.array([0.1, 0, 0]), "ok")]


def test_matching_is_one_to_one_within_three_tenths_of_the_radius():
    rows = object_rows(true_room(), found_room())
    by_true = {r["true_index"]: r for r in rows if r["true_index"] is not None}
    assert by_true[0]["outcome"] == HIT and by_true[0]["found_index"] == 4
    assert by_true[0]["distance_rel"] == pytest.approx(0.1)
    assert by_true[1]["outcome"] == HIT and by_true[1]["found_class"] == "chair"
    assert by_true[1]["distance_rel"] == pytest.approx(0.25)
    assert by_true[2]["outcome"] == MISS and by_true[2]["found_index"] is None
    assert by_true[3]["outcome"] == ON_BOX and by_true[3]["found_index"] == 3
    extra = sorted(r["found_index"] for r in rows if r["outcome"] == FALSE_POSITIVE)
    assert extra == [0, 2] and len(rows) == 6


def test_matching_prefers_more_matches_to_the_nearest_first():
    true = [TrueObject(0, "chair", np.zeros(3), 1.0), TrueObject(1, "chair", np.array([0.5, 0, 0]), 1.0)]
    found = [FoundObject(0, "chair", np.array([0.27, 0, 0])), FoundObject(1, "chair", np.array([0.76, 0, 0]))]
    # nearest first would give found 0 to true 1 (0.23 < 0.27) and leave found 1 (0.26 from true 1) unmatched
    assert match_objects(true, found) == {0: 0, 1: 1}
    assert match_objects(true, []) == {} and match_objects([], found) == {}


def test_detection_tallies_and_confusion():
    rows = object_rows(true_room(), found_room())
    d = detection(rows)
    assert (d["true_furniture"], d["found"], d["hits"], d["missed"], d["false_positives"]) == (3, 5, 2, 1, 2)
    assert d["found_on_boxes"] == 1 and d["boxes"] == 1 and d["boxes_flagged_doubtful"] == 1.0
    assert d["recall"] == pytest.approx(2 / 3, abs=1e-4) and d["precision"] == 0.5
    assert d["class_accuracy"] == 0.5
    table = confusion(rows)
    assert list(table) == ["chair", "table", "sofa", "bed", "box"]
    assert list(table["chair"]) == ["chair", "table", "sofa", "bed", "missed"]
    assert table["chair"]["chair"] == 1 and table["table"]["chair"] == 1 and table["sofa"]["missed"] == 1
    assert table["box"]["bed"] == 1 and sum(table["bed"].values()) == 0
    assert sum(sum(row.values()) for row in table.values()) == 4


def test_reported_boxes_are_scored_apart_from_furniture():
    """A reported box on a true box is a box found; on furniture it leaves that furniture missed;
    on nothing it is a false box; none is a hit or a false positive."""
    true = true_room() + [TrueObject(4, "box", np.array([0.0, 9, 0]), 0.5)]
    found = [FoundObject(0, "chair", np.array([0.1, 0, 0]), "ok"),
             FoundObject(1, "box", np.array([0.0, 5.05, 0])),  # on the box
             FoundObject(2, "box", np.array([5.2, 0, 0])),     # on the table
             FoundObject(3, "box", np.array([20.0, 0, 0]))]    # on nothing
    rows = object_rows(true, found)
    by_true = {r["true_index"]: r for r in rows if r["true_index"] is not None}
    assert by_true[3]["outcome"] == BOX_FOUND and by_true[4]["outcome"] == BOX_UNFOUND
    assert by_true[1]["outcome"] == MISS and by_true[1]["found_class"] == "box"
    assert [r["outcome"] for r in rows if r["true_index"] is None] == [FALSE_BOX]
    d = detection(rows)
    assert (d["hits"], d["missed"], d["false_positives"], d["found"]) == (1, 2, 0, 1)
    assert (d["boxes"], d["boxes_found"], d["found_on_boxes"], d["false_boxes"], d["furniture_as_boxes"]) == \
        (2, 1, 0, 1, 1)
    assert d["precision"] == 1.0 and d["recall"] == pytest.approx(1 / 3, abs=1e-4)
    assert confusion(rows)["table"]["box"] == 1


def test_fit_quality_and_the_flag_as_a_detector_of_bad_fits():
    def hit(f, flag, right=True, rotation=None, scale=None):
        return {"outcome": HIT, "fscore": f, "flag": flag, "true_class": "chair",
                "found_class": "chair" if right else "table", "rotation_error_deg": rotation, "scale_error_rel": scale}

    rows = [hit(0.9, "ok", rotation=2.0, scale=0.01), hit(0.5, "doubtful", right=False, rotation=90.0, scale=0.5),
            hit(0.6, "ok", rotation=10.0, scale=0.05), hit(0.95, "doubtful", rotation=4.0, scale=0.03),
            {"outcome": MISS, "fscore": None, "flag": None, "true_class": "sofa", "found_class": None}]
    q = fit_quality(rows)
    assert q["scored"] == 4 and q["fscore_mean"] == pytest.approx(0.7375) and q["fscore_median"] == 0.75
    assert q["fscore_mean_misses_zero"] == pytest.approx(0.59)
    assert q["rotation_error_deg_median"] == 4.0 and q["scale_error_rel_median"] == 0.03  # class right only
    assert (q["fits_below_0.7"], q["fits_at_least_0.85"]) == (2, 2)
    assert q["flag_recall"] == 0.5 and q["flag_precision"] == 0.5 and q["good_fits_flagged"] == 0.5
    assert fit_quality([])["fscore_mean"] is None and fit_quality([])["flag_recall"] is None


def test_a_room_is_the_same_for_the_same_index_and_seed():
    from jsrte.experiments.scenes import draw_room, true_objects

    settings = small_rooms()
    a, b = (draw_room(7, seed=1, objects=(3, 3), settings=settings) for _ in range(2))
    assert np.array_equal(a.scan.points, b.scan.points)
    truth = true_objects(a)
    assert len(truth) == 3 and truth[0].kind in ("chair", "table", "sofa", "bed")
    for obj, t in zip(a.objects, truth, strict=True):
        assert (a.labels == t.index).sum() > 50  # every object is seen
        height = obj.scan_from_mesh.s * np.ptp(obj.mesh.vertices[:, 1])
        assert obj.scan_from_mesh.s == pytest.approx(1.0) and 0.2 < height < 2.5  # its own size, metres


def small_rooms():
    from jsrte.experiments.scenes import ROOM_SETTINGS

    return replace(ROOM_SETTINGS, scanner=replace(ROOM_SETTINGS.scanner, width=96, height=72))


@pytest.mark.slow
def test_a_tiny_run_end_to_end(tmp_path, run_cli, monkeypatch):
    from jsrte.experiments import scenes

    monkeypatch.setattr(scenes, "ROOM_SETTINGS", small_rooms())
    out = tmp_path / "run"
    code, text, err = run_cli(["experiment", "scenes", "--out", str(out), "--rooms", "1", "--first", "3",
                               "--objects", "2,2", "--model", "chair", "--preset", "smoke", "--threads", "1",
                               "--no-report"])
    assert code == 0, err
    for name in ("objects.csv", "rooms.csv", "summary.md", "summary.csv", "config.json", "figure_room_003.png",
                 "rooms/003/scan.ply", "rooms/003/scene.json", "fits/003/scene.json"):
        assert (out / name).is_file(), name
    with open(out / "objects.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    assert {r["room"] for r in rows} == {"3"} and len([r for r in rows if r["true_index"]]) == 2
    with open(out / "summary.csv", newline="") as f:
        summary = next(csv.DictReader(f))
    outcomes = [r["outcome"] for r in rows]
    hits, missed, extra = outcomes.count("hit"), outcomes.count("missed"), outcomes.count("false positive")
    fitted = json.loads((out / "fits/003/scene.json").read_text())["counts"]["fitted"]
    assert summary["rooms"] == "1" and int(summary["true_furniture"]) == hits + missed >= 1
    assert int(summary["found"]) == fitted == hits + extra + outcomes.count("on box")
    assert float(summary["recall"]) == pytest.approx(hits / (hits + missed), abs=1e-4)
    for r in rows:
        assert (r["outcome"] == "hit") == (r["fscore"] != "")  # F@5% of every hit, of nothing else
        if r["fscore"]:
            assert 0.0 <= float(r["fscore"]) <= 1.0 and 0.0 <= float(r["rotation_error_deg"]) <= 180.0
            assert float(r["distance_rel"]) < 0.3 and r["flag"] in ("ok", "doubtful")
    assert float(summary["seconds_per_scene"]) > 0 and "detection recall" in text and "| chair |" in text
    quick = float(summary["quick_fit_seconds_per_scene"])  # one room: its own quick fits' seconds (to 0.1 s)
    assert 0.0 <= quick <= float(summary["seconds_per_scene"])
    assert quick == pytest.approx(round(float(rows[0]["quick_fit_seconds"]), 1), abs=1e-9)


def test_the_rooms_are_fitted_with_the_arithmetic_asked_for(tmp_path, run_cli, monkeypatch, short_fits):
    """Every fit of the run, quick and full, moves in the arithmetic asked for: float32 here,
    where the quick fits' own is "auto" (bfloat16 where the CPU computes it natively)."""
    from jsrte.experiments import scenes

    monkeypatch.setattr(scenes, "ROOM_SETTINGS", small_rooms())
    arithmetic = short_fits("decoder_dtype", quick=True)
    out = tmp_path / "run"
    code, _, err = run_cli(["experiment", "scenes", "--out", str(out), "--rooms", "1", "--first", "3",
                            "--objects", "2,2", "--model", "chair", "--preset", "smoke", "--threads", "1",
                            "--dtype", "float32", "--no-report"])
    assert code == 0, err
    assert json.loads((out / "config.json").read_text())["dtype"] == "float32"
    fits = list((out / "fits/003/objects").glob("*/fit.json"))
    assert fits and all(json.loads(f.read_text())["decoder_dtype"] == "float32" for f in fits)
    assert len(arithmetic) > len(fits) and set(arithmetic) == {"float32"}  # the screen's quick fits too


def test_rooms_fitted_without_their_cameras_are_segmented_on_the_given_up_axis(tmp_path, monkeypatch):
    from jsrte.errors import JsrteError
    from jsrte.experiments import scenes
    from jsrte.fit.query import scan_candidates
    from jsrte.fit.scene import SCENE_SEGMENT
    from jsrte.scans.io import read_scan_info

    monkeypatch.setattr(scenes, "ROOM_SETTINGS", small_rooms())
    seen = []

    def segment_only(path, *, up, **_):  # the scene's segmentation of what run_room hands it, no fits
        seen.append((path, up, scan_candidates(path, up=up, rng=np.random.default_rng(0), segment=SCENE_SEGMENT)))
        raise JsrteError("segmented only", path)

    monkeypatch.setattr(importlib.import_module("jsrte.fit.scene"), "fit_scene", segment_only)
    config = scenes.ScenesConfig(rooms=1, first=3, objects=(2, 2), model="chair", cameras=False)
    rows = scenes.run_room(3, config, tmp_path)
    assert {r["outcome"] for r in rows} == {"missed"} and "segmented only" in rows[0]["scene_error"]
    (path, up, candidates), = seen
    room = json.loads((tmp_path / "rooms/003/scan.json").read_text())
    assert path.name == "scan_without_cameras.ply" and read_scan_info(path) is None  # no cameras to read
    assert up == pytest.approx(room["up"])
    segmented = candidates.segmented
    assert segmented.viewpoints is None and segmented.floor is not None
    assert segmented.floor.offset == pytest.approx(room["floor"]["offset"], abs=0.02)
    labels = np.load(tmp_path / "rooms/003/labels.npy")
    assert (labels[segmented.index] == -1).mean() < 0.01  # the floor is gone, not clustered with the objects
    held = [set(labels[segmented.index[c.index]]) for c in candidates.segmentation.candidates if not c.rejected]
    assert {0, 1} <= set().union(*held)  # both objects stand in candidates


def test_bad_input_is_a_one_line_error(tmp_path, run_cli):
    done = tmp_path / "done"
    done.mkdir()
    (done / "summary.md").write_text("earlier")
    code, _, err = run_cli(["experiment", "scenes", "--out", str(done), "--rooms", "1"])
    assert code != 0 and "--overwrite" in err and err.strip().count("\n") == 0
    assert (done / "summary.md").read_text() == "earlier"
    for args, word in ((["--rooms", "0"], "--rooms"), (["--objects", "0,3"], "--objects"),
                       (["--objects", "x"], "--objects"), (["--jobs", "0"], "--jobs"),
                       (["--dtype", "half"], "--dtype")):
        code, _, err = run_cli(["experiment", "scenes", "--out", str(tmp_path / "new"), *args])
        assert code != 0 and word in err and err.strip().count("\n") == 0
        assert not (tmp_path / "new").exists()
    code, _, err = run_cli(["experiment", "scenes", "--out", str(tmp_path / "none"), "--resume"])
    assert code != 0 and "resume" in err


def test_a_run_recorded_before_a_setting_existed_resumes_with_its_default(tmp_path):
    from jsrte.errors import JsrteError
    from jsrte.experiments.scenes import CONFIG_NAME, ScenesConfig, _resumed_rows

    older = {k: v for k, v in ScenesConfig().to_json().items() if k not in ("cameras", "leftovers")}
    (tmp_path / CONFIG_NAME).write_text(json.dumps(older))
    assert _resumed_rows(ScenesConfig(rooms=5), tmp_path) == []  # no objects.csv yet: nothing kept
    with pytest.raises(JsrteError, match=r"other settings \(cameras\)"):  # the default was with the cameras
        _resumed_rows(ScenesConfig(cameras=False), tmp_path)


def test_resuming_a_damaged_run_is_a_one_line_error(tmp_path, run_cli):
    run = tmp_path / "run"
    run.mkdir()
    (run / "config.json").write_text("{not json")
    code, _, err = run_cli(["experiment", "scenes", "--out", str(run), "--resume", "--rooms", "1"])
    assert code != 0 and "config.json" in err and "unreadable" in err and err.strip().count("\n") == 0
    assert (run / "config.json").read_text() == "{not json"
