"""Time procedural shape generation per category (and per style): ``python benchmarks/bench_shapes.py``.

Each shape is generated from its training-set seed (parameters, manifold3d union, trimesh
conversion); the first shape of each category is a warm-up and not timed.
"""

from __future__ import annotations

import argparse
import os
import time
from collections import defaultdict

import numpy as np

from jsrte.shapes import CATEGORIES, TRAIN_SET_SEED, generate_shape, shape_seed


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--n", type=int, default=100, help="shapes per category")
    args = parser.parse_args()
    print(f"load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores (wall times grow with it; "
          "CPU ms is the process's own time)")
    print(f"{'category':<8} {'style':<16} {'n':>4} {'median ms':>10} {'mean ms':>8} {'max ms':>8} "
          f"{'CPU ms':>7} {'faces':>7}")
    for category in CATEGORIES:
        generate_shape(category, shape_seed(TRAIN_SET_SEED, 0))  # warm-up
        times: dict[str, list[float]] = defaultdict(list)
        cpu: dict[str, list[float]] = defaultdict(list)
        faces: dict[str, list[int]] = defaultdict(list)
        for i in range(args.n):
            start, start_cpu = time.perf_counter(), time.process_time()
            shape = generate_shape(category, shape_seed(TRAIN_SET_SEED, i))
            times[shape.style].append(1e3 * (time.perf_counter() - start))
            cpu[shape.style].append(1e3 * (time.process_time() - start_cpu))
            faces[shape.style].append(len(shape.mesh.faces))
        rows = sorted(times.items()) + [("ALL", [t for ts in times.values() for t in ts])]
        all_faces = [f for fs in faces.values() for f in fs]
        all_cpu = [c for cs in cpu.values() for c in cs]
        for style, ts in rows:
            fs, cs = faces.get(style, all_faces), cpu.get(style, all_cpu)
            print(f"{category:<8} {style:<16} {len(ts):>4} {np.median(ts):>10.1f} "
                  f"{np.mean(ts):>8.1f} {np.max(ts):>8.1f} {np.mean(cs):>7.1f} {int(np.mean(fs)):>7}")


if __name__ == "__main__":
    main()
