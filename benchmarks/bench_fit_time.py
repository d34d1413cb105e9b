"""Where a whole fit spends its time: seconds and decoder evaluations per stage, per preset.

Each scan is fitted in a fresh Python process, as ``jsrte fit SCAN --out DIR`` would: the
stages (load, floor and cleaning, normals, query samples, yaw screening where the preset
screens, solve, selection, meshing, quality, outputs) are timed by the library's stage profile
(jsrte.timing), decoder evaluations are counted by the decoder itself, and "start-up" is the
rest of the process's wall time (interpreter and imports). Prints a markdown table with the
mean over the scans of each stage, side by side for every preset, and the whole-process
times per scan. Where a scan's JSON sidecar names its true mesh and pose (scans written by
``jsrte scan`` and ``jsrte experiment scans``), each fit's F@5% against the complete true shape
is scored too (outside the timed process), as ``jsrte experiment scans`` scores it.

    PYTHONPATH=src .venv/bin/python benchmarks/bench_fit_time.py SCAN.ply ... \\
        [--preset fast,paper] [--model chair] [--threads 2] [--out docs/speed_table.md]

A preset may name the decoder arithmetic after a colon (``fast:float32``, as ``jsrte fit
--dtype``): ``--preset fast:float32,fast`` compares float32 with the preset's own.
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

STAGES = ("start-up", "load", "floor and cleaning", "normals", "query samples", "yaw screening", "solve",
          "selection", "meshing", "quality", "outputs", "other")
"""Rows of the table, in pipeline order ("other": time inside the fit outside every named stage)."""


def fit_one(scan: Path, *, preset: str, model: str, seed: int, threads: int, device: str = "cpu") -> dict:
    """In this process: fit ``scan`` and write its outputs as ``jsrte fit`` does; the stage profile."""
    import torch

    from jsrte.fit import fit
    from jsrte.fit.outputs import write_fit_outputs
    from jsrte.scans.io import load_scan
    from jsrte.timing import profiling, stage

    torch.set_num_threads(threads)
    with profiling() as profile, tempfile.TemporaryDirectory() as folder:
        name, _, dtype = preset.partition(":")
        result = fit(scan, model=model, preset=name, seed=seed, dtype=dtype or None, device=device)
        with stage("outputs"):
            write_fit_outputs(result, Path(folder), query_points=load_scan(scan).points,
                              up=result.info.get("up"), extra={"input": str(scan)})
    started, cpu_started = time.perf_counter(), time.process_time()
    fscore = truth_fscore(scan, result, seed)
    scoring = {"seconds": time.perf_counter() - started, "cpu_seconds": time.process_time() - cpu_started}
    return {"stages": profile.as_dict(), "winner_loss": result.loss, "scale": result.transform.s,
            "fscore": fscore, "scoring": scoring}


def truth_fscore(scan: Path, result: object, seed: int) -> float | None:
    """F@5% of ``result`` against the scan's complete true shape (None without one in its sidecar)."""
    import numpy as np

    from jsrte.experiments.truth import score_against_truth, truth_of
    from jsrte.geometry.mesh import load_mesh
    from jsrte.scans.io import read_scan_info

    info = read_scan_info(scan)
    mesh_name = info.raw.get("mesh") if info is not None else None
    if not mesh_name:
        return None
    mesh_path = Path(mesh_name) if Path(mesh_name).is_absolute() else scan.parent / mesh_name
    if not mesh_path.is_file():
        mesh_path = scan.parent / Path(mesh_name).name
    truth = truth_of(load_mesh(mesh_path), info.scan_from_mesh)
    return float(score_against_truth(result, truth, rng=np.random.default_rng(seed))["fscore"])


def run_fresh(scan: Path, *, preset: str, model: str, seed: int, threads: int, device: str = "cpu") -> dict:
    """Fit ``scan`` in a new Python process; its profile plus "start-up" (wall time not in any stage)."""
    command = [sys.executable, __file__, "--one", str(scan), "--preset", preset, "--model", model,
               "--seed", str(seed), "--threads", str(threads), "--device", device]
    started, cpu_started = time.perf_counter(), _children_cpu()
    proc = subprocess.run(command, capture_output=True, text=True)
    wall, cpu = time.perf_counter() - started, _children_cpu() - cpu_started
    if proc.returncode != 0:
        raise SystemExit(f"fit of {scan} failed:\n{proc.stderr[-2000:]}")
    report = json.loads(proc.stdout.strip().splitlines()[-1])
    wall -= report["scoring"]["seconds"]  # scoring against the truth is no part of a user's fit
    cpu -= report["scoring"]["cpu_seconds"]
    inside = sum(s["seconds"] for s in report["stages"].values())
    cpu_inside = sum(s["cpu_seconds"] for s in report["stages"].values())
    report["stages"]["start-up"] = {"seconds": round(wall - inside, 4), "cpu_seconds": round(cpu - cpu_inside, 4),
                                    "evaluations": 0}
    report["wall"], report["cpu"] = wall, cpu
    return report


def _children_cpu() -> float:
    """User + system CPU seconds of this process's finished children."""
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def table(reports: dict[str, list[dict]], scans: list[Path]) -> str:
    """Markdown: mean seconds and evaluations per stage for each preset, then per-scan totals."""
    presets = list(reports)
    n = len(scans)
    seen = {name for rs in reports.values() for r in rs for name in r["stages"]}
    stages = [s for s in STAGES if s in seen] + sorted(seen - set(STAGES))
    head = "| stage | " + " | ".join(f"{p}: s | {p}: CPU s | {p}: evaluations" for p in presets) + " |"
    lines = [f"Mean over {n} scan(s), each fitted in a fresh process (s: wall clock; CPU s: every "
             "thread's CPU time).", "", head, "|---|" + "---:|---:|---:|" * len(presets)]
    for name in stages:
        cells = []
        for p in presets:
            mean = {key: sum(r["stages"].get(name, {}).get(key, 0) for r in reports[p]) / n
                    for key in ("seconds", "cpu_seconds", "evaluations")}
            cells.append(f"{mean['seconds']:.2f} | {mean['cpu_seconds']:.2f} | {mean['evaluations']:,.0f}")
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    totals = []
    for p in presets:
        wall = sum(r["wall"] for r in reports[p]) / n
        cpu = sum(r["cpu"] for r in reports[p]) / n
        evaluations = sum(v["evaluations"] for r in reports[p] for v in r["stages"].values()) / n
        totals.append(f"**{wall:.2f}** | **{cpu:.2f}** | **{evaluations:,.0f}**")
    lines.append("| **whole process** | " + " | ".join(totals) + " |")
    scored = all(r.get("fscore") is not None for rs in reports.values() for r in rs)
    if scored:
        lines += ["", _accuracy(reports)]
    f_head = " | ".join(f"{p}: F@5%" for p in presets) if scored else ""
    lines += ["", "| scan | " + " | ".join(f"{p}: whole process s | {p}: CPU s" for p in presets)
              + (f" | {f_head}" if scored else "") + " |",
              "|---|" + "---:|---:|" * len(presets) + ("---:|" * len(presets) if scored else "")]
    for i, scan in enumerate(scans):
        cells = " | ".join(f"{reports[p][i]['wall']:.2f} | {reports[p][i]['cpu']:.2f}" for p in presets)
        if scored:
            cells += " | " + " | ".join(f"{reports[p][i]['fscore']:.3f}" for p in presets)
        lines.append(f"| {scan.name} | {cells} |")
    return "\n".join(lines) + "\n"


def _accuracy(reports: dict[str, list[dict]]) -> str:
    """Markdown: mean and median F@5% per preset, and each preset's worst per-scan difference
    from the first preset's."""
    import statistics

    presets = list(reports)
    first = [r["fscore"] for r in reports[presets[0]]]
    lines = ["| F@5% vs complete true shape | " + " | ".join(presets) + " |", "|---|" + "---:|" * len(presets)]
    for label, fn in (("mean", statistics.fmean), ("median", statistics.median)):
        lines.append(f"| {label} | " + " | ".join(f"{fn([r['fscore'] for r in reports[p]]):.3f}" for p in presets)
                     + " |")
    worst = [min(r["fscore"] - f for r, f in zip(reports[p], first, strict=True)) for p in presets]
    lines.append(f"| worst scan − {presets[0]} | " + " | ".join(f"{w:+.3f}" for w in worst) + " |")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("scans", type=Path, nargs="+", help="scans to fit (PLY with JSON sidecar, PCD, ...)")
    parser.add_argument("--preset", default="fast", help="preset(s), comma-separated: side-by-side columns; "
                                                          "PRESET:DTYPE sets the decoder arithmetic (fast:float32)")
    parser.add_argument("--model", default="chair", help="shipped model name or model file")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--threads", type=int, default=2, help="torch threads (the machine's 2 cores)")
    parser.add_argument("--device", default="cpu", help="where the decoder runs (cuda: a GPU that PyTorch sees; "
                                                         "the stages' seconds then end when their kernels are queued)")
    parser.add_argument("--out", type=Path, help="also write the table to this markdown file")
    parser.add_argument("--one", action="store_true", help=argparse.SUPPRESS)  # the child process
    args = parser.parse_args()
    if args.one:
        print(json.dumps(fit_one(args.scans[0], preset=args.preset, model=args.model, seed=args.seed,
                                 threads=args.threads, device=args.device)))
        return
    for scan in args.scans:
        if not scan.is_file():
            raise SystemExit(f"{scan}: no such file")
    reports: dict[str, list[dict]] = {}
    for preset in filter(None, args.preset.split(",")):
        reports[preset] = []
        for scan in args.scans:
            report = run_fresh(scan, preset=preset, model=args.model, seed=args.seed, threads=args.threads,
                               device=args.device)
            reports[preset].append(report)
            print(f"{preset} {scan.name}: {report['wall']:.2f} s", file=sys.stderr, flush=True)
    text = table(reports, args.scans)
    print(text)
    if args.out is not None:
        args.out.write_text(text)


if __name__ == "__main__":
    main()
