"""Two scenes runs side by side, room by room: what a change did to the rooms both fitted.

``python benchmarks/bench_scene_diff.py BEFORE AFTER [--all]``

``BEFORE`` and ``AFTER`` are each a ``jsrte experiment scenes --out DIR`` folder or its
``objects.csv``, or a folder of such runs (one room each, ``--first R --rooms 1``): every
``objects.csv`` under it that is not inside a run's ``fits/`` or ``rooms/`` is read. Only the
rooms both hold are compared; a room in several runs of one side counts once (the last read).

Printed: for each room whose rows differ (outcome, class, flag or F@5% to 0.01; every room with
``--all``), both sides' rows of furniture (hits, misses, false detections) with F@5%, distance to
the true centre in radii and the share of the fitted surface the cameras saw through; then, per
side, the summary of ``jsrte experiment scenes`` over the shared rooms (found, false detections,
class accuracy, mean F@5%, seconds per scene); last, over the objects found by both, the mean
change of F@5% and the objects that moved most. Reads CSV only: instant.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from jsrte.atomic import read_csv_rows
from jsrte.experiments.scenes import OBJECTS_NAME, summarize

FURNITURE = ("hit", "missed", "false positive")
"""The outcomes of objects.csv that concern furniture (boxes have their own)."""


def run_rows(path: Path) -> dict[int, list[dict]]:
    """Room -> its rows, from one objects.csv, a run's folder, or a folder of runs."""
    if path.is_file():
        files = [path]
    else:
        files = sorted(p for p in path.rglob(OBJECTS_NAME) if not {"fits", "rooms"} & set(p.relative_to(path).parts))
    if not files:
        raise SystemExit(f"{path}: holds no {OBJECTS_NAME}")
    rooms: dict[int, list[dict]] = {}
    for file in files:
        by_room: dict[int, list[dict]] = {}
        for row in read_csv_rows(file):
            by_room.setdefault(int(row["room"]), []).append(row)
        rooms |= by_room
    return rooms


def _key(row: dict) -> tuple:
    """What a change of a row is judged by: outcome, classes, flag and F@5% to 0.01."""
    score = row.get("fscore")
    return (row["outcome"], str(row.get("true_index")), row.get("found_class"), row.get("flag"),
            None if score in (None, "") else round(float(score), 2))


def _line(side: str, row: dict) -> str:
    def number(name: str) -> str:
        value = row.get(name)
        return "" if value in (None, "") else f"{float(value):.2f}"

    return (f"  {side} {row['outcome']:<14} true {str(row.get('true_index')):>4} {row.get('true_class') or '':<5} "
            f"found {str(row.get('found_index')):>4} {row.get('found_class') or '':<5} {row.get('flag') or '':<8} "
            f"F {number('fscore'):>4}  off {number('distance_rel'):>4}  seen through {number('quality_seen_through')}")


def print_room_changes(before: dict[int, list[dict]], after: dict[int, list[dict]], rooms: list[int],
                       every: bool) -> None:
    """Both sides' furniture rows of each room in ``rooms`` that changed (all with ``every``)."""
    for room in rooms:
        old = [r for r in before[room] if r["outcome"] in FURNITURE]
        new = [r for r in after[room] if r["outcome"] in FURNITURE]
        if every or sorted(map(_key, old), key=str) != sorted(map(_key, new), key=str):
            print(f"room {room}: {float(before[room][0]['scene_seconds']):.0f} s -> "
                  f"{float(after[room][0]['scene_seconds']):.0f} s")
            for side, rows in (("before", old), ("after ", new)):
                for row in rows:
                    print(_line(side, row))


def print_summaries(before: dict[int, list[dict]], after: dict[int, list[dict]], rooms: list[int]) -> None:
    """The scenes summary of each side over ``rooms``."""
    print(f"\nover the {len(rooms)} shared rooms ({', '.join(map(str, rooms))}):")
    for side, runs in (("before", before), ("after ", after)):
        s = summarize([row for room in rooms for row in runs[room]])
        accuracy, mean = (_figure(s[name], digits) for name, digits in (("class_accuracy", 2), ("fscore_mean", 3)))
        print(f"  {side} found {s['hits']} of {s['true_furniture']}, {s['false_positives']} false detections, "
              f"class accuracy {accuracy}, mean F@5% {mean}, {s['seconds_per_scene']} s per scene")


def _figure(value: float | None, digits: int) -> str:
    return "-" if value is None else f"{value:.{digits}f}"


def print_paired_change(before: dict[int, list[dict]], after: dict[int, list[dict]], rooms: list[int],
                        shown: int = 4) -> None:
    """Mean change of F@5% over the true objects found on both sides, and the largest moves."""
    def hits(runs: dict[int, list[dict]]) -> dict[tuple[int, str], dict]:
        return {(room, r["true_index"]): r for room in rooms for r in runs[room] if r["outcome"] == "hit"}

    old, new = hits(before), hits(after)
    moves = sorted((float(new[k]["fscore"]) - float(old[k]["fscore"]), k) for k in old.keys() & new.keys())
    if not moves:
        print("\nno object found on both sides")
        return
    print(f"\n{len(moves)} objects found on both sides: F@5% {sum(m for m, _ in moves) / len(moves):+.4f} on average")
    extremes = moves if len(moves) <= 2 * shown else moves[:shown] + moves[-shown:]
    for move, (room, index) in extremes:
        print(f"  {move:+.3f}  room {room} object {index} ({old[room, index]['true_class']}): "
              f"{float(old[room, index]['fscore']):.3f} -> {float(new[room, index]['fscore']):.3f}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("before", type=Path)
    parser.add_argument("after", type=Path)
    parser.add_argument("--all", action="store_true", help="print every shared room, changed or not")
    args = parser.parse_args()
    before, after = run_rows(args.before), run_rows(args.after)
    rooms = sorted(before.keys() & after.keys())
    if not rooms:
        raise SystemExit(f"{args.before} and {args.after} share no room")
    print_room_changes(before, after, rooms, args.all)
    print_summaries(before, after, rooms)
    print_paired_change(before, after, rooms)


if __name__ == "__main__":
    main()
