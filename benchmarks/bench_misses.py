"""Where a scenes experiment lost its objects: for every piece of furniture it missed, the
candidates that hold its points and what the scene did with each; for every false detection,
whose points its candidate holds.

``python benchmarks/bench_misses.py OUT_DIR [--rooms 0,3,17]``

``OUT_DIR`` is the folder of a ``jsrte experiment scenes --out OUT_DIR`` run: its ``objects.csv``
(which objects were missed, which found objects match none), ``rooms/NNN/`` (each room's scan,
truth and per-point labels) and ``fits/NNN/scene.json`` (what the scene did with each
candidate). Each listed room's scan is segmented again as the scene segmented it
(``jsrte.fit.scene.SCENE_SEGMENT``, the experiment's defaults: a scene's segmentation is the same
from run to run), so candidate numbers are scene.json's. Per missed object, each candidate that
holds a fifth or more of its points, or is mostly it, is printed with its points, the share of
the object it holds and its purity, its place in the split tree, and its fate: fitted (status,
class, flag, reason), covered by a whole or by parts (the reason), or skipped (too big, flat,
...). Labels: the object's index in the room's truth; -1 floor, -2 walls, -3 mixed pixels between
surfaces (``jsrte.scans.scene``). Takes a few seconds a room.
"""

from __future__ import annotations

import argparse
import csv
import json
from collections import defaultdict
from pathlib import Path

import numpy as np

from jsrte.fit.query import scan_candidates
from jsrte.fit.scene import SCENE_SEGMENT
from jsrte.scans.segment import Candidate


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out_dir", type=Path)
    parser.add_argument("--rooms", default="", help="the rooms to look at (default: every room with a miss)")
    args = parser.parse_args()
    rows = list(csv.DictReader((args.out_dir / "objects.csv").open()))
    lost = defaultdict(list)
    for row in rows:
        if row["outcome"] in ("missed", "false positive"):
            lost[int(row["room"])].append(row)
    rooms = [int(r) for r in args.rooms.split(",")] if args.rooms else sorted(lost)
    for room in rooms:
        _room(args.out_dir, room, lost[room])


def _room(out_dir: Path, room: int, lost: list[dict]) -> None:
    """Print what became of room ``room``'s missed objects and false detections ``lost`` (rows)."""
    room_dir = out_dir / "rooms" / f"{room:03d}"
    truth = json.loads((room_dir / "scene.json").read_text())
    labels = np.load(room_dir / "labels.npy")
    scene = json.loads((out_dir / "fits" / f"{room:03d}" / "scene.json").read_text())
    cands = scan_candidates(room_dir / "scan.ply", rng=np.random.default_rng(0), segment=SCENE_SEGMENT)
    segmented = cands.segmented
    held = [labels[segmented.index[c.index]] for c in segmented.segmentation.candidates]
    fates = _fates(scene)
    print(f"room {room}: " + ", ".join(f"{o['index']} {o['class']}" for o in truth["objects"]))
    for row in lost:
        if row["outcome"] == "missed":
            index = int(row["true_index"])
            total = int((labels == index).sum())
            print(f"  missed {index} ({row['true_class']}, {total} points)")
            for k, points in enumerate(held):
                mine = int((points == index).sum())
                if mine >= 0.2 * total or mine > 0.5 * len(points):
                    print(f"    {_describe(k, points, segmented.segmentation.candidates[k])}: "
                          f"{mine / total:.2f} of it, {mine / len(points):.2f} pure -> {fates.get(k, 'not screened')}")
        else:
            found = next(o for o in scene["objects"] if o["index"] == int(row["found_index"]))
            k = found["candidate"]
            print(f"  false detection {found['index']} ({found['class']}, {row['flag']}): "
                  f"{_describe(k, held[k], segmented.segmentation.candidates[k])}")


def _fates(scene: dict) -> dict[int, str]:
    """Candidate position -> what the scene did with it (scene.json's objects, covered, skipped)."""
    fates = {}
    for o in scene["objects"]:
        fates[o["candidate"]] = " ".join(str(v) for v in (o["status"], o["class"], o.get("flag") or "",
                                                           o.get("reason") or "") if v)
    for entry in scene["covered"]:
        fates[entry["candidate"]] = f"covered: {entry['reason']}"
    for entry in scene["skipped"]:
        fates[entry["candidate"]] = f"skipped: {entry['reason']}"
    return fates


def _describe(k: int, points: np.ndarray, candidate: Candidate) -> str:
    """Candidate ``k``: its points (their (m,) true labels) by label, its parent and parts."""
    values, counts = np.unique(points, return_counts=True)
    by_label = ", ".join(f"{v}: {c}" for v, c in zip(values.tolist(), counts.tolist(), strict=True))
    tree = "".join([f", part of {candidate.parent}" if candidate.parent is not None else "",
                    f", parts {candidate.parts}" if candidate.parts else ""])
    return f"candidate {k} ({len(points)} points: {by_label}{tree})"


if __name__ == "__main__":
    main()
