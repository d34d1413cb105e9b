"""Geometry: similarity transforms, rotations, meshes.

``Sim3``, ``rotation_from_paper`` and ``umeyama`` are imported on first use, so that reading a
mesh (``jsrte.geometry.mesh``) does not start PyTorch.
"""

from typing import Any

__all__ = ["Sim3", "rotation_from_paper", "umeyama"]


def __getattr__(name: str) -> Any:
    if name in __all__:
        from jsrte.geometry import sim3

        return getattr(sim3, name)
    raise AttributeError(f"module 'jsrte.geometry' has no attribute {name!r}")
