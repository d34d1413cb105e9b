"""Time the preprocessing's point operations against Open3D's, on one scan's points.

Usage (from the repository root; run it niced when the machine is busy):

    nice -n 19 .venv/bin/python benchmarks/bench_point_ops.py SCAN.ply --points 30000

Reads the PLY file both ways, then runs statistical outlier removal (20 neighbours, 2.0),
hidden point removal (one viewpoint, radius 1000 extents), PCA normals (6 median spacings, 30
neighbours) and DBSCAN (4 median spacings, 10 points) on ``--points`` of the scan's points
(a seeded random subset) with Open3D and with ``jsrte.geometry.point_ops``, alternating, and
prints a markdown table of the median wall-clock milliseconds of ``--repeats`` runs. Open3D's
import is not timed.
"""

from __future__ import annotations

import argparse
import statistics
import time
from collections.abc import Callable
from pathlib import Path


def _time_into(function: Callable[[], object], times: list[float]) -> None:
    start = time.perf_counter()
    function()
    times.append((time.perf_counter() - start) * 1000)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("scan", type=Path)
    parser.add_argument("--points", type=int, default=30_000)
    parser.add_argument("--repeats", type=int, default=7)
    args = parser.parse_args()

    import numpy as np
    import open3d as o3d

    from jsrte.geometry import point_ops
    from jsrte.geometry.point_ops import median_spacing
    from jsrte.scans.ply import read_ply_cloud

    cloud_points, _ = read_ply_cloud(args.scan)
    rng = np.random.default_rng(0)
    chosen = np.sort(rng.choice(len(cloud_points), min(args.points, len(cloud_points)), replace=False))
    points = np.ascontiguousarray(cloud_points[chosen])
    spacing = median_spacing(points)
    extent = float(np.linalg.norm(np.ptp(points, axis=0)))
    viewpoint = points.mean(0) + np.array([1.0, 1.0, 1.0]) * extent

    def cloud() -> o3d.geometry.PointCloud:
        return o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))

    hybrid = o3d.geometry.KDTreeSearchParamHybrid(6 * spacing, 30)
    rows = {
        f"read the PLY file ({len(cloud_points)} points)": (
            lambda: o3d.io.read_point_cloud(str(args.scan)), lambda: read_ply_cloud(args.scan)),
        "statistical outlier removal": (
            lambda: cloud().remove_statistical_outlier(20, 2.0),
            lambda: point_ops.statistical_inliers(points, 20, 2.0)),
        "hidden point removal, one viewpoint": (
            lambda: cloud().hidden_point_removal(viewpoint, 1000 * extent),
            lambda: point_ops.visible_points(points, viewpoint, 1000 * extent)),
        "PCA normals": (
            lambda: cloud().estimate_normals(hybrid), lambda: point_ops.pca_normals(points, 6 * spacing, 30)),
        "DBSCAN": (
            lambda: cloud().cluster_dbscan(4 * spacing, 10), lambda: point_ops.dbscan_labels(points, 4 * spacing, 10)),
    }
    print(f"{len(points)} points of {args.scan.name}, median spacing {spacing * 1000:.1f} mm\n")
    print("| operation | Open3D (ms) | jsrte.geometry.point_ops (ms) |\n|---|---|---|")
    for name, (theirs, ours) in rows.items():
        their_times: list[float] = []
        our_times: list[float] = []
        for _ in range(args.repeats):
            _time_into(theirs, their_times)
            _time_into(ours, our_times)
        print(f"| {name} | {statistics.median(their_times):.0f} | {statistics.median(our_times):.0f} |", flush=True)


if __name__ == "__main__":
    main()
