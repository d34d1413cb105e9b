"""Readers for real data: ShapeNetCore v2 folders and plain folders of mesh files.

ShapeNetCore v2's ``models/model_normalized.obj`` are already in our canonical frame
(+y up, front towards -z), so each file is read with :func:`jsrte.geometry.mesh.load_mesh`.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

from jsrte.errors import JsrteError
from jsrte.formats import MESH_FILE_SUFFIXES

SHAPENET_SYNSETS = {"chair": "03001627", "table": "04379243", "sofa": "04256520", "bed": "02818832"}
"""ShapeNetCore v2 synset id of each category."""
SHAPENET_MODEL = Path("models") / "model_normalized.obj"
"""Path of the mesh inside ``<synset>/<model_id>/``."""


def shapenet_synset_dir(root: str | Path, category: str) -> Path:
    """The synset folder of ``category`` under ``root``, or ``root`` itself when it is named
    like the synset or directly holds ``<model_id>/models/model_normalized.obj``."""
    if category not in SHAPENET_SYNSETS:
        raise JsrteError(f"unknown category {category!r} (known: {', '.join(SHAPENET_SYNSETS)})")
    root = Path(root)
    if not root.is_dir():
        raise JsrteError("no such folder", root)
    synset = SHAPENET_SYNSETS[category]
    if (root / synset).is_dir():
        return root / synset
    if root.name == synset or any(root.glob(f"*/{SHAPENET_MODEL.as_posix()}")):
        return root  # the synset folder itself (possibly renamed)
    raise JsrteError(f"holds no ShapeNet synset folder {synset} ({category})", root)


def iter_shapenet(root: str | Path, category: str) -> Iterator[tuple[str, Path]]:
    """Yield ``(model_id, path)`` of every ``<synset>/<model_id>/models/model_normalized.obj``.

    ``root`` is the ShapeNetCore v2 folder (holding synset folders) or a synset folder
    itself (also under another name). Model ids come sorted. Raises ``JsrteError`` for a
    missing folder or one with no models, when iteration starts (before the first item).
    """
    folder = shapenet_synset_dir(root, category)
    found = [(d.name, d / SHAPENET_MODEL) for d in sorted(folder.iterdir())
             if d.is_dir() and (d / SHAPENET_MODEL).is_file()]
    if not found:
        raise JsrteError(f"holds no models (<model_id>/{SHAPENET_MODEL.as_posix()})", folder)
    yield from found


def iter_mesh_folder(folder: str | Path) -> Iterator[Path]:
    """Yield the mesh files (suffixes ``MESH_FILE_SUFFIXES``) directly in ``folder``, sorted by name.

    Raises ``JsrteError`` for a missing folder or one holding no mesh files, when iteration
    starts.
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise JsrteError("no such folder", folder)
    found = sorted(p for p in folder.iterdir() if p.is_file() and p.suffix.lower() in MESH_FILE_SUFFIXES)
    if not found:
        raise JsrteError(f"holds no mesh files ({', '.join(MESH_FILE_SUFFIXES)})", folder)
    yield from found
