"""Marching cubes from an SDF function: dense and coarse-to-fine against analytic shapes."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
import trimesh

from jsrte.extract.marching import (
    _axis_samples,
    _containing_cells,
    _interpolate_subgrid,
    extract_coarse_to_fine,
    extract_dense,
    extract_narrow_band,
)

RADIUS = 0.5
CENTRE = torch.tensor([0.1, -0.05, 0.02])
HALF = torch.tensor([0.5, 0.3, 0.4])


def sphere_sdf(points: torch.Tensor) -> torch.Tensor:
    return (points - CENTRE).norm(dim=1) - RADIUS


def box_sdf(points: torch.Tensor) -> torch.Tensor:
    q = points.abs() - HALF
    return q.clamp(min=0).norm(dim=1) + q.max(dim=1).values.clamp(max=0)


class Counter:
    """Wraps an SDF function; records every point it is given."""

    def __init__(self, fn):
        self.fn = fn
        self.points: list[torch.Tensor] = []

    def __call__(self, points: torch.Tensor) -> torch.Tensor:
        assert points.dtype == torch.float32 and points.shape[1] == 3
        assert not torch.is_grad_enabled()
        self.points.append(points.clone())
        return self.fn(points)

    @property
    def count(self) -> int:
        return sum(len(p) for p in self.points)


@pytest.fixture(scope="module")
def sphere_dense() -> trimesh.Trimesh:
    return extract_dense(sphere_sdf, resolution=128).mesh


def test_dense_sphere_area_volume_within_2_percent(sphere_dense):
    assert sphere_dense.area == pytest.approx(4 * math.pi * RADIUS**2, rel=0.02)
    assert sphere_dense.volume == pytest.approx(4 / 3 * math.pi * RADIUS**3, rel=0.02)
    assert sphere_dense.is_watertight


def test_dense_vertices_land_in_canonical_coordinates(sphere_dense):
    distances = np.linalg.norm(sphere_dense.vertices - CENTRE.numpy(), axis=1)
    h = 2.0 / 127
    assert np.abs(distances - RADIUS).max() < 0.1 * h


def test_faces_point_outward(sphere_dense):
    assert sphere_dense.volume > 0
    outward = sphere_dense.triangles_center - CENTRE.numpy()
    assert np.all(np.einsum("ij,ij->i", sphere_dense.face_normals, outward) > 0)


def test_dense_counts_every_grid_point():
    counter = Counter(sphere_sdf)
    result = extract_dense(counter, resolution=20, chunk=1000)
    assert result.evaluations == counter.count == 20**3
    assert max(len(p) for p in counter.points) <= 1000
    points = torch.cat(counter.points)
    assert points.min().item() == pytest.approx(-1.0) and points.max().item() == pytest.approx(1.0)


def test_coarse_to_fine_matches_dense_with_far_fewer_evaluations(sphere_dense):
    counter = Counter(sphere_sdf)
    result = extract_coarse_to_fine(counter, resolution=128, coarse_resolution=32)
    assert result.evaluations == counter.count
    assert result.evaluations < 0.3 * 128**3
    # every grid point at most once
    flat = torch.cat(counter.points)
    assert len(torch.unique(flat, dim=0)) == len(flat)
    mesh = result.mesh
    assert mesh.area == pytest.approx(sphere_dense.area, rel=0.005)
    assert mesh.volume == pytest.approx(sphere_dense.volume, rel=0.005)
    # for an exact distance function the meshes are identical
    assert len(mesh.vertices) == len(sphere_dense.vertices)
    np.testing.assert_allclose(np.sort(mesh.vertices, axis=0), np.sort(sphere_dense.vertices, axis=0),
                               atol=1e-6)


@pytest.mark.parametrize("resolution, coarse", [(64, 32), (96, 8), (50, 7)])
def test_coarse_to_fine_box_matches_dense(resolution, coarse):
    dense = extract_dense(box_sdf, resolution=resolution).mesh
    fine = extract_coarse_to_fine(box_sdf, resolution=resolution, coarse_resolution=coarse)
    assert fine.evaluations < resolution**3
    assert fine.mesh.area == pytest.approx(dense.area, rel=0.005)
    assert fine.mesh.volume == pytest.approx(dense.volume, rel=0.005)
    assert len(fine.mesh.faces) == len(dense.faces)


def _hausdorff(a: trimesh.Trimesh, b: trimesh.Trimesh) -> float:
    """Largest distance from a vertex of one mesh to the nearest vertex of the other."""
    from scipy.spatial import cKDTree

    return max(cKDTree(b.vertices).query(a.vertices)[0].max(), cKDTree(a.vertices).query(b.vertices)[0].max())


def test_narrow_band_sphere_matches_dense_with_few_evaluations(sphere_dense):
    counter = Counter(sphere_sdf)
    result = extract_narrow_band(counter, resolution=128, coarse_resolution=16)
    assert result.evaluations == counter.count
    flat = torch.cat(counter.points)
    assert len(torch.unique(flat, dim=0)) == len(flat)  # every grid sample at most once
    # a band about one spacing wide: a few percent of the grid, far below the coarse-to-fine band
    assert result.evaluations < 0.05 * 128**3
    assert result.evaluations < 0.5 * extract_coarse_to_fine(sphere_sdf, resolution=128).evaluations
    mesh = result.mesh
    assert mesh.area == pytest.approx(sphere_dense.area, rel=0.01)
    assert mesh.volume == pytest.approx(sphere_dense.volume, rel=0.01)
    assert _hausdorff(mesh, sphere_dense) < 0.01 * (2.0 / 127)
    assert mesh.is_watertight


@pytest.mark.parametrize("resolution, coarse", [(64, 16), (96, 8), (50, 7), (128, 16)])
def test_narrow_band_box_matches_dense(resolution, coarse):
    """Edges and corners: the interpolated estimates are poorest there."""
    dense = extract_dense(box_sdf, resolution=resolution).mesh
    counter = Counter(box_sdf)
    thin = extract_narrow_band(counter, resolution=resolution, coarse_resolution=coarse)
    assert thin.evaluations == counter.count < 0.25 * resolution**3
    assert thin.mesh.area == pytest.approx(dense.area, rel=0.01)
    assert _hausdorff(thin.mesh, dense) < 0.01 * (2.0 / (resolution - 1))


def test_narrow_band_keeps_a_thin_rod():
    """A rod a fifth of a coarse cell thick, between the coarse samples, is still found."""

    def rod(points):
        q = points.clone()
        q[:, 1] = 0
        return (q - torch.tensor([0.03, 0.0, -0.02])).norm(dim=1) - 0.025

    dense = extract_dense(rod, resolution=64).mesh
    thin = extract_narrow_band(rod, resolution=64, coarse_resolution=8).mesh
    assert thin.area == pytest.approx(dense.area, rel=0.01)
    assert _hausdorff(thin, dense) < 0.01 * (2.0 / 63)


def test_narrow_band_no_surface_and_bad_arguments():
    assert extract_narrow_band(lambda p: torch.ones(len(p)), resolution=33, coarse_resolution=9).mesh is None
    with pytest.raises(ValueError, match="band"):
        extract_narrow_band(sphere_sdf, resolution=16, band=0.0)
    with pytest.raises(ValueError, match="coarse_resolution"):
        extract_narrow_band(sphere_sdf, resolution=16, coarse_resolution=1)


def test_interpolate_subgrid_is_exact_for_trilinear_functions():
    coarse = _axis_samples(11, 4)  # 0 4 8 10: the last cell is shorter
    fine = _axis_samples(11, 2)
    x = coarse[:, None, None].astype(np.float32)
    y = coarse[None, :, None].astype(np.float32)
    z = coarse[None, None, :].astype(np.float32)
    values = 1 + 2 * x - y + 0.5 * z + 0.1 * x * y * z
    fx, fy, fz = (fine.astype(np.float32).reshape(s) for s in ((-1, 1, 1), (1, -1, 1), (1, 1, -1)))
    np.testing.assert_allclose(_interpolate_subgrid(values, coarse, fine),
                               1 + 2 * fx - fy + 0.5 * fz + 0.1 * fx * fy * fz, rtol=1e-5)


def test_dense_box_area_volume():
    mesh = extract_dense(box_sdf, resolution=128).mesh
    half = HALF.numpy()
    area = 8 * (half[0] * half[1] + half[1] * half[2] + half[0] * half[2])
    assert mesh.volume == pytest.approx(8 * np.prod(half), rel=0.02)
    assert mesh.area == pytest.approx(area, rel=0.02)
    assert mesh.volume > 0


def test_level_set_offsets_the_surface():
    mesh = extract_coarse_to_fine(sphere_sdf, resolution=64, coarse_resolution=16, level=0.1).mesh
    distances = np.linalg.norm(mesh.vertices - CENTRE.numpy(), axis=1)
    assert distances.mean() == pytest.approx(RADIUS + 0.1, abs=0.005)


def test_no_surface_gives_none():
    def outside(points):
        return torch.ones(len(points))

    def inside(points):
        return -torch.ones(len(points), 1)  # (n, 1) outputs are accepted

    assert extract_dense(outside, resolution=16).mesh is None
    result = extract_coarse_to_fine(inside, resolution=33, coarse_resolution=9)
    assert result.mesh is None and result.evaluations == 9**3


def test_non_finite_sdf_raises():
    from jsrte.errors import JsrteError

    with pytest.raises(JsrteError, match="NaN"):
        extract_dense(lambda p: torch.full((len(p),), float("nan")), resolution=8)


def test_coarse_grid_bookkeeping():
    coarse = _axis_samples(11, 4)
    np.testing.assert_array_equal(coarse, [0, 4, 8, 10])
    fine = _axis_samples(11, 2)
    lo, hi = _containing_cells(coarse, fine)
    # fine samples 0 2 4 6 8 10 lie in cells [0] [0] [0|1] [1] [1|2] [2]
    np.testing.assert_array_equal(lo, [0, 0, 1, 1, 2, 2])
    np.testing.assert_array_equal(hi, [0, 0, 0, 1, 1, 2])
