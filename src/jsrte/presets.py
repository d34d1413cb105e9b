"""Every constant the paper names, in one place, as named presets (never bare literals in code).

``PAPER`` holds the paper's settings (main text section 3.4 and the supplementary);
faster presets are measured against it side by side (docs/presets.md).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Literal, get_args


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
    n_ray_freespace: int = 0
    """Beyond the paper (0 in ``paper``): samples on the sensor's lines of sight, in front of what
    each viewpoint saw (only when the viewpoints are known); ``fast`` has LINE_OF_SIGHT_SAMPLES
    (+0.018 mean F@5% on 20 held-out tuning scans with the near-floor bound, no yaw
    flipped; docs/presets.md). ``jsrte fit --line-of-sight / --no-line-of-sight`` overrides."""
    ray_per_point: float = 3.0
    """At most this many ray samples per object point: a sparse scan (a far or small object)
    is not drowned in free-space evidence, which would let an empty shape win."""
    ray_margin_m: float = 0.03
    """Ray samples stop this short of the point seen, and keep this far from every object point
    (metres): sensor noise and flying pixels stay out of the free-space evidence."""
    ray_region_factor: float = 1.25
    """Ray samples lie in the object's bounding sphere grown by this factor."""


LINE_OF_SIGHT_SAMPLES = 25_000
"""``ScanSdf.n_ray_freespace`` with line-of-sight free space switched on."""


def with_line_of_sight(settings: ScanSdf, on: bool | None = True) -> ScanSdf:
    """``settings`` with line-of-sight free-space samples switched on (True), off (False), or as
    they are (None: ``--line-of-sight`` / ``--no-line-of-sight`` / neither)."""
    if on is None:
        return settings
    return replace(settings, n_ray_freespace=LINE_OF_SIGHT_SAMPLES if on else 0)


LatentSpace = Literal["raw", "whitened"]
InitScale = Literal["sphere", "height", "both"]
Selection = Literal["fscore", "loss"]
Solver = Literal["adam", "gauss-newton"]
AdamStage = Literal["never", "near-tie", "always"]
DecoderDtype = Literal["float32", "bfloat16", "auto"]
DECODER_DTYPES: tuple[str, ...] = get_args(DecoderDtype)
MODES: dict[str, tuple[str, ...]] = {"latent_space": get_args(LatentSpace), "init_scale": get_args(InitScale),
                                     "selection": get_args(Selection), "solver": get_args(Solver),
                                     "adam_stage": get_args(AdamStage), "decoder_dtype": DECODER_DTYPES}
"""The mode fields of :class:`FitSettings` and their values."""


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
    latent_penalty_points: int | None = None
    """Beyond the paper: scale the latent penalty by this many points over the query's surface
    points (a scan's object points), so that sparse evidence leans on the prior more and dense
    evidence less (a MAP estimate with a mean data term); None: the penalty as given."""
    latent_init_std: float = 0.01
    """z0 ~ N(0, std^2 I) (the whitened code w0 with ``latent_space = "whitened"``)."""
    latent_space: LatentSpace = "raw"
    """Optimize z itself ("raw", the paper) or the whitened code w of the training codes'
    Gaussian, z = μ + L w ("whitened", beyond the paper: fit.params.LatentPrior). The
    penalty is then latent_penalty × s0 × ‖w‖²."""
    latent_prior_shrinkage: float = 0.01
    """Added to the training codes' covariance, times its mean eigenvalue ("whitened" only)."""
    hold_axis: bool = True
    """With a known up axis (the floor normal, or ``--up``) hold ψ and ρ there and optimize θ
    about it: the paper's known-axis scenario, which its scan experiment uses ("we estimate ω
    using the normal vector to the floor plane ... the only parameter left is θ"). False lets
    the axis move too (``jsrte fit --free-axis``); it tipped sparse scans over (docs/presets.md)."""
    theta_grid_deg: float = 30.0
    """Initial yaw hypotheses every this many degrees (12 for 30 deg)."""
    prune_after: int | None = None
    """Keep only ``prune_keep`` hypotheses (lowest loss) after this many iterations; None: never."""
    prune_keep: int = 3
    prune_again_after: int | None = None
    """A second pruning, to ``prune_again_keep``, after this many iterations; None: none."""
    prune_again_keep: int = 2
    clamp_canonical: float | None = 0.1
    """Clamp predicted and target SDF at this distance in canonical units times the *initial*
    scale (a fixed distance in scan units, as DeepSDF's reconstruction clamps at 0.1); None: no
    clamp. A clamp that shrank with the optimized s would let the loss vanish by shrinking s."""
    init_scale: InitScale = "sphere"
    """How s0 and t0 come from the data: "sphere" (the paper: bounding sphere of the query),
    "height" (the object's height above the floor over the model's canonical height; robust to
    partial scans), or "both": the yaw starts at the height's scale, and again at the sphere's
    where the two disagree by more than ``init_scales_agree`` (the first pruning keeps the best
    of all; an object whose proportions are far from its class's mean shape, a tall pedestal
    table, is misjudged by its height)."""
    init_scales_agree: float = 0.1
    """With ``init_scale`` "both": the sphere's start is added only where the two scales differ
    by more than this share (|ln(s_sphere / s_height)| > ln(1 + this))."""
    selection: Selection = "fscore"
    """Pick the winning hypothesis by "fscore" (the paper: F@5% of its decoded surface against
    the query points) or by "loss" (its final loss on ``eval_samples`` fixed samples: against a
    partial scan F@5% favours shapes that hide the unseen side; docs/presets.md)."""
    selection_resolution: int = 64
    """Marching-cubes resolution of the surfaces decoded to score hypotheses."""
    eval_samples: int = 16_000
    """Samples on which the final losses of all hypotheses are compared."""
    near_sample_share: float | None = None
    """Beyond the paper: at least this share of every iteration's samples is drawn among those
    whose |SDF| is under the clamp (a scan's ±1 cm samples; the freespace ones mostly lie
    beyond it and only say "outside"); None: uniformly over all samples (the paper)."""
    near_sample_from: int = 0
    """Iterations before this one draw uniformly even with a ``near_sample_share``."""
    below_floor_samples: int = 0
    """Beyond the paper: samples under a known floor saying "outside" (fit.floor); 0: none."""
    below_floor_depth: tuple[float, float] = (1.5, 4.0)
    """Their depth under the floor, in units of the loss's clamp (uniform in this range). Each
    bounds the SDF from below (one-sided loss), so samples nearer than the clamp count too."""
    floor_contact: float = 0.0
    """Beyond the paper: weight w of a penalty w·max(0, g − τ) on the gap g between the fitted
    shape and a known floor under it (the least SDF on a grid of the floor plane about the object,
    fit.floor.FloorContact), plus w times the depth it sinks through the floor: furniture stands
    on the floor, and a table whose legs the scan missed otherwise ends in the air. The Adam fit
    (``solver`` "adam") only; 0: none."""
    floor_contact_classes: tuple[str, ...] | None = None
    """The classes (a model's ``category``) whose fits the floor contact acts on; None: every
    class. A model of another class, or one that names none, is fitted without it."""
    floor_contact_points: int = 2048
    """About this many points of that grid (its half-diagonal, the least τ, shrinks as they grow)."""
    floor_contact_tolerance: float = 1.0
    """τ in units of the loss's clamp (at least the grid's half-diagonal): a shape whose lowest
    point floats less than this above the floor costs nothing (a model's thin legs may end a few
    centimetres short of the floor on a fit that is right); a shape sunk through the floor costs
    the depth it sinks, up to half a clamp (within the distances a model learned)."""
    size_margin: float | None = None
    """Beyond the paper: where the model knows its class's sizes (``jsrte.model.sizes``: its
    training shapes', in metres), the scale s stays within them widened by this factor each way
    (from the smallest over the margin to the largest times it; the starts too): a table model
    fitted to a bed cannot grow to the bed's size. The scan must be in metres. None: s anywhere
    in ``scale_min``..``scale_max``."""
    scale_prior: float = 0.0
    """Beyond the paper: weight w of a penalty w s0 ln(s/s0)^2 that holds s near its start s0 (the
    median initial scale; in the Adam fit with ``init_scale`` "both" and two start scales, each
    hypothesis's own (Levenberg–Marquardt keeps the median); s0 makes it scan-unit like the data
    term); 0: none."""
    line_of_sight_before_pruning: bool = False
    """Draw a query's line-of-sight samples (its refine-only tail) from the first iteration, not
    only once the hypotheses are pruned."""
    fscore_points: int = 3000
    fscore_fraction: float = 0.05
    extract_resolution: int = 128
    solver: Solver = "adam"
    """How the objective is minimized: "adam" (the paper: ``iterations`` Adam steps on
    ``samples_per_iteration`` fresh samples each) or "gauss-newton" (beyond the paper,
    fit.gauss_newton: Levenberg–Marquardt with IRLS weights on ``samples_per_iteration``
    samples drawn once; ``iterations`` bounds its iterations, and the prunings count them)."""
    huber_canonical: float = 0.005
    """Gauss–Newton: residuals under this (canonical units times s0) are weighted as a quadratic
    (Huber); above it, as the L1 loss (IRLS weight 1 / 2|r|)."""
    damping: float = 1e-2
    """Gauss–Newton: the initial Levenberg–Marquardt damping μ (times the system's diagonal)."""
    tolerance: float = 1e-3
    """Gauss–Newton: a hypothesis stops once an accepted step lowers its objective by less than
    this fraction."""
    samples_after_pruning: int | None = None
    """Gauss–Newton: from the first pruning on (with the translation search and the code
    restarts), the survivors are solved on a fresh set of this many samples; None: the
    ``samples_per_iteration`` samples throughout."""
    translation_search: float = 0.0
    """Gauss–Newton: at the first pruning, every survivor moves to the translation of lowest
    objective on a grid across its up axis reaching this far each way (units of s0), code and
    the rest of the pose held (forward passes on ``translation_search_samples`` samples); 0: none."""
    translation_search_step: float = 0.1
    """Step of that grid (units of s0)."""
    translation_search_samples: int | None = None
    """Samples on which the translations are scored (the same for every one); None:
    ``yaw_screen_samples``."""
    yaw_screen_keep: int | None = None
    """Gauss–Newton: screen the yaw starts (the θ grid) by forward passes only, at their
    initial pose and code, and solve only the best this many; None: solve them all."""
    yaw_screen_samples: int = 400
    """Samples on which the yaw starts are screened (the same for every start)."""
    code_starts: int = 0
    """Gauss–Newton, whitened latent: at the first pruning every survivor also restarts from this
    many training codes at its pose (those with the lowest objective there, by forward passes on
    ``yaw_screen_samples`` samples), as more hypotheses; only the copy with the lowest objective
    of each survivor is kept at the end. Levenberg–Marquardt goes to the nearest minimum of the
    code; on 4 of 20 tuning scans that was a local one (docs/solver.md). 0: none."""
    retrieval_start: int = 0
    """Gauss–Newton, whitened latent: before the solve, every start's code becomes the mean
    (whitened) of this many training codes with the lowest objective at its start pose (forward
    passes on ``retrieval_samples`` samples; 1: the best training code); 0: the mean code."""
    retrieval_samples: int = 100
    """Samples on which the training codes are scored for the retrieval start."""
    code_screen_samples: int | None = None
    """Samples on which the training codes are scored at each survivor's pose; None:
    ``yaw_screen_samples``."""
    code_starts_prune_after: int | None = None
    """Gauss–Newton: this many iterations after the code restarts, only the copy with the lowest
    objective of each survivor goes on; None: every copy is solved to the end."""
    polish_iterations: int = 0
    """Gauss–Newton: Adam iterations after the Levenberg–Marquardt solve, on the survivors, with
    ``polish_samples`` fresh samples each (the fixed sample set's draw averaged out); 0: none
    (``fast-gn``: 20, docs/solver.md)."""
    polish_lr: float = 0.005
    """Adam learning rate of the polish, every free parameter."""
    polish_samples: int = 1500
    """Samples of each polish iteration."""
    adam_stage: AdamStage = "never"
    """Gauss–Newton: after the Levenberg–Marquardt solve, every survivor takes ``adam_stage_iterations``
    Adam steps on fresh samples at the Adam fit's learning rates (fit.polish.adam_stage) before
    the polish and the comparison: "always", only when the best hypothesis at another pose ends
    within ``adam_stage_margin`` of the best one's objective ("near-tie"), or "never". The solve
    goes straight to the nearest minimum of the code; these steps let each survivor leave it."""
    adam_stage_margin: float = 0.1
    """The relative gap between two poses' objectives under which "near-tie" runs the stage."""
    adam_stage_contenders_only: bool = False
    """Only the hypotheses still in contention take the Adam stage: the best one, and the best at
    another pose where it ends within ``adam_stage_margin`` of it (the others are pruned); False:
    every survivor takes it."""
    adam_stage_iterations: int = 100
    """Adam steps of that stage."""
    adam_stage_lr: float = 0.05
    """Its learning rate for the first ``adam_stage_decay_after`` steps; divided by
    ``lr_decay_factor`` after."""
    adam_stage_decay_after: int = 40
    adam_stage_samples: int = 1500
    """Samples of each of its steps."""
    decoder_dtype: DecoderDtype = "float32"
    """The decoder's arithmetic while the fit moves its hypotheses (every Adam step, every
    Levenberg–Marquardt linearization, the yaw, translation and code screening): "float32",
    "bfloat16" matrix products (torch.autocast), or "auto": bfloat16 where the device computes it
    natively (a CPU with AVX-512 BF16 or AMX, a CUDA GPU with bfloat16; about 1.8× faster than
    float32 on this project's CPU), float32 elsewhere (model.decoder.native_bfloat16). The final
    losses that pick the winner, the quality block and the meshes are always float32."""
    refine_iterations: int = 0
    """Gauss–Newton: after the Adam stage, at most this many Levenberg–Marquardt iterations on
    every survivor (the solve's last sample set) settle the code where the stage left it; 0: none."""
    float32_retry: bool = False
    """A full fit (``jsrte.fit.fit_recorded``) that moved in bfloat16 and ends flagged "doubtful"
    is fitted again in float32 (``jsrte.fit.solve.fit_with_retry``), and the one with the higher
    inlier share is kept: bfloat16's coarser products can tip a fit whose hypotheses lie close
    into the wrong one (docs/presets.md)."""

    distilled_search: bool = False
    """The model's distilled decoder (``jsrte distill``: a network 4-5× cheaper taught the model's
    SDF over its latent space, so its codes mean the same) moves the hypotheses; the model itself
    takes the final losses that pick the winner, the mesh and the quality block (docs/speed.md,
    "A distilled decoder"). Gauss–Newton: the distilled decoder takes the screens, the solve and
    the Adam stage, the model the refinement and the polish. Adam: the distilled decoder takes
    the first ``distilled_iterations``, the model the rest. The model must have one (the shipped
    models do)."""
    distilled_screen: bool = False
    """The quick fits that choose among candidates and classes (``jsrte.fit.screen``) searched by
    the distilled decoder too (``express``); False: by the model, whatever the full fit's search
    (with the Adam search, distilled quick fits chose a wrong candidate on a tuning bed)."""
    judge_samples: int = 2000
    """Adam with ``distilled_search``: each pruning keeps the hypotheses of lowest loss by the
    model itself on this many fixed samples (forward passes only), not by the distilled
    decoder's running loss."""
    distilled_iterations: int | None = None
    """Adam with ``distilled_search``: the iterations the distilled decoder moves the hypotheses
    before the model takes the survivors over, their Adam moments kept (None: up to the last
    pruning)."""

    def __post_init__(self) -> None:
        """Every mode field holds one of its values (a typo is an error here, not a silent default),
        and the floor contact is asked only of the solver that has it."""
        for name, values in MODES.items():
            if getattr(self, name) not in values:
                raise ValueError(f"FitSettings.{name} must be one of {', '.join(values)}, got {getattr(self, name)!r}")
        if self.floor_contact and self.solver != "adam":
            raise ValueError("FitSettings.floor_contact acts on the Adam fit only: with solver "
                             f"{self.solver!r} it must be 0, got {self.floor_contact!r}")

    def without_pruning(self) -> FitSettings:
        """The same settings with every hypothesis run to the end (both prunings off)."""
        return replace(self, prune_after=None, prune_again_after=None)


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
    scan_sdf=with_line_of_sight(ScanSdf()),
    fit=FitSettings(iterations=160, samples_per_iteration=1500, lr_decay_every=100,
                    prune_after=20, prune_keep=4, prune_again_after=60, prune_again_keep=2,
                    init_scale="height", selection="loss",
                    latent_space="whitened", latent_penalty=1e-5, latent_penalty_points=6000,
                    below_floor_samples=2000, below_floor_depth=(0.1, 4.0), scale_prior=0.05,
                    line_of_sight_before_pruning=True, decoder_dtype="auto", float32_retry=True),
)
"""The default on a CPU: 5.3x fewer samples and 5x fewer iterations, yaw hypotheses pruned to
the best four after 20 iterations and the best two after 60, scale initialized from the object's
height and held near it by a weak prior, the latent optimized in the training codes' whitened
space under a penalty that weakens as the scan's object points grow, the winner picked by
its final loss rather than by F@5% against a partial scan; beyond the paper's samples, free
space on the sensor's lines of sight (where the viewpoints are known, from the first iteration)
and depth bounds under the floor from just below it; the decoder's matrix products in bfloat16
where the device computes them natively, and a fit they leave flagged doubtful fitted again in
float32 (docs/presets.md)."""

FAST_GAUSS_NEWTON = Preset(
    name="fast-gn",
    scan_sdf=FAST.scan_sdf,
    fit=replace(FAST.fit, solver="gauss-newton", iterations=15, samples_per_iteration=1000,
                samples_after_pruning=3000, prune_after=4, prune_keep=2, prune_again_after=None,
                translation_search=0.3, yaw_screen_samples=200, code_starts=2, code_screen_samples=50,
                code_starts_prune_after=1, adam_stage="always", polish_iterations=20, polish_samples=500,
                eval_samples=4000),
)
"""``fast``'s objective, starts and selection, minimized by Levenberg–Marquardt (fit.gauss_newton):
the 12 yaw starts take 4 iterations on 1000 samples drawn once; the best two move to the
translation of lowest objective on a grid across the up axis (±0.3 s0, step 0.1 s0, scored on
200 samples: a partial scan's visible part can put the start a quarter metre off), are each
also restarted from the two training codes that fit best there (all training codes scored on
50 samples), and go on on 3000 fresh samples, only the best of each start's three copies after
one iteration, to at most 15 iterations in all (stopping once a step gains under 0.1%); then both
take ``fast``'s last stage, 100 Adam steps on 1500 fresh samples each (40 at lr 0.05, 60 at 0.01),
and 20 more on 500 at lr 0.005, and the winner is the lowest loss on 4000 samples: about 0.51 M
decoder evaluations in the solve (docs/solver.md)."""

EXPRESS = Preset(name="express", scan_sdf=FAST.scan_sdf,
                 fit=replace(FAST_GAUSS_NEWTON.fit, distilled_search=True, distilled_screen=True,
                             adam_stage_iterations=60, adam_stage_decay_after=24, refine_iterations=5,
                             polish_iterations=0))
"""``fast-gn`` with the model's distilled decoder doing the search (``distilled_search``): the
screens, the Levenberg–Marquardt solve and a shorter Adam stage (60 steps, 24 at lr 0.05) run on
a network about five times cheaper; the model itself then settles the two survivors (at most 5
Levenberg–Marquardt iterations on the solve's 3000 samples; no polish), picks the winner on its
final losses and makes the mesh (docs/speed.md, "A distilled decoder")."""

FAST_SCALES = Preset(name="fast-scales", scan_sdf=FAST.scan_sdf, fit=replace(FAST.fit, init_scale="both"))
"""``fast``, its yaw starts also at the scale of the object's bounding sphere where that differs
from its height's by more than 10% (24 starts instead of 12 there, each held near its own start
scale by the scale prior; the same fit elsewhere): tables, sofas and beds vary in proportions
far more than chairs, and a fit started at the wrong scale rarely recovers (docs/presets.md)."""

FAST_DISTILLED = Preset(name="fast-distilled", scan_sdf=FAST.scan_sdf,
                        fit=replace(FAST.fit, distilled_search=True, distilled_iterations=130))
"""``fast`` with the model's distilled decoder moving the hypotheses through their first 130 Adam
steps, each pruning keeping those the model itself explains best; the model takes the two
survivors' last 30 steps, picks the winner and makes the mesh. The quick fits that choose among
candidates stay the model's (docs/speed.md, "Adam searched by the distilled decoder")."""

FAST_SCALES_DISTILLED = Preset(name="fast-scales-distilled", scan_sdf=FAST.scan_sdf,
                               fit=replace(FAST_DISTILLED.fit, init_scale="both"))
"""``fast-scales`` searched as ``fast-distilled``."""

EXPRESS_SCALES = Preset(name="express-scales", scan_sdf=FAST.scan_sdf, fit=replace(EXPRESS.fit, init_scale="both"))
"""``express``, its yaw starts also at the scale of the object's bounding sphere where that
differs from its height's by more than 10%, as ``fast-scales`` does for ``fast``: for tables,
sofas and beds (docs/speed.md, "A distilled decoder")."""

FAST_SCALES_FLOOR = Preset(name="fast-scales-floor", scan_sdf=FAST.scan_sdf,
                           fit=replace(FAST_SCALES.fit, floor_contact=0.3, floor_contact_classes=("table",)))
"""``fast-scales``, each table's fit held to the floor under it (``FitSettings.floor_contact``
0.3, tables only): a table seen mostly by its top otherwise ends with its legs in the air. Not
the default: in rooms it drops tables that grow to reach the floor (docs/presets.md, "Tables
held to the floor")."""

SIZED = Preset(name="sized", scan_sdf=FAST.scan_sdf, fit=replace(FAST_SCALES.fit, size_margin=1.2))
"""``fast-scales``, each class held to its own sizes (those of its training shapes, from 1/1.2 of
the smallest to 1.2 times the largest; ``FitSettings.size_margin``): a table model cannot
explain a bed at twice any table's size. Scans in metres only (docs/presets.md)."""

SMOKE = Preset(
    name="smoke",
    fit=FitSettings(iterations=10, samples_per_iteration=500, selection="loss", extract_resolution=32,
                    selection_resolution=32, prune_after=None),
)
"""A few seconds end to end: for tests and for checking that a pipeline runs, never for results."""

PRESETS: dict[str, Preset] = {
    "paper": PAPER,
    "fast": FAST,
    "fast-gn": FAST_GAUSS_NEWTON,
    "express": EXPRESS,
    "express-scales": EXPRESS_SCALES,
    "fast-distilled": FAST_DISTILLED,
    "fast-scales-distilled": FAST_SCALES_DISTILLED,
    "fast-scales": FAST_SCALES,
    "fast-scales-floor": FAST_SCALES_FLOOR,
    "sized": SIZED,
    "smoke": SMOKE,
}
DEFAULT_PRESET = "fast"
SCENE_PRESET = "fast-scales"
"""The default of a whole scene (``jsrte fit --scene``, ``fit_scene``, ``jsrte experiment scenes``):
a room's beds, sofas and tables vary in proportions, and each full fit also starts at its
points' scale (docs/clutter.md, "Whole scenes")."""
CLASS_PRESET = "fast-scales"
"""The default for one object of unknown class (``--model auto`` or several models), as for a
whole scene: the class's shape decides its proportions, so each full fit also starts at its
points' scale (docs/presets.md, "Tables and sofas")."""


def default_preset(*, scene: bool = False, class_unknown: bool = False) -> str:
    """The preset a fit takes unless told: :data:`SCENE_PRESET` for a whole scene,
    :data:`CLASS_PRESET` for one object of unknown class, else :data:`DEFAULT_PRESET`."""
    return SCENE_PRESET if scene else CLASS_PRESET if class_unknown else DEFAULT_PRESET


def names_several_models(model: object) -> bool:
    """Whether ``model`` (a ``--model`` value, or a list) lets the fit choose the class: "auto",
    names separated by commas, or a list of more than one."""
    if isinstance(model, list | tuple):
        return len(model) > 1
    return isinstance(model, str) and (model == "auto" or "," in model)

def get_preset(name: str) -> Preset:
    """Return the preset called ``name``; raises KeyError listing the known names."""
    try:
        return PRESETS[name]
    except KeyError:
        raise KeyError(f"unknown preset {name!r}; known: {', '.join(sorted(PRESETS))}") from None


def with_fit(preset: Preset, **changes: object) -> Preset:
    """A copy of ``preset`` with fit settings changed."""
    return replace(preset, fit=replace(preset.fit, **changes))
