"""Evidence from the floor (beyond the paper): the object stands on it, so nothing of it lies below.

A scan's floor plane is removed before its SDF samples are built, and with it the knowledge
that the object ends there: on sparse scans (legs barely seen) fits sank through the floor.
A point at depth d under the floor is at least d from an object standing on it, so samples
under the floor carry their depth as a *lower bound* on the SDF: the loss counts only
predictions that fall short of it (``SdfQuery.lower_bound``).

Nor does it float: furniture touches the floor. Where only a table's top or a bed's upper side
was seen, nothing in the scan's samples says how far down the shape reaches, and fits ended with
their legs in the air. :class:`FloorContact` adds, per hypothesis, a penalty on the gap between
the fitted shape and the floor plane under it (``FitSettings.floor_contact``).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import torch

from jsrte.fit.params import HypothesisBatch
from jsrte.fit.query import SdfQuery
from jsrte.presets import FitSettings


def with_below_floor_samples(query: SdfQuery, n: int, *, clamp: float, rng: np.random.Generator,
                             depth: tuple[float, float] = FitSettings.below_floor_depth,
                             spread: float = 1.5) -> SdfQuery:
    """``query`` plus ``n`` samples under its floor (unchanged without a floor or for ``n`` 0).

    The samples lie in a disc of ``spread`` times the object's horizontal radius about its
    horizontal centre (from ``query.surface``), ``depth`` × ``clamp`` below the floor plane
    (scan units). Their SDF is their depth, marked as a lower bound on the true distance to an
    object standing on the floor (beyond the clamp it just says "outside"). They go before the
    query's refine-only tail (line-of-sight samples).
    """
    if n <= 0 or query.up is None or query.floor_offset is None:
        return query
    up, centre, radius, basis = _footprint(query, spread)
    r = radius * np.sqrt(rng.uniform(size=n))
    angle = rng.uniform(0, 2 * np.pi, size=n)
    below = rng.uniform(depth[0] * clamp, depth[1] * clamp, size=n)
    points = (centre + (r * np.cos(angle))[:, None] * basis[0] + (r * np.sin(angle))[:, None] * basis[1]
              + np.outer(query.floor_offset - below, up))
    split = len(query.sdf) - query.n_refine_only
    lower = np.zeros(len(query.sdf), bool) if query.lower_bound is None else query.lower_bound
    return replace(query, points=np.concatenate([query.points[:split], points, query.points[split:]]),
                   sdf=np.concatenate([query.sdf[:split], below, query.sdf[split:]]),
                   lower_bound=np.concatenate([lower[:split], np.ones(n, bool), lower[split:]]))


def _footprint(query: SdfQuery, spread: float) -> tuple[np.ndarray, np.ndarray, float, np.ndarray]:
    """The disc about the object's horizontal centre (from ``query.surface``) reaching ``spread``
    times its horizontal radius: the unit up axis (3,), the centre (3,) in the plane through the
    origin normal to up, the disc's radius (scan units) and two unit vectors spanning the plane
    (2, 3)."""
    up = np.asarray(query.up, float) / np.linalg.norm(query.up)
    flat = query.surface - np.outer(query.surface @ up, up)
    centre = flat.mean(0)
    radius = spread * float(np.linalg.norm(flat - centre, axis=1).max())
    basis = np.linalg.svd(up[None, :])[2][1:]  # (2, 3): two unit vectors orthogonal to up
    return up, centre, radius, basis


def floor_grid(query: SdfQuery, n: int, *, spread: float = 1.5) -> tuple[np.ndarray, float] | None:
    """About ``n`` points of a square grid on the floor plane, in the disc of ``spread`` times the
    object's horizontal radius about its horizontal centre: (m, 3) float64 scan units, and the
    grid's spacing (scan units). None without a floor or for ``n`` 0."""
    if n <= 0 or query.up is None or query.floor_offset is None:
        return None
    up, centre, radius, basis = _footprint(query, spread)
    spacing = radius * float(np.sqrt(np.pi / n))
    steps = np.arange(-radius, radius + spacing / 2, spacing)
    u, v = (a.ravel() for a in np.meshgrid(steps, steps))
    inside = u * u + v * v <= radius * radius
    points = centre + np.outer(u[inside], basis[0]) + np.outer(v[inside], basis[1]) + query.floor_offset * up
    return points, spacing


class FloorContact:
    """The floor-contact penalty of every hypothesis (H,), w · (max(0, min_c s·f(c) − τ) +
    max(0, d − min_c s·f(c − d·up))): the fitted shape's SDF at the floor grid's points ``c`` is at
    most the grid's half-diagonal wherever the shape reaches the floor (a point that near the
    contact) and about the gap where it floats, which counts beyond the ``tolerance`` τ (at least
    that half-diagonal: a model's thin legs may end short of the floor); at the same grid lowered
    by ``depth`` d it is at least d unless the shape pokes through the floor (by about d less the
    least SDF there). Zero for a shape standing on the floor; linear in the gap beyond τ and in
    the depth it sinks (up to d).

    The minima are taken over each hypothesis's ``keep`` lowest grid points, chosen every
    ``refresh`` iterations by forward passes over the whole grid (and shared, so every hypothesis
    is evaluated at the union); :meth:`final` takes them over the whole grid.

    ``points`` (m, 3) scan units on the decoder's device; ``up`` (3,) unit; ``spacing`` the
    grid's, ``depth`` and ``tolerance`` scan units.
    """

    def __init__(self, points: torch.Tensor, up: torch.Tensor, spacing: float, *, weight: float, depth: float,
                 tolerance: float = 0.0, keep: int = 8, refresh: int = 10) -> None:
        self.points = points
        self.below = points - depth * up
        self.tolerance = max(spacing / np.sqrt(2.0), tolerance)
        self.depth = depth
        self.weight = weight
        self.keep = keep
        self.refresh = refresh
        self.active: torch.Tensor | None = None
        self.evaluations = 0
        """Decoder evaluations spent so far (hypotheses times points)."""

    def penalty(self, decoder: torch.nn.Module, batch: HypothesisBatch, iteration: int, *,
                bfloat16: bool = False) -> torch.Tensor:
        """(H,) the penalty at this iteration (differentiable); the grid's lowest points chosen
        again where ``iteration`` is a multiple of ``refresh`` (or none are yet)."""
        if self.active is None or iteration % self.refresh == 0:
            with torch.no_grad():
                sdf = batch.sdf(decoder, self.points, bfloat16=bfloat16)
            self.evaluations += sdf.numel()
            lowest = torch.topk(sdf, min(self.keep, sdf.shape[1]), dim=1, largest=False).indices
            self.active = torch.unique(lowest)
        n = len(self.active)
        sdf = batch.sdf(decoder, torch.cat([self.points[self.active], self.below[self.active]]), bfloat16=bfloat16)
        self.evaluations += sdf.numel()
        return self._of(sdf[:, :n], sdf[:, n:])

    def final(self, decoder: torch.nn.Module, batch: HypothesisBatch) -> torch.Tensor:
        """(H,) the penalty over the whole grid (forward passes, float32)."""
        self.evaluations += 2 * len(batch) * len(self.points)
        with torch.no_grad():
            return self._of(batch.sdf(decoder, self.points), batch.sdf(decoder, self.below))

    def _of(self, at_floor: torch.Tensor, below: torch.Tensor) -> torch.Tensor:
        gap = (at_floor.min(dim=1).values - self.tolerance).clamp(min=0.0)
        sunk = (self.depth - below.min(dim=1).values).clamp(min=0.0)
        return self.weight * (gap + sunk)


def floor_contact(query: SdfQuery, weight: float, n: int, *, depth: float, tolerance: float,
                  device: torch.device) -> FloorContact | None:
    """The :class:`FloorContact` of ``query``'s floor (grid of about ``n`` points, lowered by
    ``depth`` scan units to tell a shape that sinks; a gap counts beyond ``tolerance`` scan
    units), None where the weight is 0 or the query knows no floor."""
    grid = None if weight <= 0 else floor_grid(query, n)
    if grid is None:
        return None
    points, spacing = grid
    up = np.asarray(query.up, float) / np.linalg.norm(query.up)
    return FloorContact(torch.as_tensor(points, dtype=torch.float64, device=device),
                        torch.as_tensor(up, dtype=torch.float64, device=device), spacing, weight=weight, depth=depth,
                        tolerance=tolerance)
