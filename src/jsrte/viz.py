"""Figures: fitted meshes in gray overlaid with scan points in red (as in the paper's figures).

Views are drawn by :mod:`jsrte.raster`, a NumPy software renderer (no OpenGL, EGL or
matplotlib): meshes shaded flat and two-sided, scan points as small red discs hidden where they
lie behind the surface. Tiles are composed with Pillow and every PNG is written atomically.

Cameras orbit the ``up`` axis; azimuth 0 looks at the object's front (the canonical frame's
front faces -z when up is +y) and positive azimuths turn towards the object's left, so the
default single view ("front-left") shows the front and a side, 25 degrees from above.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import trimesh

from jsrte.atomic import write_with
from jsrte.raster import Camera, render

__all__ = ["Camera", "compose_tiles", "render_mesh_grid", "render_overlay", "render_panels"]

YFOV = math.radians(35.0)
ELEVATION_DEG = 25.0
FRONT_LEFT_AZIMUTH_DEG = 40.0
MAX_POINTS = 20_000
"""Scan points drawn at most (a seeded subsample beyond this)."""
POINT_TOLERANCE = 0.015
"""A scan point is drawn where it lies at most this fraction of the view's radius behind the mesh
(scan noise and the fit's residual leave points just under the fitted surface)."""

Panel = tuple[str, trimesh.Trimesh | None, np.ndarray | None]


# --- public figures ----------------------------------------------------------------------


def render_overlay(
    mesh: trimesh.Trimesh | None,
    points: np.ndarray,
    out_path: str | Path,
    *,
    up: Sequence[float] = (0.0, 1.0, 0.0),
    views: int = 2,
    size: tuple[int, int] = (640, 480),
    title: str | None = None,
) -> None:
    """A PNG of ``mesh`` (gray) with ``points`` (red) from ``views`` cameras around ``up``.

    Parameters
    ----------
    mesh : trimesh.Trimesh or None
        The fitted surface (None: points only).
    points : (n, 3) float
        Scan points, same frame as ``mesh``.
    out_path : path of the PNG (written atomically)
    up : (3,) float, the up axis of that frame
    views : int
        Cameras spread evenly in azimuth, the first front-left; tiles side by side.
    size : (width, height) pixels of each view
    title : optional text above the views
    """
    if views < 1:
        raise ValueError(f"views must be >= 1, got {views}")
    points = _as_points(points)
    centre, radius = _frame(_extent_points([mesh], [points]))
    cameras = [
        _orbit_camera(centre, radius, up, FRONT_LEFT_AZIMUTH_DEG + 360.0 * k / views, size)
        for k in range(views)
    ]
    images = [_render(mesh, points, camera, size, radius) for camera in cameras]
    compose_tiles(images, [None] * views, out_path, cols=views, title=title)


def render_mesh_grid(
    meshes: list[trimesh.Trimesh],
    titles: list[str],
    out_path: str | Path,
    *,
    cols: int = 4,
    up: Sequence[float] = (0.0, 1.0, 0.0),
    tile: tuple[int, int] = (320, 320),
) -> None:
    """A contact sheet: each mesh gray, front-left, framed on itself, its title underneath.

    Parameters
    ----------
    meshes : list of trimesh.Trimesh (a None entry leaves an empty tile)
    titles : list of str, one per mesh
    out_path : path of the PNG (written atomically)
    cols : tiles per row
    up : (3,) float, the meshes' up axis
    tile : (width, height) pixels of each tile
    """
    if len(titles) != len(meshes):
        raise ValueError(f"{len(meshes)} meshes but {len(titles)} titles")
    if not meshes:
        raise ValueError("render_mesh_grid needs at least one mesh")
    images = []
    for mesh in meshes:
        centre, radius = _frame(_extent_points([mesh], []))
        camera = _orbit_camera(centre, radius, up, FRONT_LEFT_AZIMUTH_DEG, tile)
        images.append(_render(mesh, None, camera, tile, radius))
    compose_tiles(images, list(titles), out_path, cols=max(1, min(cols, len(meshes))))


def render_panels(
    panels: list[Panel],
    out_path: str | Path,
    *,
    up: Sequence[float] = (0.0, 1.0, 0.0),
    tile: tuple[int, int] = (360, 360),
) -> None:
    """One row of labelled panels ``(label, mesh or None, points or None)``, one shared camera.

    Used to compare methods on one scan (the paper's qualitative figures: the test shape,
    then each method's result in gray overlaid with the input in red). All panels are
    framed on the union of their contents, seen front-left, so positions are comparable.
    """
    if not panels:
        raise ValueError("render_panels needs at least one panel")
    meshes = [mesh for _, mesh, _ in panels]
    clouds = [_as_points(points) for _, _, points in panels]
    centre, radius = _frame(_extent_points(meshes, clouds))
    camera = _orbit_camera(centre, radius, up, FRONT_LEFT_AZIMUTH_DEG, tile)
    images = [_render(mesh, cloud, camera, tile, radius) for mesh, cloud in zip(meshes, clouds, strict=True)]
    labels = [label if mesh is not None or cloud is not None else f"{label} (empty)"
              for (label, _, _), mesh, cloud in zip(panels, meshes, clouds, strict=True)]
    compose_tiles(images, labels, out_path, cols=len(panels))


# --- cameras -----------------------------------------------------------------------------


def _as_points(points: np.ndarray | None) -> np.ndarray | None:
    if points is None:
        return None
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    points = points[np.all(np.isfinite(points), axis=1)]
    if len(points) > MAX_POINTS:
        points = points[np.random.default_rng(0).choice(len(points), MAX_POINTS, replace=False)]
    return points if len(points) else None


def _extent_points(meshes: Sequence[trimesh.Trimesh | None],
                   clouds: Sequence[np.ndarray | None]) -> np.ndarray:
    parts = [m.vertices for m in meshes if m is not None and len(m.vertices)]
    parts += [c for c in clouds if c is not None and len(c)]
    return np.concatenate(parts) if parts else np.zeros((1, 3))


def _frame(points: np.ndarray) -> tuple[np.ndarray, float]:
    """Bounding-box centre and radius of what is drawn (radius 1 when it is a single point)."""
    centre = (points.min(axis=0) + points.max(axis=0)) / 2.0
    radius = float(np.linalg.norm(points - centre, axis=1).max())
    return centre, radius if radius > 0 else 1.0


def _basis(up: Sequence[float]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(up, front, left) orthonormal: front is the canonical -z made orthogonal to ``up``."""
    u = np.asarray(up, dtype=np.float64)
    u = u / np.linalg.norm(u)
    for candidate in ((0.0, 0.0, -1.0), (0.0, -1.0, 0.0), (1.0, 0.0, 0.0)):
        front = np.asarray(candidate) - np.dot(candidate, u) * u
        if np.linalg.norm(front) > 0.3:
            break
    front /= np.linalg.norm(front)
    left = np.cross(u, front)  # -x for up +y, front -z: the object's left
    return u, front, left


def _orbit_camera(centre: np.ndarray, radius: float, up: Sequence[float], azimuth_deg: float,
                  size: tuple[int, int]) -> Camera:
    """A camera on a circle around ``up`` looking at ``centre``, the sphere filling the view."""
    u, front, left = _basis(up)
    az, el = math.radians(azimuth_deg), math.radians(ELEVATION_DEG)
    direction = math.cos(el) * (math.cos(az) * front + math.sin(az) * left) + math.sin(el) * u
    width, height = size
    half_fov = min(YFOV, 2.0 * math.atan(math.tan(YFOV / 2.0) * width / height)) / 2.0
    distance = 1.0 * radius / math.sin(half_fov)
    eye = centre + distance * direction
    back = direction  # the camera looks along -back
    right = np.cross(u, back)
    right /= np.linalg.norm(right)
    cam_up = np.cross(back, right)
    pose = np.eye(4)
    pose[:3, 0], pose[:3, 1], pose[:3, 2], pose[:3, 3] = right, cam_up, back, eye
    return Camera(pose=pose, yfov=YFOV)


# --- rendering ---------------------------------------------------------------------------


def _render(mesh: trimesh.Trimesh | None, points: np.ndarray | None, camera: Camera,
            size: tuple[int, int], radius: float) -> np.ndarray:
    """One view (height, width, 3) uint8; ``radius`` is the framed sphere's (world units)."""
    vertices = faces = None
    if mesh is not None and len(mesh.faces):
        vertices, faces = np.asarray(mesh.vertices, np.float64), np.asarray(mesh.faces, np.int64)
    return render(vertices, faces, points, camera, size, point_tolerance=POINT_TOLERANCE * radius)


# --- composition -------------------------------------------------------------------------

LABEL_PX = 30
TITLE_PX = 36


def compose_tiles(images: list[np.ndarray], labels: list[str | None], out_path: str | Path, *,
                  cols: int, title: str | None = None) -> None:
    """Tiles in a grid (labels under them, optional title on top) -> one PNG, atomically.

    ``images``: (height, width, 3) uint8 each, all one size; ``labels``: one per image (None or
    "" for none); ``cols``: tiles per row. Composed with Pillow (no matplotlib import)."""
    from PIL import Image, ImageDraw

    rows = math.ceil(len(images) / cols)
    tile_h, tile_w = images[0].shape[:2]
    label_h = LABEL_PX if any(labels) else 0
    title_h = TITLE_PX if title else 0
    width, height = cols * tile_w, rows * (tile_h + label_h) + title_h
    sheet = Image.new("RGB", (width, height), "white")
    draw = ImageDraw.Draw(sheet)
    if title:
        draw.text((width / 2.0, title_h / 2.0), title, fill="black", anchor="mm", font=_font(TITLE_FONT_PX))
    for index, (image, label) in enumerate(zip(images, labels, strict=True)):
        row, col = divmod(index, cols)
        top = title_h + row * (tile_h + label_h)
        sheet.paste(Image.fromarray(np.ascontiguousarray(image[..., :3], dtype=np.uint8)), (col * tile_w, top))
        if label:
            draw.text(((col + 0.5) * tile_w, top + tile_h + label_h / 2.0), label, fill="black", anchor="mm",
                      font=_font(LABEL_FONT_PX))
    write_with(out_path, lambda tmp: sheet.save(tmp, format="png"))


TITLE_FONT_PX = 18
LABEL_FONT_PX = 15


def _font(size: int) -> object:
    """DejaVu Sans at ``size`` pixels (the font matplotlib ships, found without importing it), else
    Pillow's own default font."""
    import importlib.util

    from PIL import ImageFont

    spec = importlib.util.find_spec("matplotlib")
    if spec is not None and spec.origin is not None:
        path = Path(spec.origin).parent / "mpl-data" / "fonts" / "ttf" / "DejaVuSans.ttf"
        if path.exists():
            return ImageFont.truetype(str(path), size)
    return ImageFont.load_default(size)
