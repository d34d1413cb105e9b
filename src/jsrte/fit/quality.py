"""How far to trust a fit: measures computed after the fit, and a flag ("ok" / "doubtful").

Every measure costs at most one decoder pass over the query's points (no extra optimization).
Distances are in scan units (metres for scans); "relative" ones are divided by the fit's scale
``s``, the radius of the fitted shape's bounding sphere (the decoder's shapes fill the unit
sphere). docs/confidence.md gives the rule's precision and recall and how it was chosen.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING, Any

import numpy as np
import torch

from jsrte.geometry.sim3 import Sim3, rotation_angle_deg
from jsrte.model.decoder import Decoder, decoder_device
from jsrte.result import FitResult, HypothesisReport

if TYPE_CHECKING:
    from jsrte.scans.views import CameraViews

INLIER_FRACTION = 0.02
"""A query point is an inlier when |fitted SDF| < this fraction of the fit's scale (1 cm on a chair)."""
FREE_SPACE_MIN_M = 0.03
"""Query samples whose SDF is at least this (scan units) count as observed free space."""
TRIM = 0.9
"""The robust mean |SDF| averages the smallest 90% (a few outliers or clutter points do not rule it)."""
OTHER_POSE_DEG = 30.0
"""A hypothesis is at a different pose than the winner when its rotation differs by more than
this, or its centre by more than ``OTHER_POSE_SHIFT`` times the scale."""
OTHER_POSE_SHIFT = 0.2
SAME_SHAPE_DISTANCE = 0.025
"""Another pose is the winner's shape again (a symmetry: a table turned half a turn) when the
winner's shape placed there lies within this many scales of the winner's surface (robust mean
distance at points on that surface); such a pose is no rival and its loss no margin."""
SURFACE_BAND = 0.02
"""Points within this canonical distance of the winner's surface stand for the surface."""
SURFACE_PROBES = 20_000
"""Uniform points in the canonical unit ball, of which those in the band are kept."""
MAX_POINTS = 20_000
"""At most this many surface points and as many free-space samples are evaluated (a random subset)."""
COVERAGE_FRACTION = 0.03
"""A point of the fitted surface is covered when a scan point of the object lies within this
fraction of the fit's scale (1.5 cm on a chair)."""
COVERAGE_SAMPLES = 4000
"""Points drawn on the fitted mesh (by area) to measure its coverage."""
TOP_BAND = 0.1
"""The fitted shape's top: its surface within this share of its height (along its canonical up,
+y) of its highest point."""
VOLUME_SAMPLES = 20_000
"""Points drawn in a fitted shape's cube to measure the share of its volume inside another."""

RULE = {"inlier_share_min": 0.3, "loss_margin_min": 0.12, "free_space_violation_max": 0.05,
        "latent_mahalanobis_ratio_max": 0.9, "surface_coverage_min": 0.25}
"""The flag's thresholds: "doubtful" when the inlier share is below ``inlier_share_min``, or
another pose's loss is within ``loss_margin_min`` (relative) of the winner's, or the free-space
violation is above ``free_space_violation_max``, or the code lies further from the training
codes than ``latent_mahalanobis_ratio_max`` times their median, or the object's points cover
less than ``surface_coverage_min`` of the fitted surface (chosen on a tuning set:
docs/confidence.md)."""


def fitted_sdf(decoder: Decoder, latent: np.ndarray, transform: Sim3, points: np.ndarray) -> np.ndarray:
    """The fitted shape's SDF (n,) at ``points`` (n, 3), scan units: s·f(T⁻¹x, z), negative inside
    (saturates at the decoder's clamp times s far from the surface)."""
    device = decoder_device(decoder)
    canonical = transform.inverse().apply(points)
    with torch.no_grad():
        x = torch.as_tensor(canonical, dtype=torch.float32, device=device)
        z = torch.as_tensor(np.asarray(latent), dtype=torch.float32, device=device)
        values = decoder(x, z) if len(x) else torch.zeros(0)
    return transform.s * values.detach().cpu().numpy().astype(np.float64)


def assess(decoder: Decoder, result: FitResult, *, surface: np.ndarray, points: np.ndarray, sdf: np.ndarray,
           codes: np.ndarray | None = None, seed: int = 0) -> dict[str, Any]:
    """The quality block of a fit.

    Parameters
    ----------
    decoder : the model's decoder
    result : the fit (its ``latent``, ``transform``, ``loss`` and ``hypotheses``)
    surface : (k, 3) the object's points (scan units)
    points, sdf : (m, 3), (m,) the query's SDF samples (scan units); those with sdf >=
        ``FREE_SPACE_MIN_M`` are observed free space
    codes : (n, d) the model's training codes, for the code's distance under the prior

    Returns
    -------
    dict of JSON-ready numbers (None where a measure does not apply), see ``MEASURES``
    """
    rng = np.random.default_rng(seed)
    s = result.transform.s
    out: dict[str, Any] = {"scale_m": s}
    if result.latent is None:
        return out
    seen = np.asarray(surface, float)
    surface = _subset(seen, rng)
    distance = np.abs(fitted_sdf(decoder, result.latent, result.transform, surface))
    out.update(_point_measures(distance, s))
    out["surface_coverage"] = surface_coverage(result.mesh_canonical, result.transform, seen, seed=seed)
    free = np.asarray(points, float)[np.asarray(sdf) >= FREE_SPACE_MIN_M]
    free = _subset(free, rng)
    if len(free):
        inside = fitted_sdf(decoder, result.latent, result.transform, free) < 0
        out["free_space_violation"] = float(inside.mean())
    else:
        out["free_space_violation"] = None
    out["free_space_samples"] = len(free)
    out["loss_margin_rel"] = loss_margin(result, symmetric=_symmetry_test(decoder, result, rng))
    if codes is not None:
        out.update(latent_distance(result.latent, codes))
    return out


def _subset(points: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    if len(points) <= MAX_POINTS:
        return points
    return points[rng.choice(len(points), MAX_POINTS, replace=False)]


def _point_measures(distance: np.ndarray, scale: float) -> dict[str, Any]:
    """Inlier share and robust mean |SDF| of the object's points, given their |SDF| (k,)."""
    if not len(distance):
        return {"points": 0, "inlier_share": None, "mean_abs_sdf_m": None, "mean_abs_sdf_rel": None}
    kept = np.sort(distance)[: max(1, int(np.ceil(TRIM * len(distance))))]
    robust = float(kept.mean())
    return {"points": len(distance), "inlier_share": float((distance < INLIER_FRACTION * scale).mean()),
            "mean_abs_sdf_m": robust, "mean_abs_sdf_rel": robust / scale}


def loss_margin(result: FitResult, symmetric: Callable[[Sim3], bool] | None = None) -> float | None:
    """(loss of the best surviving hypothesis at another pose − the winner's loss) / the winner's
    loss; None without such a hypothesis. Small or negative: another pose explains the data as well.
    A pose at which ``symmetric`` says the winner's shape looks the same is not another pose."""
    winner = result.transform
    others = [h.loss for h in result.hypotheses
              if _other_pose(h, winner) and not (symmetric is not None and symmetric(h.transform))]
    if not others or not np.isfinite(result.loss) or result.loss <= 0:
        return None
    return float((min(others) - result.loss) / result.loss)


def _other_pose(h: HypothesisReport, winner: Sim3) -> bool:
    if h.pruned or h.transform is None or not np.isfinite(h.loss):
        return False
    return other_pose(h.transform, winner)


def other_pose(transform: Sim3, reference: Sim3) -> bool:
    """Whether ``transform`` places the shape at another pose than ``reference``: turned by more
    than ``OTHER_POSE_DEG`` or its centre moved by more than ``OTHER_POSE_SHIFT`` times the
    reference's scale."""
    turned = rotation_angle_deg(transform.R, reference.R) > OTHER_POSE_DEG
    shifted = np.linalg.norm(transform.t - reference.t) > OTHER_POSE_SHIFT * reference.s
    return bool(turned or shifted)


def pose_distance(decoder: Decoder, latent: np.ndarray, winner: Sim3, other: Sim3, surface: np.ndarray) -> float:
    """How different the winner's shape placed at ``other`` is from itself placed at ``winner``,
    near its surface: the robust mean (over ``TRIM`` of the points) of the difference of their
    SDFs (scan units) at the winner's surface points ``surface`` (k, 3; canonical), divided by
    the winner's scale. 0 when ``other`` is a symmetry of the shape."""
    placed = winner.apply(surface)
    difference = np.abs(fitted_sdf(decoder, latent, other, placed) - fitted_sdf(decoder, latent, winner, placed))
    kept = np.sort(difference)[: max(1, int(np.ceil(TRIM * len(difference))))]
    return float(kept.mean() / winner.s)


def surface_points(decoder: Decoder, latent: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Points (k, 3; canonical) within ``SURFACE_BAND`` of the shape's surface: of
    ``SURFACE_PROBES`` uniform points in the unit ball, those whose |SDF| is under the band."""
    probes = rng.normal(size=(SURFACE_PROBES, 3))
    probes *= (rng.uniform(size=(SURFACE_PROBES, 1)) ** (1 / 3)) / np.linalg.norm(probes, axis=1, keepdims=True)
    sdf = fitted_sdf(decoder, latent, Sim3(1.0, np.eye(3), np.zeros(3)), probes)
    return probes[np.abs(sdf) < SURFACE_BAND]


def _symmetry_test(decoder: Decoder, result: FitResult, rng: np.random.Generator) -> Callable[[Sim3], bool] | None:
    """``other pose -> bool``: whether the winner's shape looks the same there (None without a
    surface to compare: every pose then counts as another)."""
    if not any(_other_pose(h, result.transform) for h in result.hypotheses):
        return None
    surface = surface_points(decoder, result.latent, rng)
    if len(surface) < 10:
        return None
    return lambda other: pose_distance(decoder, result.latent, result.transform, other, surface) < SAME_SHAPE_DISTANCE


def latent_distance(latent: np.ndarray, codes: np.ndarray) -> dict[str, float | None]:
    """The code's distance from the training codes, each relative to the training codes' own median:
    ``latent_norm_ratio`` = ‖z‖ / median ‖z_train‖; ``latent_mahalanobis_ratio`` = Mahalanobis
    distance of z / the median one of the training codes (slightly shrunk covariance). 1 is typical;
    None where the training codes are all zero (norm) or fewer than two (Mahalanobis)."""
    from jsrte.fit.params import LatentPrior

    codes = np.asarray(codes, dtype=np.float64)
    z = np.asarray(latent, dtype=np.float64)
    typical = float(np.median(np.linalg.norm(codes, axis=1)))
    out: dict[str, float | None] = {"latent_norm_ratio": float(np.linalg.norm(z) / typical) if typical > 1e-9 else None}
    if len(codes) > 1:
        prior = LatentPrior.of_codes(codes, shrinkage=0.01)
        train = np.linalg.norm(np.linalg.solve(prior.factor, (codes - prior.mean).T), axis=0)
        out["latent_mahalanobis_ratio"] = float(np.linalg.norm(prior.whiten(z)) / max(np.median(train), 1e-12))
    return out


def surface_coverage(mesh_canonical: Any, transform: Sim3, points: np.ndarray, seed: int = 0) -> float | None:
    """Share of the fitted surface that the scan saw: of ``COVERAGE_SAMPLES`` points drawn by area
    on the fitted mesh (``mesh_canonical``, a trimesh in the canonical frame, placed by
    ``transform``), those within ``COVERAGE_FRACTION`` times its scale of one of ``points`` (n, 3;
    the object's scan points, scan units). None without a mesh or points. Low on a fit that
    invents most of its shape: an object seen in part (half a bed, cut from the rest), or a shape
    laid over a scrap."""
    if mesh_canonical is None or not len(mesh_canonical.faces) or not len(points):
        return None
    drawn = np.asarray(mesh_canonical.sample(COVERAGE_SAMPLES, seed=seed), float)
    return _covered_share(transform.apply(drawn), points, transform.s)


def top_coverage(mesh_canonical: Any, transform: Sim3, points: np.ndarray, seed: int = 0) -> float | None:
    """Share of the fitted shape's top that the scan saw: as :func:`surface_coverage`, of the
    drawn points in its highest ``TOP_BAND`` of height (canonical +y). A table is seen by its
    top; a table fitted to something else (a piece of a sofa or bed, two objects at once) puts
    its top where the scan saw little."""
    if mesh_canonical is None or not len(mesh_canonical.faces) or not len(points):
        return None
    drawn = np.asarray(mesh_canonical.sample(COVERAGE_SAMPLES, seed=seed), float)
    height = drawn[:, 1]
    top = drawn[height >= height.max() - TOP_BAND * np.ptp(height)]
    return _covered_share(transform.apply(top), points, transform.s)


def seen_through_share(mesh_canonical: Any, transform: Sim3, views: CameraViews | None,
                       seed: int = 0) -> float | None:
    """Share of the fitted surface that the scan's cameras saw through: of ``COVERAGE_SAMPLES``
    points drawn by area on the fitted mesh (``mesh_canonical`` placed by ``transform``), those
    in the observed free space of some camera of ``views``, clear of every reading
    (``jsrte.scans.views.CameraViews.seen_through``). None without a mesh or without the cameras
    and which camera saw each point. High on a shape the scan contradicts (fitted too big, or over
    the floor beside its object); low on a right fit whatever was not seen of it."""
    if views is None or mesh_canonical is None or not len(mesh_canonical.faces):
        return None
    drawn = transform.apply(np.asarray(mesh_canonical.sample(COVERAGE_SAMPLES, seed=seed), float))
    return float(views.seen_through(drawn).mean())


def volume_inside(decoder: Decoder, result: FitResult, other_decoder: Decoder, other: FitResult,
                  seed: int = 0) -> float | None:
    """Share of the volume of the fitted shape of ``result`` (decoded by ``decoder``) that lies
    inside the fitted shape of ``other`` (by ``other_decoder``): of ``VOLUME_SAMPLES`` points
    drawn uniformly in the first shape's canonical cube [-1, 1]³ (the unit sphere holds every
    normalized shape), placed by its transform, those inside it (SDF < 0), the share inside the
    other. None when no drawn point is inside the first shape."""
    drawn = result.transform.apply(np.random.default_rng(seed).uniform(-1.0, 1.0, size=(VOLUME_SAMPLES, 3)))
    inside = drawn[fitted_sdf(decoder, result.latent, result.transform, drawn) < 0]
    if not len(inside):
        return None
    return float((fitted_sdf(other_decoder, other.latent, other.transform, inside) < 0).mean())


def _covered_share(drawn: np.ndarray, points: np.ndarray, scale: float) -> float:
    """Share of ``drawn`` (m, 3) within ``COVERAGE_FRACTION * scale`` of one of ``points`` (n, 3)."""
    from pykdtree.kdtree import KDTree

    distance, _ = KDTree(np.ascontiguousarray(points, dtype=np.float64)).query(drawn, k=1)
    return float((distance < COVERAGE_FRACTION * scale).mean())


def flag_of(quality: dict[str, Any], rule: dict[str, float] = RULE) -> str:
    """"doubtful" when a measure of ``quality`` breaks ``rule`` (or there is no surface to measure),
    else "ok". A measure that is None (no other pose survived, no free-space samples) breaks nothing."""
    inliers = quality.get("inlier_share")
    if inliers is None or inliers < rule["inlier_share_min"]:
        return "doubtful"
    margin = quality.get("loss_margin_rel")
    if margin is not None and margin < rule["loss_margin_min"]:
        return "doubtful"
    violation = quality.get("free_space_violation")
    if violation is not None and violation > rule["free_space_violation_max"]:
        return "doubtful"
    code = quality.get("latent_mahalanobis_ratio")
    if code is not None and code > rule["latent_mahalanobis_ratio_max"]:
        return "doubtful"
    coverage = quality.get("surface_coverage")
    if coverage is not None and coverage < rule.get("surface_coverage_min", 0.0):
        return "doubtful"
    return "ok"


MEASURES = {
    "scale_m": "the fit's scale s: radius of the fitted shape's bounding sphere (scan units)",
    "points": "object points evaluated",
    "inlier_share": f"share of the object's points with |fitted SDF| < {INLIER_FRACTION} s",
    "mean_abs_sdf_m": f"mean |fitted SDF| of the object's points, the smallest {TRIM:.0%} (scan units)",
    "mean_abs_sdf_rel": "mean_abs_sdf_m / s",
    "free_space_violation": f"share of observed free-space samples (query SDF >= {FREE_SPACE_MIN_M} m) "
                            "that the fitted shape holds inside",
    "free_space_samples": "free-space samples evaluated",
    "loss_margin_rel": "(best loss at another pose - winner's loss) / winner's loss",
    "latent_norm_ratio": "|z| / median |z| of the training codes",
    "latent_mahalanobis_ratio": "Mahalanobis distance of z / median one of the training codes",
    "surface_coverage": f"share of the fitted surface within {COVERAGE_FRACTION} s of the object's points "
                        "(None without a mesh)",
    "top_coverage": f"objects of a scene: the same share of the fitted surface's top (its highest "
                    f"{TOP_BAND:.0%} of height)",
    "seen_through": "objects of a scene: share of the fitted surface in space the cameras saw through, "
                    "clear of every scan point (None without the cameras or the view of each point)",
}
"""Each measure of the quality block and its unit."""


def quality_columns(result: FitResult) -> dict[str, Any]:
    """A fit's flag and quality block as flat table columns (``flag``, ``quality_<measure>``); empty
    for a fit that was not assessed (baselines)."""
    if result.flag is None:
        return {}
    return {"flag": result.flag} | {f"quality_{k}": _rounded(v) for k, v in result.quality.items()}


def _rounded(value: Any) -> Any:
    if isinstance(value, float):
        return round(value, 5) if np.isfinite(value) else None
    return value
