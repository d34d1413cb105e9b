"""Meshes from a signed distance function: marching cubes on a dense or coarse-to-fine grid.

Grid convention: ``resolution`` samples per axis over ``[-bound, bound]^3`` (both ends
included), so the spacing is ``h = 2 * bound / (resolution - 1)`` and grid index ``(i, j, k)``
is the point ``-bound + h * (i, j, k)`` (x, y, z in canonical coordinates, as DeepSDF does).
The SDF is negative inside; faces of the returned meshes are oriented outward.

Decoding the grid dominates the cost (a 6x256 decoder evaluates ~90k points/s on two CPU
cores: 128^3 takes ~25 s), so :func:`extract_coarse_to_fine` evaluates the function only in
cells the surface may cross and gives the same mesh as :func:`extract_dense`, and
:func:`extract_narrow_band` evaluates only a band about one grid spacing wide around it.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import torch
import trimesh
from skimage import measure

from jsrte.errors import JsrteError

SdfFunction = Callable[[torch.Tensor], torch.Tensor]
"""``points (n, 3) float32 tensor`` in the canonical cube -> ``sdf (n,)`` (or ``(n, 1)``) tensor."""

NARROW_BAND = 1.0
"""Half-width, in fine grid spacings, of the band :func:`extract_narrow_band` evaluates on the
last level: samples whose estimate lies closer to the level set are evaluated. The cells that
turn out to change sign get all their corners evaluated as well, so the band may be narrower
than the sqrt(3) spacings a crossing cell's corner can lie from the surface (chosen on
training codes of the shipped chair model, docs/speed.md)."""

COARSE_BAND = 2.0
"""The same half-width on the earlier, coarser levels (cheap there; it keeps thin parts that a
coarser level barely resolves)."""

REFINE_MARGIN = 0.5
"""A cell is refined when a corner's |sdf - level| is below its diagonal times (1 + margin).

For a true distance function (1-Lipschitz) a margin of 0 is exact; learned decoders are
only roughly Lipschitz, so refine a band somewhat wider than the cell.
"""


@dataclass(frozen=True)
class Extraction:
    """A marching-cubes result.

    Attributes
    ----------
    mesh : trimesh.Trimesh or None
        The level set in canonical coordinates, faces oriented outward, vertices merged;
        None when the level set does not cross the grid.
    evaluations : int
        How many points were passed to the SDF function.
    """

    mesh: trimesh.Trimesh | None
    evaluations: int


def grid_spacing(resolution: int, bound: float) -> float:
    """Distance between neighbouring grid samples for ``resolution`` samples over [-bound, bound]."""
    return 2.0 * bound / (resolution - 1)


def extract_dense(
    sdf_fn: SdfFunction,
    *,
    resolution: int = 128,
    bound: float = 1.0,
    chunk: int = 65536,
    level: float = 0.0,
) -> Extraction:
    """Evaluate ``sdf_fn`` on the full ``resolution^3`` grid and run marching cubes.

    Parameters
    ----------
    sdf_fn : SdfFunction
        Canonical points (n, 3) float32 -> sdf (n,); called under ``torch.no_grad`` on at
        most ``chunk`` points at a time (memory stays bounded).
    resolution : int
        Samples per axis (>= 2).
    bound : float
        The grid covers [-bound, bound]^3 (canonical units).
    chunk : int
        Points per call of ``sdf_fn``.
    level : float
        The iso-value to extract.

    Returns
    -------
    Extraction
        ``evaluations == resolution**3``.
    """
    _check_grid(resolution, bound, chunk)
    n = resolution
    h = grid_spacing(n, bound)
    values = np.empty(n**3, dtype=np.float32)
    for start in range(0, n**3, chunk):  # indices made per chunk: memory stays bounded
        flat = np.arange(start, min(start + chunk, n**3), dtype=np.int64)
        values[start:start + len(flat)] = _evaluate_indices(sdf_fn, flat, n, h, bound, chunk)
    values = values.reshape(n, n, n)
    return Extraction(mesh=_marching_cubes(values, h, bound, level), evaluations=n**3)


def extract_coarse_to_fine(
    sdf_fn: SdfFunction,
    *,
    resolution: int = 256,
    coarse_resolution: int = 32,
    bound: float = 1.0,
    chunk: int = 65536,
    level: float = 0.0,
    margin: float = REFINE_MARGIN,
) -> Extraction:
    """Marching cubes at ``resolution`` evaluating ``sdf_fn`` only near the surface.

    The fine grid is sampled first with a stride ``k`` (a power of two chosen so that about
    ``coarse_resolution`` samples lie on each axis; the last sample of each axis is always
    included, so the last coarse cell may be shorter). Then, halving the stride each time
    down to 1: a cell whose eight corners were all evaluated is *active* when its corners
    change sign or one of them has ``|sdf - level|`` below the cell diagonal times
    ``1 + margin`` (the surface may cross it); the next level's samples on active cells are
    evaluated, the other samples are filled with ``level ± fill`` by the sign of the cell
    they lie in, ``fill`` larger than any cell diagonal. Marching cubes then runs on the full
    fine grid. Every fine cell the surface crosses has its eight corners evaluated, so for a
    1-Lipschitz SDF the mesh equals :func:`extract_dense`'s exactly.

    Parameters
    ----------
    sdf_fn, bound, chunk, level
        As for :func:`extract_dense`.
    resolution : int
        Samples per axis of the fine grid (>= 2).
    coarse_resolution : int
        About this many samples per axis on the first, fully evaluated grid.
    margin : float
        Safety margin on the refinement band (see :data:`REFINE_MARGIN`).

    Returns
    -------
    Extraction
        ``evaluations`` counts every point passed to ``sdf_fn`` (each grid sample at most once).
    """
    _check_grid(resolution, bound, chunk)
    if coarse_resolution < 2:
        raise ValueError(f"coarse_resolution must be >= 2, got {coarse_resolution}")
    n = resolution
    h = grid_spacing(n, bound)
    fill = np.float32(4.0 * bound * math.sqrt(3.0))  # > the grid's diameter
    values = np.full((n, n, n), np.nan, dtype=np.float32)
    evaluated = np.zeros((n, n, n), dtype=bool)
    stride = _initial_stride(n, coarse_resolution)

    axis = _axis_samples(n, stride)
    count = _evaluate_subgrid(sdf_fn, values, evaluated, axis, None, h, bound, chunk)
    while stride > 1:
        finer = _axis_samples(n, stride // 2)
        sub = np.ix_(axis, axis, axis)
        active = _active_cells(values[sub] - level, evaluated[sub],
                               threshold=stride * h * math.sqrt(3.0) * (1.0 + margin))
        lo, hi = _containing_cells(axis, finer)
        touched = _touched_by(active, lo, hi)
        count += _evaluate_subgrid(sdf_fn, values, evaluated, finer, touched, h, bound, chunk)
        _fill_untouched(values, finer, touched, values[sub] - level, lo, level, fill)
        axis, stride = finer, stride // 2
    return Extraction(mesh=_marching_cubes(values, h, bound, level), evaluations=count)


def extract_narrow_band(
    sdf_fn: SdfFunction,
    *,
    resolution: int = 128,
    coarse_resolution: int = 16,
    bound: float = 1.0,
    chunk: int = 65536,
    level: float = 0.0,
    band: float = NARROW_BAND,
    coarse_band: float = COARSE_BAND,
) -> Extraction:
    """Marching cubes at ``resolution`` evaluating ``sdf_fn`` only in a thin band around the surface.

    Like :func:`extract_coarse_to_fine` the grid is sampled with a power-of-two stride first
    (about ``coarse_resolution`` samples per axis, all evaluated), then the stride is halved
    down to 1. At each finer level every new sample first gets the trilinear interpolation of
    the coarser level's values; only the samples whose estimate lies within ``band`` times the
    new spacing of the level set are evaluated (``coarse_band`` spacings on the earlier levels,
    ``band`` on the last). Then, until nothing changes, every cell of the
    new level whose corners change sign and which has a corner still estimated gets its
    corners evaluated. Samples never evaluated keep their estimate (far from the surface its
    sign is right, its value a smooth guess), and marching cubes runs on the full fine grid.

    The cost grows with the surface area in cells instead of the volume: for a 128^3 chair
    about a fifth of the decoder calls of :func:`extract_coarse_to_fine` and 2-3% of
    :func:`extract_dense` (docs/speed.md). For smooth shapes the mesh equals the dense one;
    features thinner than the coarse spacing that no estimate brings near the band can be
    missed, as in any sparse scheme.

    Parameters
    ----------
    sdf_fn, bound, chunk, level
        As for :func:`extract_dense`.
    resolution : int
        Samples per axis of the fine grid (>= 2).
    coarse_resolution : int
        About this many samples per axis on the first, fully evaluated grid.
    band, coarse_band : float
        Half-width of the evaluated band in units of the level's grid spacing, on the last
        level and on the earlier ones (see :data:`NARROW_BAND`, :data:`COARSE_BAND`).

    Returns
    -------
    Extraction
        ``evaluations`` counts every point passed to ``sdf_fn`` (each grid sample at most once).
    """
    _check_grid(resolution, bound, chunk)
    if coarse_resolution < 2:
        raise ValueError(f"coarse_resolution must be >= 2, got {coarse_resolution}")
    if not (band > 0 and coarse_band > 0):
        raise ValueError(f"band and coarse_band must be positive, got {band} and {coarse_band}")
    n = resolution
    h = grid_spacing(n, bound)
    values = np.zeros((n, n, n), dtype=np.float32)
    evaluated = np.zeros((n, n, n), dtype=bool)
    stride = _initial_stride(n, coarse_resolution)
    axis = _axis_samples(n, stride)
    count = _evaluate_subgrid(sdf_fn, values, evaluated, axis, None, h, bound, chunk)
    while stride > 1:
        finer = _axis_samples(n, stride // 2)
        estimate = _interpolate_subgrid(_subgrid(values, axis), axis, finer)
        known = _subgrid(evaluated, finer)
        if len(finer) == n:  # the last level: write in place
            np.copyto(values, estimate, where=~known)
        else:
            values[np.ix_(finer, finer, finer)] = np.where(known, _subgrid(values, finer), estimate)
        width = (band if stride == 2 else coarse_band) * (stride // 2) * h
        near = ~known & (np.abs(estimate - np.float32(level)) < width)
        count += _evaluate_subgrid(sdf_fn, values, evaluated, finer, near, h, bound, chunk)
        count += _close_crossings(sdf_fn, values, evaluated, finer, level, h, bound, chunk)
        axis, stride = finer, stride // 2
    return Extraction(mesh=_marching_cubes(values, h, bound, level), evaluations=count)


# --- grid evaluation ---------------------------------------------------------------------


def _check_grid(resolution: int, bound: float, chunk: int) -> None:
    if resolution < 2:
        raise ValueError(f"resolution must be >= 2, got {resolution}")
    if not bound > 0:
        raise ValueError(f"bound must be positive, got {bound}")
    if chunk < 1:
        raise ValueError(f"chunk must be >= 1, got {chunk}")


def _evaluate_indices(
    sdf_fn: SdfFunction, flat: np.ndarray, n: int, h: float, bound: float, chunk: int
) -> np.ndarray:
    """SDF at flat grid indices ``flat`` (m,) int64 of an ``n^3`` grid -> (m,) float32."""
    out = np.empty(len(flat), dtype=np.float32)
    with torch.no_grad():
        for start in range(0, len(flat), chunk):
            idx = flat[start:start + chunk]
            ijk = np.stack([idx // (n * n), (idx // n) % n, idx % n], axis=1)
            points = torch.from_numpy((ijk * h - bound).astype(np.float32))
            sdf = sdf_fn(points)
            out[start:start + len(idx)] = sdf.detach().reshape(-1).to("cpu", torch.float32).numpy()
    return out


def _evaluate_subgrid(
    sdf_fn: SdfFunction,
    values: np.ndarray,
    evaluated: np.ndarray,
    axis: np.ndarray,
    wanted: np.ndarray | None,
    h: float,
    bound: float,
    chunk: int,
) -> int:
    """Evaluate the samples ``axis^3`` (where ``wanted``, all if None) not evaluated yet.

    Writes into ``values`` / ``evaluated`` (fine grid, (n, n, n)); returns the count.
    """
    n = values.shape[0]
    todo = ~_subgrid(evaluated, axis)
    if wanted is not None:
        todo &= wanted
    a, b, c = np.nonzero(todo)
    flat = (axis[a] * n + axis[b]) * n + axis[c]
    if len(flat):
        values.reshape(-1)[flat] = _evaluate_indices(sdf_fn, flat, n, h, bound, chunk)
        evaluated.reshape(-1)[flat] = True
    return len(flat)


# --- coarse-to-fine bookkeeping ----------------------------------------------------------


def _initial_stride(n: int, coarse_resolution: int) -> int:
    """The power-of-two stride giving about ``coarse_resolution`` samples per axis."""
    if coarse_resolution >= n:
        return 1
    ratio = (n - 1) / (coarse_resolution - 1)
    return 2 ** max(0, round(math.log2(ratio)))


def _axis_samples(n: int, stride: int) -> np.ndarray:
    """Fine-grid indices 0, stride, 2 stride, ... and always n - 1: (m,) int64."""
    samples = np.arange(0, n, stride, dtype=np.int64)
    if samples[-1] != n - 1:
        samples = np.append(samples, n - 1)
    return samples


def _active_cells(shifted: np.ndarray, evaluated: np.ndarray, *, threshold: float) -> np.ndarray:
    """Cells (m-1)^3 of a sub-grid m^3 the level set may cross.

    ``shifted`` holds sdf - level on the sub-grid; only cells with all corners evaluated
    can be active (the others lie in regions already known to be free of surface).
    """
    corners = [(slice(0, -1), slice(1, None))] * 3
    lo = np.full(tuple(s - 1 for s in shifted.shape), np.inf, dtype=np.float32)
    hi = np.full_like(lo, -np.inf)
    nearest = np.full_like(lo, np.inf)
    complete = np.ones(lo.shape, dtype=bool)
    for sx in corners[0]:
        for sy in corners[1]:
            for sz in corners[2]:
                v = shifted[sx, sy, sz]
                np.minimum(lo, v, out=lo)
                np.maximum(hi, v, out=hi)
                np.minimum(nearest, np.abs(v), out=nearest)
                complete &= evaluated[sx, sy, sz]
    crossing = (lo <= 0) & (hi >= 0)
    return complete & (crossing | (nearest < threshold))


def _containing_cells(coarse: np.ndarray, fine: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For each fine sample (fine-grid index), the coarse cells along one axis containing it.

    Returns ``lo, hi`` (len(fine),) int: the cell to the left and to the right of a sample on
    a coarse sample (equal inside a cell), clipped to the valid cell range.
    """
    cells = len(coarse) - 1
    right = np.searchsorted(coarse, fine, side="right") - 1  # cell starting at or before
    lo = np.clip(right, 0, cells - 1)
    on_sample = coarse[np.clip(right, 0, cells)] == fine
    left = np.where(on_sample, right - 1, right)
    hi = np.clip(left, 0, cells - 1)
    return lo, hi


def _touched_by(active: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Fine samples (len(lo),)^3 lying on an active coarse cell (including its boundary)."""
    touched = np.zeros((len(lo),) * 3, dtype=bool)
    for cx in (lo, hi):
        for cy in (lo, hi):
            for cz in (lo, hi):
                touched |= active[np.ix_(cx, cy, cz)]
    return touched


def _fill_untouched(
    values: np.ndarray,
    fine: np.ndarray,
    touched: np.ndarray,
    coarse_shifted: np.ndarray,
    lo: np.ndarray,
    level: float,
    fill: np.float32,
) -> None:
    """Give not-yet-valued fine samples off active cells ``level ± fill`` (sign of their cell)."""
    sub = np.ix_(fine, fine, fine)
    missing = np.isnan(values[sub]) & ~touched
    a, b, c = np.nonzero(missing)
    if not len(a):
        return
    sign = np.where(coarse_shifted[lo[a], lo[b], lo[c]] < 0, -1.0, 1.0).astype(np.float32)
    n = values.shape[0]
    flat = (fine[a] * n + fine[b]) * n + fine[c]
    values.reshape(-1)[flat] = np.float32(level) + sign * fill


def _interpolate_subgrid(coarse_values: np.ndarray, coarse: np.ndarray, fine: np.ndarray) -> np.ndarray:
    """Trilinear interpolation of values on the sub-grid ``coarse^3`` at the sub-grid ``fine^3``.

    ``coarse`` (m,) and ``fine`` (k,) are increasing fine-grid indices with the same ends;
    returns (k, k, k) float32.
    """
    cell = np.clip(np.searchsorted(coarse, fine, side="right") - 1, 0, len(coarse) - 2)
    weight = ((fine - coarse[cell]) / (coarse[cell + 1] - coarse[cell])).astype(np.float32)
    out = coarse_values
    for axis in range(3):
        shape = [1, 1, 1]
        shape[axis] = len(fine)
        w = weight.reshape(shape)
        out = np.take(out, cell, axis=axis) * (1 - w) + np.take(out, cell + 1, axis=axis) * w
    return out


def _close_crossings(
    sdf_fn: SdfFunction,
    values: np.ndarray,
    evaluated: np.ndarray,
    axis: np.ndarray,
    level: float,
    h: float,
    bound: float,
    chunk: int,
) -> int:
    """Evaluate the corners of every sub-grid ``axis^3`` cell that changes sign with a corner
    not evaluated yet, until there is none; returns the count of new evaluations."""
    count = 0
    while True:
        known = _subgrid(evaluated, axis)
        inside = _subgrid(values, axis) < level
        crossing = _cells_where_any(inside) & ~_cells_where_all(inside)
        wanted = _cell_corners(crossing & _cells_where_any(~known)) & ~known
        if not wanted.any():
            return count
        count += _evaluate_subgrid(sdf_fn, values, evaluated, axis, wanted, h, bound, chunk)


def _subgrid(array: np.ndarray, axis: np.ndarray) -> np.ndarray:
    """``array[axis][:, axis][:, :, axis]`` for an (n, n, n) array: a view when ``axis`` is every index."""
    if len(axis) == array.shape[0]:
        return array
    return array[np.ix_(axis, axis, axis)]


def _cells_where_any(samples: np.ndarray) -> np.ndarray:
    """Cells (m-1)^3 of a boolean sample grid (m, m, m) with at least one corner True."""
    out = np.zeros(tuple(s - 1 for s in samples.shape), dtype=bool)
    for sx in (slice(0, -1), slice(1, None)):
        for sy in (slice(0, -1), slice(1, None)):
            for sz in (slice(0, -1), slice(1, None)):
                out |= samples[sx, sy, sz]
    return out


def _cells_where_all(samples: np.ndarray) -> np.ndarray:
    """Cells (m-1)^3 of a boolean sample grid (m, m, m) with all eight corners True."""
    out = np.ones(tuple(s - 1 for s in samples.shape), dtype=bool)
    for sx in (slice(0, -1), slice(1, None)):
        for sy in (slice(0, -1), slice(1, None)):
            for sz in (slice(0, -1), slice(1, None)):
                out &= samples[sx, sy, sz]
    return out


def _cell_corners(cells: np.ndarray) -> np.ndarray:
    """Samples (m, m, m) that are a corner of some cell marked in ``cells`` (m-1, m-1, m-1)."""
    corners = np.zeros(tuple(s + 1 for s in cells.shape), dtype=bool)
    for sx in (slice(0, -1), slice(1, None)):
        for sy in (slice(0, -1), slice(1, None)):
            for sz in (slice(0, -1), slice(1, None)):
                corners[sx, sy, sz] |= cells
    return corners


# --- marching cubes ----------------------------------------------------------------------


def _marching_cubes(values: np.ndarray, h: float, bound: float, level: float) -> trimesh.Trimesh | None:
    """Level set of a full grid (n, n, n) -> outward-oriented mesh in canonical coordinates."""
    if not np.all(np.isfinite(values)):
        raise JsrteError("the SDF gave NaN or infinite values (is the model damaged?)")
    if values.min() > level or values.max() < level:
        return None
    # skimage's "descent" (its default, documented for a solid holding the larger values)
    # winds the faces so that, with our (i, j, k) -> (x, y, z) axes and the SDF negative
    # inside, normals point out of the solid (tests/test_extract.py checks volume > 0).
    verts, faces, _, _ = measure.marching_cubes(
        values, level=level, spacing=(h, h, h), gradient_direction="descent", allow_degenerate=False
    )
    if len(faces) == 0:
        return None
    mesh = trimesh.Trimesh(verts - bound, faces, process=True)
    return mesh if len(mesh.faces) else None
