"""Time the virtual scanner, the real-scan preprocessing and scan SDF sampling.

``python benchmarks/bench_scans.py [--repeats 5] [--faces 20000]``

The mesh is a procedural chair (jsrte.shapes) subdivided to about ``--faces`` faces. Each
row is the median over ``--repeats`` seeds (after one warm-up call, which pays Open3D's
first-use costs). Wall and process-CPU seconds are both printed: wall time grows with the
machine's load.
"""

from __future__ import annotations

import argparse
import os
import time
from collections.abc import Callable

import numpy as np
import trimesh

from jsrte.presets import ScanSdf
from jsrte.scans.io import ScanCloud
from jsrte.scans.preprocess import prepare_scan
from jsrte.scans.scanner import ScannerSettings, scan_mesh
from jsrte.sdf.from_scan import scan_sdf_samples


def chair_mesh(faces: int) -> trimesh.Trimesh:
    """A procedural chair with four legs and a back, subdivided to at least ``faces`` faces."""
    from jsrte.shapes import generate_shape

    mesh = next(shape.mesh for seed in range(100)
                if (shape := generate_shape("chair", seed)).style.startswith("four_leg"))
    while len(mesh.faces) < faces:
        mesh = mesh.subdivide()
    return mesh


def timed(fn: Callable[[int], object], repeats: int) -> tuple[float, float, object]:
    """Median wall and CPU seconds of ``fn(seed)`` over ``repeats`` seeds; the last result."""
    fn(1000)  # warm-up
    wall, cpu, result = [], [], None
    for seed in range(repeats):
        start, start_cpu = time.perf_counter(), time.process_time()
        result = fn(seed)
        wall.append(time.perf_counter() - start)
        cpu.append(time.process_time() - start_cpu)
    return float(np.median(wall)), float(np.median(cpu)), result


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--faces", type=int, default=20_000)
    args = parser.parse_args()
    mesh = chair_mesh(args.faces)
    print(f"load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores; "
          f"mesh: procedural chair, {len(mesh.faces)} faces; median of {args.repeats}")
    print(f"{'step':<58} {'wall s':>7} {'CPU s':>7}  result")

    scans = {}
    for width, height in ((160, 120), (320, 240), (640, 480)):
        settings = ScannerSettings(width=width, height=height)
        wall, cpu, scan = timed(
            lambda seed, s=settings: scan_mesh(mesh, rng=np.random.default_rng(seed), settings=s),
            args.repeats)
        scans[width] = scan
        print(f"{f'scan_mesh 3 views {width}x{height}':<58} {wall:7.3f} {cpu:7.3f}  "
              f"{len(scan.points)} points, {int(scan.is_object.sum())} on the object")

    for width in (160, 320):
        scan = scans[width]
        cases = {
            "normals from the scan": dict(cloud=ScanCloud(scan.points, scan.normals)),
            "normals from the scan, viewpoints (HPR)": dict(
                cloud=ScanCloud(scan.points, scan.normals), viewpoints=scan.cameras),
            "no normals (estimated)": dict(cloud=ScanCloud(scan.points, None)),
        }
        for name, kwargs in cases.items():
            wall, cpu, prepared = timed(
                lambda seed, k=kwargs: prepare_scan(rng=np.random.default_rng(seed), **k),
                args.repeats)
            on_object = scan.is_object[prepared.index]
            print(f"{f'prepare_scan {width}: {name}':<58} {wall:7.3f} {cpu:7.3f}  "
                  f"{len(prepared.points)} kept, {on_object.mean():.4f} on the object")

    prepared = prepare_scan(ScanCloud(scans[160].points, scans[160].normals),
                            rng=np.random.default_rng(0))
    wall, cpu, (xyz, _) = timed(
        lambda seed: scan_sdf_samples(prepared.points, prepared.normals,
                                      rng=np.random.default_rng(seed), settings=ScanSdf()),
        args.repeats)
    print(f"{'scan_sdf_samples (paper: 25k freespace)':<58} {wall:7.3f} {cpu:7.3f}  "
          f"{len(xyz)} samples")


if __name__ == "__main__":
    main()
