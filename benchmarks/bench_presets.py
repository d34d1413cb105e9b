"""The `paper` preset against the default (`fast`) on the same scans: F@5%, time, decoder evaluations.

Two steps, so the fits can run on another machine (a GPU box without Open3D):

    .venv/bin/python benchmarks/bench_presets.py prepare --scans 5 --out DIR   # here: scans -> queries
    python benchmarks/bench_presets.py run DIR --device cuda [--presets fast,paper]

``prepare`` scans held-out chairs (evaluation seed set, never trained on) with the virtual
scanner, as ``jsrte experiment scans`` does, preprocesses each into a query file
(``jsrte prepare``) and pickles the truths. ``run`` fits every query with every preset (12 θ
hypotheses, the shipped model) and writes ``DIR/presets.csv`` and ``DIR/presets.md``: F@5%
against the complete true shape, rotation and scale errors, fit time and decoder evaluations.
A stopped ``run`` resumes: the (scan, preset) pairs already in ``presets.csv`` are kept.
"""

from __future__ import annotations

import argparse
import csv
import pickle
import statistics
import sys
import time
from pathlib import Path


def prepare(args: argparse.Namespace) -> None:
    import numpy as np

    from jsrte.experiments.scans import virtual_cases
    from jsrte.fit.query import load_query, save_query
    from jsrte.presets import get_preset

    out = Path(args.out)
    cases = virtual_cases(args.category, args.scans, out / "scans", seed=args.seed, first=args.first_shape)
    truths = {}
    for case in cases:
        query_seed = args.seed if args.query_seed is None else args.query_seed
        query = load_query(case.path, rng=np.random.default_rng(query_seed),
                           scan_settings=get_preset(args.scan_preset).scan_sdf)
        save_query(query, out / f"{case.name}.npz")
        truths[case.name] = case.truth
        print(f"{case.name}: {len(query.sdf)} samples")
    (out / "truths.pkl").write_bytes(pickle.dumps(truths))


def run(args: argparse.Namespace) -> None:
    import numpy as np
    import torch

    from jsrte.experiments.truth import score_against_truth
    from jsrte.fit import fit
    from jsrte.model.registry import resolve_model

    torch.set_num_threads(args.threads)
    folder = Path(args.folder)
    truths = pickle.loads((folder / "truths.pkl").read_bytes())
    missing = sorted(name for name in truths if not (folder / f"{name}.npz").exists())
    if missing:
        print(f"no query file for {', '.join(missing)}: skipped", flush=True)
        truths = {name: truth for name, truth in truths.items() if name not in missing}
    model = resolve_model(args.model).to(args.device)
    rows = read_rows(folder / "presets.csv")
    done = {(r["scan"], r["preset"]) for r in rows}
    for preset in args.presets.split(","):  # preset by preset: a run stopped early still pairs scans
        for name, truth in sorted(truths.items())[: args.scans]:
            if (name, preset) in done:  # resumed: a stopped run keeps what it finished
                continue
            if args.device.startswith("cuda"):
                torch.cuda.synchronize()
            started = time.perf_counter()
            result = fit(folder / f"{name}.npz", model=model, preset=preset, seed=args.seed, device=args.device)
            seconds = time.perf_counter() - started
            score = score_against_truth(result, truth, rng=np.random.default_rng(args.seed))
            rows.append({"scan": name, "preset": preset, "fscore": round(score["fscore"], 4),
                         "rotation_error_deg": round(score["rotation_error_deg"], 2),
                         "scale_error_rel": round(score["scale_error_rel"], 4), "seconds": round(seconds, 2),
                         "decoder_evaluations": result.info["decoder_evaluations"]})
            print(rows[-1], flush=True)
            write(rows, folder, device=args.device, model=model.name, threads=torch.get_num_threads())


def read_rows(path: Path) -> list[dict]:
    """Rows a previous run wrote (numbers parsed), or none."""
    if not path.exists():
        return []
    with open(path, newline="") as f:
        return [{k: v if k in ("scan", "preset") else float(v) for k, v in row.items()} for row in csv.DictReader(f)]


def write(rows: list[dict], folder: Path, *, device: str, model: str, threads: int) -> None:
    with open(folder / "presets.csv", "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    where = device if device != "cpu" else f"cpu, {threads} thread(s)"
    (folder / "presets.md").write_text(table(rows, device=where, model=model))


def table(rows: list[dict], *, device: str, model: str) -> str:
    """Markdown: per preset, means over the scans every preset has finished (paired)."""
    presets = list(dict.fromkeys(r["preset"] for r in rows))
    paired = set.intersection(*({r["scan"] for r in rows if r["preset"] == p} for p in presets))
    lines = [f"{len(paired)} virtual scans of held-out chairs (evaluation seed set, never trained on), "
             f"model `{model}`, device {device}, 12 θ hypotheses.", "",
             "| preset | mean F@5% | median rot. err. (°) | mean time (s) | decoder evaluations |",
             "|---|---|---|---|---|"]
    for p in presets:
        mine = [r for r in rows if r["preset"] == p and r["scan"] in paired]
        lines.append(f"| {p} | {statistics.mean(r['fscore'] for r in mine):.3f} | "
                     f"{statistics.median(r['rotation_error_deg'] for r in mine):.1f} | "
                     f"{statistics.mean(r['seconds'] for r in mine):.1f} | "
                     f"{statistics.mean(r['decoder_evaluations'] for r in mine) / 1e6:.2f} M |")
    return "\n".join(lines) + "\n"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="step", required=True)
    p = sub.add_parser("prepare")
    p.add_argument("--scans", type=int, default=5)
    p.add_argument("--category", default="chair")
    p.add_argument("--seed", type=int, default=0, help="Scan seed (poses, noise).")
    p.add_argument("--first-shape", type=int, default=0,
                   help="First held-out shape index (Table 2 uses 0..29; the tuning set 100..119).")
    p.add_argument("--scan-preset", default="paper",
                   help="Whose scan SDF settings make the queries (fast: with line-of-sight samples).")
    p.add_argument("--query-seed", type=int, default=None, help="Seed of the query sampling (default: --seed).")
    p.add_argument("--out", required=True)
    r = sub.add_parser("run")
    r.add_argument("folder")
    r.add_argument("--model", default="chair")
    r.add_argument("--presets", default="fast,paper")
    r.add_argument("--device", default="cpu")
    r.add_argument("--scans", type=int, default=None, help="Only the first N scans.")
    r.add_argument("--threads", type=int, default=1)
    r.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    prepare(args) if args.step == "prepare" else run(args)


if __name__ == "__main__":
    sys.exit(main())
