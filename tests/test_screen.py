"""Choosing the object, and its class, by a quick fit of each candidate (jsrte.fit.screen)."""

from __future__ import annotations

import importlib
import json
from dataclasses import replace

import numpy as np
import pytest
import trimesh

from cli_runner import run_cli
from jsrte.fit import model_names
from jsrte.fit.query import scan_candidates
from jsrte.fit.screen import ScreenSettings, choose_in_scan
from jsrte.model.registry import resolve_model
from jsrte.scans.scanner import scan_mesh, write_scan
from jsrte.scans.scene import SceneSettings, scan_room, write_room
from jsrte.scans.segment import ClassShape
from jsrte.shapes import EVAL_SET_SEED, generate_shape, shape_seed

SMALL = SceneSettings(scanner=replace(SceneSettings().scanner, width=120, height=90), walls=(1, 1),
                      wall_gap_m=(0.2, 0.3), neighbour_gap_m=(0.3, 0.5), first_neighbour_gap_m=(0.3, 0.4),
                      mixed_pixel_fraction=0.0)
"""One wall and a box well apart from the chair (one cluster each)."""


def box(size: tuple[float, float, float]) -> trimesh.Trimesh:
    mesh = trimesh.creation.box(size)
    mesh.apply_translation([0.0, size[1] / 2.0, 0.0])
    return mesh


def held_out(category: str, index: int = 100) -> trimesh.Trimesh:
    return generate_shape(category, shape_seed(EVAL_SET_SEED, index)).mesh


@pytest.fixture(scope="module")
def chair_model():
    return resolve_model("chair")


@pytest.mark.slow
def test_the_fit_picks_the_chair_that_a_box_outranks_by_proportions(tmp_path, chair_model):
    crate = box((0.45, 0.8, 0.45))
    settings = replace(SMALL, scanner=replace(SMALL.scanner, width=240, height=180))
    room = scan_room(held_out("chair", 106), rng=np.random.default_rng(3), settings=settings, target_kind="chair",
                     others=[("box", crate, "box")])
    ply = write_room(room, tmp_path / "room")
    box_like = ClassShape.of_mesh("box-like", crate.vertices, crate.sample(3000, seed=0))

    def segment(model):  # proportions that favour the box: the class rank alone takes it
        return scan_candidates(ply, rng=np.random.default_rng(0), shape=box_like)

    cands = segment(chair_model)
    labels = room.labels[cands.segmented.index]
    first = cands.segmentation.candidates[cands.valid()[0]]
    assert np.mean(labels[first.index] == 1) > 0.9  # the box ranks first by proportions
    choice = choose_in_scan(ply, {"chair": chair_model}, segment=segment)
    seg = choice.query.info["segmentation"]
    chosen = seg["candidates"][seg["chosen"]]
    picked = cands.segmentation.candidates[seg["chosen"]].index
    assert np.mean(labels[picked] == 0) > 0.9 and len(picked) > 0.8 * np.sum(labels == 0)
    assert seg["chosen_by"] == "fit" and chosen["chosen"]
    screened = [c["screen"] for c in seg["candidates"] if "screen" in c]
    assert len(screened) >= 2 and chosen["screen"]["score"] == min(s["score"] for s in screened)
    assert chosen["screen"]["residual"] < 0.03  # the chair's points lie on its fitted surface
    assert all(s.result.flag is None and not s.result.quality for s in choice.screened)  # quick fits only rank


def test_model_names():
    assert model_names("chair, table") == ["chair", "table"]
    assert model_names("auto") == ["bed", "chair", "sofa", "table"]
    assert model_names("chair") == ["chair"]


def test_auto_without_shipped_models_is_a_clear_error(tmp_path, monkeypatch, capsys):
    import jsrte.model.registry as registry

    scan = scan_mesh(held_out("chair", 102), rng=np.random.default_rng(5))
    ply = write_scan(scan, tmp_path / "chair.ply")
    monkeypatch.setattr(registry, "shipped_models", lambda: {})
    code, _, err = run_cli(monkeypatch, capsys, "fit", ply, "--model", "auto", "--out", tmp_path / "fit",
                           "--no-progress")
    assert code != 0 and "no shipped model" in err and err.count("\n") == 1
    assert not (tmp_path / "fit").exists()


@pytest.mark.slow
def test_chair_or_table_on_a_table_scan_is_a_table(tmp_path, monkeypatch, capsys):
    """``jsrte fit TABLE_SCAN --model table,chair`` fits a table; fit.json holds both scores."""
    scan = scan_mesh(held_out("table", 101), rng=np.random.default_rng(4))
    ply = write_scan(scan, tmp_path / "table.ply")
    code, out, err = run_cli(monkeypatch, capsys, "fit", ply, "--model", "chair,table", "--preset", "smoke",
                             "--hypotheses", "2", "--threads", "1", "--no-progress", "--out", tmp_path / "fit")
    assert code == 0, err
    record = json.loads((tmp_path / "fit" / "fit.json").read_text())
    choice = record["class"]
    assert "class table" in out and choice["chosen"] == "table" and record["model"] == "table"
    assert set(choice["scores"]) == {"chair", "table"} and choice["margin"] > 0
    assert choice["scores"]["table"] + choice["margin"] == pytest.approx(choice["scores"]["chair"], abs=1e-4)


# --- a split's whole against its parts ---------------------------------------------------------


class _Cand:
    def __init__(self, points: int, parts: list[int] | None = None, parent: int | None = None):
        self.index, self.parts, self.parent = np.arange(points), parts or [], parent


def test_a_whole_explained_better_than_by_its_parts_covers_them():
    from jsrte.fit.screen import split_or_whole

    # 0 = 1 + 2, 1 = 3 + 4 (the split's tree, most points first)
    tree = [_Cand(1000, [1, 2]), _Cand(600, [3, 4], 0), _Cand(400, parent=0), _Cand(400, parent=1),
            _Cand(200, parent=1)]
    # a bed cut in pieces: the whole's fit explains all of it, a piece's fit only that piece
    assert split_or_whole(tree, {0: 0.02, 1: 0.03, 2: 0.05, 3: 0.02, 4: 0.06}) == {1, 2, 3, 4}
    # a chair (3) beside a box (4) beside a table (2): each whole explains its points worse
    assert split_or_whole(tree, {0: 0.05, 1: 0.04, 2: 0.03, 3: 0.01, 4: 0.03}) == {0, 1}
    # the chair and the box are one object, beside a table
    assert split_or_whole(tree, {0: 0.05, 1: 0.015, 2: 0.02, 3: 0.01, 4: 0.03}) == {0, 3, 4}
    # the whole's fit explains its points as well as the parts' fits, but its best part (1, a
    # chair judged whole) three times worse than that part's own fit: a chair fitted to a chair
    # beside a table is a poor chair
    asked = []

    def explains(whole: int, part: int, objects: list[list[int]]) -> float:
        asked.append((whole, part))
        return 3.0 if whole == 0 else 1.0

    scores = {0: 0.02, 1: 0.03, 2: 0.05, 3: 0.02, 4: 0.06}
    assert split_or_whole(tree, scores, explains) == {0, 3, 4} and asked == [(1, 3), (0, 1)]
    # a part judged to hold several objects (1: a sofa and a table) stands for them when its
    # whole is judged: the whole's fit is asked about the sofa and the table, not about 1
    stands_for = {}

    def explains_whole(whole: int, part: int, objects: list[list[int]]) -> float:
        stands_for[whole] = objects
        return 3.0 if whole == 1 else 1.0

    assert split_or_whole(tree, {0: 0.02, 1: 0.02, 2: 0.05, 3: 0.02, 4: 0.02}, explains_whole) == {1, 2, 3, 4}
    assert stands_for == {1: [[3], [4]], 0: [[3, 4], [2]]}


@pytest.fixture(scope="module")
def bed_model():
    return resolve_model("bed")


@pytest.mark.slow
def test_a_bed_cut_at_its_headboard_is_fitted_whole(tmp_path, bed_model):
    """Held-out bed 100: the split by class likeness cuts it in two; the screen keeps it whole."""
    from jsrte.fit.query import class_shape

    scan = scan_mesh(held_out("bed", 100), rng=np.random.default_rng(100))
    ply = write_scan(scan, tmp_path / "bed.ply")
    labels = scan.is_object

    def segment(model):
        return scan_candidates(ply, rng=np.random.default_rng(0), shape=class_shape(model))

    cands = segment(bed_model)
    seg = cands.segmentation
    whole = [k for k, c in enumerate(seg.candidates) if c.parts]
    assert len(whole) == 1 and len(cands.valid()) == 2  # cut in two; the whole is no part of valid()
    assert all(seg.candidates[p].parent == whole[0] for p in seg.candidates[whole[0]].parts)
    assert seg.chosen != whole[0]  # proportions alone take a part
    choice = choose_in_scan(ply, {"bed": bed_model}, segment=segment)
    record = choice.query.info["segmentation"]
    chosen = record["candidates"][record["chosen"]]
    assert record["chosen"] == whole[0] and len(chosen["parts"]) == 2
    assert all(record["candidates"][p]["parent"] == whole[0] and record["candidates"][p]["screen"]["covered"]
               for p in chosen["parts"])
    picked = cands.segmentation.candidates[record["chosen"]].index
    assert labels[cands.segmented.index[picked]].sum() > 0.95 * labels[cands.segmented.index].sum()


def chair_beside_box(chair, folder):
    """A small room scan (scene, scan.ply path) of ``chair`` 2-3 cm from a 0.4 x 0.5 x 0.5 box."""
    settings = replace(SMALL, scanner=replace(SMALL.scanner, width=240, height=180),
                       first_neighbour_gap_m=(0.02, 0.03))
    room = scan_room(chair, rng=np.random.default_rng(2), settings=settings, target_kind="chair",
                     others=[("box", box((0.4, 0.5, 0.5)), "box")])
    return room, write_room(room, folder / "room")


@pytest.mark.slow
def test_a_chair_beside_a_box_is_chosen_without_the_box(tmp_path, chair_model):
    """A held-out chair 2-3 cm from a box (one cluster, cut in two): the whole is screened too,
    and the chair alone is chosen."""
    from jsrte.fit.query import class_shape

    room, ply = chair_beside_box(held_out("chair", 102), tmp_path)

    segmented = []

    def segment(model):
        segmented.append(scan_candidates(ply, rng=np.random.default_rng(0), shape=class_shape(model)))
        return segmented[-1]

    record = choose_in_scan(ply, {"chair": chair_model}, segment=segment).query.info["segmentation"]
    labels = room.labels[segmented[0].segmented.index]
    seg = segmented[0].segmentation
    pair = [k for k, c in enumerate(seg.candidates) if c.parts and np.mean(labels[c.index] == 1) > 0.2]
    assert pair and np.mean(labels[seg.candidates[pair[0]].index] == 0) > 0.2  # chair and box, one whole
    picked = seg.candidates[record["chosen"]].index
    assert "screen" in record["candidates"][pair[0]]  # the whole competed
    assert np.mean(labels[picked] == 0) > 0.9 and len(picked) > 0.7 * np.sum(labels == 0)


def test_screen_terms_count_the_points_the_fit_leaves_unexplained():
    """A sphere fitted exactly to 700 points of a 1 m sphere, beside 300 points of a neighbour's
    face 0.3-0.8 m off it (one merged candidate): 30% unexplained, each capped in the residual."""
    import torch

    from analytic import SphereDecoder
    from jsrte.fit.query import SdfQuery
    from jsrte.fit.screen import screen_terms
    from jsrte.geometry.sim3 import Sim3
    from jsrte.model.checkpoint import DeepSdfModel
    from jsrte.result import FitResult

    rng = np.random.default_rng(0)
    centre = np.array([2.0, 0.5, -1.0])
    ball = rng.normal(size=(700, 3))
    ball = centre + ball / np.linalg.norm(ball, axis=1, keepdims=True)
    face = centre + np.column_stack([rng.uniform(1.3, 1.8, 300), rng.uniform(-0.2, 0.2, 300), np.zeros(300)])
    surface = np.concatenate([ball, face])
    query = SdfQuery(surface, np.zeros(len(surface)), surface)
    model = DeepSdfModel(SphereDecoder(), torch.zeros(1, 2), {"name": "sphere"})
    fitted = FitResult("jsrte", Sim3(2.0, np.eye(3), centre), np.zeros(2, np.float32), None, 0.0, {})
    terms = screen_terms(model, query, fitted, ScreenSettings(), rng)
    assert terms["unexplained"] == pytest.approx(0.3)
    assert terms["residual"] == pytest.approx(0.3 * ScreenSettings().residual_cap)  # the face's points capped
    alone = SdfQuery(ball, np.zeros(len(ball)), ball)
    assert screen_terms(model, alone, fitted, ScreenSettings(), rng)["unexplained"] < 1e-3


def _noisy_plane(rng: np.random.Generator, n: int, origin: tuple[float, float, float]) -> np.ndarray:
    """A 1 m x 1 m vertical patch of a wall (x-y plane at z = origin z), 1 cm depth noise."""
    return np.asarray(origin) + np.column_stack([rng.uniform(0, 1, n), rng.uniform(0, 1, n), rng.normal(0, 0.01, n)])


def test_slabs_are_screened_after_every_other_candidate():
    """Two wall remnants outrank a box and a chair by proportions: the three screened are the
    box, the chair and the better remnant; without the slab rule the chair is left out."""
    from types import SimpleNamespace

    from jsrte.fit.screen import screened_candidates, slabs, thickness
    from jsrte.scans.segment import Candidate

    rng = np.random.default_rng(0)
    chair = held_out("chair").sample(3000, seed=0)
    crate = box((0.5, 0.6, 0.4)).sample(3000, seed=0)
    pieces = [_noisy_plane(rng, 800, (3.0, 0.0, 2.0)), _noisy_plane(rng, 800, (-3.0, 0.0, 2.0)),
              crate + [1.5, 0.0, 0.0], chair + [-1.5, 0.0, 0.0]]
    points = np.concatenate(pieces)
    starts = np.cumsum([0] + [len(p) for p in pieces])
    candidates = [Candidate(index=np.arange(starts[i], starts[i + 1]), summary={"rank": 0.1 * i}) for i in range(4)]
    scan = SimpleNamespace(cloud=SimpleNamespace(points=points), index=np.arange(len(points)))
    cands = SimpleNamespace(segmentation=SimpleNamespace(candidates=candidates), valid=lambda: [0, 1, 2, 3],
                            segmented=scan)
    assert thickness(pieces[0]) < 0.05 and thickness(pieces[3]) > 0.1  # a wall's remnant; a chair
    thin = slabs(cands, 0.08)
    assert thin == {0, 1} and candidates[2].summary["thickness_m"] == pytest.approx(0.4, abs=0.05)
    assert screened_candidates(cands, 3) == [0, 1, 2]
    assert screened_candidates(cands, 3, thin) == [2, 3, 0]


# --- the class judged on whole objects ----------------------------------------------------------


def _two_pieces(rng: np.random.Generator, centre: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """700 points of a 1 m sphere at ``centre`` and 300 of a 0.5 m sphere 1.5 m beside it (+x)."""
    ball = rng.normal(size=(700, 3))
    blob = rng.normal(size=(300, 3))
    return (centre + ball / np.linalg.norm(ball, axis=1, keepdims=True),
            centre + [1.5, 0.0, 0.0] + 0.5 * blob / np.linalg.norm(blob, axis=1, keepdims=True))


def _whole_and_parts(ball: np.ndarray, blob: np.ndarray) -> object:
    """``ScanCandidates``-like: candidate 0 (both pieces) split into 1 (the ball) and 2 (the blob)."""
    from types import SimpleNamespace

    from jsrte.scans.segment import Candidate

    n = len(ball) + len(blob)
    candidates = [Candidate(np.arange(n), parts=[1, 2], summary={"rank": 0.0}),
                  Candidate(np.arange(len(ball)), parent=0, summary={"rank": 0.0}),
                  Candidate(np.arange(len(ball), n), parent=0, summary={"rank": 0.0})]
    return SimpleNamespace(segmentation=SimpleNamespace(candidates=candidates))


def test_a_class_that_explains_only_part_of_a_whole_pays_for_the_rest():
    """One model fits the ball of a ball-and-blob cluster exactly; another fits the whole cluster
    1% too large. On its part the first scores lower; judged on the whole, the second wins."""
    import torch

    from analytic import BallAndBlobDecoder, SphereDecoder
    from jsrte.fit.query import SdfQuery
    from jsrte.fit.screen import Screened, ScreenSettings, _points_key, class_scores, screen_score, screen_terms
    from jsrte.geometry.sim3 import Sim3
    from jsrte.model.checkpoint import DeepSdfModel
    from jsrte.result import FitResult

    rng = np.random.default_rng(0)
    centre = np.array([2.0, 0.5, -1.0])
    ball, blob = _two_pieces(rng, centre)
    cands = _whole_and_parts(ball, blob)
    pieces = {0: np.concatenate([ball, blob]), 1: ball, 2: blob}
    queries = {_points_key(cands, k): SdfQuery(p, np.zeros(len(p)), p) for k, p in pieces.items()}
    models = {"ball": DeepSdfModel(SphereDecoder(), torch.zeros(1, 2), {"name": "ball"}),
              "pair": DeepSdfModel(BallAndBlobDecoder(), torch.zeros(1, 2), {"name": "pair"})}
    settings = ScreenSettings(class_refit_margin=0.0)

    def screened(name: str, k: int, scale: float) -> Screened:
        result = FitResult("jsrte", Sim3(scale, np.eye(3), centre), np.zeros(2, np.float32), None, 0.0, {})
        parts = screen_terms(models[name], queries[_points_key(cands, k)], result, settings, rng) | {"rank": 0.0}
        return Screened(name, k, queries[_points_key(cands, k)], result, screen_score(parts, settings), parts)

    on_part, on_whole = screened("ball", 1, 2.0), screened("pair", 0, 2.02)
    assert on_part.score < 1e-6 < on_whole.score < 0.01  # by its own candidate the ball model wins
    scores, refits = class_scores({"ball": cands, "pair": cands}, [on_part, on_whole], queries, models, settings, 0)
    assert scores["pair"] == pytest.approx(on_whole.score) and not refits
    assert scores["ball"] > 0.02  # the blob's 30% of the points, each capped at 0.1 radii
    assert min(scores, key=scores.__getitem__) == "pair"


def test_the_contended_classes_are_fitted_again_to_their_wholes(monkeypatch):
    """Classes within ``class_refit_margin`` of the best are refitted on their whole (its query)
    and keep the lower score; the others are not."""
    from types import SimpleNamespace

    from jsrte.fit.screen import Screened, ScreenSettings, class_scores

    screen_module = importlib.import_module("jsrte.fit.screen")
    cands = _whole_and_parts(np.zeros((70, 3)), np.zeros((30, 3)))
    keys = {k: screen_module._points_key(cands, k) for k in range(3)}
    queries = {key: SimpleNamespace(name=k) for k, key in keys.items()}
    own = {"a": (0, 0.030), "b": (0, 0.035), "c": (0, 0.080)}  # each class screened on the whole
    screened = [Screened(m, k, queries[keys[k]], None, score, {"residual": score, "freespace": 0.0, "rank": 0.0})
                for m, (k, score) in own.items()]
    asked = []

    def refit(model, name, query, candidate, settings, seed, rank=0.0):
        asked.append((name, query.name, candidate, settings.fit.iterations))
        score = {"a": 0.033, "b": 0.020}[name]
        return Screened(name, candidate, query, None, score, {"residual": score, "freespace": 0.0, "rank": rank})

    monkeypatch.setattr(screen_module, "screen", refit)
    settings = ScreenSettings(class_refit_margin=0.01)
    scores, refits = class_scores({m: cands for m in own}, screened, queries, dict.fromkeys(own), settings, 0)
    assert asked == [("a", 0, 0, settings.class_fit.iterations), ("b", 0, 0, settings.class_fit.iterations)]
    assert scores == {"a": 0.030, "b": 0.020, "c": 0.080} and [r.model for r in refits] == ["a", "b"]
    assert settings.class_fit.iterations > settings.fit.iterations
    asked.clear()  # no other class within the margin: nothing is contended, nothing refitted
    scores, refits = class_scores({m: cands for m in own}, screened, queries, dict.fromkeys(own),
                                  replace(settings, class_refit_margin=0.004), 0)
    assert scores == {"a": 0.030, "b": 0.035, "c": 0.080} and not refits and not asked


@pytest.mark.slow
def test_a_bed_cut_in_parts_is_classed_a_bed_on_its_whole(tmp_path):
    """Held-out bed 100, cut in two by the bed's and the table's proportions: the table model
    explains the larger part better than the bed model's quick fit explains the whole, but not
    the whole; judged on the whole, with the contended wholes fitted again, it is a bed."""
    from jsrte.fit import load_models
    from jsrte.fit.query import class_shape
    from jsrte.options import FitOptions

    scan = scan_mesh(held_out("bed", 100), rng=np.random.default_rng(100))
    ply = write_scan(scan, tmp_path / "bed.ply")
    models = load_models("auto", None)
    scan_sdf = FitOptions(preset="fast").settings().scan_sdf  # as `jsrte fit`: line-of-sight free space

    def segment(model):
        return scan_candidates(ply, rng=np.random.default_rng(0), shape=class_shape(model), settings=scan_sdf)

    choice = choose_in_scan(ply, models, segment=segment)
    own_best = {name: min(s.score for s in choice.screened if s.model == name) for name in models}
    assert min(own_best, key=own_best.__getitem__) == "table"  # each class on its own best candidate
    record = choice.class_json()
    assert record["chosen"] == "bed" and "bed" in record["refitted"] and record["margin"] > 0
    seg = choice.query.info["segmentation"]
    assert "parts" in seg["candidates"][seg["chosen"]]  # the whole bed, not a part
def test_a_candidate_explained_badly_is_cut_at_its_neck():
    """Only a screened candidate scoring worse than the threshold, with a neck, is cut: its parts
    are appended as its ``parts`` (their ``parent`` it) and returned, to be screened."""
    from types import SimpleNamespace

    from jsrte.fit.screen import cut_necks
    from jsrte.scans.segment import Candidate

    def with_neck(start: int) -> Candidate:
        return Candidate(index=np.arange(start, start + 10),
                         neck=[Candidate(index=np.arange(start, start + 4)),
                               Candidate(index=np.arange(start + 4, start + 10))])

    candidates = [with_neck(0), with_neck(10), Candidate(index=np.arange(20, 30))]
    screened = [SimpleNamespace(candidate=0, score=0.08), SimpleNamespace(candidate=1, score=0.02),
                SimpleNamespace(candidate=2, score=0.09)]
    assert cut_necks(candidates, screened, 0.05) == [3, 4]
    assert candidates[0].parts == [3, 4] and not candidates[0].neck
    assert [c.parent for c in candidates[3:]] == [0, 0] and len(candidates[3].index) == 4
    assert not candidates[1].parts and candidates[1].neck  # explained well: left whole
    assert cut_necks(candidates, screened, 0.05) == []  # cut once


@pytest.mark.slow
def test_a_chair_and_a_box_one_candidate_are_cut_when_the_chair_model_explains_them_badly(tmp_path, chair_model,
                                                                                          monkeypatch):
    """A held-out chair 2-3 cm from a box, one cluster whose cut at the gap proportions refuse
    (every split refused here, and the box left in): the chair model's quick fit of the pair is
    poor, so the pair is cut at its neck and the chair alone is chosen."""
    import jsrte.scans.segment as segment_module
    from jsrte.fit.query import class_shape

    cut = segment_module._cut

    def refused(*args):
        found = cut(*args)
        return None if found is None else (found[0], found[1], False)

    monkeypatch.setattr(segment_module, "_cut", refused)
    monkeypatch.setattr(segment_module, "_peel", lambda *args: None)  # nor is the box taken out
    room, ply = chair_beside_box(held_out("chair", 106), tmp_path)

    def segment(model):
        return scan_candidates(ply, rng=np.random.default_rng(0), shape=class_shape(model))

    cands = segment(chair_model)
    labels = room.labels[cands.segmented.index]
    seg = cands.segmentation
    merged = [k for k in cands.valid() if np.mean(labels[seg.candidates[k].index] == 1) > 0.2
              and np.mean(labels[seg.candidates[k].index] == 0) > 0.2]
    assert merged and seg.candidates[merged[0]].neck and not seg.candidates[merged[0]].parts
    record = choose_in_scan(ply, {"chair": chair_model}, segment=lambda model: cands).query.info["segmentation"]
    whole = record["candidates"][merged[0]]
    assert whole["screen"]["score"] > ScreenSettings().neck_score and len(whole["parts"]) == 2
    picked = seg.candidates[record["chosen"]].index
    assert np.mean(labels[picked] == 0) > 0.9 and len(picked) > 0.7 * np.sum(labels == 0)


def _cut_ball(rng: np.random.Generator, centre: np.ndarray) -> tuple[np.ndarray, object]:
    """Points: a 1 m sphere at ``centre`` and the blob of :func:`_two_pieces` 0.2 m farther off;
    ``ScanCandidates``-like: 0 (both) cut through the sphere into 1 (its cap x < 0.2) and 2 (the
    rest of the sphere with the blob)."""
    from types import SimpleNamespace

    from jsrte.scans.segment import Candidate

    ball, blob = _two_pieces(rng, centre)
    points = np.concatenate([ball, blob + [0.2, 0.0, 0.0]])
    cap = np.flatnonzero(points[:, 0] - centre[0] < 0.2)
    rest = np.setdiff1d(np.arange(len(points)), cap)
    candidates = [Candidate(np.arange(len(points)), parts=[1, 2], summary={"rank": 0.0}),
                  Candidate(cap, parent=0, summary={"rank": 0.1}), Candidate(rest, parent=0, summary={"rank": 0.2})]
    segmented = SimpleNamespace(cloud=SimpleNamespace(points=points), index=np.arange(len(points)))
    return points, SimpleNamespace(segmentation=SimpleNamespace(candidates=candidates), segmented=segmented,
                                   query=lambda k: candidates[k].index)


@pytest.mark.parametrize("grown_score", [0.012, 0.05])
def test_a_piece_of_an_object_grows_over_the_points_its_fit_passes_through(monkeypatch, grown_score):
    """A cut through a sphere leaves its cap alone and the rest with a blob beside it. The cap's
    fit (the whole sphere) passes through the rest of the sphere, not the blob: the grown
    candidate holds the sphere, and it is chosen unless its screen scores worse than the cap's
    by more than ``grow_margin``."""
    import torch

    from analytic import SphereDecoder
    from jsrte.fit.screen import Screened, ScreenSettings, grow
    from jsrte.geometry.sim3 import Sim3
    from jsrte.model.checkpoint import DeepSdfModel
    from jsrte.result import FitResult

    screen_module = importlib.import_module("jsrte.fit.screen")
    rng = np.random.default_rng(0)
    centre = np.array([2.0, 0.5, -1.0])
    points, cands = _cut_ball(rng, centre)
    model = DeepSdfModel(SphereDecoder(), torch.zeros(1, 2), {"name": "ball"})
    result = FitResult("jsrte", Sim3(2.0, np.eye(3), centre), np.zeros(2, np.float32), None, 0.0, {})
    cap = Screened("ball", 1, None, result, 0.01, {"residual": 0.01, "freespace": 0.0, "rank": 0.1, "radius": 0.6})
    asked = []

    def screened(model, name, index, candidate, settings, seed, rank=0.0):
        asked.append((candidate, len(index), rank))
        return Screened(name, candidate, index, result, grown_score, {"residual": grown_score, "rank": rank})

    monkeypatch.setattr(screen_module, "screen", screened)
    chosen = grow(cap, cands, model, ScreenSettings(), 0)
    candidates = cands.segmentation.candidates
    assert asked == [(3, 700, 0.1)] and len(candidates) == 4
    assert np.array_equal(candidates[3].index, np.arange(700)) and candidates[3].parent == 0
    assert candidates[3].summary["grown_from"] == 1 and candidates[3].summary["screen"]["score"] == grown_score
    assert chosen.candidate == (3 if grown_score <= 0.01 + ScreenSettings().grow_margin else 1)
    whole = Screened("ball", 0, None, result, 0.01, {"residual": 0.01, "rank": 0.0, "radius": 1.0})
    assert grow(whole, cands, model, ScreenSettings(), 0) is whole and len(asked) == 1  # nothing to grow over


@pytest.mark.slow
def test_an_unknown_class_starts_every_full_fit_at_both_scales_unless_a_preset_is_named(tmp_path, short_fits):
    """One object, class unknown: the default preset is ``fast-scales`` (each full fit started at
    the height's and the bounding sphere's scale); a named preset, or a known class, keeps its own."""
    fitting = importlib.import_module("jsrte.fit")
    starts = short_fits("init_scale")  # the full fits, not the screen's quick ones
    scan = scan_mesh(held_out("table", 101), rng=np.random.default_rng(4))
    ply = write_scan(scan, tmp_path / "table.ply")
    unknown = fitting.fit(ply, model="chair,table", hypotheses=2)
    assert unknown.info["preset"] == "fast-scales" and starts and set(starts) == {"both"}
    starts.clear()
    named = fitting.fit(ply, model="chair,table", preset="fast", hypotheses=2)
    assert named.info["preset"] == "fast" and starts and set(starts) == {"height"}
    assert fitting.fit(ply, model="table", hypotheses=2).info["preset"] == "fast"


def test_every_fit_of_an_unknown_class_follows_the_arithmetic_asked_for(tmp_path, short_fits):
    """``dtype`` reaches the screen's quick fits as well as the full fit; without it the quick
    fits keep their own ("auto")."""
    fitting = importlib.import_module("jsrte.fit")
    arithmetic = short_fits("decoder_dtype", quick=True)
    ply = write_scan(scan_mesh(held_out("table", 101), rng=np.random.default_rng(4)), tmp_path / "table.ply")
    fitting.fit(ply, model="chair,table", hypotheses=2, dtype="float32")
    assert len(arithmetic) >= 3 and set(arithmetic) == {"float32"}  # two quick fits, then the full one
    arithmetic.clear()
    fitting.fit(ply, model="chair,table", hypotheses=2, preset="smoke")  # a float32 preset
    assert "auto" in arithmetic[:-1] and arithmetic[-1] == "float32"


def test_express_screens_with_the_distilled_decoders_too(tmp_path, short_fits):
    """With ``express`` every fit of an unknown class, the quick fits that choose it as well as
    the full one, searches with the model's distilled decoder; with ``fast-gn`` none does."""
    fitting = importlib.import_module("jsrte.fit")
    distilled = short_fits("distilled_search", quick=True)
    ply = write_scan(scan_mesh(held_out("table", 101), rng=np.random.default_rng(4)), tmp_path / "table.ply")
    result = fitting.fit(ply, model="chair,table", hypotheses=2, preset="express", dtype="float32")
    assert len(distilled) >= 3 and set(distilled) == {True}
    assert result.info["search_decoder"] == f"{result.info['class']['chosen']}-tiny"
    distilled.clear()
    fitting.fit(ply, model="chair,table", hypotheses=2, preset="fast-gn", dtype="float32")
    assert len(distilled) >= 3 and set(distilled) == {False}
