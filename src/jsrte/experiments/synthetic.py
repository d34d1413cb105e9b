"""The synthetic experiment (paper section 4.1, Table 1, Fig. 2; supplementary Table 1).

Held-out shapes of a class (the evaluation set, ``EVAL_SET_SEED``: never seen in training),
normalized to the canonical unit-sphere frame, get a ground-truth similarity transform drawn
as the paper does (``SyntheticTruth``: s ~ U[1/2, 2), ψ, ρ, θ ~ U[-π, π), ||t|| ~ U[0, 4) in a
uniform direction; R = R(ψ, ρ, θ), base rotation identity). The query is the SDF of the
transformed complete mesh. Each shape is fitted from M initializations drawn around the truth
by a scenario (``SCENARIOS``: s0 = s(1 + Δs), θ0 = θ + Δθ, ..., Δ uniform in the scenario's
ranges; with a known axis ψ and ρ stay fixed at the truth), all M as one batch of hypotheses
without pruning, and *every* hypothesis is scored: F@5% of its own decoded surface, placed by
its own transform, against the transformed true mesh.
"""

from __future__ import annotations

import csv
import json
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import numpy as np
import torch
import trimesh

from jsrte.atomic import read_csv_rows, write_bytes_atomic, write_with
from jsrte.errors import JsrteError
from jsrte.experiments.settings import SCENARIOS, SYNTHETIC_FSCORE_GOOD, SyntheticScenario, SyntheticTruth
from jsrte.fit.optimize import optimize
from jsrte.fit.params import Init
from jsrte.fit.query import SdfQuery, query_from_mesh
from jsrte.fit.solve import latent_prior
from jsrte.geometry.mesh import normalized
from jsrte.geometry.sim3 import Sim3, rotation_angle_deg, rotation_from_paper
from jsrte.metrics.surface import fscore
from jsrte.model.checkpoint import DeepSdfModel
from jsrte.model.meshing import decode_mesh
from jsrte.presets import FitSettings, SdfSampling
from jsrte.shapes import CATEGORIES, EVAL_SET_SEED, generate_shape, shape_seed

Log = Callable[[str], None]

RUNS_NAME = "runs.csv"
CONFIG_NAME = "config.json"
SUMMARY_MD = "summary.md"
SUMMARY_CSV = "summary.csv"
FIGURE_NAME = "fscore_boxplots.png"

PAPER_STATEMENT = {
    "known": "most F@5% above 0.8 (Fig. 2 left)",
    "unknown": "most F@5% above 0.8, slightly worse than known axis (Fig. 2 right)",
    "known-wide": "most median F@5% above 0.8, more in [0.5, 0.7] (supp. Fig. 1 left)",
    "unknown-wide": "most median F@5% above 0.8, more in [0.5, 0.7] (supp. Fig. 1 right)",
}
"""What the paper says of each scenario (it gives plots, not numbers)."""


# --- sampling ----------------------------------------------------------------------------------


@dataclass(frozen=True)
class Pose:
    """A similarity transform in the paper's parameters (radians, scan units).

    Attributes
    ----------
    scale : s > 0
    psi, rho : polar angle and azimuth of the rotation axis
    theta : rotation angle about that axis
    translation : (3,)
    """

    scale: float
    psi: float
    rho: float
    theta: float
    translation: np.ndarray

    def rotation(self) -> np.ndarray:
        """R(ψ, ρ, θ) (3, 3), the paper's eq. 5."""
        angles = [torch.tensor(float(a), dtype=torch.float64) for a in (self.psi, self.rho, self.theta)]
        return rotation_from_paper(*angles).numpy()

    def transform(self) -> Sim3:
        """``scan_from_canonical``: x -> s R x + t."""
        return Sim3(self.scale, self.rotation(), self.translation)


def uniform_directions(n: int, *, rng: np.random.Generator) -> np.ndarray:
    """``n`` directions (n, 3) uniform on the unit sphere (normalized Gaussian vectors)."""
    v = rng.normal(size=(n, 3))
    norms = np.linalg.norm(v, axis=1, keepdims=True)
    while np.any(norms == 0):  # probability zero; redraw rather than divide by zero
        bad = norms[:, 0] == 0
        v[bad] = rng.normal(size=(int(bad.sum()), 3))
        norms = np.linalg.norm(v, axis=1, keepdims=True)
    return v / norms


def _uniform(rng: np.random.Generator, bounds: tuple[float, float], n: int | None = None) -> np.ndarray:
    lo, hi = bounds
    return rng.uniform(lo, hi, size=n)


def sample_truth(*, rng: np.random.Generator, ranges: SyntheticTruth = SyntheticTruth()) -> Pose:
    """A ground-truth transform drawn as the paper does (every range half-open)."""
    scale = float(_uniform(rng, ranges.scale))
    psi, rho, theta = (float(a) for a in _uniform(rng, ranges.angle, 3))
    norm = float(_uniform(rng, ranges.translation_norm))
    return Pose(scale, psi, rho, theta, norm * uniform_directions(1, rng=rng)[0])


@dataclass(frozen=True)
class InitDeltas:
    """Differences between M initializations and the truth (the paper's Δ variables).

    Attributes
    ----------
    scale : (M,) Δs, s0 = s (1 + Δs)
    psi, rho, theta : (M,) radians (Δψ = Δρ = 0 with a known axis)
    translation : (M, 3) Δt, t0 = t + Δt
    """

    scale: np.ndarray
    psi: np.ndarray
    rho: np.ndarray
    theta: np.ndarray
    translation: np.ndarray


def sample_deltas(scenario: SyntheticScenario, n: int, *, rng: np.random.Generator) -> InitDeltas:
    """``n`` draws of the Δ variables from ``scenario``'s ranges (uniform, half-open)."""
    scale = _uniform(rng, scenario.scale_delta, n)
    theta = _uniform(rng, scenario.theta_delta, n)
    if scenario.known_axis:
        psi, rho = np.zeros(n), np.zeros(n)
    else:
        psi, rho = _uniform(rng, scenario.axis_delta, n), _uniform(rng, scenario.axis_delta, n)
    norms = _uniform(rng, scenario.translation_delta_norm, n)
    translation = norms[:, None] * uniform_directions(n, rng=rng)
    return InitDeltas(scale, psi, rho, theta, translation)


def inits_around(truth: Pose, deltas: InitDeltas) -> list[Init]:
    """The initializations ``truth + deltas`` (latents left to the optimizer: z0 ~ N(0, σ²))."""
    return [Init(scale=truth.scale * (1.0 + float(deltas.scale[i])), psi=truth.psi + float(deltas.psi[i]),
                 rho=truth.rho + float(deltas.rho[i]), theta=truth.theta + float(deltas.theta[i]),
                 translation=truth.translation + deltas.translation[i])
            for i in range(len(deltas.scale))]


def fixed_parameters(scenario: SyntheticScenario) -> frozenset[str]:
    """Parameters held at their initial value: ψ and ρ when the axis is known."""
    return frozenset({"psi", "rho"}) if scenario.known_axis else frozenset()


# --- one shape -----------------------------------------------------------------------------------


@dataclass
class SyntheticCase:
    """One held-out shape under its ground-truth transform.

    Attributes
    ----------
    category : class name
    index : index in the evaluation set (seed ``shape_seed(EVAL_SET_SEED, index)``)
    truth : the true ``scan_from_canonical`` in the paper's parameters
    mesh : the complete true surface in the scan frame
    query : SDF samples of ``mesh`` (scan units)
    """

    category: str
    index: int
    truth: Pose
    mesh: trimesh.Trimesh
    query: SdfQuery


def make_case(category: str, index: int, *, rng: np.random.Generator,
              sampling: SdfSampling = SdfSampling(), truth: Pose | None = None) -> SyntheticCase:
    """Held-out shape ``index`` of ``category``, normalized to the canonical frame, transformed
    by ``truth`` (drawn from ``rng`` when None), and its DeepSDF-style SDF query."""
    shape = generate_shape(category, shape_seed(EVAL_SET_SEED, index))
    canonical = normalized(shape.mesh)
    truth = truth if truth is not None else sample_truth(rng=rng)
    mesh = trimesh.Trimesh(truth.transform().apply(canonical.vertices), canonical.faces.copy(), process=False)
    query = query_from_mesh(mesh, rng=rng, settings=sampling)
    return SyntheticCase(category, index, truth, mesh, query)


@dataclass(frozen=True)
class HypothesisOutcome:
    """Where one initialization ended.

    Attributes
    ----------
    transform : ``scan_from_canonical`` it converged to
    latent : (d,) float32
    loss : final objective on the evaluation subset
    mesh : its decoded surface placed by ``transform`` (scan frame), None if empty
    """

    transform: Sim3
    latent: np.ndarray
    loss: float
    mesh: trimesh.Trimesh | None


def fit_hypotheses(model: DeepSdfModel, query: SdfQuery, inits: list[Init], settings: FitSettings, *,
                   fixed: frozenset[str] = frozenset(), seed: int = 0,
                   resolution: int | None = None) -> list[HypothesisOutcome]:
    """Optimize all ``inits`` as one batch (no pruning) and decode every hypothesis.

    ``resolution``: marching-cubes resolution of the decoded surfaces (default
    ``settings.selection_resolution``, the one the fit scores its hypotheses at). No scale prior:
    these starts are the truth perturbed on purpose (the paper's Table 1), not the data's estimate.
    """
    settings = replace(settings.without_pruning(), scale_prior=0.0)
    generator = torch.Generator().manual_seed(seed)
    result = optimize(model.decoder, query, inits, settings, fixed=fixed, generator=generator,
                      prior=latent_prior(model, settings))
    resolution = resolution or settings.selection_resolution
    outcomes = []
    for h in range(len(inits)):
        latent = result.batch.latent[h].detach().to("cpu", torch.float32).numpy()
        transform = result.batch.transform(h)
        mesh = decode_mesh(model.decoder, latent, resolution=resolution).mesh
        if mesh is not None:
            mesh.vertices = transform.apply(mesh.vertices)
        outcomes.append(HypothesisOutcome(transform, latent, float(result.losses[h]), mesh))
    return outcomes


def score_outcome(outcome: HypothesisOutcome, case: SyntheticCase, *, rng: np.random.Generator,
                  settings: FitSettings = FitSettings()) -> dict[str, float]:
    """F@5% (precision, recall, Chamfer) against the true mesh, and the transform's errors."""
    f = fscore(outcome.mesh, case.mesh, fraction=settings.fscore_fraction, n_points=settings.fscore_points,
               rng=rng)
    true = case.truth.transform()
    est = outcome.transform
    return {"fscore": f.fscore, "precision": f.precision, "recall": f.recall, "chamfer": f.chamfer,
            "scale_error_rel": abs(est.s / true.s - 1.0),
            "rotation_error_deg": rotation_angle_deg(est.R, true.R),
            "translation_error": float(np.linalg.norm(est.t - true.t))}


# --- the experiment ------------------------------------------------------------------------------


@dataclass(frozen=True)
class SyntheticConfig:
    """What to run.

    Attributes
    ----------
    categories : classes to run (those without a model are skipped and reported)
    scenarios : names in ``SCENARIOS``
    shapes : held-out shapes per class
    inits : initializations per shape and scenario
    fit : fit settings (pruning is switched off)
    preset_name, scale_name : for the record
    sampling : SDF sampling of the queries
    seed : everything random derives from it
    resolution : marching cubes of the scored surfaces (None: ``fit.selection_resolution``)
    """

    categories: tuple[str, ...]
    scenarios: tuple[str, ...]
    shapes: int
    inits: int
    fit: FitSettings
    preset_name: str = "fast"
    scale_name: str = "custom"
    sampling: SdfSampling = SdfSampling()
    seed: int = 0
    resolution: int | None = None

    @property
    def surface_resolution(self) -> int:
        return self.resolution or self.fit.selection_resolution


@dataclass
class SyntheticReport:
    """Rows of runs.csv and summary.csv, what was skipped, and where the files are."""

    runs: list[dict] = field(default_factory=list)
    summary: list[dict] = field(default_factory=list)
    skipped: dict[str, str] = field(default_factory=dict)
    models: dict[str, dict] = field(default_factory=dict)
    files: list[Path] = field(default_factory=list)
    seconds: float = 0.0
    resumed_runs: int = 0
    """Rows taken over from an interrupted run of the same configuration (``resume``)."""


def _model_source(path: str | None) -> str:
    """'shipped' for a model inside the package, else the file's name (no machine paths in reports)."""
    from jsrte.model.registry import PRETRAINED_DIR

    if path is None:
        return "in memory"
    return "shipped" if Path(path).resolve().parent == PRETRAINED_DIR.resolve() else Path(path).name


def _category_number(category: str) -> int:
    return CATEGORIES.index(category) if category in CATEGORIES else len(CATEGORIES)


def _case_rng(seed: int, category: str, index: int) -> np.random.Generator:
    """The same truth and query for a shape in every scenario (scenarios compare like for like)."""
    return np.random.default_rng([seed, _category_number(category), index])


def _init_rng(seed: int, scenario: str, category: str, index: int) -> np.random.Generator:
    return np.random.default_rng([seed, 1 + list(SCENARIOS).index(scenario), _category_number(category), index])


def run_shape(model: DeepSdfModel, case: SyntheticCase, scenario: SyntheticScenario,
              config: SyntheticConfig) -> list[dict]:
    """Fit one case from ``config.inits`` initializations of ``scenario``: one row per run."""
    rng = _init_rng(config.seed, scenario.name, case.category, case.index)
    deltas = sample_deltas(scenario, config.inits, rng=rng)
    started = time.perf_counter()
    outcomes = fit_hypotheses(model, case.query, inits_around(case.truth, deltas), config.fit,
                              fixed=fixed_parameters(scenario), seed=int(rng.integers(2**31)),
                              resolution=config.surface_resolution)
    seconds = (time.perf_counter() - started) / len(outcomes)
    t = case.truth
    rows = []
    for i, outcome in enumerate(outcomes):
        score = score_outcome(outcome, case, rng=np.random.default_rng([config.seed, case.index, i]),
                              settings=config.fit)
        rows.append({
            "category": case.category, "scenario": scenario.name, "shape_index": case.index,
            "shape_seed": shape_seed(EVAL_SET_SEED, case.index), "init_index": i,
            "true_scale": t.scale, "true_psi": t.psi, "true_rho": t.rho, "true_theta": t.theta,
            "true_translation_norm": float(np.linalg.norm(t.translation)),
            "delta_scale": float(deltas.scale[i]), "delta_psi": float(deltas.psi[i]),
            "delta_rho": float(deltas.rho[i]), "delta_theta": float(deltas.theta[i]),
            "delta_translation_norm": float(np.linalg.norm(deltas.translation[i])),
            **score, "loss": outcome.loss, "empty_surface": outcome.mesh is None,
            "seconds": round(seconds, 3),
        })
    return rows


def run_synthetic(config: SyntheticConfig, models: dict[str, DeepSdfModel | None], out: Path, *,
                  log: Log | None = None, resume: bool = False) -> SyntheticReport:
    """Run the experiment and write runs.csv, summary.csv, summary.md and the box plots in ``out``.

    ``models`` maps each category of ``config.categories`` to its model, or None (skipped).
    ``out/config.json`` records what is run and runs.csv grows shape by shape, so ``resume``
    continues an interrupted run of the same configuration where it stopped (each shape and
    scenario draws from its own seeds: the rows are those of an uninterrupted run).
    """
    from jsrte.experiments.plots import plot_fscore_boxplots

    log = log or (lambda _msg: None)
    unknown = [s for s in config.scenarios if s not in SCENARIOS]
    if unknown:
        raise ValueError(f"unknown scenarios {unknown}; known: {', '.join(SCENARIOS)}")
    started = time.perf_counter()
    report = SyntheticReport()
    identity = run_identity(config, models)
    if resume:
        report.runs = resumable_runs(out, identity, config.inits)
        report.resumed_runs = len(report.runs)
        log(f"resuming: {len(report.runs)} runs already in {out / RUNS_NAME}")
    else:
        write_bytes_atomic(out / CONFIG_NAME, json.dumps(identity, indent=1).encode())
    done = {(r["category"], r["shape_index"], r["scenario"]) for r in report.runs}
    for category in config.categories:
        model = models.get(category)
        if model is None:
            report.skipped[category] = "no model"
            log(f"{category}: skipped, no model")
            continue
        report.models[category] = {"name": model.name, "sha256": model.meta.get("sha256"),
                                   "path": model.meta.get("path")}
        for index in range(config.shapes):
            todo = [name for name in config.scenarios if (category, index, name) not in done]
            if not todo:
                continue
            case = make_case(category, index, rng=_case_rng(config.seed, category, index),
                             sampling=config.sampling)
            for name in todo:
                rows = run_shape(model, case, SCENARIOS[name], config)
                report.runs.extend(rows)
                f = np.array([r["fscore"] for r in rows])
                log(f"{category} shape {index} {name}: F@5% median {np.median(f):.3f} "
                    f"(min {f.min():.3f}, max {f.max():.3f}) over {len(f)} inits")
                _write_runs(out / RUNS_NAME, report.runs)  # progress survives in the file as it grows
    report.summary = summarize(report.runs, config, report.skipped)
    report.seconds = time.perf_counter() - started
    report.files = [out / RUNS_NAME, out / SUMMARY_CSV, out / SUMMARY_MD]
    _write_runs(out / RUNS_NAME, report.runs)
    _write_csv(out / SUMMARY_CSV, report.summary)
    panels = figure_panels(report.runs, config)
    if panels:
        plot_fscore_boxplots(panels, out / FIGURE_NAME, n_inits=config.inits,
                             title=f"F@5% per initialization, binned per shape ({_classes(report)})")
        report.files.append(out / FIGURE_NAME)
        for category in report.models:
            if len(report.models) > 1:
                path = out / f"fscore_boxplots_{category}.png"
                plot_fscore_boxplots(figure_panels(report.runs, config, category=category), path,
                                     n_inits=config.inits, title=f"F@5% per initialization ({category})")
                report.files.append(path)
    write_bytes_atomic(out / SUMMARY_MD, summary_markdown(report, config).encode())
    return report


def run_identity(config: SyntheticConfig, models: dict[str, DeepSdfModel | None]) -> dict:
    """What makes two runs the same experiment (JSON-ready): every setting and each model's hash."""
    settings = asdict(config)
    settings.pop("scale_name")
    settings["models"] = {c: None if m is None else m.meta.get("sha256") for c, m in sorted(models.items())}
    return json.loads(json.dumps(settings))  # tuples become lists, as read back from the file


def resumable_runs(out: Path, identity: dict, inits: int) -> list[dict]:
    """The rows of an interrupted run in ``out`` with the same ``identity``: every shape and scenario
    that has all ``inits`` rows (a row's numbers as numbers)."""
    config_path = out / CONFIG_NAME
    if not config_path.is_file():
        raise JsrteError(f"nothing to resume ({CONFIG_NAME} missing)", out)
    try:
        earlier = json.loads(config_path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as error:
        raise JsrteError(f"unreadable ({error})", config_path) from error
    changed = sorted(k for k in identity.keys() | earlier.keys() if identity.get(k) != earlier.get(k))
    if changed:
        raise JsrteError(f"settings differ from the run being resumed ({', '.join(changed)})", config_path)
    runs_path = out / RUNS_NAME
    if not runs_path.is_file() or runs_path.stat().st_size == 0:
        return []
    rows = read_csv_rows(runs_path)
    try:
        keys = [(r["category"], r["shape_index"], r["scenario"]) for r in rows]
    except KeyError as error:
        raise JsrteError(f"unreadable runs table (no column {error})", runs_path) from error
    counts = {key: keys.count(key) for key in set(keys)}
    return [r for r, key in zip(rows, keys, strict=True) if counts[key] == inits]


def _classes(report: SyntheticReport) -> str:
    return ", ".join(report.models) or "none"


def figure_panels(runs: list[dict], config: SyntheticConfig, *,
                  category: str | None = None) -> list[tuple[str, list[np.ndarray]]]:
    """Per scenario: its title and, per shape, the F@5% of its initializations."""
    panels = []
    for name in config.scenarios:
        per_shape: dict[tuple[str, int], list[float]] = {}
        for r in runs:
            if r["scenario"] == name and (category is None or r["category"] == category):
                per_shape.setdefault((r["category"], r["shape_index"]), []).append(r["fscore"])
        if per_shape:
            panels.append((f"{SCENARIOS[name].title} ({SCENARIOS[name].source})",
                           [np.array(v) for v in per_shape.values()]))
    return panels


# --- tables --------------------------------------------------------------------------------------


def _stats(rows: list[dict]) -> dict:
    f = np.array([r["fscore"] for r in rows])
    per_shape = {}
    for r in rows:
        per_shape.setdefault((r["category"], r["shape_index"]), []).append(r["fscore"])
    shape_medians = np.array([np.median(v) for v in per_shape.values()])
    return {"shapes": len(per_shape), "runs": len(f), "median_fscore": round(float(np.median(f)), 4),
            "mean_fscore": round(float(np.mean(f)), 4),
            "fraction_ge_0.8": round(float(np.mean(f >= SYNTHETIC_FSCORE_GOOD)), 4),
            "shapes_median_ge_0.8": round(float(np.mean(shape_medians >= SYNTHETIC_FSCORE_GOOD)), 4),
            "median_rotation_error_deg": round(float(np.median([r["rotation_error_deg"] for r in rows])), 2),
            "median_scale_error_rel": round(float(np.median([r["scale_error_rel"] for r in rows])), 4)}


def summarize(runs: list[dict], config: SyntheticConfig, skipped: dict[str, str]) -> list[dict]:
    """One row per scenario and class (and per scenario over all classes when several ran)."""
    rows = []
    ran = [c for c in config.categories if c not in skipped]
    for name in config.scenarios:
        for category in config.categories:
            base = {"scenario": name, "category": category, "paper": PAPER_STATEMENT[name]}
            if category in skipped:
                rows.append({**base, "status": f"skipped: {skipped[category]}"})
                continue
            chosen = [r for r in runs if r["scenario"] == name and r["category"] == category]
            rows.append({**base, "status": "ok", **_stats(chosen)} if chosen
                        else {**base, "status": "no runs"})
        if len(ran) > 1:
            chosen = [r for r in runs if r["scenario"] == name]
            rows.append({"scenario": name, "category": "all", "paper": PAPER_STATEMENT[name], "status": "ok",
                         **_stats(chosen)})
    return rows


SUMMARY_COLUMNS = ("scenario", "category", "status", "shapes", "runs", "median_fscore", "mean_fscore",
                   "fraction_ge_0.8", "shapes_median_ge_0.8", "median_rotation_error_deg",
                   "median_scale_error_rel", "paper")


def _write_csv(path: Path, rows: list[dict], columns: tuple[str, ...] | None = None) -> None:
    columns = columns or tuple(dict.fromkeys(k for r in rows for k in r))

    def write(tmp: Path) -> None:
        with open(tmp, "w", newline="") as fh:
            writer = csv.DictWriter(fh, fieldnames=list(columns), extrasaction="ignore")
            writer.writeheader()
            writer.writerows(rows)

    write_with(path, write)


def _write_runs(path: Path, runs: list[dict]) -> None:
    if runs:
        _write_csv(path, runs)
    else:
        write_bytes_atomic(path, b"")


def summary_markdown(report: SyntheticReport, config: SyntheticConfig) -> str:
    """The human-readable summary: setup, table beside the paper's statement, skipped classes."""

    def degrees(bounds: tuple[float, float] | None) -> str:
        if bounds is None:
            return "N/A (fixed)"
        return f"[{np.degrees(bounds[0]):g}°, {np.degrees(bounds[1]):g}°)"

    scen = "\n".join(
        f"| {s.name} | [{s.scale_delta[0]:g}, {s.scale_delta[1]:g}) | {degrees(s.axis_delta)} | "
        f"{degrees(s.theta_delta)} | [{s.translation_delta_norm[0]:g}, {s.translation_delta_norm[1]:g}) | "
        f"{s.source} |"
        for s in (SCENARIOS[n] for n in config.scenarios))
    fit = config.fit
    lines = [
        "# Synthetic experiment (paper section 4.1, Fig. 2; supplementary wider ranges)", "",
        f"- Scale: **{config.scale_name}** — {config.shapes} held-out shapes per class × {config.inits} "
        f"initializations per scenario; fit preset `{config.preset_name}` ({fit.iterations} iterations, "
        f"{fit.samples_per_iteration} samples/iteration), no pruning: every initialization is scored.",
        f"- Shapes are **held out**: the evaluation set (set seed EVAL_SET_SEED = {EVAL_SET_SEED}), never "
        "used in training; normalized to the canonical unit sphere, then transformed by s ~ U[1/2, 2), "
        "ψ, ρ, θ ~ U[-π, π), ||t|| ~ U[0, 4) in a uniform direction (R = R(ψ, ρ, θ)).",
        f"- Query: {config.sampling.n_points} DeepSDF-style SDF samples of the transformed complete mesh.",
        f"- Score: F@5% of each initialization's own decoded surface (marching cubes at "
        f"{config.surface_resolution}³) against the transformed true mesh ({fit.fscore_points} points).",
        f"- Seed {config.seed}; {report.seconds / 60:.1f} min"
        + (f" (resumed: {report.resumed_runs} runs from an earlier start, whose time is not counted)."
           if report.resumed_runs else "."), "",
        "| scenario | Δs | Δψ, Δρ | Δθ | ‖Δt‖ | source |", "|---|---|---|---|---|---|", scen, "",
    ]
    for category, info in report.models.items():
        where = _model_source(info.get("path"))
        lines.append(f"- Model for {category}: `{info['name']}` ({where}, sha256 "
                     f"{str(info.get('sha256'))[:16]}…)")
    for category, why in report.skipped.items():
        lines.append(f"- **{category}: skipped** — {why} (none shipped under this name; run it alone with "
                     f"`--categories {category} --model PATH`)")
    lines += ["", "| scenario | class | shapes | runs | median F@5% | mean F@5% | F ≥ 0.8 | shapes with "
              "median ≥ 0.8 | median rot. err. (°) | median scale err. | paper |",
              "|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in report.summary:
        if r["status"] != "ok":
            lines.append(f"| {r['scenario']} | {r['category']} | {r['status']} | – | – | – | – | – | – | – "
                         f"| {r['paper']} |")
            continue
        lines.append(f"| {r['scenario']} | {r['category']} | {r['shapes']} | {r['runs']} "
                     f"| {r['median_fscore']:.3f} | {r['mean_fscore']:.3f} | {r['fraction_ge_0.8']:.0%} "
                     f"| {r['shapes_median_ge_0.8']:.0%} | {r['median_rotation_error_deg']:.1f} "
                     f"| {r['median_scale_error_rel']:.3f} | {r['paper']} |")
    if any(p.name == FIGURE_NAME for p in report.files):
        lines += ["", f"![F@5% box plots]({FIGURE_NAME})", "",
                  "Box plots as the paper's Fig. 2: per shape, the number of initializations whose F@5% "
                  "falls in each bin of width 0.1; one box per bin, over shapes, at the bin's right edge "
                  "(the left edge is the previous tick); orange line the median, circles outliers."]
    return "\n".join(lines) + "\n"
