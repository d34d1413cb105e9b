"""The baselines' shape database: the training shapes of a model, in the canonical unit sphere.

Every method sees the same data: the shapes the named model was trained on, regenerated from
the procedural seeds recorded in the model (``meta["data"]["source"] == "procedural"``) or read
from its data folder (``"folder"``), each normalized like DeepSDF (bounding-box centre, largest
vertex distance x 1.03). Regenerating 100 procedural chairs takes 30-100 s, so a database built
from a model is cached on disk (:mod:`jsrte.baselines.cache`, keyed by the model's SHA-256).
Per-shape surface samples are drawn once; descriptors are computed lazily and cached in memory
and on disk (keyed by the database and the descriptor's settings).
"""

from __future__ import annotations

import hashlib
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import trimesh

from jsrte.baselines.cache import cache_dir, digest, load_arrays, save_arrays
from jsrte.errors import JsrteError
from jsrte.geometry.mesh import normalized

DEFAULT_SAMPLES = 10_000
"""Surface points drawn per database shape (with their face normals)."""

Arrays = dict[str, np.ndarray]


class ShapeDatabase:
    """Shapes in the normalized canonical frame, with cached samples and descriptors.

    Parameters
    ----------
    meshes : the shapes (any frame unless ``normalize`` is False)
    names : one name per shape (default ``shape_0000``, ...)
    normalize : bring each mesh into the DeepSDF unit sphere (False: already there)
    key : identity used by the caches (default: a hash of the meshes' vertices and faces)
    samples : surface points drawn per shape
    seed : seed of the surface sampling (shape ``i`` uses ``[seed, i]``)
    persist : keep descriptors in the user cache folder between runs
    """

    def __init__(self, meshes: Sequence[trimesh.Trimesh], names: Sequence[str] | None = None, *,
                 normalize: bool = True, key: str | None = None, samples: int = DEFAULT_SAMPLES,
                 seed: int = 0, persist: bool = True, source: dict[str, Any] | None = None) -> None:
        if len(meshes) == 0:
            raise JsrteError("the shape database is empty")
        self.meshes = [normalized(m) if normalize else m for m in meshes]
        self.names = list(names) if names is not None else [f"shape_{i:04d}" for i in range(len(meshes))]
        if len(self.names) != len(self.meshes):
            raise JsrteError(f"{len(self.names)} names for {len(self.meshes)} database shapes")
        self.key = key or _mesh_hash(self.meshes)
        self.n_samples = int(samples)
        self.seed = int(seed)
        self.persist = persist
        self.source = source or {"source": "memory"}
        self._points: list[np.ndarray | None] = [None] * len(self.meshes)
        self._normals: list[np.ndarray | None] = [None] * len(self.meshes)
        self._descriptors: dict[str, list[Arrays]] = {}

    def __len__(self) -> int:
        return len(self.meshes)

    def describe(self) -> dict[str, Any]:
        """A JSON-ready summary (for result files)."""
        return {"shapes": len(self), "key": self.key} | self.source

    # --- samples ------------------------------------------------------------------------------

    def points(self, index: int) -> np.ndarray:
        """Surface samples ``(samples, 3)`` of shape ``index`` (canonical units)."""
        self._sample(index)
        return self._points[index]

    def normals(self, index: int) -> np.ndarray:
        """Outward unit normals ``(samples, 3)`` at :meth:`points` (the faces' normals)."""
        self._sample(index)
        return self._normals[index]

    def _sample(self, index: int) -> None:
        if self._points[index] is not None:
            return
        mesh = self.meshes[index]
        seed = int(np.random.SeedSequence([self.seed, index]).generate_state(1)[0])
        pts, faces = trimesh.sample.sample_surface(mesh, self.n_samples, seed=seed)
        self._points[index] = np.asarray(pts, dtype=np.float64)
        self._normals[index] = np.asarray(mesh.face_normals[faces], dtype=np.float64)

    # --- descriptors --------------------------------------------------------------------------

    def descriptors(self, kind: str, settings: Any, compute: Callable[[int], Arrays]) -> list[Arrays]:
        """Per-shape descriptor arrays of ``kind``, computed once by ``compute(index)``.

        ``settings`` (a dataclass or any JSON-able value) is part of the cache key, so changing
        a descriptor's parameters never reuses stale values. Cached in memory, and on disk when
        ``persist`` is set.
        """
        tag = f"{kind}-{digest([kind, repr(settings), self.n_samples, self.seed])}"
        if tag in self._descriptors:
            return self._descriptors[tag]
        path = cache_dir("descriptors") / f"{self.key[:32]}-{tag}.npz" if self.persist else None
        stored = load_arrays(path) if path is not None else None
        if stored is not None and _complete(stored, len(self)):
            values = _unflatten(stored, len(self))
        else:
            values = [compute(i) for i in range(len(self))]
            if path is not None:
                save_arrays(path, _flatten(values))
        self._descriptors[tag] = values
        return values

    # --- construction -------------------------------------------------------------------------

    @classmethod
    def from_model(cls, model: Any, *, samples: int = DEFAULT_SAMPLES, persist: bool = True
                   ) -> ShapeDatabase:
        """The training shapes of ``model`` (a ``DeepSdfModel``), as its metadata records them."""
        data = dict(model.meta.get("data") or {})
        source = data.get("source")
        if source not in ("procedural", "folder"):
            raise JsrteError(f"model {model.name!r} does not record its training data "
                             f"(meta['data']['source'] is {source!r}); cannot build the baselines' database")
        key = str(model.meta.get("sha256") or digest(data))
        described = {"source": source, "category": data.get("category"), "model": model.name}
        path = cache_dir("databases") / f"{key[:32]}.npz" if persist else None
        stored = load_arrays(path) if path is not None else None
        if stored is not None:
            meshes, names = _meshes_from_arrays(stored)
        else:
            meshes, names = _training_meshes(data)
            if path is not None:
                save_arrays(path, _meshes_to_arrays(meshes, names))
        return cls(meshes, names, normalize=False, key=key, samples=samples, persist=persist,
                   source=described)


# --- training data -------------------------------------------------------------------------------


def _training_meshes(data: dict[str, Any]) -> tuple[list[trimesh.Trimesh], list[str]]:
    """Normalized meshes and names of the training data a model's metadata describes."""
    n = int(data.get("n_shapes") or 0)
    if n < 1:
        raise JsrteError("the model's training data records no shapes (meta['data']['n_shapes'])")
    if data["source"] == "procedural":
        from jsrte.shapes import generate_set, shape_stem

        category, set_seed = data.get("category"), data.get("set_seed")
        if category is None or set_seed is None:
            raise JsrteError("the model's procedural training data lacks 'category' or 'set_seed'")
        shapes = generate_set(category, n, int(set_seed))
        return [normalized(s.mesh) for s in shapes], [shape_stem(category, i) for i in range(n)]
    return _folder_meshes(data, n)


def _folder_meshes(data: dict[str, Any], n: int) -> tuple[list[trimesh.Trimesh], list[str]]:
    from jsrte.geometry.mesh import load_mesh
    from jsrte.model.data import _looks_like_shapenet
    from jsrte.shapes.shapenet import iter_mesh_folder, iter_shapenet

    folder = Path(str(data.get("folder")))
    if not folder.is_dir():
        raise JsrteError("the model's training folder is not there (the baselines need its meshes)", folder)
    category = data.get("category")
    if category is not None and _looks_like_shapenet(folder):
        found = [(model_id, p) for model_id, p in iter_shapenet(folder, category)][:n]
    else:
        names = data.get("meshes") or [p.name for p in iter_mesh_folder(folder)]
        found = [(Path(name).stem, folder / name) for name in names][:n]
    if len(found) != n:
        raise JsrteError(f"holds {len(found)} of the model's {n} training meshes", folder)
    return [normalized(load_mesh(p)) for _, p in found], [name for name, _ in found]


# --- (de)serialization ---------------------------------------------------------------------------


def _mesh_hash(meshes: Sequence[trimesh.Trimesh]) -> str:
    h = hashlib.sha256()
    for m in meshes:
        h.update(np.ascontiguousarray(m.vertices, dtype=np.float64).tobytes())
        h.update(np.ascontiguousarray(m.faces, dtype=np.int64).tobytes())
    return h.hexdigest()


def _meshes_to_arrays(meshes: Sequence[trimesh.Trimesh], names: Sequence[str]) -> Arrays:
    arrays: Arrays = {"names": np.array(list(names))}
    for i, m in enumerate(meshes):
        arrays[f"{i}/vertices"] = np.asarray(m.vertices, dtype=np.float64)
        arrays[f"{i}/faces"] = np.asarray(m.faces, dtype=np.int64)
    return arrays


def _meshes_from_arrays(arrays: Arrays) -> tuple[list[trimesh.Trimesh], list[str]]:
    names = [str(n) for n in arrays["names"]]
    meshes = [trimesh.Trimesh(arrays[f"{i}/vertices"], arrays[f"{i}/faces"], process=False)
              for i in range(len(names))]
    return meshes, names


def _flatten(values: list[Arrays]) -> Arrays:
    return {f"{i}/{k}": v for i, d in enumerate(values) for k, v in d.items()}


def _unflatten(arrays: Arrays, n: int) -> list[Arrays]:
    values: list[Arrays] = [{} for _ in range(n)]
    for key, v in arrays.items():
        i, name = key.split("/", 1)
        values[int(i)][name] = v
    return values


def _complete(arrays: Arrays, n: int) -> bool:
    return {int(k.split("/", 1)[0]) for k in arrays} == set(range(n))
