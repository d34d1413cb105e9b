"""Contact sheets: a grid of shaded 3D views of meshes, to check generated shapes by eye.

Each tile is drawn by the software renderer (:mod:`jsrte.raster`: no OpenGL or matplotlib),
from the front-left and above; tiles are composed with Pillow, titled underneath.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np
import trimesh

from jsrte.raster import Camera, render

MAX_SHEET_SHAPES = 16
"""At most this many shapes on one sheet (a 4 x 4 grid)."""
TILE_PX = 320
"""Side of one rendered tile in pixels."""
VIEW_DIRECTION = np.array([-0.55, 0.45, -1.0])
"""From the shape's centre towards the camera (canonical frame): in front (-z), above, at -x."""
YFOV = 0.7
"""Vertical field of view of a tile (radians)."""
TILE_RGB = (0.62, 0.62, 0.64)
"""Base colour of the shapes (0-1 floats)."""


def look_at(eye: np.ndarray, target: np.ndarray, up: Sequence[float] = (0.0, 1.0, 0.0)) -> np.ndarray:
    """(4, 4) OpenGL camera-to-world pose at ``eye`` (3,) looking at ``target`` (3,), ``up`` up."""
    eye = np.asarray(eye, np.float64)
    forward = np.asarray(target, np.float64) - eye
    forward /= np.linalg.norm(forward)
    right = np.cross(forward, up)
    right /= np.linalg.norm(right)
    pose = np.eye(4)
    pose[:3, 0], pose[:3, 1], pose[:3, 2], pose[:3, 3] = right, np.cross(right, forward), -forward, eye
    return pose


def render_tile(mesh: trimesh.Trimesh) -> np.ndarray:
    """(TILE_PX, TILE_PX, 3) uint8 gray rendering of ``mesh`` (canonical frame) from the front-left."""
    centre = mesh.bounds.mean(axis=0)
    radius = float(np.linalg.norm(mesh.bounds[1] - mesh.bounds[0])) / 2
    distance = 1.15 * radius / np.sin(YFOV / 2)
    eye = centre + distance * VIEW_DIRECTION / np.linalg.norm(VIEW_DIRECTION)
    camera = Camera(pose=look_at(eye, centre), yfov=YFOV)
    return render(np.asarray(mesh.vertices), np.asarray(mesh.faces), None, camera, (TILE_PX, TILE_PX),
                  mesh_rgb=TILE_RGB)


def render_sheet(meshes: Sequence[trimesh.Trimesh], titles: Sequence[str], path: str | Path,
                 *, columns: int = 4) -> Path:
    """Render up to ``MAX_SHEET_SHAPES`` meshes in a grid, titled, to a PNG at ``path`` (atomically)."""
    from jsrte.viz import compose_tiles

    meshes, titles = list(meshes)[:MAX_SHEET_SHAPES], list(titles)[:MAX_SHEET_SHAPES]
    if not meshes:
        raise ValueError("render_sheet needs at least one mesh")
    images = [render_tile(mesh) for mesh in meshes]
    compose_tiles(images, titles, path, cols=min(columns, len(meshes)))
    return Path(path)
