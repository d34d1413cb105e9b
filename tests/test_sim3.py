"""Similarity transforms, the paper's rotation parameterization, Umeyama."""

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from jsrte.geometry.sim3 import (
    Sim3,
    axis_from_spherical,
    rodrigues,
    rotation_between,
    rotation_from_paper,
    spherical_from_axis,
    umeyama,
)

angles = st.floats(-np.pi, np.pi, allow_nan=False)


@settings(max_examples=50, deadline=None)
@given(psi=angles, rho=angles, theta=angles)
def test_paper_rotation_matches_reference(psi, rho, theta):
    r = rotation_from_paper(torch.tensor(psi, dtype=torch.float64), torch.tensor(rho, dtype=torch.float64),
                            torch.tensor(theta, dtype=torch.float64)).numpy()
    axis = np.array([np.sin(psi) * np.cos(rho), np.sin(psi) * np.sin(rho), np.cos(psi)])
    reference = Rotation.from_rotvec(axis * theta).as_matrix()
    np.testing.assert_allclose(r, reference, atol=1e-12)
    np.testing.assert_allclose(r @ r.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(r) == pytest.approx(1.0)


def test_rodrigues_gradients_finite_at_zero_angle():
    psi = torch.tensor(0.3, dtype=torch.float64, requires_grad=True)
    rho = torch.tensor(-1.2, dtype=torch.float64, requires_grad=True)
    theta = torch.tensor(0.0, dtype=torch.float64, requires_grad=True)
    x = torch.tensor([0.2, -0.5, 0.7], dtype=torch.float64)
    (rotation_from_paper(psi, rho, theta) @ x).sum().backward()
    for p in (psi, rho, theta):
        assert torch.isfinite(p.grad)
    assert theta.grad.abs() > 0  # the angle still moves the point


def test_rodrigues_batched():
    axes = torch.nn.functional.normalize(torch.randn(5, 3, dtype=torch.float64), dim=-1)
    thetas = torch.linspace(-3, 3, 5, dtype=torch.float64)
    batch = rodrigues(axes, thetas)
    for i in range(5):
        np.testing.assert_allclose(batch[i].numpy(), rodrigues(axes[i], thetas[i]).numpy())


def test_spherical_round_trip():
    axis = np.array([0.3, -0.8, 0.52])
    axis /= np.linalg.norm(axis)
    psi, rho = spherical_from_axis(axis)
    got = axis_from_spherical(torch.tensor(psi, dtype=torch.float64), torch.tensor(rho, dtype=torch.float64))
    np.testing.assert_allclose(got.numpy(), axis, atol=1e-12)


def test_sim3_inverse_compose_matrix():
    rng = np.random.default_rng(0)
    a = Sim3(1.7, Rotation.random(random_state=1).as_matrix(), rng.normal(size=3))
    b = Sim3(0.4, Rotation.random(random_state=2).as_matrix(), rng.normal(size=3))
    x = rng.normal(size=(10, 3))
    np.testing.assert_allclose(a.inverse().apply(a.apply(x)), x, atol=1e-12)
    np.testing.assert_allclose((a @ b).apply(x), a.apply(b.apply(x)), atol=1e-12)
    homogeneous = np.c_[x, np.ones(10)] @ a.matrix().T
    np.testing.assert_allclose(homogeneous[:, :3], a.apply(x), atol=1e-12)
    back = Sim3.from_matrix(a.matrix())
    assert back.s == pytest.approx(a.s)
    np.testing.assert_allclose(back.R, a.R, atol=1e-12)


def test_umeyama_recovers_known_similarity_exactly():
    rng = np.random.default_rng(3)
    truth = Sim3(2.5, Rotation.random(random_state=4).as_matrix(), np.array([1.0, -2.0, 0.5]))
    x = rng.normal(size=(50, 3))
    est = umeyama(x, truth.apply(x))
    assert est.s == pytest.approx(truth.s, rel=1e-10)
    np.testing.assert_allclose(est.R, truth.R, atol=1e-10)
    np.testing.assert_allclose(est.t, truth.t, atol=1e-10)


def test_rotation_between_takes_a_to_b():
    for a, b in [([0, 1, 0], [0.3, 0.2, -0.9]), ([0, 1, 0], [0, -1, 0]), ([1, 0, 0], [1, 0, 0])]:
        r = rotation_between(np.array(a, float), np.array(b, float))
        bn = np.array(b, float) / np.linalg.norm(b)
        np.testing.assert_allclose(r @ np.array(a, float), bn, atol=1e-12)
        assert np.linalg.det(r) == pytest.approx(1.0)


def test_scale_must_be_positive():
    with pytest.raises(ValueError):
        Sim3(0.0, np.eye(3), np.zeros(3))
