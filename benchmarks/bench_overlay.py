"""Time ``overlay.png`` alone: ``render_overlay`` on the inputs real fits hand it.

``--save DIR`` fits each scan (preset, model, one thread) and stores what ``jsrte fit`` renders
(the fitted mesh in the scan's frame, the query points, the up axis, the title) as
``DIR/NAME.npz``. Without ``--save`` the stored inputs are each rendered in a fresh process
(so the renderer's imports are counted, as in a fit): the first call's seconds, with its imports,
and the best of ``--repeat`` further calls, wall-clock and the process's CPU time (two
overlay views, 640 x 480 each). Run it with ``PYTHONPATH`` on two source trees to
compare renderers; ``--png DIR`` keeps the images.

    PYTHONPATH=src .venv/bin/python benchmarks/bench_overlay.py --save /tmp/ov SCAN.ply ...
    PYTHONPATH=src .venv/bin/python benchmarks/bench_overlay.py /tmp/ov/*.npz [--png /tmp/png]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

import numpy as np

RENDER_ONE = """
import json, sys, time
t0 = time.perf_counter()
import numpy as np, trimesh
t1 = time.perf_counter()
from jsrte.viz import render_overlay
data = np.load(sys.argv[1])
mesh = trimesh.Trimesh(data["vertices"], data["faces"], process=False)
args = dict(up=tuple(data["up"]), title=str(data["title"]))
times, cpu = [], []
for k in range(1 + int(sys.argv[3])):
    start, start_cpu = time.perf_counter(), time.process_time()
    render_overlay(mesh, data["points"], sys.argv[2], **args)
    times.append(time.perf_counter() - start)
    cpu.append(time.process_time() - start_cpu)
print(json.dumps({"first": times[0], "best": min(times[1:] or times), "first_cpu": cpu[0],
                  "best_cpu": min(cpu[1:] or cpu), "faces": len(mesh.faces), "points": len(data["points"])}))
"""


def save_inputs(scans: list[Path], out: Path, *, preset: str, model: str) -> None:
    """Fit each scan and store the overlay's inputs as ``out/NAME.npz``."""
    import torch

    from jsrte.fit import fit

    torch.set_num_threads(1)
    out.mkdir(parents=True, exist_ok=True)
    for scan in scans:
        result = fit(scan, model=model, preset=preset)
        up = result.info.get("up")
        np.savez(out / f"{scan.stem}.npz", vertices=np.asarray(result.mesh.vertices),
                 faces=np.asarray(result.mesh.faces), points=np.asarray(result.query_points),
                 up=np.asarray((0.0, 1.0, 0.0) if up is None else up, float), title=result.method)


def main() -> None:
    """Command line: see the module's docstring."""
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("inputs", nargs="+", type=Path, help="scans (with --save) or stored .npz inputs")
    parser.add_argument("--save", type=Path, help="fit the scans and store the overlay inputs here")
    parser.add_argument("--preset", default="fast-gn")
    parser.add_argument("--model", default="chair")
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--png", type=Path, help="keep the rendered PNGs here")
    args = parser.parse_args()
    if args.save:
        save_inputs(args.inputs, args.save, preset=args.preset, model=args.model)
        return
    png_dir = args.png or Path("/tmp")
    png_dir.mkdir(parents=True, exist_ok=True)
    rows = []
    for path in args.inputs:
        proc = subprocess.run([sys.executable, "-c", RENDER_ONE, str(path), str(png_dir / f"{path.stem}.png"),
                               str(args.repeat)], capture_output=True, text=True, check=True)
        rows.append(json.loads(proc.stdout.strip().splitlines()[-1]) | {"name": path.stem})
    keys = ("first", "first_cpu", "best", "best_cpu")
    print("| input | faces | points | first call (s, with imports) | its CPU (s) | best call (s) | its CPU (s) |")
    print("|---|---:|---:|---:|---:|---:|---:|")
    for row in rows:
        cells = " | ".join(f"{row[k]:.3f}" for k in keys)
        print(f"| {row['name']} | {row['faces']} | {row['points']} | {cells} |")
    print("| mean | | | " + " | ".join(f"{np.mean([r[k] for r in rows]):.3f}" for k in keys) + " |")


if __name__ == "__main__":
    main()
