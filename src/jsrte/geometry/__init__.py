"""Geometry: similarity transforms, rotations, meshes."""

from jsrte.geometry.sim3 import Sim3, rotation_from_paper, umeyama

__all__ = ["Sim3", "rotation_from_paper", "umeyama"]
