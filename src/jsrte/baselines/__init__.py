"""The recognize-then-register baselines of the paper's Table 2, plus Open3D's pipeline.

=================  ==========================================================================
``harris3d-shot``  Harris 3D keypoints + SHOT descriptors (PCL); recognition by descriptor
                   matches; RANSAC + Umeyama (with scale) over the matched keypoints
``ourcvfh-icp``    OUR-CVFH global descriptor (PCL); nearest neighbour; the supplementary's
                   registration (bounding spheres, 20° yaw search, ICP with optimal assignment)
``pointnet-icp``   PointNet classifier (PyTorch) trained on the database; the same registration
``fpfh-ransac-icp`` Open3D FPFH + RANSAC global registration + ICP; recognition by fitness
=================  ==========================================================================

Every baseline has ``fit(query_points, query_normals, up, database, *, rng) -> FitResult``
(the type :func:`jsrte.fit` returns: the retrieved database shape in its canonical frame and the
``scan_from_canonical`` similarity) and raises :class:`BaselineFailed` on a query it cannot
handle. The database (:class:`ShapeDatabase`) is the shape set the model was trained on, so
every method sees the same data.

Why PCL, and how
----------------
The paper's Harris3D, SHOT and OUR-CVFH baselines ran PCL's implementations, and we
prefer those very implementations. We measured, on this project's 2-core machine kind: Debian
12's ``libpcl-dev`` (PCL 1.13.0) installs with ``apt-get`` in 3.5 minutes (490 packages, about
300 MB to download, 1.6 GB on disk: it pulls VTK, Qt and Boost), and the pybind11 binding
(``pcl_binding.cpp``, three functions) compiles in 40-75 s using 0.9 GB of memory. That fits
a fresh CI machine's 90 minutes with ample room, so we use PCL itself rather than
re-implementations from the papers: no doubt about fidelity, and PCL's parameters keep their
names. The binding is built on first use into the user cache, or at install time with
``python -m jsrte.baselines.pcl`` (:mod:`jsrte.baselines.pcl`); without PCL these two
baselines raise a ``JsrteError`` that says what to install, and the other two still work
(they need only Open3D, SciPy and PyTorch).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from jsrte.errors import JsrteError

if TYPE_CHECKING:
    from jsrte.baselines.database import ShapeDatabase
    from jsrte.baselines.protocol import Baseline, BaselineFailed

BASELINE_NAMES = ("harris3d-shot", "ourcvfh-icp", "pointnet-icp", "fpfh-ransac-icp")
"""The baselines, in the order of the paper's table (Open3D's last)."""

NEEDS_PCL = frozenset({"harris3d-shot", "ourcvfh-icp"})


def get_baseline(name: str, **options: object) -> Baseline:
    """A baseline by name, built with its default settings (``options`` go to its constructor)."""
    if name == "harris3d-shot":
        from jsrte.baselines.harris_shot import HarrisShot as cls
    elif name == "ourcvfh-icp":
        from jsrte.baselines.ourcvfh_icp import OurCvfhIcp as cls
    elif name == "pointnet-icp":
        from jsrte.baselines.pointnet_icp import PointNetIcp as cls
    elif name == "fpfh-ransac-icp":
        from jsrte.baselines.fpfh_ransac import FpfhRansacIcp as cls
    else:
        raise JsrteError(f"unknown baseline {name!r} (known: {', '.join(BASELINE_NAMES)})")
    return cls(**options)


def __getattr__(name: str) -> Any:
    """Import the heavier names on first use (keeps ``jsrte --help`` and the CLI start fast)."""
    if name in ("Baseline", "BaselineFailed"):
        from jsrte.baselines import protocol

        return getattr(protocol, name)
    if name == "ShapeDatabase":
        from jsrte.baselines.database import ShapeDatabase

        return ShapeDatabase
    raise AttributeError(f"module 'jsrte.baselines' has no attribute {name!r}")


__all__ = ["BASELINE_NAMES", "NEEDS_PCL", "Baseline", "BaselineFailed", "ShapeDatabase", "get_baseline"]
