"""Split wholes fitted in full: for every candidate with parts that a scenes run judged to hold
several objects and that lies in no found object's candidate, a part of which stands for no
object found and flagged ``ok``, the whole's full fit as the scene makes it and whether it stands
in the parts' stead (``jsrte.fit.scene.whole_turned_down``), with its F@5% against the true object
most of its points are.

``python benchmarks/bench_split_wholes.py ROOMS_DIR OBJECTS_CSV [--first 100 --rooms 70]``

``ROOMS_DIR`` holds the rooms (``NNN/scan.ply``, ``labels.npy``) of a ``jsrte experiment scenes``
run of seed 0 and ``OBJECTS_CSV`` its rows, from a build without this step. The scene's
judgement is not replayed: a whole is taken as split where no found object has its point count,
and an object found stands for the candidate of its point count. The pieces' fits count
``quality_inlier_share`` times their points; the check for a second fit of another object is
left out. One full fit per whole looked at (19-215 s on one thread).
"""

from __future__ import annotations

import argparse
import csv
import time
from collections import defaultdict
from pathlib import Path

import numpy as np
import torch

from jsrte.experiments.scenes import _found_centre, draw_room, true_objects
from jsrte.experiments.truth import score_against_truth, truth_of
from jsrte.fit import load_models
from jsrte.fit.query import scan_candidates
from jsrte.fit.scene import (
    SCENE_BOXES,
    SCENE_FIT_VEIL,
    SCENE_FLOAT32_RETRY,
    SCENE_SCREEN,
    SCENE_SEGMENT,
    CameraViews,
    SceneObject,
    _screen_candidate,
    candidate_boxes,
    fit_whole_checked,
    whole_turned_down,
)
from jsrte.options import FitOptions
from jsrte.presets import SCENE_PRESET

ONE_OBJECT = 0.9
"""A whole holds one object when that object has this share of its labelled points."""


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("rooms_dir", type=Path)
    parser.add_argument("objects_csv", type=Path)
    parser.add_argument("--first", type=int, default=0)
    parser.add_argument("--rooms", type=int, default=20)
    args = parser.parse_args()
    torch.set_num_threads(1)
    rows = defaultdict(list)
    for row in csv.DictReader(args.objects_csv.open()):
        rows[int(row["room"])].append(row)
    options = FitOptions(preset=SCENE_PRESET, float32_retry=SCENE_FLOAT32_RETRY)
    models = load_models("auto", options.device)
    settings = options.settings()
    screen = SCENE_SCREEN.held_to_sizes(settings.fit.size_margin).in_arithmetic(options.dtype).searched_as(settings.fit)
    tally = defaultdict(int)
    for room in range(args.first, args.first + args.rooms):
        room_dir = args.rooms_dir / f"{room:03d}"
        if room_dir.is_dir() and rows[room]:
            for verdict in _room(room, room_dir, rows[room], models, options, screen):
                tally[verdict] += 1
    print("wholes: " + ", ".join(f"{k} {v}" for k, v in sorted(tally.items())))


def _room(room: int, room_dir: Path, rows: list[dict], models: dict, options: FitOptions, screen: object) -> list[str]:
    """Print each whole of ``room`` the step looks at; return a verdict per whole."""
    labels = np.load(room_dir / "labels.npy")
    settings = options.settings()
    cands = scan_candidates(room_dir / "scan.ply", rng=np.random.default_rng(options.seed), settings=settings.scan_sdf,
                            segment=SCENE_SEGMENT, units_check=options.units_check, fit_veil=SCENE_FIT_VEIL)
    segmented, candidates = cands.segmented, cands.segmentation.candidates
    boxes = candidate_boxes(cands, cands.possible(), SCENE_BOXES)
    views = CameraViews.of_scan(segmented.cloud.points, segmented.cloud.view, segmented.viewpoints)
    cloud = np.asarray(segmented.cloud.points, float)
    by_points = defaultdict(list)
    for row in rows:
        if row["points"]:
            by_points[int(row["points"])].append(row)

    def subtree(k: int) -> list[int]:
        return [k] + [q for p in candidates[k].parts for q in subtree(p)]

    def found_in(k: int) -> list[dict]:
        return [r for q in subtree(k) for r in by_points[len(candidates[q].index)]]

    found = [q for q, c in enumerate(candidates)
             if any(r["outcome"] in ("hit", "false positive") for r in by_points[len(c.index)])]

    def inside_found(k: int) -> bool:
        return any(k in subtree(q)[1:] for q in found)

    drawn = draw_room(room, seed=options.seed)
    truth = {t.index: t for t in true_objects(drawn)}
    verdicts = []
    for k, c in enumerate(candidates):
        if (not c.parts or by_points[len(c.index)] or inside_found(k)
                or any(q in boxes for q in subtree(k))
                or all(any(r["flag"] == "ok" for r in found_in(p)) for p in c.parts)):
            continue
        whole = SceneObject(0, k, cloud[segmented.index[c.index]], views=views,
                            choice=_screen_candidate(k, cands, models, options, screen)[1])
        started = time.perf_counter()
        fit_whole_checked(whole, cands, models, options, screen)
        seconds = time.perf_counter() - started
        pieces = found_in(k)
        why = whole_turned_down(whole, [cloud[segmented.index[candidates[p].index]] for p in c.parts],
                                round(sum(float(r["quality_inlier_share"]) * int(r["points"]) for r in pieces)),
                                [r["flag"] for r in pieces], models)
        stands = not why
        held = labels[segmented.index[c.index]]
        values, counts = np.unique(held[held >= 0], return_counts=True)
        top = int(values[np.argmax(counts)])
        one = counts.max() >= ONE_OBJECT * counts.sum()
        verdicts.append(f"{'stands' if stands else 'turned down'} ({'one object' if one else 'several'})")
        print(f"room {room} whole {k} ({len(c.index)} points, {'one object' if one else 'several objects'}): "
              f"{whole.model} {whole.status} {'' if whole.result is None else whole.result.flag} "
              f"in {seconds:.0f} s -> {'stands' if stands else 'turned down: ' + why}; "
              f"{_against_truth(whole, drawn, truth[top])}; pieces: "
              + ", ".join(f"{r['found_class']} {r['flag']} {r['outcome']} F {r['fscore'] or '-'}" for r in pieces),
              flush=True)
    return verdicts


def _against_truth(whole: SceneObject, drawn: object, true: object) -> str:
    """The whole's fit against the true object ``true``: class, centre distance over radius, F@5%."""
    if whole.result is None:
        return f"true {true.kind}: no fit"
    off = np.linalg.norm(_found_centre(whole) - np.asarray(true.centre)) / true.radius
    if whole.model != true.kind:
        return f"true {true.kind}, {off:.2f} radii off"
    placed = drawn.objects[true.index]
    f = score_against_truth(whole.result, truth_of(placed.mesh, placed.scan_from_mesh), rng=np.random.default_rng(0))
    return f"true {true.kind}, {off:.2f} radii off, F@5% {f['fscore']:.2f}"


if __name__ == "__main__":
    main()
