"""The fit's query (:class:`SdfQuery`) and how it is built from what the user has: samples, a
mesh, a scan, or a query file (the file's kind: :func:`jsrte.formats.input_kind`)."""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import trimesh

from jsrte.errors import JsrteError
from jsrte.formats import input_kind
from jsrte.geometry.mesh import load_mesh
from jsrte.presets import ScanSdf, SdfSampling
from jsrte.scans.segment import ClassShape, Segmentation, SegmentSettings
from jsrte.scans.veil import VeilSettings
from jsrte.sdf.mesh_sdf import SdfSamples, sample_sdf
from jsrte.timing import stage

SURFACE_POINTS = 20_000


@dataclass
class SdfQuery:
    """SDF samples of a query in scan units.

    Attributes
    ----------
    points : (m, 3) float64, scan units (metres for scans)
    sdf : (m,) float64, scan units, negative inside
    surface : (k, 3) float64, points on the query surface (scan units): for F-scores and figures
    up : (3,) unit vector or None: the known rotation axis (floor normal)
    floor_offset : float or None: the floor plane is {x : up·x = floor_offset}
    n_refine_only : the last this many samples (line-of-sight free space) are drawn only once
        the hypotheses are pruned (the yaw decided on the paper's evidence), unless
        ``FitSettings.line_of_sight_before_pruning``
    lower_bound : (m,) bool or None: samples whose ``sdf`` is only a lower bound on the true SDF
        (under the floor: fit.floor); the loss counts their predictions only where they fall short
    """

    points: np.ndarray
    sdf: np.ndarray
    surface: np.ndarray
    up: np.ndarray | None = None
    floor_offset: float | None = None
    info: dict = field(default_factory=dict)
    n_refine_only: int = 0
    lower_bound: np.ndarray | None = None


def query_from_samples(samples: SdfSamples, *, up: np.ndarray | None = None) -> SdfQuery:
    """An SDF-sample file (``jsrte sample``) as a query in the mesh's own frame."""
    points = samples.points.astype(np.float64) * samples.scale + samples.centre
    sdf = samples.sdf.astype(np.float64) * samples.scale
    near = np.abs(samples.sdf) < 0.01
    if near.sum() < 100:
        raise JsrteError("the SDF samples have too few points near the surface")
    surface = points[near][:SURFACE_POINTS]
    return SdfQuery(points, sdf, surface, up=up, info={"input": "sdf-samples", "samples": len(sdf)})


def query_from_mesh(mesh: trimesh.Trimesh, *, rng: np.random.Generator, up: np.ndarray | None = None,
                    settings: SdfSampling = SdfSampling()) -> SdfQuery:
    """A complete mesh in any pose: DeepSDF-style samples of its SDF, in its own frame."""
    query = query_from_samples(sample_sdf(mesh, rng=rng, settings=settings), up=up)
    query.surface = np.asarray(mesh.sample(SURFACE_POINTS, seed=int(rng.integers(2**31))))
    axis = np.array([0.0, 1.0, 0.0]) if up is None else np.asarray(up, float)
    query.floor_offset = float((mesh.vertices @ axis).min() / np.linalg.norm(axis))
    query.info["input"] = "mesh"
    return query


def class_shape(model: object) -> ClassShape | None:
    """The proportions and height profile of ``model``'s class (a ``DeepSdfModel``): its mean
    training code's surface, decoded once and cached in the model's metadata (None when that
    surface is empty: then a scan's largest object is taken)."""
    meta = model.meta
    name = str(meta.get("category") or model.name)
    if "class_aspect" not in meta or "class_profile" not in meta:
        from jsrte.model.meshing import decode_mesh

        mesh = decode_mesh(model.decoder, model.mean_code(), resolution=64).mesh
        if mesh is None:
            return None
        samples = np.asarray(mesh.sample(5000, seed=0))
        shape = ClassShape.of_mesh(name, np.asarray(mesh.vertices), samples)
        meta["class_aspect"], meta["class_profile"] = shape.aspect, shape.profile.tolist()
    return ClassShape(name=name, aspect=float(meta["class_aspect"]),
                      profile=np.asarray(meta["class_profile"], dtype=np.float64))


@dataclass
class ScanCandidates:
    """A scan segmented into candidate objects, any of which becomes an SDF query.

    Attributes
    ----------
    segmented : the scan, its floor and its candidates (``jsrte.scans.preprocess.SegmentedScan``)
    settings : how the SDF samples are drawn
    seed : seeds each candidate's samples (the same candidate always gives the same query)
    """

    segmented: object  # jsrte.scans.preprocess.SegmentedScan
    settings: ScanSdf = field(default_factory=ScanSdf)
    seed: int = 0

    @property
    def segmentation(self) -> Segmentation:
        """The candidates and the choice (``jsrte.scans.segment.Segmentation``)."""
        return self.segmented.segmentation

    def possible(self) -> list[int]:
        """Positions of every candidate that may be an object, a split's whole too, best class
        rank (else most points) first."""
        cands = self.segmentation.candidates
        ok = [k for k, c in enumerate(cands) if not c.rejected]
        return sorted(ok, key=lambda k: cands[k].summary.get("rank", -len(cands[k].index)))

    def valid(self) -> list[int]:
        """Positions of the candidates that may be the object, best class rank first: those not
        split further (a split's whole overlaps its parts; the screen weighs it against them)."""
        cands = self.segmentation.candidates
        return [k for k in self.possible() if not cands[k].parts]

    def query(self, candidate: int | None = None, *, keep: np.ndarray | None = None,
              rng: np.random.Generator | None = None) -> SdfQuery:
        """The SDF query of the candidate at position ``candidate`` (default: the chosen one), of
        its points in ``keep`` (bool mask over them) if given: surface samples from its points
        only; line-of-sight free space from every point the sensor saw. ``rng`` draws the
        samples (default: one seeded by ``seed``)."""
        from jsrte.sdf.from_scan import ray_freespace_samples, scan_sdf_samples

        segmented, settings = self.segmented, self.settings
        prepared = segmented.prepare(candidate, keep=keep)
        rng = np.random.default_rng(self.seed) if rng is None else rng
        with stage("query samples"):
            points, sdf = scan_sdf_samples(prepared.points, prepared.normals, settings=settings, rng=rng)
            n_rays = 0
            if segmented.viewpoints is not None:
                ray_points, ray_sdf = ray_freespace_samples(prepared.points, segmented.seen_points(),
                                                            segmented.viewpoints, rng=rng, settings=settings)
                points, sdf, n_rays = (np.concatenate([points, ray_points]), np.concatenate([sdf, ray_sdf]),
                                       len(ray_sdf))
        floor_offset = prepared.floor.offset if prepared.floor is not None else None
        return SdfQuery(points.astype(np.float64), sdf.astype(np.float64), prepared.points, up=prepared.up,
                        floor_offset=floor_offset,
                        info={"input": "scan", "scan_points": len(segmented.cloud.points),
                              "object_points": len(prepared.points), "samples": len(sdf),
                              "ray_freespace_samples": n_rays,
                              "floor_found": prepared.floor is not None,
                              "segmentation": self.segmentation.to_json()},
                        n_refine_only=n_rays)


def scan_candidates(path: str | Path, *, rng: np.random.Generator, up: np.ndarray | None = None,
                    viewpoints: np.ndarray | None = None, settings: ScanSdf = ScanSdf(),
                    units_check: bool = True, shape: ClassShape | None = None,
                    at: np.ndarray | None = None, segment: SegmentSettings = SegmentSettings(),
                    fit_veil: VeilSettings | None = None) -> ScanCandidates:
    """A scan (point cloud or scan mesh, metres, floor optional when ``up`` is given) loaded and
    segmented into candidate objects (``jsrte.scans.segment`` with ``segment``): the one nearest
    ``at`` (3,) is chosen if given, else the one most like ``shape`` (the class's proportions,
    see :func:`class_shape`). The sensor's ``viewpoints`` (k, 3) are given, or the ``cameras``
    of the scan's JSON sidecar. With ``fit_veil``, each candidate's mixed pixels are left out of
    its points for its fit (``PrepareSettings.fit_veil``)."""
    from jsrte.scans.io import load_scan, read_scan_info
    from jsrte.scans.preprocess import PrepareSettings, segment_scan

    with stage("load"):
        cloud = load_scan(path, rng=rng)
        info = read_scan_info(path) if Path(path).suffix.lower() == ".ply" else None
    if viewpoints is None and info is not None and len(info.cameras):
        viewpoints = info.cameras
    segmented = segment_scan(cloud, rng=rng, up=up, viewpoints=viewpoints, shape=shape, at=at,
                             settings=PrepareSettings(units_check=units_check, fit_veil=fit_veil), segment=segment)
    return ScanCandidates(segmented, settings)


def query_from_scan(path: str | Path, *, rng: np.random.Generator, up: np.ndarray | None = None,
                    viewpoints: np.ndarray | None = None, settings: ScanSdf = ScanSdf(),
                    units_check: bool = True, shape: ClassShape | None = None,
                    at: np.ndarray | None = None) -> SdfQuery:
    """A scan (point cloud or scan mesh, metres, floor optional when ``up`` is given): the
    paper's preprocessing, then SDF samples ±δ along the normals plus freespace samples, plus
    free space on the lines of sight when the sensor's ``viewpoints`` (k, 3) are known (given,
    or the ``cameras`` of the scan's JSON sidecar). ``units_check`` False skips the check that
    the object's size is plausible in metres.

    The object is told from walls and other objects (``jsrte.scans.segment``): the one nearest
    ``at`` (3,) if given, else the one most like ``shape`` (the class's proportions, see
    :func:`class_shape`). Only its points give surface samples; everything else the sensor saw
    (floor, walls, other objects) only bounds free space on the lines of sight, never where a
    point of the object was seen (samples keep ``ray_margin_m`` from every object point)."""
    return scan_candidates(path, rng=rng, up=up, viewpoints=viewpoints, settings=settings,
                           units_check=units_check, shape=shape, at=at).query(rng=rng)


QUERY_FORMAT = "jsrte-query"
"""The ``format`` entry of a query file (``jsrte prepare``), told apart from ``jsrte sample`` files."""


def save_query(query: SdfQuery, path: str | Path) -> None:
    """Write ``query`` as an ``.npz`` query file, atomically (read back by :func:`read_query_file`)."""
    from jsrte.atomic import write_with

    arrays = {"format": np.array(QUERY_FORMAT), "points": query.points, "sdf": query.sdf, "surface": query.surface,
              "up": np.full(3, np.nan) if query.up is None else np.asarray(query.up, float),
              "floor_offset": np.float64(np.nan if query.floor_offset is None else query.floor_offset),
              "n_refine_only": np.int64(query.n_refine_only), "info": np.array(json.dumps(query.info))}
    if query.lower_bound is not None:
        arrays["lower_bound"] = np.asarray(query.lower_bound, bool)

    def write(tmp: Path) -> None:
        with open(tmp, "wb") as f:
            np.savez(f, **arrays)

    write_with(path, write)


def is_query_file(path: str | Path) -> bool:
    """Whether ``path`` is an ``.npz`` written by :func:`save_query`."""
    try:
        with np.load(path) as data:
            return "format" in data.files and str(data["format"]) == QUERY_FORMAT
    except Exception:
        return False


def read_query_file(path: str | Path) -> SdfQuery:
    """The query saved by :func:`save_query`; JsrteError naming the file if it is not one."""
    try:
        with np.load(path) as data:
            points, sdf, surface = data["points"], data["sdf"], data["surface"]
            up, floor = data["up"], float(data["floor_offset"])
            n_refine, info = int(data["n_refine_only"]), json.loads(str(data["info"]))
            lower = data["lower_bound"] if "lower_bound" in data.files else None
    except Exception as exc:
        raise JsrteError(f"not a jsrte query file ({type(exc).__name__}: {exc})", path) from exc
    if points.ndim != 2 or points.shape[1] != 3 or sdf.shape != (len(points),) or surface.ndim != 2:
        raise JsrteError(f"points {points.shape}, sdf {sdf.shape} and surface {surface.shape} do not fit", path)
    if lower is not None and (lower.dtype != bool or lower.shape != sdf.shape):
        raise JsrteError(f"lower_bound {lower.dtype} {lower.shape} does not fit sdf {sdf.shape}", path)
    if not (np.isfinite(points).all() and np.isfinite(sdf).all()):
        raise JsrteError("holds NaN or infinite samples", path)
    return SdfQuery(points.astype(np.float64), sdf.astype(np.float64), surface.astype(np.float64),
                    up=None if np.isnan(up).any() else up.astype(np.float64),
                    floor_offset=None if np.isnan(floor) else floor, info=info, n_refine_only=n_refine,
                    lower_bound=lower)


def load_query(path: str | Path, *, rng: np.random.Generator, up: np.ndarray | None = None,
               viewpoints: np.ndarray | None = None, scan_settings: ScanSdf = ScanSdf(),
               units_check: bool = True, shape: ClassShape | None = None,
               at: np.ndarray | None = None) -> SdfQuery:
    """Dispatch on the file: ``.npz`` query files (``jsrte prepare``; ``up`` overrides theirs) or
    SDF samples (``jsrte sample``); OBJ/OFF/STL/GLB complete meshes (up: ``up``
    or +y); PLY/PCD/XYZ/PTS scans (point clouds or scan meshes, floor plane gives up; the object
    is the one nearest ``at`` (3,) or most like ``shape``: :func:`query_from_scan`)."""
    path = Path(path)
    kind = input_kind(path)
    if at is not None and kind != "scan":
        raise JsrteError("--at picks an object in a scan; this input is not a scan (PLY/PCD/XYZ/PTS)", path)
    if kind == "npz" and is_query_file(path):
        query = read_query_file(path)
        if up is not None:
            query.up = np.asarray(up, float) / np.linalg.norm(up)
        return query
    if kind == "npz":
        return query_from_samples(SdfSamples.load(path), up=up)
    if kind == "mesh":
        return query_from_mesh(load_mesh(path), rng=rng, up=up)
    return query_from_scan(path, rng=rng, up=up, viewpoints=viewpoints, settings=scan_settings,
                           units_check=units_check, shape=shape, at=at)
