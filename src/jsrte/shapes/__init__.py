"""Procedural furniture of the paper's four classes: the embedded default training data.

ShapeNet cannot be downloaded here, so chairs, tables, sofas and beds are generated from a
seed: watertight single-body meshes in metres with real furniture proportions, in the
canonical frame of ShapeNetCore v2 (+y up, standing on ``y = 0``, front towards -z,
bilaterally symmetric about the y-z plane, centred at ``x = z = 0``). Readers for real
ShapeNet folders and plain mesh folders live in :mod:`jsrte.shapes.shapenet`.

Sets of shapes are numbered: shape ``index`` of the set with seed ``set_seed`` is
``generate_shape(category, shape_seed(set_seed, index))``. Training sets use
``TRAIN_SET_SEED`` and evaluation sets ``EVAL_SET_SEED``. Shape seeds are 32-bit values that
``numpy.random.SeedSequence([set_seed, index])`` draws; the first 10 000 shapes of the
training set and of the evaluation set share no seed (checked in tests/test_shapes.py), so no
evaluation shape is a training shape for any set size used here. (Beyond ~50 000 shapes per
set, 32-bit seeds start to repeat by chance.)
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass, field
from pathlib import Path
from types import ModuleType
from typing import Any

import numpy as np
import trimesh

from jsrte.errors import JsrteError

CATEGORIES = ("chair", "table", "sofa", "bed")
"""The paper's four classes, in its order."""
TRAIN_SET_SEED = 0
"""Set seed of training sets."""
EVAL_SET_SEED = 1
"""Set seed of evaluation (held-out) sets; its first 10 000 shape seeds never coincide with
training's."""


@dataclass
class GeneratedShape:
    """One procedural shape.

    Attributes
    ----------
    mesh : watertight single-body trimesh in metres, canonical orientation, on ``y = 0``
    category : one of ``CATEGORIES``
    style : the structural style (one of ``category_styles(category)``)
    params : every parameter drawn (lengths in m, angles in degrees, flags, counts)
    seed : the seed it was generated from
    """

    mesh: trimesh.Trimesh
    category: str
    style: str
    params: dict[str, Any] = field(default_factory=dict)
    seed: int = 0

    def to_json(self) -> dict[str, Any]:
        """A JSON-ready description (no geometry)."""
        return {
            "category": self.category,
            "style": self.style,
            "params": self.params,
            "seed": int(self.seed),
            "height_m": float(self.mesh.bounds[1, 1] - self.mesh.bounds[0, 1]),
            "watertight": bool(self.mesh.is_watertight),
        }


def check_category(category: str) -> str:
    """Return ``category`` if known, else raise ``JsrteError`` listing the known ones."""
    if category not in CATEGORIES:
        raise JsrteError(f"unknown category {category!r} (known: {', '.join(CATEGORIES)})")
    return category


def _module(category: str) -> ModuleType:
    """The generator module of ``category`` (``STYLES``, ``generate(rng)``)."""
    return importlib.import_module(f"jsrte.shapes.{check_category(category)}")


def category_styles(category: str) -> tuple[str, ...]:
    """The structurally different styles of ``category``."""
    return tuple(_module(category).STYLES)


def generate_shape(category: str, seed: int) -> GeneratedShape:
    """Generate one shape of ``category``, deterministically from ``seed`` (int >= 0)."""
    parts, style, params = _module(category).generate(np.random.default_rng(int(seed)))
    return GeneratedShape(mesh=parts.to_trimesh(), category=category, style=style, params=params,
                          seed=int(seed))


def shape_seed(set_seed: int, index: int) -> int:
    """The seed (a 32-bit int) of shape ``index`` in the set with seed ``set_seed``."""
    return int(np.random.SeedSequence([int(set_seed), int(index)]).generate_state(1)[0])


def generate_set(category: str, n: int, set_seed: int) -> list[GeneratedShape]:
    """Shapes ``0..n-1`` of the set ``set_seed`` of ``category``."""
    check_category(category)
    return [generate_shape(category, shape_seed(set_seed, i)) for i in range(n)]


def shape_stem(category: str, index: int) -> str:
    """File stem of shape ``index`` of a set: ``{category}_{index:04d}``."""
    return f"{category}_{index:04d}"


def write_shape(shape: GeneratedShape, out_dir: str | Path, index: int) -> Path:
    """Write ``shape`` as ``{category}_{index:04d}.ply`` + ``.json`` (atomically); returns the PLY."""
    from jsrte.atomic import write_json_atomic
    from jsrte.geometry.mesh import save_mesh

    out_dir = Path(out_dir)
    stem = shape_stem(shape.category, index)
    path = out_dir / f"{stem}.ply"
    save_mesh(shape.mesh, path)
    write_json_atomic(out_dir / f"{stem}.json", shape.to_json())
    return path


def write_set(category: str, n: int, set_seed: int, out_dir: str | Path) -> list[Path]:
    """Generate and write shapes ``0..n-1`` of a set; returns the PLY paths."""
    check_category(category)
    return [write_shape(generate_shape(category, shape_seed(set_seed, i)), out_dir, i)
            for i in range(n)]


from jsrte.shapes.shapenet import (  # noqa: E402  (re-exported readers)
    SHAPENET_SYNSETS,
    iter_mesh_folder,
    iter_shapenet,
)

__all__ = [
    "CATEGORIES",
    "EVAL_SET_SEED",
    "SHAPENET_SYNSETS",
    "TRAIN_SET_SEED",
    "GeneratedShape",
    "category_styles",
    "check_category",
    "generate_set",
    "generate_shape",
    "iter_mesh_folder",
    "iter_shapenet",
    "shape_seed",
    "shape_stem",
    "write_set",
    "write_shape",
]
