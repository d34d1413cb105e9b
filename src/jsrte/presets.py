"""Every constant the paper names, in one place, as named presets (never bare literals in code).

``PAPER`` holds the paper's settings (main text section 3.4 and the supplementary);
faster presets are measured against it side by side (docs/presets.md).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from math import pi


@dataclass(frozen=True)
class SdfSampling:
    """DeepSDF-style SDF sampling of a mesh in the normalized canonical frame."""

    n_points: int = 250_000
    """Total samples per mesh."""
    near_fraction: float = 0.9
    """Fraction of samples near the surface (split evenly over the two widths)."""
    near_std_wide: float = 0.025
    """Std of the wide Gaussian perturbation of surface points (canonical units)."""
    near_std_narrow: float = 0.0025
    """Std of the narrow Gaussian perturbation (canonical units)."""
    uniform_extent: float = 1.0
    """Uniform samples lie in the cube [-extent, extent]^3."""
    normalization_padding: float = 1.03
    """DeepSDF: divide by the largest vertex distance times this."""


@dataclass(frozen=True)
class ScanSdf:
    """SDF samples built from a scan with normals (paper supplementary, 'SDF Sampling')."""

    surface_offset_m: float = 0.01
    """Points +/- this far along the normal get SDF +/- this value (metres)."""
    freespace_min_m: float = 0.07
    freespace_max_m: float = 0.20
    """Freespace samples lie this far out along the outward normal (metres)."""
    n_freespace: int = 25_000


@dataclass(frozen=True)
class FitSettings:
    """The JSRTE optimization (paper eq. 6, Algorithm 1, supplementary 'Optimization Parameters')."""

    iterations: int = 800
    samples_per_iteration: int = 8000
    lr: float = 0.05
    """Adam learning rate for every free parameter."""
    lr_decay_every: int = 400
    lr_decay_factor: float = 5.0
    """The learning rate is divided by this every ``lr_decay_every`` iterations."""
    scale_min: float = 0.01
    scale_max: float = 10.0
    latent_penalty: float = 1e-4
    """Weight of ||z||^2 (DeepSDF's code regularization)."""
    latent_init_std: float = 0.01
    """z0 ~ N(0, std^2 I)."""
    theta_grid_deg: float = 30.0
    """Initial yaw hypotheses every this many degrees (12 for 30 deg)."""
    prune_after: int | None = None
    """Keep only ``prune_keep`` hypotheses (lowest loss) after this many iterations; None: never."""
    prune_keep: int = 3
    clamp_canonical: float | None = 0.1
    """Clamp predicted and target SDF at this distance in canonical units times the *initial*
    scale (a fixed distance in scan units, as DeepSDF's reconstruction clamps at 0.1); None: no
    clamp. A clamp that shrank with the optimized s would let the loss vanish by shrinking s."""
    init_scale: str = "sphere"
    """How s0 and t0 come from the data: "sphere" (the paper: bounding sphere of the query) or
    "height" (the object's height above the floor over the model's canonical height; robust to
    partial scans)."""
    selection: str = "fscore"
    """Pick the winning hypothesis by "fscore" (the paper: F@5% of its decoded surface against
    the query points) or by "loss"."""
    selection_resolution: int = 64
    """Marching-cubes resolution of the surfaces decoded to score hypotheses."""
    eval_samples: int = 16_000
    """Samples on which the final losses of all hypotheses are compared."""
    fscore_points: int = 3000
    fscore_fraction: float = 0.05
    extract_resolution: int = 128


@dataclass(frozen=True)
class Preset:
    """A named bundle of settings."""

    name: str
    sampling: SdfSampling = field(default_factory=SdfSampling)
    scan_sdf: ScanSdf = field(default_factory=ScanSdf)
    fit: FitSettings = field(default_factory=FitSettings)


PAPER = Preset(name="paper")

FAST = Preset(
    name="fast",
    fit=FitSettings(iterations=240, samples_per_iteration=2000, lr_decay_every=160,
                    prune_after=40, prune_keep=2, init_scale="height"),
)
"""The default on a CPU: 4x fewer samples and 3.3x fewer iterations, yaw hypotheses pruned to
the best two after 40 iterations, scale initialized from the object's height (docs/presets.md)."""

PRESETS: dict[str, Preset] = {
    "paper": PAPER,
    "fast": FAST,
}
DEFAULT_PRESET = "fast"

# Synthetic experiment ranges (paper Table 1 and supplementary Table 1).
SYNTHETIC_TRUTH = {
    "scale": (0.5, 2.0),
    "angle": (-pi, pi),
    "translation_norm": (0.0, 4.0),
}


def get_preset(name: str) -> Preset:
    """Return the preset called ``name``; raises KeyError listing the known names."""
    try:
        return PRESETS[name]
    except KeyError:
        raise KeyError(f"unknown preset {name!r}; known: {', '.join(sorted(PRESETS))}") from None


def with_fit(preset: Preset, **changes: object) -> Preset:
    """A copy of ``preset`` with fit settings changed."""
    return replace(preset, fit=replace(preset.fit, **changes))
