"""The free parameters of H hypotheses, optimized as one batch.

Each hypothesis h has a scale s_h, the paper's rotation angles (ψ_h, ρ_h, θ_h), a translation
t_h (3,) and a latent code z_h (d,). Its rotation is ``R_h = R(ψ_h, ρ_h, θ_h) @ B_h`` with a
fixed base rotation B_h (identity in the paper's synthetic setting; for floor scans, the
rotation taking canonical +y to the floor normal, so θ turns the object about its up axis).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from jsrte.geometry.sim3 import Sim3, rotation_from_paper

PARAMETER_NAMES = ("scale", "psi", "rho", "theta", "translation", "latent")


@dataclass(frozen=True)
class LatentPrior:
    """The Gaussian of a model's training codes, z = mean + factor @ w with w ~ N(0, I).

    Optimizing the whitened code w instead of z (``FitSettings.latent_space = "whitened"``)
    gives Adam steps in units of each principal direction's spread, and ‖w‖² is the
    Mahalanobis distance to the training codes: a code cannot drift along directions the
    training shapes never varied in, where the decoder's output is arbitrary.

    Attributes
    ----------
    mean : (d,) float64, the training codes' mean
    factor : (d, d) float64, lower-triangular Cholesky factor of their covariance plus
        ``shrinkage`` times its mean eigenvalue on the diagonal
    """

    mean: np.ndarray
    factor: np.ndarray
    codes: np.ndarray | None = None
    """(n, d) float64: the training codes themselves (restarts of the code), when known."""

    @classmethod
    def of_codes(cls, codes: np.ndarray, *, shrinkage: float) -> LatentPrior:
        """Fit to ``codes`` (n, d); ``shrinkage`` > 0 keeps the factor invertible."""
        codes = np.asarray(codes, dtype=np.float64)
        d = codes.shape[1]
        cov = np.cov(codes.T).reshape(d, d) if len(codes) > 1 else np.zeros((d, d))
        spread = float(np.trace(cov)) / d
        cov += shrinkage * (spread if spread > 0 else 1.0) * np.eye(d)  # one code: an isotropic prior
        return cls(codes.mean(0), np.linalg.cholesky(cov), codes)

    def whiten(self, latent: np.ndarray) -> np.ndarray:
        """w (d,) with ``latent`` = mean + factor @ w."""
        return np.linalg.solve(self.factor, np.asarray(latent, dtype=np.float64) - self.mean)


@dataclass(frozen=True)
class Init:
    """One starting point (scan units: metres, radians).

    Attributes
    ----------
    scale : s0 > 0
    psi, rho, theta : the paper's axis angles (polar, azimuth) and rotation angle
    translation : (3,)
    latent : (d,) or None (then drawn from N(0, std^2) by the optimizer)
    base_rotation : (3, 3) or None (identity)
    """

    scale: float
    psi: float
    rho: float
    theta: float
    translation: np.ndarray
    latent: np.ndarray | None = None
    base_rotation: np.ndarray | None = None


class HypothesisBatch(torch.nn.Module):
    """Parameters (H, ...) of H hypotheses; ``fixed`` names are not optimized.

    The latent is optimized as ``code`` (H, d): z itself (the paper), or with a ``prior`` the
    whitened w, z = prior.mean + prior.factor @ w. z0 draws ``code`` from N(0, std²).
    """

    def __init__(self, inits: list[Init], latent_size: int, *, latent_init_std: float,
                 fixed: frozenset[str] = frozenset(), generator: torch.Generator | None = None,
                 prior: LatentPrior | None = None) -> None:
        super().__init__()
        unknown = set(fixed) - set(PARAMETER_NAMES)
        if unknown:
            raise ValueError(f"unknown parameter names {sorted(unknown)}; known: {PARAMETER_NAMES}")
        f64 = torch.float64

        def param(name: str, values: list) -> torch.nn.Parameter:
            return torch.nn.Parameter(torch.tensor(np.array(values), dtype=f64),
                                      requires_grad=name not in fixed)

        self.scale = param("scale", [i.scale for i in inits])
        self.psi = param("psi", [i.psi for i in inits])
        self.rho = param("rho", [i.rho for i in inits])
        self.theta = param("theta", [i.theta for i in inits])
        self.translation = param("translation", [np.asarray(i.translation, float) for i in inits])
        z = torch.randn(len(inits), latent_size, generator=generator, dtype=f64) * latent_init_std
        for h, init in enumerate(inits):
            if init.latent is not None:
                z[h] = torch.as_tensor(init.latent if prior is None else prior.whiten(init.latent), dtype=f64)
        self.code = torch.nn.Parameter(z, requires_grad="latent" not in fixed)
        self.register_buffer("prior_mean", None if prior is None else torch.as_tensor(prior.mean, dtype=f64))
        self.register_buffer("prior_factor", None if prior is None else torch.as_tensor(prior.factor, dtype=f64))
        base = [np.eye(3) if i.base_rotation is None else np.asarray(i.base_rotation, float) for i in inits]
        self.register_buffer("base_rotation", torch.tensor(np.array(base), dtype=f64))
        self.register_buffer("start_scale", torch.tensor([float(i.scale) for i in inits], dtype=f64))

    def __len__(self) -> int:
        return int(self.scale.shape[0])

    @property
    def latent(self) -> torch.Tensor:
        """z (H, d) of every hypothesis (differentiable)."""
        if self.prior_mean is None:
            return self.code
        return self.prior_mean + self.code @ self.prior_factor.T

    def rotation(self) -> torch.Tensor:
        """R (H, 3, 3) = R(ψ, ρ, θ) @ base."""
        return rotation_from_paper(self.psi, self.rho, self.theta) @ self.base_rotation

    def to_canonical(self, points: torch.Tensor) -> torch.Tensor:
        """Scan points (H, K, 3) or (K, 3) -> canonical R^T (x - t) / s, (H, K, 3)."""
        centred = points - self.translation[:, None, :]
        return centred @ self.rotation() / self.scale[:, None, None]

    def sdf(self, decoder: torch.nn.Module, points: torch.Tensor, *, bfloat16: bool = False) -> torch.Tensor:
        """s·f(R⁻¹(x − t)/s, z) (H, K) float32, scan units, of every hypothesis at scan points
        ``points`` (K, 3) (differentiable); ``bfloat16``: the decoder's matrix products in bfloat16."""
        h, k = len(self), points.shape[0]
        canonical = self.to_canonical(points).to(torch.float32)  # (H, K, 3)
        codes = self.latent.to(torch.float32)[:, None, :].expand(h, k, -1)
        with torch.autocast(canonical.device.type, dtype=torch.bfloat16, enabled=bfloat16):
            pred = decoder(canonical.reshape(-1, 3), codes.reshape(h * k, -1))
        return self.scale.to(torch.float32)[:, None] * pred.to(torch.float32).reshape(h, k)

    def clamp_scale(self, lo: float, hi: float) -> None:
        """Project s back into [lo, hi] (the paper keeps s in [0.01, 10])."""
        with torch.no_grad():
            self.scale.clamp_(lo, hi)

    def keep(self, index: torch.Tensor) -> None:
        """Keep only hypotheses ``index`` (pruning); optimizer state must be rebuilt after."""
        for name in ("scale", "psi", "rho", "theta", "translation", "code"):
            old = getattr(self, name)
            kept = old.detach()[index.to(old.device)].clone()
            setattr(self, name, torch.nn.Parameter(kept, requires_grad=old.requires_grad))
        self.base_rotation = self.base_rotation[index.to(self.base_rotation.device)]
        self.start_scale = self.start_scale[index.to(self.start_scale.device)]

    def transform(self, h: int) -> Sim3:
        """``scan_from_canonical`` of hypothesis ``h``."""
        with torch.no_grad():
            return Sim3(float(self.scale[h]), self.rotation()[h].cpu().numpy(), self.translation[h].cpu().numpy())

    def angles(self, h: int) -> dict[str, float]:
        with torch.no_grad():
            return {"psi": float(self.psi[h]), "rho": float(self.rho[h]), "theta": float(self.theta[h])}
