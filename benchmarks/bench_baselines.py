"""Time the four baselines: database preparation once, then per query, on a procedural chair set.

Usage (from the repository root; run it niced when the machine is busy):

    nice -n 19 .venv/bin/python benchmarks/bench_baselines.py --shapes 100 --queries 5

The database is the first ``--shapes`` training chairs (``TRAIN_SET_SEED``); the queries are
virtual scans (``jsrte scan`` defaults: 3 views, Kinect-like noise, a floor) of held-out chairs
(``EVAL_SET_SEED``), prepared as ``jsrte baseline`` prepares them. Caches go to a fresh
temporary folder, so preparation is timed cold. Prints a markdown table (median seconds per
query) and writes it as JSON with ``--json``.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--shapes", type=int, default=100)
    parser.add_argument("--queries", type=int, default=5)
    parser.add_argument("--methods", default="harris3d-shot,ourcvfh-icp,pointnet-icp,fpfh-ransac-icp")
    parser.add_argument("--pointnet-epochs", type=int, default=None, help="Override the 60 epochs.")
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args()
    os.environ["JSRTE_CACHE"] = tempfile.mkdtemp(prefix="jsrte-bench-cache-")
    pcl_build = Path.home() / ".cache" / "jsrte" / "pcl"
    if pcl_build.is_dir():  # reuse the compiled PCL binding: its build is an install step
        os.symlink(pcl_build, Path(os.environ["JSRTE_CACHE"]) / "pcl")

    import numpy as np
    import torch

    from jsrte.baselines import BaselineFailed, ShapeDatabase, get_baseline
    from jsrte.baselines.pointnet import PointNetSettings
    from jsrte.baselines.run import load_baseline_query
    from jsrte.geometry.mesh import normalized
    from jsrte.scans.scanner import scan_mesh, write_scan
    from jsrte.shapes import EVAL_SET_SEED, TRAIN_SET_SEED, generate_set

    torch.set_num_threads(args.threads)
    rows: dict[str, dict] = {}
    started = time.perf_counter()
    meshes = [normalized(s.mesh) for s in generate_set("chair", args.shapes, TRAIN_SET_SEED)]
    database = ShapeDatabase(meshes, normalize=False, persist=False)
    for i in range(len(database)):
        database.points(i)
    t_db = time.perf_counter() - started
    print(f"database: {args.shapes} chairs generated, normalized, sampled in {t_db:.1f} s", file=sys.stderr)

    folder = Path(tempfile.mkdtemp(prefix="jsrte-bench-scans-"))
    queries = []
    for i, shape in enumerate(generate_set("chair", args.queries, EVAL_SET_SEED)):
        path = folder / f"scan_{i}.ply"
        write_scan(scan_mesh(shape.mesh, rng=np.random.default_rng(i)), path, seed=i)
        queries.append(load_baseline_query(path, rng=np.random.default_rng(i)))

    for name in args.methods.split(","):
        options = {}
        if name == "pointnet-icp":
            epochs = args.pointnet_epochs or PointNetSettings.epochs
            options = {"settings": PointNetSettings(epochs=epochs), "progress": True}
        baseline = get_baseline(name, **options)
        t0 = time.perf_counter()
        if name == "pointnet-icp":
            trained = baseline.classifier(database)
            extra = {"train_accuracy": trained.report.get("final_train_accuracy"), "epochs": epochs}
        else:
            baseline.database_descriptors(database)
            extra = {}
        prep = time.perf_counter() - t0
        times, failures, stages = [], 0, []
        for q in queries:
            t1 = time.perf_counter()
            try:
                result = baseline.fit(q.points, q.normals, q.up, database, rng=np.random.default_rng(0))
                stages.append(result.timing)
            except BaselineFailed as exc:
                failures += 1
                print(f"{name}: failed ({exc})", file=sys.stderr)
            times.append(time.perf_counter() - t1)
        rows[name] = {"prepare_s": round(prep, 1), "query_median_s": round(statistics.median(times), 2),
                      "query_max_s": round(max(times), 2), "failures": failures, "stages": stages} | extra
        print(f"{name}: prepare {prep:.1f} s, query median {statistics.median(times):.2f} s", file=sys.stderr)

    print(f"\n{args.shapes}-chair database (generation + sampling {t_db:.1f} s), {args.queries} scan "
          f"queries, {args.threads} threads\n")
    print("| method | database preparation (s) | per query, median (s) | max (s) | failures |")
    print("|---|---|---|---|---|")
    for name, r in rows.items():
        print(f"| {name} | {r['prepare_s']} | {r['query_median_s']} | {r['query_max_s']} | "
              f"{r['failures']}/{args.queries} |")
    if args.json:
        args.json.write_text(json.dumps({"database_s": t_db, "methods": rows}, indent=2))


if __name__ == "__main__":
    main()
