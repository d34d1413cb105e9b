"""Evidence from the floor (beyond the paper): the object stands on it, so nothing of it lies below.

A scan's floor plane is removed before its SDF samples are built, and with it the knowledge
that the object ends there: on sparse scans (legs barely seen) fits sank through the floor.
A point at depth d under the floor is at least d from an object standing on it, so samples
under the floor carry their depth as a *lower bound* on the SDF: the loss counts only
predictions that fall short of it (``SdfQuery.lower_bound``).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

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
    up = np.asarray(query.up, float) / np.linalg.norm(query.up)
    flat = query.surface - np.outer(query.surface @ up, up)
    centre = flat.mean(0)
    radius = spread * float(np.linalg.norm(flat - centre, axis=1).max())
    basis = np.linalg.svd(up[None, :])[2][1:]  # (2, 3): two unit vectors orthogonal to up
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
