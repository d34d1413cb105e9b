"""How many objects of a room the scene's segmentation gives a candidate of their own, before any fit.

``python benchmarks/bench_segmentation.py ROOMS_DIR [--rooms 20 --first 0 --seed 0] [--jobs 2]
[--settings cut_max_without_class=0.012,split_depth=3,join_apart_m=none]``

``ROOMS_DIR`` holds one folder per room (``000``, ``001``, ...: ``scan.ply``, ``scene.json``,
``labels.npy``), as ``jsrte experiment scenes --out DIR`` leaves in ``DIR/rooms``; a room missing
there is drawn and written first (``jsrte.experiments.scenes.draw_room``, the experiment's
defaults). Each room's scan is segmented as ``jsrte fit SCAN --scene`` segments it
(``jsrte.fit.scene.SCENE_SEGMENT``, with ``--settings`` changed), and every true piece of
furniture (boxes aside) is matched with the candidate holding most of it at the highest purity
(share of the object's points in the candidate times the candidate's share of points that are
the object's). An object is:

- ``own``: that candidate holds at least ``--share`` of its points at ``--purity`` or more;
- ``merged``: most of that candidate is another object's (a chair pushed against a bed);
- ``pieces``: the candidate is mostly the object's but holds less than ``--share`` of it (cut
  apart, or the rest seen as a scrap);
- ``impure``: the candidate holds enough of it but too much of something else;
- ``unseen``: no candidate holds any of its points (or the room's segmentation failed: its
  error is printed).

An object without a candidate of its own is seldom found by the scene's fits (on the tuning
rooms 100-129: 71 of the 87 objects with one were found, 9 of the 24 without), so the share
tells in seconds per room, not minutes, where a scene's detection recall stands. Printed: the counts
overall and per class, the candidates per room (each costs a quick fit by every model) and the
seconds per room. ``--without-cameras`` segments each scan as a scan from another tool: without
its cameras (the JSON sidecar), its up axis given as ``--up`` would give it.

Also printed: the candidates the scene would report as boxes (``jsrte.scans.boxes.candidate_boxes``,
before any fit), each counted as the true box or piece of furniture most of its points are: how
many of the rooms' boxes are reported, and how many candidates of furniture are taken for one.

``--regroup`` counts more candidates, not made by the segmentation: where a whole was cut in two
(A, B) and part A cut again (A1, A2), the unions B + A1 and B + A2 where they touch (points within
``join_m`` of each other): what undoing a first cut through one object (a bed cut across, a chair
left with one half) would give, and how many candidates more it would cost.
"""

from __future__ import annotations

import argparse
import json
import time
from collections import Counter
from concurrent.futures import ProcessPoolExecutor
from dataclasses import replace
from pathlib import Path

import numpy as np

OUTCOMES = ("own", "merged", "pieces", "impure", "unseen")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("rooms_dir", type=Path)
    parser.add_argument("--rooms", type=int, default=20)
    parser.add_argument("--first", type=int, default=0)
    parser.add_argument("--seed", type=int, default=0, help="the rooms' seed (as jsrte experiment scenes)")
    parser.add_argument("--share", type=float, default=0.7)
    parser.add_argument("--purity", type=float, default=0.85)
    parser.add_argument("--settings", default="", help="SegmentSettings changes: name=value,...")
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--without-cameras", action="store_true",
                        help="segment each scan without its cameras (JSON sidecar), its up axis given")
    parser.add_argument("--regroup", action="store_true",
                        help="also count the unions of a cut's part with its sibling's touching parts")
    args = parser.parse_args()

    rooms = range(args.first, args.first + args.rooms)
    jobs = [(args.rooms_dir / f"{r:03d}", r, args.seed, args.settings, args.share, args.purity,
             args.without_cameras, args.regroup) for r in rooms]
    with ProcessPoolExecutor(args.jobs) as pool:
        results = list(pool.map(_room, *zip(*jobs, strict=True)))
    rows = [row for room_rows, _, _ in results for row in room_rows if row["class"] != "box"]
    boxes = [row for room_rows, _, _ in results for row in room_rows if row["class"] == "box"]
    for room, error in sorted({(row["room"], row["error"]) for row in rows if "error" in row}):
        print(f"room {room}: {error}")
    total = Counter(row["outcome"] for row in rows)
    print(f"{len(rooms)} rooms, {len(rows)} furniture objects, settings: {args.settings or 'as shipped'}"
          + (", without cameras (up axis given)" if args.without_cameras else ""))
    print("outcome: " + ", ".join(f"{o} {total[o]} ({total[o] / max(len(rows), 1):.2f})" for o in OUTCOMES))
    for kind in sorted({row["class"] for row in rows}):
        counts = Counter(row["outcome"] for row in rows if row["class"] == kind)
        print(f"  {kind}: " + ", ".join(f"{o} {counts[o]}" for o in OUTCOMES if counts[o]))
    found = sum(row["reported_as_box"] > 0 for row in boxes)
    taken = sum(row.get("reported_as_box", 0) for row in rows)
    print(f"boxes reported: {found} of {len(boxes)} boxes; candidates of furniture reported as a box: {taken}")
    print(f"candidates per room {sum(n for _, n, _ in results) / len(results):.1f}, "
          f"seconds per room {sum(s for _, _, s in results) / len(results):.1f} (one thread, {args.jobs} at once)")


def _room(room_dir: Path, room: int, seed: int, changes: str, share: float, purity: float,
          without_cameras: bool = False, regroup: bool = False) -> tuple[list[dict], int, float]:
    """The furniture of one room, each with its outcome (:data:`OUTCOMES`); the room's candidates
    the scene would screen (``regroup``: with the unions :func:`_regrouped` adds); the seconds
    its segmentation took."""
    import shutil
    import tempfile

    import torch

    from jsrte.errors import JsrteError
    from jsrte.experiments.scenes import ROOM_SETTINGS, draw_room
    from jsrte.fit.query import scan_candidates
    from jsrte.fit.scene import SCENE_SEGMENT
    from jsrte.scans.boxes import candidate_boxes
    from jsrte.scans.scene import write_room

    torch.set_num_threads(1)
    if not (room_dir / "labels.npy").exists():
        write_room(draw_room(room, seed=seed, settings=ROOM_SETTINGS), room_dir, seed=seed)
    truth = json.loads((room_dir / "scene.json").read_text())
    labels = np.load(room_dir / "labels.npy")
    started = time.perf_counter()
    try:
        with tempfile.TemporaryDirectory() as folder:
            scan, up = room_dir / "scan.ply", None
            if without_cameras:  # the scan alone, as another tool writes it, and its up axis
                scan, up = Path(shutil.copy(scan, folder)), json.loads((room_dir / "scan.json").read_text())["up"]
            cands = scan_candidates(scan, rng=np.random.default_rng(0), up=up,
                                    segment=replace(SCENE_SEGMENT, **_settings(changes)))
    except JsrteError as exc:  # e.g. no floor: every object unseen
        return [{"room": room, "class": entry["class"], "outcome": "unseen", "error": str(exc),
                 "reported_as_box": 0} for entry in truth["objects"]], 0, time.perf_counter() - started
    seconds = time.perf_counter() - started
    segmented = cands.segmented
    if len(segmented.cloud.points) != len(labels):
        raise SystemExit(f"{room_dir}: labels.npy has {len(labels)} labels for {len(segmented.cloud.points)} points")
    def objects_held(index: np.ndarray) -> dict[int, int]:
        values, counts = np.unique(labels[segmented.index[index]], return_counts=True)
        return dict(zip(values.tolist(), counts.tolist(), strict=True))

    held = [objects_held(segmented.segmentation.candidates[k].index) for k in cands.possible()]
    as_box = Counter()  # object index -> candidates reported as a box that are mostly it
    possible = cands.possible()
    for k in candidate_boxes(cands, possible):
        counts = held[possible.index(k)]
        as_box[max(counts, key=counts.__getitem__)] += 1
    if regroup:
        settings = replace(SCENE_SEGMENT, **_settings(changes))
        held += [objects_held(index) for index in _regrouped(segmented.segmentation.candidates,
                                                             np.asarray(segmented.cloud.points), settings.join_m)]
    rows = [{"room": room, "class": entry["class"], "reported_as_box": as_box[entry["index"]],
             "outcome": _outcome(entry["index"], int((labels == entry["index"]).sum()), held, share, purity)}
            for entry in truth["objects"]]
    return rows, len(held), seconds


def _regrouped(candidates: list, points: np.ndarray, touch_m: float) -> list[np.ndarray]:
    """The point indices of B + Ai for every candidate not rejected cut in two (A, B) whose part A
    was cut again (into A1, A2), where B and Ai have points within ``touch_m`` (metres) of each
    other; ``points`` (n, 3) the segmented cloud's."""
    from pykdtree.kdtree import KDTree

    points = np.ascontiguousarray(points, dtype=np.float64)
    unions = []
    for whole in candidates:
        if whole.rejected or len(whole.parts) != 2:
            continue
        for cut_again, other in (whole.parts, whole.parts[::-1]):
            near_other = KDTree(points[candidates[other].index])
            for piece in candidates[cut_again].parts:
                index = candidates[piece].index
                gaps, _ = near_other.query(points[index], k=1)
                if gaps.min() <= touch_m:
                    unions.append(np.concatenate([candidates[other].index, index]))
    return unions


def _outcome(index: int, total: int, held: list[dict[int, int]], share: float, purity: float) -> str:
    """The outcome of object ``index`` (``total`` scan points) among candidates ``held`` (each:
    object index -> its points in the candidate)."""
    def weight(counts: dict[int, int]) -> float:
        return counts.get(index, 0) / max(total, 1) * counts.get(index, 0) / sum(counts.values())

    best = max(held, key=weight, default=None)
    if best is None or not best.get(index):
        return "unseen"
    mine = best[index]
    if max(best, key=best.__getitem__) != index:
        return "merged"
    if mine < share * total:
        return "pieces"
    return "own" if mine >= purity * sum(best.values()) else "impure"


def _settings(text: str) -> dict[str, float | int | None]:
    """``name=value,...`` as SegmentSettings changes (numbers, or ``none`` for None: off)."""
    changes: dict[str, float | int | None] = {}
    for item in filter(None, text.split(",")):
        name, value = (part.strip() for part in item.split("="))
        changes[name] = None if value.lower() == "none" else float(value) if "." in value else int(value)
    return changes


if __name__ == "__main__":
    main()
