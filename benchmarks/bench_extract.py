"""Dense vs coarse-to-fine vs narrow-band marching cubes: wall time, SDF evaluations, agreement.

Two SDFs: an analytic chair (a union of boxes: thin legs test that no part is lost) and a
decoder-sized MLP (6 hidden layers of 256, a 64-d latent; random weights, its output added
to a sphere's SDF so that a surface exists). ``--shipped`` adds shapes of the shipped models
(their training codes). Prints a markdown table.

    .venv/bin/python benchmarks/bench_extract.py [--resolutions 128 256] [--threads 2]
    .venv/bin/python benchmarks/bench_extract.py --resolutions 128 --no-synthetic \\
        --shipped "chair:20,21,22;table:0;sofa:0;bed:0"
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import torch
from pykdtree.kdtree import KDTree

from jsrte.extract.marching import extract_coarse_to_fine, extract_dense, extract_narrow_band

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


def agreement(mesh, dense) -> str:
    """How closely ``mesh`` matches the dense grid's mesh: area, vertex Hausdorff, F@5%, Chamfer."""
    from jsrte.metrics.surface import fscore

    f = fscore(mesh, dense, rng=np.random.default_rng(0))
    same_faces = "equal" if len(mesh.faces) == len(dense.faces) else f"{len(mesh.faces) - len(dense.faces):+d}"
    return (f"area {100 * (mesh.area / dense.area - 1):+.3f}%, vertex Hausdorff "
            f"{vertex_hausdorff(dense, mesh):.1e}, F@5% {f.fscore:.4f}, Chamfer {f.chamfer:.2e}, "
            f"faces {same_faces}")


METHODS = {
    "coarse-to-fine": lambda fn, r: extract_coarse_to_fine(fn, resolution=r, coarse_resolution=32),
    "narrow band": lambda fn, r: extract_narrow_band(fn, resolution=r),
}


def compare(name: str, fn, resolution: int, skip_dense: bool) -> list[str]:
    rows = []
    dense = None
    if not skip_dense:
        start = time.perf_counter()
        dense = extract_dense(fn, resolution=resolution)
        seconds = time.perf_counter() - start
        rows.append(f"| {name} | {resolution}³ | dense | {seconds:.2f} | {dense.evaluations:,} | 100% "
                    f"| {len(dense.mesh.faces):,} | — |")
    for method, extract in METHODS.items():
        start = time.perf_counter()
        fine = extract(fn, resolution)
        seconds = time.perf_counter() - start
        share = f"{100 * fine.evaluations / resolution**3:.1f}%"
        match = agreement(fine.mesh, dense.mesh) if dense is not None else "(dense skipped)"
        rows.append(f"| {name} | {resolution}³ | {method} | {seconds:.2f} | {fine.evaluations:,} "
                    f"| {share} | {len(fine.mesh.faces):,} | {match} |")
    return rows


def shipped_shapes(spec: str) -> list[tuple[str, object]]:
    """'chair:20,21;table:0' -> [(label, sdf function of that training code of the shipped model)]."""
    from jsrte.model.meshing import sdf_function
    from jsrte.model.registry import resolve_model

    shapes = []
    for part in filter(None, spec.split(";")):
        name, codes = part.split(":")
        model = resolve_model(name)
        model.decoder.eval()
        for i in (int(c) for c in codes.split(",")):
            shapes.append((f"{name} code {i}", sdf_function(model.decoder, model.codes[i].detach())))
    return shapes


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--resolutions", type=int, nargs="+", default=[128, 256])
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--skip-dense-mlp-above", type=int, default=10**9,
                        help="skip the dense MLP grid above this resolution (it takes minutes)")
    parser.add_argument("--shipped", default="",
                        help="also shapes of shipped models: 'chair:20,21;table:0' (training codes)")
    parser.add_argument("--no-synthetic", action="store_true", help="only the --shipped shapes")
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    shapes = [] if args.no_synthetic else [("analytic chair", chair_sdf), ("MLP 6×256, z 64", LatentMlp().eval())]
    shapes += shipped_shapes(args.shipped)
    print(f"torch threads: {torch.get_num_threads()}\n")
    print("| SDF | grid | method | seconds | evaluations | of dense | faces | agreement with dense |")
    print("|---|---|---|---|---|---|---|---|")
    for resolution in args.resolutions:
        for name, fn in shapes:
            skip = name.startswith("MLP") and resolution > args.skip_dense_mlp_above
            for row in compare(name, fn, resolution, skip_dense=skip):
                print(row, flush=True)


if __name__ == "__main__":
    main()
