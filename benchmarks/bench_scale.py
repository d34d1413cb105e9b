"""Scaling on one machine: fit-many throughput with 1..N worker processes, and ``jsrte train``
steps/s as one process and under ``torchrun --nproc_per_node=1..N``. Prints markdown tables.

Tiny settings, so that it is quick (this measures the machinery, not the fits' quality): a small
decoder trained for a few steps, virtual scans of held-out chairs (small images), the ``smoke``
preset. Everything is written under ``--work`` (scans and model are reused between runs).

    nice -n 19 .venv/bin/python benchmarks/bench_scale.py [--scans 8] [--workers 1 2] [--procs 1 2]
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import statistics
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

TRAIN_ARGS = ["--category", "chair", "--shapes", "4", "--samples", "4000", "--batch-shapes", "4",
              "--points", "256", "--threads", "1", "--no-progress"]


def make_scans(folder: Path, n: int) -> None:
    """``n`` virtual scans of held-out chairs, with their truth (skipped when already there)."""
    from jsrte.geometry.mesh import save_mesh
    from jsrte.scans import ScannerSettings, scan_mesh, write_scan
    from jsrte.shapes import EVAL_SET_SEED, generate_shape, shape_seed

    settings = ScannerSettings(views=2, width=80, height=60)
    for i in range(n):
        ply = folder / f"chair_{i:03d}.ply"
        if ply.exists():
            continue
        shape = generate_shape("chair", shape_seed(EVAL_SET_SEED, i))
        mesh = folder / "meshes" / f"chair_{i:03d}.obj"
        mesh.parent.mkdir(parents=True, exist_ok=True)
        save_mesh(shape.mesh, mesh)
        scan = scan_mesh(shape.mesh, rng=np.random.default_rng(i), settings=settings)
        write_scan(scan, ply, seed=i, mesh=mesh)


def make_model(path: Path) -> None:
    """A small decoder (latent 16, 4 x 64) trained briefly on 4 procedural chairs."""
    if path.exists():
        return
    from jsrte.model.checkpoint import save_model
    from jsrte.model.data import procedural_training_data
    from jsrte.model.decoder import DecoderConfig
    from jsrte.model.train import Trainer, TrainSettings
    from jsrte.presets import SdfSampling

    sampling = SdfSampling(n_points=5000)
    data = procedural_training_data("chair", 4, path.parent / "train-data", settings=sampling)
    settings = TrainSettings(steps=200, shapes_per_batch=4, points_per_shape=512, checkpoint_every=200)
    config = DecoderConfig(latent_size=16, hidden=64, depth=4, skip_layer=2)
    meta = {"name": "bench-chair", "category": "chair"}
    model = Trainer(config, settings, data, path.parent / "train-run", meta).run(progress=False)
    save_model(model, path)


def bench_fit_many(work: Path, scans: int, workers: list[int], preset: str, hypotheses: int | None) -> None:
    from jsrte.batch import fit_many
    from jsrte.options import FitOptions

    folder, model = work / "scans", work / "model.safetensors"
    make_scans(folder, scans)
    make_model(model)
    print(f"\n### fit-many: {scans} scans, preset {preset}, hypotheses {hypotheses or 'preset grid'}\n")
    print("| workers | wall (s) | scans / minute | after start-up, scans / minute | median fit (s) | "
          "worker CPU (s) | load average |")
    print("|---|---|---|---|---|---|---|")
    for w in workers:
        out = work / f"fits-{w}"
        shutil.rmtree(out, ignore_errors=True)
        cpu = _children_cpu()
        started = time.perf_counter()
        report = fit_many(folder, out=out, model=model, options=FitOptions(preset=preset, hypotheses=hypotheses),
                          workers=w, progress=False)
        wall = time.perf_counter() - started
        cpu = _children_cpu() - cpu
        assert report.failed == 0, report.rows
        median = statistics.median(float(r["time_s"]) for r in report.rows)
        done = sorted((out / r["result"] / "fit.json").stat().st_mtime for r in report.rows)
        steady = 60 * (len(done) - w) / max(done[-1] - done[w - 1], 1e-9) if len(done) > w else float("nan")
        print(f"| {w} | {wall:.1f} | {60 * scans / wall:.1f} | {steady:.1f} | {median:.2f} | {cpu:.1f} | "
              f"{os.getloadavg()[0]:.1f} |", flush=True)


def bench_torchrun(work: Path, procs: list[int], steps: int) -> None:
    print(f"\n### jsrte train, tiny setting ({steps} steps, global batch 4 shapes x 256 points)\n")
    print("| launch | processes | steps / s | CPU (s) | load average |")
    print("|---|---|---|---|---|")
    env = dict(os.environ, OMP_NUM_THREADS="1")
    runs = [("python -m jsrte.cli", 1, [sys.executable, "-m", "jsrte.cli"])]
    runs += [("torchrun", n, [sys.executable, "-m", "torch.distributed.run", "--standalone",
                              f"--nproc_per_node={n}", "-m", "jsrte.cli"]) for n in procs]
    for label, n, launcher in runs:
        out = work / f"train-{label.split()[0]}-{n}"
        shutil.rmtree(out, ignore_errors=True)
        cpu = _children_cpu()
        subprocess.run(launcher + ["train", *TRAIN_ARGS, "--steps", str(steps), "--checkpoint-every",
                                   str(steps), "--out", str(out)], check=True, env=env, capture_output=True)
        cpu = _children_cpu() - cpu
        seconds = json.loads((out / "model.json").read_text())["training"]["seconds"]
        print(f"| {label} | {n} | {steps / seconds:.1f} | {cpu:.1f} | {os.getloadavg()[0]:.1f} |", flush=True)


def _children_cpu() -> float:
    """User + system seconds of this process's finished children (the workers, the trainers)."""
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--work", type=Path, default=Path("runs/bench_scale"))
    parser.add_argument("--scans", type=int, default=8)
    parser.add_argument("--workers", type=int, nargs="+", default=[1, 2])
    parser.add_argument("--preset", default="smoke")
    parser.add_argument("--hypotheses", type=int, default=None)
    parser.add_argument("--procs", type=int, nargs="+", default=[1, 2])
    parser.add_argument("--steps", type=int, default=300)
    parser.add_argument("--skip-fit", action="store_true")
    parser.add_argument("--skip-train", action="store_true")
    args = parser.parse_args()
    args.work.mkdir(parents=True, exist_ok=True)
    print(f"machine: {os.cpu_count()} cores, load average {os.getloadavg()[0]:.1f} at start")
    if not args.skip_fit:
        bench_fit_many(args.work, args.scans, args.workers, args.preset, args.hypotheses)
    if not args.skip_train:
        bench_torchrun(args.work, args.procs, args.steps)
    print(f"\nload average {os.getloadavg()[0]:.1f} at the end")


if __name__ == "__main__":
    main()
