"""Sample the SDF of a whole folder of meshes in parallel, caching by mesh hash."""

from __future__ import annotations

import os
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from tqdm import tqdm

from jsrte.atomic import write_json_atomic
from jsrte.errors import JsrteError
from jsrte.geometry.mesh import load_mesh
from jsrte.presets import SdfSampling
from jsrte.processes import die_with_parent
from jsrte.sdf.mesh_sdf import sample_cache_key, sample_sdf

INDEX_NAME = "index.json"


@dataclass(frozen=True)
class _Job:
    mesh_path: Path
    out_path: Path
    settings: SdfSampling
    seed: int


def _run(job: _Job) -> Path:
    mesh = load_mesh(job.mesh_path)
    samples = sample_sdf(mesh, rng=np.random.default_rng(job.seed), settings=job.settings)
    samples.save(job.out_path)
    return job.out_path


def build_sdf_dataset(
    mesh_paths: list[Path],
    out_dir: str | Path,
    *,
    settings: SdfSampling = SdfSampling(),
    seed: int = 0,
    workers: int | None = None,
    progress: bool = True,
) -> list[Path]:
    """Sample every mesh into ``out_dir/<hash>.npz``; meshes already sampled are skipped.

    The cache key hashes the mesh file, the settings and the seed, so a changed mesh or
    setting is sampled again. Writes ``out_dir/index.json`` mapping each mesh to its file.
    Returns the sample paths (n,) in the order of ``mesh_paths``.
    """
    if not mesh_paths:
        raise JsrteError("no meshes to sample")
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    jobs, outputs = [], []
    for i, mesh_path in enumerate(mesh_paths):
        key = sample_cache_key(mesh_path, settings, seed + i)
        out = out_dir / f"{key}.npz"
        outputs.append(out)
        if not out.exists():
            jobs.append(_Job(Path(mesh_path), out, settings, seed + i))
    if jobs:
        with ProcessPoolExecutor(max_workers=workers, initializer=die_with_parent,
                                 initargs=(os.getpid(),)) as pool:
            done = pool.map(_run, jobs)
            for _ in tqdm(done, total=len(jobs), desc="sampling SDF", disable=not progress):
                pass
    index = {str(Path(p).resolve()): o.name for p, o in zip(mesh_paths, outputs, strict=True)}
    write_json_atomic(out_dir / INDEX_NAME, {"seed": seed, "meshes": index})
    return outputs
