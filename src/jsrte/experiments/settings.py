"""Settings of the paper's experiments (synthetic queries, compression) and the paper's own
figures they are compared with; the fit's settings are in :mod:`jsrte.presets`."""

from __future__ import annotations

from dataclasses import dataclass
from math import pi

from jsrte.presets import SdfSampling

SYNTHETIC_TRUTH = {
    "scale": (0.5, 2.0),
    "angle": (-pi, pi),
    "translation_norm": (0.0, 4.0),
}
"""Synthetic experiment ranges (paper Table 1 and supplementary Table 1)."""


@dataclass(frozen=True)
class SyntheticTruth:
    """Ground-truth transforms of the synthetic experiment (paper section 4.1): every value is
    drawn uniformly from its half-open range [lo, hi); t has a uniform direction."""

    scale: tuple[float, float] = SYNTHETIC_TRUTH["scale"]
    angle: tuple[float, float] = SYNTHETIC_TRUTH["angle"]
    """Range of each of ψ, ρ, θ (radians)."""
    translation_norm: tuple[float, float] = SYNTHETIC_TRUTH["translation_norm"]
    """Range of ||t|| (scan units)."""


@dataclass(frozen=True)
class SyntheticScenario:
    """How initializations are drawn around the truth (paper Table 1, supplementary Table 1).

    s0 = s (1 + Δs), ψ0 = ψ + Δψ, ρ0 = ρ + Δρ, θ0 = θ + Δθ, t0 = t + Δt, every Δ uniform in
    its half-open range, Δt with a uniform direction; z0 ~ N(0, FitSettings.latent_init_std²).
    With a known axis (``axis_delta`` None) ψ0 = ψ, ρ0 = ρ and both stay fixed.
    """

    name: str
    title: str
    scale_delta: tuple[float, float]
    theta_delta: tuple[float, float]
    translation_delta_norm: tuple[float, float]
    axis_delta: tuple[float, float] | None
    """Range of Δψ and of Δρ (radians); None: the rotation axis is known."""
    source: str
    """Where the ranges come from."""

    @property
    def known_axis(self) -> bool:
        return self.axis_delta is None


SCENARIOS: dict[str, SyntheticScenario] = {
    "known": SyntheticScenario("known", "known rotation axis", (0.0, 0.3), (-pi / 9, pi / 9), (0.0, 0.15),
                               None, "paper Table 1"),
    "unknown": SyntheticScenario("unknown", "unknown rotation axis", (0.0, 0.3), (-pi / 9, pi / 9),
                                 (0.0, 0.15), (-pi / 36, pi / 36), "paper Table 1"),
    "known-wide": SyntheticScenario("known-wide", "known rotation axis, wider ranges", (0.0, 0.5),
                                    (-2 * pi / 9, 2 * pi / 9), (0.0, 0.20), None, "supplementary Table 1"),
    "unknown-wide": SyntheticScenario("unknown-wide", "unknown rotation axis, wider ranges", (0.0, 0.5),
                                      (-2 * pi / 9, 2 * pi / 9), (0.0, 0.20), (-pi / 36, pi / 36),
                                      "supplementary Table 1"),
}


@dataclass(frozen=True)
class SyntheticScale:
    """How much of the synthetic experiment to run."""

    name: str
    shapes: int
    """Held-out shapes per class."""
    inits: int
    """Random initializations per shape (one batch of hypotheses)."""
    scenarios: tuple[str, ...]
    preset: str
    """Fit preset (its pruning is switched off: every initialization is scored)."""
    query_samples: int
    """SDF samples of each query (the paper samples as DeepSDF: 250 000)."""


SYNTHETIC_SCALES: dict[str, SyntheticScale] = {
    "quick": SyntheticScale("quick", shapes=3, inits=4, scenarios=("known", "unknown"), preset="fast",
                            query_samples=50_000),
    "medium": SyntheticScale("medium", shapes=10, inits=10, scenarios=tuple(SCENARIOS), preset="fast",
                             query_samples=50_000),
    "paper": SyntheticScale("paper", shapes=30, inits=50, scenarios=tuple(SCENARIOS), preset="paper",
                            query_samples=SdfSampling.n_points),
}

SYNTHETIC_FSCORE_GOOD = 0.8
"""The paper's reading of Fig. 2: "most F@5% scores greater than 0.8"."""


@dataclass(frozen=True)
class CompressionSettings:
    """The 3D compression experiment (paper section 4.3, Table 3)."""

    qe_factors: tuple[int, ...] = (100, 1000)
    """Quadric-error decimation to 1/factor of the original faces (QE-100, QE-1000)."""
    vc_fractions: tuple[float, ...] = (0.1, 0.2)
    """Vertex-clustering cell size as a fraction of the bounding-sphere radius (VC-0.1, VC-0.2)."""
    dense_faces: int = 100_000
    """Our procedural meshes have a few thousand faces, the paper's Redwood meshes (TSDF fusion +
    marching cubes) far more: the original is re-meshed to about this many faces first."""
    latent_formats: tuple[str, ...] = ("fp32", "fp16", "int8")


PAPER_TABLE3 = {
    "Ours": {"fscore": 0.902, "size_kb": 1.088},
    "QE-100": {"fscore": 0.977, "size_kb": 20.120},
    "QE-1000": {"fscore": 0.778, "size_kb": 3.454},
    "VC-0.1": {"fscore": 0.978, "size_kb": 34.833},
    "VC-0.2": {"fscore": 0.839, "size_kb": 9.073},
}
"""The paper's Table 3 (Redwood meshes): mean F@5% against the original and mean file size."""
