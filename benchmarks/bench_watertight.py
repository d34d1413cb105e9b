"""Count procedural meshes that are not watertight once read back from a file:
``python benchmarks/bench_watertight.py --n 50 --seeds 0,1``.

A mesh file stores vertex positions only, so a reader merges coincident vertices; where two
parts of a shape touch along a line (not overlapping), the merged mesh has edges shared by four
faces and ``trimesh``'s ``is_watertight`` is False. A shape whose parts do not form one body
(a generator error) is counted apart.
"""

from __future__ import annotations

import argparse
from collections import Counter

import numpy as np
import trimesh

from jsrte.shapes import CATEGORIES, generate_shape, shape_seed


def non_manifold_edges(mesh: trimesh.Trimesh) -> int:
    """Edges of ``mesh`` (vertices merged) shared by more than two faces."""
    _, counts = np.unique(np.sort(mesh.edges, axis=1), axis=0, return_counts=True)
    return int((counts > 2).sum())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--n", type=int, default=50, help="shapes per category and set seed")
    parser.add_argument("--seeds", default="0,1", help="set seeds, comma-separated")
    args = parser.parse_args()
    print(f"{'category':<8} {'seed':>4} {'n':>4} {'not watertight':>15} {'failed':>7}  styles not watertight")
    for category in CATEGORIES:
        for seed in (int(s) for s in args.seeds.split(",")):
            bad: Counter[str] = Counter()
            failed = 0
            for i in range(args.n):
                try:
                    shape = generate_shape(category, shape_seed(seed, i))
                except RuntimeError:
                    failed += 1
                    continue
                merged = trimesh.Trimesh(shape.mesh.vertices, shape.mesh.faces)  # as a reader sees it
                if not merged.is_watertight or non_manifold_edges(merged):
                    bad[shape.style] += 1
            print(f"{category:<8} {seed:>4} {args.n:>4} {sum(bad.values()):>15} {failed:>7}  "
                  f"{', '.join(f'{k} {v}' for k, v in sorted(bad.items())) or '-'}", flush=True)


if __name__ == "__main__":
    main()
