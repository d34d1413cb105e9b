"""Starting points from the data, as the paper does for real scans.

The rotation axis is the floor normal (or a given up vector); the base rotation takes the
canonical +y to it, so θ turns the object about its own up axis; θ runs over a grid (30°
steps: 12 hypotheses). Scale and translation come from the query's bounding sphere (the
paper) or from the object's height above the floor (robust to partial scans).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from jsrte.errors import JsrteError
from jsrte.fit.params import Init
from jsrte.fit.query import SdfQuery
from jsrte.geometry.sim3 import rotation_between, spherical_from_axis
from jsrte.metrics.surface import bounding_sphere
from jsrte.presets import FitSettings

CANONICAL_UP = np.array([0.0, 1.0, 0.0])


@dataclass(frozen=True)
class ClassGeometry:
    """Size of the class's shapes in the canonical frame (from the model).

    Attributes
    ----------
    height : extent along +y (canonical units)
    radius : bounding-sphere radius (canonical units)
    """

    height: float
    radius: float


def theta_grid(step_deg: float, n: int | None = None) -> np.ndarray:
    """Initial yaw angles (radians): every ``step_deg`` degrees over a turn, or ``n`` evenly spread."""
    count = n if n is not None else int(round(360.0 / step_deg))
    if count < 1:
        raise JsrteError(f"need at least one hypothesis, got {count}")
    return np.arange(count) * (2.0 * np.pi / count)


def scale_and_translation(query: SdfQuery, geometry: ClassGeometry, up: np.ndarray,
                          mode: str) -> tuple[float, np.ndarray]:
    """s0 and t0 (3,) for the query: ``mode`` "sphere" (the paper) or "height"."""
    pts = query.surface
    if mode == "sphere":
        centre, radius = bounding_sphere(pts)
        return radius / geometry.radius, centre
    if mode != "height":
        raise ValueError(f"unknown init_scale mode {mode!r}")
    heights = pts @ up
    bottom = query.floor_offset if query.floor_offset is not None else float(heights.min())
    height = float(heights.max()) - bottom
    if height <= 0:
        raise JsrteError("the object has no height above the floor")
    flat = pts - np.outer(heights, up)
    horizontal = (flat.min(0) + flat.max(0)) / 2.0
    horizontal -= up * (horizontal @ up)
    return height / geometry.height, horizontal + up * (bottom + height / 2.0)


def initial_hypotheses(query: SdfQuery, geometry: ClassGeometry, settings: FitSettings, *,
                       n_hypotheses: int | None = None,
                       latent: np.ndarray | None = None) -> list[Init]:
    """One ``Init`` per yaw of the θ grid and per start scale (:func:`start_scales`), all
    sharing the up axis."""
    up = CANONICAL_UP if query.up is None else np.asarray(query.up, float) / np.linalg.norm(query.up)
    base = rotation_between(CANONICAL_UP, up)
    psi, rho = spherical_from_axis(up)
    return [Init(scale=float(np.clip(s0, settings.scale_min, settings.scale_max)), psi=psi, rho=rho,
                 theta=float(theta), translation=t0, latent=latent, base_rotation=base)
            for s0, t0 in start_scales(query, geometry, up, settings)
            for theta in theta_grid(settings.theta_grid_deg, n_hypotheses)]


def start_scales(query: SdfQuery, geometry: ClassGeometry, up: np.ndarray,
                 settings: FitSettings) -> list[tuple[float, np.ndarray]]:
    """The (s0, t0 (3,)) pairs the yaw starts begin from: one of ``settings.init_scale``; with
    "both", the height's, then the sphere's where the two scales differ by more than
    ``settings.init_scales_agree``."""
    if settings.init_scale != "both":
        return [scale_and_translation(query, geometry, up, settings.init_scale)]
    by_height = scale_and_translation(query, geometry, up, "height")
    by_sphere = scale_and_translation(query, geometry, up, "sphere")
    if abs(np.log(by_sphere[0] / by_height[0])) <= np.log1p(settings.init_scales_agree):
        return [by_height]
    return [by_height, by_sphere]
