"""RANSAC over point correspondences with Umeyama's similarity (scale included), batched."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from jsrte.geometry.sim3 import Sim3, umeyama


@dataclass(frozen=True)
class RansacResult:
    """The best similarity and its support.

    Attributes
    ----------
    transform : ``target_from_source`` Sim3, refit on all inliers
    inliers : (m,) bool over the correspondences
    rmse : RMS residual of the inliers (target units)
    """

    transform: Sim3
    inliers: np.ndarray
    rmse: float


def batched_umeyama(source: np.ndarray, target: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Umeyama's similarity for a batch: ``source``, ``target`` (b, k, 3) -> s (b,), R (b, 3, 3), t (b, 3)."""
    mx, my = source.mean(1, keepdims=True), target.mean(1, keepdims=True)
    xc, yc = source - mx, target - my
    cov = np.einsum("bki,bkj->bij", yc, xc) / source.shape[1]
    u, d, vt = np.linalg.svd(cov)
    sign = np.ones((len(source), 3))
    sign[:, 2] = np.where(np.linalg.det(u) * np.linalg.det(vt) < 0, -1.0, 1.0)
    r = u @ (sign[:, :, None] * vt)
    var_x = (xc**2).sum(axis=(1, 2)) / source.shape[1]
    s = (d * sign).sum(1) / np.maximum(var_x, 1e-300)
    t = my[:, 0] - s[:, None] * np.einsum("bij,bj->bi", r, mx[:, 0])
    return s, r, t


def ransac_similarity(source: np.ndarray, target: np.ndarray, *, threshold: float, iterations: int,
                      rng: np.random.Generator) -> RansacResult | None:
    """Robust ``target_from_source`` similarity from correspondences ``source[i] <-> target[i]``.

    Draws ``iterations`` minimal samples of 3 correspondences, scores each similarity by its
    inliers (residual below ``threshold``, target units; ties by the sum of residuals), then refits
    Umeyama on the best one's inliers. Returns None with fewer than 3 correspondences or when no
    sample gives a proper similarity.
    """
    source = np.asarray(source, dtype=np.float64)
    target = np.asarray(target, dtype=np.float64)
    m = len(source)
    if m < 3:
        return None
    picks = np.argsort(rng.random((iterations, m)), axis=1)[:, :3]
    s, r, t = batched_umeyama(source[picks], target[picks])
    good = np.isfinite(s) & (s > 1e-9)
    if not good.any():
        return None
    s, r, t = s[good], r[good], t[good]
    moved = s[:, None, None] * np.einsum("bij,mj->bmi", r, source) + t[:, None, :]
    residual = np.linalg.norm(moved - target[None], axis=2)
    inl = residual < threshold
    score = inl.sum(1) - np.minimum(residual, threshold).sum(1) / (threshold * (m + 1))
    best = int(np.argmax(score))
    inliers = inl[best]
    g = Sim3(s[best], r[best], t[best])
    if inliers.sum() >= 3:
        try:
            g = umeyama(source[inliers], target[inliers], with_scale=True)
        except ValueError:  # degenerate inliers (collinear): keep the minimal sample's estimate
            pass
    res = np.linalg.norm(g.apply(source) - target, axis=1)
    inliers = res < threshold
    rmse = float(np.sqrt(np.mean(res[inliers] ** 2))) if inliers.any() else float("inf")
    return RansacResult(g, inliers, rmse)
