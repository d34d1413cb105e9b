"""Similarity transforms Sim(3), the paper's axis-angle parameterization, and Umeyama.

A ``Sim3`` maps x to ``s * R @ x + t``. Name instances by direction, e.g.
``scan_from_canonical``: canonical (unit-sphere) coordinates to scan metres.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch


@dataclass(frozen=True)
class Sim3:
    """A similarity transform ``x -> s * R @ x + t``.

    Attributes
    ----------
    s : float, > 0
    R : (3, 3) float64, a rotation (det +1)
    t : (3,) float64
    """

    s: float
    R: np.ndarray
    t: np.ndarray

    def __post_init__(self) -> None:
        object.__setattr__(self, "R", np.asarray(self.R, dtype=np.float64).reshape(3, 3))
        object.__setattr__(self, "t", np.asarray(self.t, dtype=np.float64).reshape(3))
        object.__setattr__(self, "s", float(self.s))
        if not self.s > 0:
            raise ValueError(f"Sim3 scale must be positive, got {self.s}")

    @staticmethod
    def identity() -> Sim3:
        return Sim3(1.0, np.eye(3), np.zeros(3))

    def apply(self, points: np.ndarray) -> np.ndarray:
        """Transform ``points`` (n, 3) -> (n, 3)."""
        return self.s * np.asarray(points, dtype=np.float64) @ self.R.T + self.t

    def apply_vectors(self, vectors: np.ndarray) -> np.ndarray:
        """Rotate direction vectors (n, 3), e.g. normals (no scale, no translation)."""
        return np.asarray(vectors, dtype=np.float64) @ self.R.T

    def inverse(self) -> Sim3:
        return Sim3(1.0 / self.s, self.R.T, -(self.R.T @ self.t) / self.s)

    def compose(self, other: Sim3) -> Sim3:
        """``self ∘ other``: apply ``other`` first, then ``self``."""
        return Sim3(self.s * other.s, self.R @ other.R, self.s * self.R @ other.t + self.t)

    def __matmul__(self, other: Sim3) -> Sim3:
        return self.compose(other)

    def matrix(self) -> np.ndarray:
        """The 4x4 homogeneous matrix."""
        m = np.eye(4)
        m[:3, :3] = self.s * self.R
        m[:3, 3] = self.t
        return m

    @staticmethod
    def from_matrix(m: np.ndarray) -> Sim3:
        """Inverse of :meth:`matrix`; ``m`` (4, 4) with a uniformly scaled rotation block."""
        m = np.asarray(m, dtype=np.float64)
        a = m[:3, :3]
        s = float(np.cbrt(np.linalg.det(a)))
        return Sim3(s, a / s, m[:3, 3])

    def to_dict(self) -> dict:
        return {"scale": self.s, "rotation": self.R.tolist(), "translation": self.t.tolist()}

    @staticmethod
    def from_dict(d: dict) -> Sim3:
        return Sim3(d["scale"], np.array(d["rotation"]), np.array(d["translation"]))


def axis_from_spherical(psi: torch.Tensor, rho: torch.Tensor) -> torch.Tensor:
    """Unit axis from the paper's polar angle ``psi`` and azimuth ``rho``.

    ω = (sin ψ cos ρ, sin ψ sin ρ, cos ψ). Inputs (...,), output (..., 3).
    """
    return torch.stack(
        [torch.sin(psi) * torch.cos(rho), torch.sin(psi) * torch.sin(rho), torch.cos(psi)], dim=-1
    )


def spherical_from_axis(axis: np.ndarray) -> tuple[float, float]:
    """(ψ, ρ) of a unit axis (3,), the inverse of :func:`axis_from_spherical`."""
    a = np.asarray(axis, dtype=np.float64)
    a = a / np.linalg.norm(a)
    psi = float(np.arccos(np.clip(a[2], -1.0, 1.0)))
    rho = float(np.arctan2(a[1], a[0]))
    return psi, rho


def hat(w: torch.Tensor) -> torch.Tensor:
    """Skew-symmetric matrix of vectors (..., 3) -> (..., 3, 3) with hat(w) @ v = w × v."""
    zero = torch.zeros_like(w[..., 0])
    return torch.stack(
        [
            torch.stack([zero, -w[..., 2], w[..., 1]], dim=-1),
            torch.stack([w[..., 2], zero, -w[..., 0]], dim=-1),
            torch.stack([-w[..., 1], w[..., 0], zero], dim=-1),
        ],
        dim=-2,
    )


def rodrigues(axis: torch.Tensor, theta: torch.Tensor) -> torch.Tensor:
    """exp(ω̂ θ) = I + ω̂ sin θ + ω̂² (1 − cos θ) for unit ``axis`` (..., 3), ``theta`` (...,).

    Smooth in θ everywhere (finite gradients at θ = 0). Returns (..., 3, 3).
    """
    k = hat(axis)
    eye = torch.eye(3, dtype=axis.dtype, device=axis.device).expand_as(k)
    st = torch.sin(theta)[..., None, None]
    ct = torch.cos(theta)[..., None, None]
    return eye + k * st + (k @ k) * (1.0 - ct)


def rotation_from_paper(psi: torch.Tensor, rho: torch.Tensor, theta: torch.Tensor) -> torch.Tensor:
    """R(ψ, ρ, θ) of the paper (eq. 5): Rodrigues on the spherical-coordinate axis. (..., 3, 3)."""
    return rodrigues(axis_from_spherical(psi, rho), theta)


def rotation_between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The smallest rotation (3, 3) taking unit vector ``a`` (3,) to unit vector ``b`` (3,)."""
    a = np.asarray(a, dtype=np.float64) / np.linalg.norm(a)
    b = np.asarray(b, dtype=np.float64) / np.linalg.norm(b)
    v = np.cross(a, b)
    c = float(np.dot(a, b))
    if c < -1.0 + 1e-12:  # opposite: turn by pi about any axis orthogonal to a
        ortho = np.eye(3)[np.argmin(np.abs(a))]
        axis = np.cross(a, ortho)
        axis /= np.linalg.norm(axis)
        return 2.0 * np.outer(axis, axis) - np.eye(3)
    k = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
    return np.eye(3) + k + k @ k / (1.0 + c)


def axis_angle_matrix(axis: np.ndarray, theta: float) -> np.ndarray:
    """NumPy rotation (3, 3) by ``theta`` radians about unit ``axis`` (3,)."""
    r = rodrigues(torch.as_tensor(np.asarray(axis, np.float64)), torch.tensor(float(theta)))
    return r.numpy()


def umeyama(source: np.ndarray, target: np.ndarray, *, with_scale: bool = True) -> Sim3:
    """Least-squares similarity taking ``source`` (n, 3) onto ``target`` (n, 3) (Umeyama 1991).

    Returns the ``Sim3`` g minimizing Σ‖target_i − g(source_i)‖².
    """
    x = np.asarray(source, dtype=np.float64)
    y = np.asarray(target, dtype=np.float64)
    if x.shape != y.shape or x.ndim != 2 or x.shape[1] != 3 or len(x) < 3:
        raise ValueError(f"umeyama needs two (n>=3, 3) arrays of equal shape, got {x.shape}, {y.shape}")
    mx, my = x.mean(0), y.mean(0)
    xc, yc = x - mx, y - my
    cov = yc.T @ xc / len(x)
    u, d, vt = np.linalg.svd(cov)
    sign = np.ones(3)
    if np.linalg.det(u) * np.linalg.det(vt) < 0:
        sign[2] = -1.0
    r = u @ np.diag(sign) @ vt
    var_x = (xc**2).sum() / len(x)
    s = float((d * sign).sum() / var_x) if with_scale else 1.0
    t = my - s * r @ mx
    return Sim3(s, r, t)


def rotation_angle_deg(r_a: np.ndarray, r_b: np.ndarray) -> float:
    """Geodesic angle (degrees) between two rotations (3, 3)."""
    c = (np.trace(np.asarray(r_a).T @ np.asarray(r_b)) - 1.0) / 2.0
    return float(np.degrees(np.arccos(np.clip(c, -1.0, 1.0))))
