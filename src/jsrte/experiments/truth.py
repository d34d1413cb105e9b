"""Scoring a result against the ground truth of a simulated scan."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import trimesh

from jsrte.geometry.mesh import unit_sphere_normalization
from jsrte.geometry.sim3 import Sim3, rotation_angle_deg
from jsrte.metrics.surface import fscore
from jsrte.presets import FitSettings
from jsrte.result import FitResult


@dataclass(frozen=True)
class Truth:
    """The true shape and pose of a query.

    Attributes
    ----------
    mesh : the complete true surface in the scan frame
    scan_from_canonical : the true transform from the shape's normalized canonical frame
    """

    mesh: trimesh.Trimesh
    scan_from_canonical: Sim3


def truth_of(mesh: trimesh.Trimesh, scan_from_mesh: Sim3) -> Truth:
    """Truth of a scan of ``mesh`` (its own frame) placed by ``scan_from_mesh``."""
    norm = unit_sphere_normalization(mesh)
    mesh_from_canonical = Sim3(norm.scale, np.eye(3), norm.centre)
    in_scan = mesh.copy()
    in_scan.vertices = scan_from_mesh.apply(mesh.vertices)
    return Truth(in_scan, scan_from_mesh @ mesh_from_canonical)


def score_against_truth(result: FitResult, truth: Truth, *, rng: np.random.Generator,
                        settings: FitSettings = FitSettings()) -> dict[str, float]:
    """F@5% (and precision, recall, Chamfer) against the complete true shape, and the errors
    of the transform: relative scale, rotation angle (degrees), translation (scan units)."""
    f = fscore(result.mesh, truth.mesh, fraction=settings.fscore_fraction, n_points=settings.fscore_points,
               rng=rng)
    est, true = result.transform, truth.scan_from_canonical
    return {
        "fscore": f.fscore, "precision": f.precision, "recall": f.recall, "chamfer": f.chamfer,
        "scale_error_rel": abs(est.s / true.s - 1.0),
        "rotation_error_deg": rotation_angle_deg(est.R, true.R),
        "translation_error": float(np.linalg.norm(est.t - true.t)),
    }
