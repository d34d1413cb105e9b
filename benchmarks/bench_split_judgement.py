"""How many objects of a room keep a candidate of their own once a scene's splits are judged.

``python benchmarks/bench_split_judgement.py ROOMS_DIR --cache DIR [--rooms 20 --first 0 --seed 0]
[--jobs 2] [--floors 0,0.01,0.02,0.03,0.04]``

``ROOMS_DIR`` holds one folder per room, as for ``bench_segmentation.py`` (a room missing there is
drawn and written first). Each room's scan is segmented as ``jsrte fit SCAN --scene`` segments it,
and every candidate of a split (a whole and its parts) is fitted quickly by every model, as the
scene's quick fits do (about a minute and a half a room on one thread). Its screen scores, and how
far each whole's best fit and each part's own best fit lie from the part's points, are written to
``--cache/NNN.json`` once; a room found there is not fitted again. The splits are then judged
(``jsrte.fit.scene.judge_splits``) from those records for each ``explained_floor`` of ``--floors``
(``jsrte.fit.screen.ScreenSettings``; the scene's other settings as shipped), in a moment.

An object keeps a candidate of its own where a candidate the judgement leaves (not covered by a
whole or by its parts, not a box) holds at least ``--share`` of its points at ``--purity`` or
more. Printed per floor: the furniture objects with a candidate of their own; the candidates left
that are mostly one object but hold less than the share of it (a piece: often a false detection or
a second fit); those that hold too much of another object (a merge); the wholes kept that hold
two objects or more.
"""

from __future__ import annotations

import argparse
import json
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import replace
from pathlib import Path
from types import SimpleNamespace


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("rooms_dir", type=Path)
    parser.add_argument("--cache", type=Path, required=True, help="folder of each room's quick fits (NNN.json)")
    parser.add_argument("--rooms", type=int, default=20)
    parser.add_argument("--first", type=int, default=0)
    parser.add_argument("--seed", type=int, default=0, help="the rooms' seed (as jsrte experiment scenes)")
    parser.add_argument("--floors", default="0,0.01,0.02,0.03,0.04", help="explained_floor values, comma-separated")
    parser.add_argument("--share", type=float, default=0.7)
    parser.add_argument("--purity", type=float, default=0.85)
    parser.add_argument("--jobs", type=int, default=2)
    args = parser.parse_args()

    rooms = list(range(args.first, args.first + args.rooms))
    args.cache.mkdir(parents=True, exist_ok=True)
    missing = [r for r in rooms if not (args.cache / f"{r:03d}.json").exists()]
    with ProcessPoolExecutor(args.jobs) as pool:
        for room, seconds in pool.map(_record_room, [args.rooms_dir / f"{r:03d}" for r in missing], missing,
                                      [args.seed] * len(missing), [args.cache] * len(missing)):
            print(f"room {room:03d}: quick fits recorded in {seconds:.0f} s", flush=True)
    records = [json.loads((args.cache / f"{r:03d}.json").read_text()) for r in rooms]
    furniture = sum(kind != "box" for record in records for kind, _ in record["truth"].values())
    print(f"{len(rooms)} rooms, {furniture} furniture objects; --share {args.share}, --purity {args.purity}")
    print("| explained_floor | own candidate | pieces left | merges left | wholes of several objects kept |")
    print("|---|---|---|---|---|")
    for floor in (float(v) for v in args.floors.split(",")):
        counts = [0, 0, 0, 0]
        for record in records:
            left, kept = _judged(record, floor)
            counts = [a + b for a, b in zip(counts, _tally(record, left, kept, args.share, args.purity), strict=True)]
        print(f"| {floor:g} | {counts[0]} of {furniture} | {counts[1]} | {counts[2]} | {counts[3]} |")


def _record_room(room_dir: Path, room: int, seed: int, cache: Path) -> tuple[int, float]:
    """Segment room ``room`` as a scene does, fit every candidate of a split quickly by every
    model, and write the record (``cache/NNN.json``): truth, candidates (points, parent, parts,
    rejection, whether a join of clusters apart, labels held, screen scores), boxes and, per
    whole and part below it, the mean distances (m) of the whole's and the part's own best fit
    from the part's points."""
    import numpy as np
    import torch

    from jsrte.experiments.scenes import ROOM_SETTINGS, draw_room
    from jsrte.fit import load_models
    from jsrte.fit.query import scan_candidates
    from jsrte.fit.scene import SCENE_BOXES, SCENE_FIT_VEIL, SCENE_SCREEN, SCENE_SEGMENT, _screen_candidate
    from jsrte.fit.screen import part_distance
    from jsrte.model.decoder import flush_denormals
    from jsrte.options import FitOptions
    from jsrte.presets import SCENE_PRESET
    from jsrte.scans.boxes import candidate_boxes
    from jsrte.scans.scene import write_room

    flush_denormals()
    torch.set_num_threads(1)
    started = time.perf_counter()
    if not (room_dir / "labels.npy").exists():
        write_room(draw_room(room, seed=seed, settings=ROOM_SETTINGS), room_dir, seed=seed)
    truth = json.loads((room_dir / "scene.json").read_text())
    labels = np.load(room_dir / "labels.npy")
    options = FitOptions(preset=SCENE_PRESET)
    settings = options.settings()
    models = load_models("auto", None)
    screen = SCENE_SCREEN.held_to_sizes(settings.fit.size_margin).in_arithmetic(options.dtype).searched_as(settings.fit)
    cands = scan_candidates(room_dir / "scan.ply", rng=np.random.default_rng(options.seed), settings=settings.scan_sdf,
                            segment=SCENE_SEGMENT, fit_veil=SCENE_FIT_VEIL)
    candidates = cands.segmentation.candidates
    possible = cands.possible()
    boxes = candidate_boxes(cands, possible, SCENE_BOXES)
    in_split = [k for k in possible if candidates[k].parts or candidates[k].parent is not None]
    screened = dict(_screen_candidate(k, cands, models, options, screen) for k in in_split)
    fitted = {k: min(c.screened, key=lambda s: s.score) for k, c in screened.items() if not isinstance(c, str)}

    def distance(k: int, part: int) -> float:
        return part_distance(models[fitted[k].model], fitted[k], fitted[part], screen, options.seed)

    def below(k: int) -> list[int]:
        return [q for p in candidates[k].parts for q in [p, *below(p)]]

    record = {"room": room, "truth": {str(e["index"]): [e["class"], int((labels == e["index"]).sum())]
                                      for e in truth["objects"]},
              "boxes": sorted(int(k) for k in boxes), "candidates": {}, "distances": {}}
    for k, c in enumerate(candidates):
        values, counts = np.unique(labels[cands.segmented.index[c.index]], return_counts=True)
        record["candidates"][str(k)] = {
            "points": len(c.index), "parent": c.parent, "parts": list(c.parts), "rejected": c.rejected,
            "possible": k in possible, "joined_apart": bool(c.summary.get("joined_apart", False)),
            "labels": {str(v): int(n) for v, n in zip(values, counts, strict=True)},
            "scores": None if k not in fitted else {s.model: float(s.score) for s in screened[k].screened}}
    for k in fitted:
        for part in (p for p in below(k) if p in fitted):
            record["distances"][f"{k},{part}"] = {"by_whole": distance(k, part), "own": distance(part, part),
                                                  "radius": float(fitted[part].parts["radius"])}
    (cache / f"{room:03d}.json").write_text(json.dumps(record))
    return room, time.perf_counter() - started


def _judged(record: dict, floor: float) -> tuple[list[int], list[int]]:
    """The candidates a scene's judgement of ``record``'s splits leaves as objects (boxes aside),
    with ``explained_floor`` = ``floor``; and of them the wholes of a split."""
    from jsrte.fit.scene import SCENE_SCREEN, judge_splits
    from jsrte.fit.screen import Choice, Screened, distance_ratio

    settings = replace(SCENE_SCREEN, explained_floor=floor)
    entries = {int(k): v for k, v in record["candidates"].items()}
    candidates = [SimpleNamespace(index=range(e["points"]), parent=e["parent"], parts=e["parts"],
                                  rejected=e["rejected"], summary={"joined_apart": e.get("joined_apart", False)})
                  for _, e in sorted(entries.items())]
    screened = {k: Choice(None, None, [Screened(m, k, None, None, s, {}) for m, s in e["scores"].items()],
                          e["scores"]) for k, e in entries.items() if e["scores"]}
    distances = {tuple(int(v) for v in key.split(",")): d for key, d in record["distances"].items()}

    def ratio(whole: int, part: int) -> float:
        d = distances[(whole, part)]
        return distance_ratio(d["by_whole"], d["own"], d["radius"], settings)

    models = {m: None for e in entries.values() if e["scores"] for m in e["scores"]}
    covered = judge_splits(candidates, screened, models, settings, 0, boxes=set(record["boxes"]), ratio=ratio)
    left = [k for k, e in entries.items() if e["possible"] and k not in covered and k not in record["boxes"]]
    return left, [k for k in left if entries[k]["parts"]]


def _tally(record: dict, left: list[int], wholes: list[int], share: float, purity: float) -> list[int]:
    """Furniture with a candidate of its own among ``left``; pieces and merges left; ``wholes``
    holding two objects or more (each with at least ``1 - purity`` of the whole's points)."""
    truth = {int(k): v for k, v in record["truth"].items()}
    entries = {int(k): v for k, v in record["candidates"].items()}
    owned, pieces, merges, several = set(), 0, 0, 0
    for k in left:
        held = {int(v): n for v, n in entries[k]["labels"].items() if int(v) >= 0}
        points = entries[k]["points"]
        if not held:
            continue
        main = max(held, key=held.__getitem__)
        if main in truth and truth[main][0] != "box":
            if held[main] >= purity * points:
                if held[main] >= share * truth[main][1]:
                    owned.add(main)
                else:
                    pieces += 1
            else:
                merges += 1
        several += k in wholes and sum(n >= (1 - purity) * points for n in held.values()) >= 2
    return [len(owned), pieces, merges, several]


if __name__ == "__main__":
    main()
