"""Fuzz every reader with many damaged files and count the outcomes per format:
``PYTHONPATH=src python benchmarks/bench_fuzz.py --examples 300``.

The cases are those of ``tests/test_fuzz_readers.py`` (``tests/fuzz_cases.py``): a valid file of
each format, cut, flipped, grown or shrunk, or with a text token replaced. Each ends as a sane
result, a clean error (one ``JsrteError`` line), or a failure: any other exception, a hang, or a
result that fails its checks.
"""

from __future__ import annotations

import argparse
import sys
import time
from collections import Counter
from pathlib import Path

from hypothesis import HealthCheck, given, settings

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

from fuzz_cases import READERS, mutate, mutations, original_bytes, run_case  # noqa: E402


def fuzz(fmt: str, examples: int) -> tuple[Counter, list[str]]:
    counts: Counter[str] = Counter()
    failures: list[str] = []
    original = original_bytes(fmt)

    @settings(max_examples=examples, deadline=None, database=None,
              suppress_health_check=list(HealthCheck))
    @given(mutations(fmt))
    def case(edits: list) -> None:
        try:
            counts[run_case(fmt, mutate(original, edits))] += 1
        except AssertionError as exc:
            counts["failure"] += 1
            failures.append(str(exc)[:300])

    case()
    return counts, failures


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--examples", type=int, default=300, help="damaged files per format")
    parser.add_argument("--formats", default=",".join(sorted(READERS)), help="formats, comma-separated")
    args = parser.parse_args()
    print("| format | cases | clean error | result | failure (traceback, hang, wrong result) | seconds |")
    print("|---|---|---|---|---|---|")
    total: Counter[str] = Counter()
    for fmt in args.formats.split(","):
        started = time.perf_counter()
        counts, failures = fuzz(fmt, args.examples)
        total.update(counts)
        n = sum(counts.values())
        print(f"| {fmt} | {n} | {counts['error']} | {counts['result']} | {counts['failure']} | "
              f"{time.perf_counter() - started:.0f} |", flush=True)
        for failure in failures[:3]:
            print(f"    {failure}", file=sys.stderr)
    print(f"| all | {sum(total.values())} | {total['error']} | {total['result']} | {total['failure']} | |")


if __name__ == "__main__":
    main()
