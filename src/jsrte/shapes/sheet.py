"""Contact sheets: a grid of shaded 3D views of meshes, to check generated shapes by eye.

Each tile is rendered offscreen with pyrender (``PYOPENGL_PLATFORM=egl``, headless); where
no OpenGL context can be made, tiles are drawn with matplotlib's ``Poly3DCollection``
instead (slower, and its per-face depth sorting shows artefacts on large faces).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np
import trimesh

from jsrte.atomic import write_with

MAX_SHEET_SHAPES = 16
"""At most this many shapes on one sheet (a 4 x 4 grid)."""
TILE_PX = 320
"""Side of one rendered tile in pixels."""
VIEW_DIRECTION = np.array([-0.55, 0.45, -1.0])
"""From the shape's centre towards the camera (canonical frame): in front (-z), above, at -x."""
LIGHT_DIRECTION = np.array([-0.6, 1.6, -1.0])
"""From the shape's centre towards the light: above, front, same side as the camera."""


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


def render_tile_pyrender(mesh: trimesh.Trimesh, renderer: object) -> np.ndarray:
    """(TILE_PX, TILE_PX, 3) uint8 gray rendering of ``mesh`` (canonical frame) from the front-left."""
    import pyrender

    scene = pyrender.Scene(bg_color=np.ones(4), ambient_light=np.full(3, 0.25))
    material = pyrender.MetallicRoughnessMaterial(baseColorFactor=[0.62, 0.62, 0.64, 1.0],
                                                  metallicFactor=0.0, roughnessFactor=0.9)
    scene.add(pyrender.Mesh.from_trimesh(mesh, smooth=False, material=material))
    centre = mesh.bounds.mean(axis=0)
    radius = float(np.linalg.norm(mesh.bounds[1] - mesh.bounds[0])) / 2
    yfov = 0.7
    distance = 1.15 * radius / np.sin(yfov / 2)
    eye = centre + distance * VIEW_DIRECTION / np.linalg.norm(VIEW_DIRECTION)
    scene.add(pyrender.PerspectiveCamera(yfov=yfov, znear=0.05 * distance, zfar=4 * distance),
              pose=look_at(eye, centre))
    scene.add(pyrender.DirectionalLight(intensity=2.5), pose=look_at(centre + LIGHT_DIRECTION, centre))
    color, _ = renderer.render(scene)
    return np.asarray(color)[:, :, :3]


def draw_mesh_matplotlib(ax: object, mesh: trimesh.Trimesh) -> None:
    """Draw ``mesh`` (canonical frame, +y up, front -z) on a matplotlib 3D axis (fallback)."""
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    # plot axes (X, Y, Z) = (x, -z, y): a proper rotation, +y up, the front towards +Y
    to_plot = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])
    vertices = mesh.vertices @ to_plot.T
    light = LIGHT_DIRECTION / np.linalg.norm(LIGHT_DIRECTION)
    gray = 0.25 + 0.65 * np.clip(mesh.face_normals @ light, 0.0, 1.0)
    colours = np.column_stack([gray, gray, gray, np.ones_like(gray)])
    ax.add_collection3d(Poly3DCollection(vertices[mesh.faces], facecolors=colours, edgecolors="none"))
    lo, hi = vertices.min(axis=0), vertices.max(axis=0)
    centre, half = (lo + hi) / 2, (hi - lo).max() / 2
    for setter, c in zip((ax.set_xlim, ax.set_ylim, ax.set_zlim), centre, strict=True):
        setter(c - half, c + half)
    ax.set_box_aspect((1, 1, 1))
    view = VIEW_DIRECTION @ to_plot.T
    ax.view_init(elev=np.degrees(np.arctan2(view[2], np.hypot(view[0], view[1]))),
                 azim=np.degrees(np.arctan2(view[1], view[0])))


def _pyrender_renderer() -> object | None:
    """The shared offscreen renderer sized for tiles, or None where no (EGL) context can be made."""
    from jsrte.viz import shared_offscreen_renderer

    renderer = shared_offscreen_renderer()
    if renderer is not None:
        renderer.viewport_width, renderer.viewport_height = TILE_PX, TILE_PX
    return renderer


def render_sheet(meshes: Sequence[trimesh.Trimesh], titles: Sequence[str], path: str | Path,
                 *, columns: int = 4) -> Path:
    """Render up to ``MAX_SHEET_SHAPES`` meshes in a grid, titled, to a PNG at ``path`` (atomically)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    meshes, titles = list(meshes)[:MAX_SHEET_SHAPES], list(titles)[:MAX_SHEET_SHAPES]
    n = max(len(meshes), 1)
    columns = min(columns, n)
    rows = -(-n // columns)
    renderer = _pyrender_renderer()
    fig = plt.figure(figsize=(3.2 * columns, 3.3 * rows), dpi=100)
    try:
        for i, (mesh, title) in enumerate(zip(meshes, titles, strict=True)):
            if renderer is not None:
                ax = fig.add_subplot(rows, columns, i + 1)
                ax.imshow(render_tile_pyrender(mesh, renderer))
            else:
                ax = fig.add_subplot(rows, columns, i + 1, projection="3d")
                draw_mesh_matplotlib(ax, mesh)
            ax.set_axis_off()
            ax.set_title(title, fontsize=9)
        fig.tight_layout()
        write_with(path, lambda tmp: fig.savefig(tmp, format="png"))
    finally:
        plt.close(fig)
    return Path(path)
