"""The sizes of a class's training shapes in metres, so that a fit keeps a class to its own sizes.

A shape's size is the scale s a fit recovers for it: the radius of DeepSDF's unit-sphere
normalization (the largest distance of a vertex from the bounding-box centre, padded), in the
mesh's units. A model trained on metric meshes (the procedural furniture) knows the range of its
class's sizes; a fit of that model to a scan in metres can be held within it
(``jsrte.presets.FitSettings.size_margin``): a table 4.6 m across or a bed 1 m across is no table
and no bed. Meshes in arbitrary units (ShapeNet's are normalized) give no sizes.
"""

from __future__ import annotations

import json
from collections.abc import Iterable
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import trimesh

from jsrte.model.registry import PRETRAINED_DIR

SHIPPED_SIZES = PRETRAINED_DIR / "sizes.json"
"""The shipped models' class sizes, by model name, each with the SHA-256 of the model it belongs
to (written by ``scripts/ship_model.py``)."""


@dataclass(frozen=True)
class ClassSizes:
    """The sizes (m) of a model's training shapes: smallest, median and largest, over ``shapes``."""

    smallest: float
    median: float
    largest: float
    shapes: int

    def bounds(self, margin: float, above: float | None = None) -> tuple[float, float]:
        """The scales (m) a fit may take: from ``smallest / margin`` to ``largest * above``
        (``above`` None: ``margin`` both ways)."""
        return self.smallest / margin, self.largest * (margin if above is None else above)


def measure_sizes(meshes: Iterable[trimesh.Trimesh]) -> ClassSizes:
    """The sizes of ``meshes`` (their units): each one's unit-sphere normalization radius."""
    from jsrte.geometry.mesh import unit_sphere_normalization

    sizes = np.array([unit_sphere_normalization(mesh).scale for mesh in meshes])
    return ClassSizes(float(sizes.min()), float(np.median(sizes)), float(sizes.max()), len(sizes))


def procedural_sizes(category: str, n_shapes: int, set_seed: int) -> ClassSizes:
    """The sizes of procedural shapes ``0..n_shapes-1`` of ``category`` in set ``set_seed`` (m)."""
    from jsrte.shapes import generate_shape, shape_seed

    return measure_sizes(generate_shape(category, shape_seed(set_seed, i)).mesh for i in range(n_shapes))


def training_sizes(meta: dict) -> ClassSizes | None:
    """The sizes of the shapes a model was trained on, from its metadata's ``data`` record: those
    of procedural shapes (metres) are measured again; None for other data."""
    data = meta.get("data") or {}
    if data.get("source") != "procedural":
        return None
    return procedural_sizes(data["category"], int(data["n_shapes"]), int(data["set_seed"]))


def model_sizes(meta: dict) -> ClassSizes | None:
    """A model's class sizes: its metadata's ``sizes_m``, else the shipped record of a shipped
    model (the same name and SHA-256), else None (unknown: the fit's scale is not held)."""
    own = meta.get("sizes_m")
    if isinstance(own, dict):
        return ClassSizes(**own)
    record = shipped_sizes().get(str(meta.get("name")))
    if record is None or record.get("sha256") != meta.get("sha256"):
        return None
    return ClassSizes(**{k: record[k] for k in ("smallest", "median", "largest", "shapes")})


def shipped_sizes(path: Path = SHIPPED_SIZES) -> dict[str, dict]:
    """Name -> the shipped record (sizes and the model's ``sha256``); empty when there is none."""
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError):
        return {}


def record_shipped_sizes(name: str, sha256: str, sizes: ClassSizes, path: Path = SHIPPED_SIZES) -> None:
    """Write (or replace) the shipped record of model ``name``."""
    from jsrte.atomic import write_json_atomic

    records = shipped_sizes(path)
    records[name] = {"sha256": sha256, **{k: round(v, 4) if isinstance(v, float) else v
                                          for k, v in asdict(sizes).items()}}
    write_json_atomic(path, dict(sorted(records.items())))
