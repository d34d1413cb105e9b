"""Dense vs coarse-to-fine marching cubes: wall time, SDF evaluations, and agreement of the meshes.

Two SDFs: an analytic chair (a union of boxes: thin legs test that no part is lost) and a
decoder-sized MLP (6 hidden layers of 256, a 64-d latent; random weights, its output added
to a sphere's SDF so that a surface exists). Prints a markdown table.

    .venv/bin/python benchmarks/bench_extract.py [--resolutions 128 256] [--threads 2]
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import torch
from pykdtree.kdtree import KDTree

from jsrte.extract.marching import extract_coarse_to_fine, extract_dense

CHAIR_BOXES = [  # (centre, half extents) in canonical units, +y up, back towards +z
    ((0.0, -0.05, 0.0), (0.35, 0.04, 0.33)),
    ((0.0, 0.4, 0.3), (0.35, 0.41, 0.03)),
    *[((x, -0.47, z), (0.03, 0.38, 0.03)) for x in (-0.3, 0.3) for z in (-0.28, 0.28)],
]


def chair_sdf(points: torch.Tensor) -> torch.Tensor:
    """Union (min) of box SDFs: exact outside, 1-Lipschitz everywhere."""
    best = None
    for centre, half in CHAIR_BOXES:
        q = (points - torch.tensor(centre)).abs() - torch.tensor(half)
        d = q.clamp(min=0).norm(dim=1) + q.max(dim=1).values.clamp(max=0)
        best = d if best is None else torch.minimum(best, d)
    return best


class LatentMlp(torch.nn.Module):
    """f(x, z): 6 hidden layers of 256 (ReLU) on [x, z], z of size 64, like the small decoder."""

    def __init__(self, *, latent: int = 64, width: int = 256, layers: int = 6, seed: int = 0):
        super().__init__()
        torch.manual_seed(seed)
        sizes = [3 + latent] + [width] * layers
        blocks: list[torch.nn.Module] = []
        for a, b in zip(sizes[:-1], sizes[1:], strict=True):
            blocks += [torch.nn.Linear(a, b), torch.nn.ReLU()]
        self.net = torch.nn.Sequential(*blocks, torch.nn.Linear(width, 1))
        self.z = torch.nn.Parameter(torch.randn(latent) * 0.01)

    def forward(self, points: torch.Tensor) -> torch.Tensor:
        z = self.z.expand(len(points), -1)
        bump = 0.05 * torch.tanh(self.net(torch.cat([points, z], dim=1)).squeeze(1))
        return points.norm(dim=1) - 0.6 + bump


def vertex_hausdorff(a, b) -> float:
    """Largest distance from a vertex of either mesh to the nearest vertex of the other."""
    va, vb = np.asarray(a.vertices, np.float64), np.asarray(b.vertices, np.float64)
    return float(max(KDTree(vb).query(va, k=1)[0].max(), KDTree(va).query(vb, k=1)[0].max()))


def compare(name: str, fn, resolution: int, skip_dense: bool) -> list[str]:
    rows = []
    dense = None
    if not skip_dense:
        start = time.perf_counter()
        dense = extract_dense(fn, resolution=resolution)
        seconds = time.perf_counter() - start
        rows.append(f"| {name} | {resolution}³ | dense | {seconds:.1f} | {dense.evaluations:,} | 100% "
                    f"| {len(dense.mesh.faces):,} | — |")
    start = time.perf_counter()
    fine = extract_coarse_to_fine(fn, resolution=resolution, coarse_resolution=32)
    seconds = time.perf_counter() - start
    share = f"{100 * fine.evaluations / resolution**3:.1f}%"
    if dense is not None:
        same_faces = "equal" if len(fine.mesh.faces) == len(dense.mesh.faces) else "differ"
        agreement = (f"area {100 * (fine.mesh.area / dense.mesh.area - 1):+.3f}%, vertex "
                     f"Hausdorff {vertex_hausdorff(dense.mesh, fine.mesh):.1e}, faces {same_faces}")
    else:
        agreement = "(dense skipped)"
    rows.append(f"| {name} | {resolution}³ | coarse-to-fine | {seconds:.1f} | {fine.evaluations:,} "
                f"| {share} | {len(fine.mesh.faces):,} | {agreement} |")
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--resolutions", type=int, nargs="+", default=[128, 256])
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--skip-dense-mlp-above", type=int, default=10**9,
                        help="skip the dense MLP grid above this resolution (it takes minutes)")
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    mlp = LatentMlp().eval()
    print(f"torch threads: {torch.get_num_threads()}; MLP parameters: "
          f"{sum(p.numel() for p in mlp.parameters()):,}\n")
    print("| SDF | grid | method | seconds | evaluations | of dense | faces | agreement with dense |")
    print("|---|---|---|---|---|---|---|---|")
    for resolution in args.resolutions:
        for row in compare("analytic chair", chair_sdf, resolution, skip_dense=False):
            print(row, flush=True)
        for row in compare("MLP 6×256, z 64", mlp, resolution,
                           skip_dense=resolution > args.skip_dense_mlp_above):
            print(row, flush=True)


if __name__ == "__main__":
    main()
