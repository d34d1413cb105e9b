"""Figures: fitted meshes in gray overlaid with scan points in red (as in the paper's figures).

Rendering uses pyrender offscreen through EGL (headless; ``PYOPENGL_PLATFORM`` is set to
``egl`` unless already set). Where EGL or pyrender is unavailable, a matplotlib renderer
(painter's algorithm, same cameras) is used instead; pass ``backend="matplotlib"`` to force it.
Tiles are composed with Pillow and every PNG is written atomically.

Cameras orbit the ``up`` axis; azimuth 0 looks at the object's front (the canonical frame's
front faces -z when up is +y) and positive azimuths turn towards the object's left, so the
default single view ("front-left") shows the front and a side, 25 degrees from above.
"""

from __future__ import annotations

import os

os.environ.setdefault("PYOPENGL_PLATFORM", "egl")

import math  # noqa: E402
import warnings  # noqa: E402
from collections.abc import Sequence  # noqa: E402
from dataclasses import dataclass  # noqa: E402
from pathlib import Path  # noqa: E402
from typing import Literal  # noqa: E402

import numpy as np  # noqa: E402
import trimesh  # noqa: E402

from jsrte.atomic import write_with  # noqa: E402

Backend = Literal["auto", "pyrender", "matplotlib"]

MESH_RGBA = (0.6, 0.6, 0.6, 1.0)
"""Gray of fitted meshes (float colours, as pyrender wants them)."""
POINTS_RGBA = (0.9, 0.05, 0.05, 1.0)
"""Red of scan points."""
BACKGROUND_RGBA = (1.0, 1.0, 1.0, 1.0)
YFOV = math.radians(35.0)
ELEVATION_DEG = 25.0
FRONT_LEFT_AZIMUTH_DEG = 40.0
MAX_POINTS = 20_000
"""Scan points drawn at most (a seeded subsample beyond this)."""
FALLBACK_MAX_FACES = 12_000
"""The matplotlib renderer simplifies larger meshes to about this many faces."""

Panel = tuple[str, trimesh.Trimesh | None, np.ndarray | None]


@dataclass(frozen=True)
class Camera:
    """A perspective camera: ``pose`` (4, 4) camera-to-world (looks along its -z, +y up)."""

    pose: np.ndarray
    yfov: float = YFOV


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
    backend: Backend = "auto",
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
    backend : "auto" (pyrender, matplotlib if EGL fails), "pyrender" or "matplotlib"
    """
    if views < 1:
        raise ValueError(f"views must be >= 1, got {views}")
    points = _as_points(points)
    centre, radius = _frame(_extent_points([mesh], [points]))
    cameras = [
        _orbit_camera(centre, radius, up, FRONT_LEFT_AZIMUTH_DEG + 360.0 * k / views, size)
        for k in range(views)
    ]
    images = [_render(mesh, points, camera, size, backend) for camera in cameras]
    _compose(images, [None] * views, out_path, cols=views, title=title)


def render_mesh_grid(
    meshes: list[trimesh.Trimesh],
    titles: list[str],
    out_path: str | Path,
    *,
    cols: int = 4,
    up: Sequence[float] = (0.0, 1.0, 0.0),
    tile: tuple[int, int] = (320, 320),
    backend: Backend = "auto",
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
        images.append(_render(mesh, None, camera, tile, backend))
    _compose(images, list(titles), out_path, cols=max(1, min(cols, len(meshes))))


def render_panels(
    panels: list[Panel],
    out_path: str | Path,
    *,
    up: Sequence[float] = (0.0, 1.0, 0.0),
    tile: tuple[int, int] = (360, 360),
    backend: Backend = "auto",
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
    images = [_render(mesh, cloud, camera, tile, backend) for mesh, cloud in zip(meshes, clouds, strict=True)]
    labels = [label if mesh is not None or cloud is not None else f"{label} (empty)"
              for (label, _, _), mesh, cloud in zip(panels, meshes, clouds, strict=True)]
    _compose(images, labels, out_path, cols=len(panels))


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
    return Camera(pose=pose)


# --- rendering ---------------------------------------------------------------------------


def _render(mesh: trimesh.Trimesh | None, points: np.ndarray | None, camera: Camera,
            size: tuple[int, int], backend: Backend) -> np.ndarray:
    """One view (height, width, 3) uint8."""
    if mesh is not None and len(mesh.faces) == 0:
        mesh = None
    if backend in ("auto", "pyrender") and shared_offscreen_renderer(strict=backend == "pyrender") is not None:
        try:
            return _render_pyrender(mesh, points, camera, size)
        except Exception as exc:  # a GL context that broke after the probe: fall back for good
            if backend == "pyrender":
                raise
            _mark_pyrender_unusable(exc)
    return _render_matplotlib(mesh, points, camera, size)


_PYRENDER: dict[str, object] = {}


def shared_offscreen_renderer(*, strict: bool = False) -> object | None:
    """The process's one pyrender ``OffscreenRenderer``, or None where offscreen GL is unusable.

    Made once and never deleted: pyrender's ``delete()`` terminates the EGL display, which every
    renderer of the process shares, so a second renderer deleted would break this one. Callers
    set ``viewport_width``/``viewport_height`` before rendering. The probe renders a tiny scene,
    since a context can be created on systems where drawing then fails. With ``strict``, an
    unusable renderer raises RuntimeError instead of returning None.
    """
    if "ok" not in _PYRENDER:
        try:
            import pyrender

            renderer = pyrender.OffscreenRenderer(16, 16)
            probe = pyrender.Scene()
            probe.add(pyrender.PerspectiveCamera(yfov=YFOV))
            renderer.render(probe)
            _PYRENDER["renderer"], _PYRENDER["ok"] = renderer, True
        except Exception as exc:  # no EGL / no GL driver: many exception types
            _mark_pyrender_unusable(exc)
    if strict and not _PYRENDER["ok"]:
        raise RuntimeError(f"pyrender offscreen rendering unavailable: {_PYRENDER['error']}")
    return _PYRENDER["renderer"] if _PYRENDER["ok"] else None


def _mark_pyrender_unusable(exc: Exception) -> None:
    _PYRENDER.update(ok=False, renderer=None, error=f"{type(exc).__name__}: {exc}")
    warnings.warn(f"pyrender offscreen rendering unavailable ({_PYRENDER['error']}); using matplotlib",
                  RuntimeWarning, stacklevel=3)


def _render_pyrender(mesh: trimesh.Trimesh | None, points: np.ndarray | None, camera: Camera,
                     size: tuple[int, int]) -> np.ndarray:
    import pyrender

    width, height = size
    scene = pyrender.Scene(bg_color=list(BACKGROUND_RGBA), ambient_light=[0.12, 0.12, 0.12])
    if mesh is not None:
        material = pyrender.MetallicRoughnessMaterial(
            baseColorFactor=list(MESH_RGBA), metallicFactor=0.0, roughnessFactor=0.9,
            doubleSided=True)
        scene.add(pyrender.Mesh.from_trimesh(mesh, material=material, smooth=False))
    if points is not None:
        # Unlit pure red: a black base colour and a red emission (points have no normals).
        material = pyrender.MetallicRoughnessMaterial(
            baseColorFactor=[0.0, 0.0, 0.0, 1.0], emissiveFactor=list(POINTS_RGBA[:3]))
        primitive = pyrender.Primitive(positions=points.astype(np.float32), mode=0,
                                       material=material)  # mode 0: GL_POINTS
        scene.add(pyrender.Mesh([primitive]))
    scene.add(pyrender.PerspectiveCamera(yfov=camera.yfov, aspectRatio=width / height),
              pose=camera.pose)
    scene.add(pyrender.DirectionalLight(color=np.ones(3), intensity=1.2), pose=camera.pose)
    scene.add(pyrender.DirectionalLight(color=np.ones(3), intensity=2.0), pose=_key_light_pose(camera))
    renderer = shared_offscreen_renderer(strict=True)
    renderer.viewport_width, renderer.viewport_height = width, height
    renderer.point_size = max(2.0, round(min(width, height) / 160.0))
    colour, _ = renderer.render(scene, flags=pyrender.RenderFlags.SKIP_CULL_FACES)
    return np.ascontiguousarray(colour[..., :3])


def _key_light_pose(camera: Camera) -> np.ndarray:
    """A light from above and to the side of the camera (pose (4, 4); it shines along its -z)."""
    key = camera.pose.copy()
    key[:3, :3] = key[:3, :3] @ _rotation_x(math.radians(-35.0)) @ _rotation_y(math.radians(30.0))
    return key


def _fallback_tessellation(mesh: trimesh.Trimesh) -> trimesh.Trimesh:
    """About FALLBACK_MAX_FACES faces of similar size (painter's sorting needs small faces)."""
    if len(mesh.faces) > FALLBACK_MAX_FACES:
        try:
            return mesh.simplify_quadric_decimation(face_count=FALLBACK_MAX_FACES)
        except Exception:  # fast-simplification missing: draw every face
            return mesh
    max_edge = 2.0 * math.sqrt(2.0 * mesh.area / FALLBACK_MAX_FACES)
    if max_edge > 0 and mesh.edges_unique_length.max() > max_edge:
        vertices, faces = trimesh.remesh.subdivide_to_size(mesh.vertices, mesh.faces, max_edge)
        return trimesh.Trimesh(vertices, faces, process=False)
    return mesh


def _fallback_shading(normals: np.ndarray, camera: Camera) -> np.ndarray:
    """Two-sided Lambert shading of faces (f, 3) with the pyrender lights -> RGB (f, 3)."""
    towards_camera = camera.pose[:3, 2]
    facing = np.where((normals @ towards_camera)[:, None] < 0, -normals, normals)
    key = _key_light_pose(camera)[:3, 2]
    shade = 0.25 + 0.35 * (facing @ towards_camera) + 0.5 * np.clip(facing @ key, 0.0, None)
    return np.clip(np.asarray(MESH_RGBA[:3])[None, :] * (0.4 + shade[:, None]), 0.0, 1.0)


def _rotation_x(angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def _rotation_y(angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def _project(points: np.ndarray, camera: Camera, size: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """World points (n, 3) -> pixel coordinates (n, 2) and depth along the view (n,)."""
    width, height = size
    world_to_camera = np.linalg.inv(camera.pose)
    local = points @ world_to_camera[:3, :3].T + world_to_camera[:3, 3]
    depth = np.maximum(-local[:, 2], 1e-9)
    focal = (height / 2.0) / math.tan(camera.yfov / 2.0)
    pixels = np.stack([width / 2.0 + focal * local[:, 0] / depth,
                       height / 2.0 - focal * local[:, 1] / depth], axis=1)
    return pixels, depth


def _render_matplotlib(mesh: trimesh.Trimesh | None, points: np.ndarray | None, camera: Camera,
                       size: tuple[int, int]) -> np.ndarray:
    """Painter's-algorithm rendering with the same camera (fallback without EGL)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.collections import PolyCollection
    from matplotlib.figure import Figure

    width, height = size
    fig = Figure(figsize=(width / 100.0, height / 100.0), dpi=100, facecolor=BACKGROUND_RGBA)
    canvas = FigureCanvasAgg(fig)
    ax = fig.add_axes((0.0, 0.0, 1.0, 1.0))
    ax.set_xlim(0, width)
    ax.set_ylim(height, 0)
    ax.axis("off")
    polygons: list[np.ndarray] = []
    depths: list[np.ndarray] = []
    colours: list[np.ndarray] = []
    if mesh is not None:
        mesh = _fallback_tessellation(mesh)
        pixels, depth = _project(np.asarray(mesh.vertices, dtype=np.float64), camera, size)
        faces = np.asarray(mesh.faces)
        polygons += list(pixels[faces])
        depths.append(depth[faces].mean(axis=1))
        colours.append(_fallback_shading(np.asarray(mesh.face_normals), camera))
    if points is not None:
        pixels, depth = _project(points, camera, size)
        half = max(1.0, min(width, height) / 320.0)
        square = np.array([[-half, -half], [half, -half], [half, half], [-half, half]])
        polygons += list(pixels[:, None, :] + square[None])
        depths.append(depth - 1e-3 * float(depth.mean()))  # a point on a face is drawn over it
        colours.append(np.tile(np.asarray(POINTS_RGBA[:3]), (len(points), 1)))
    if polygons:
        order = np.argsort(-np.concatenate(depths), kind="stable")  # far to near
        colour = np.concatenate(colours)[order]
        ax.add_collection(PolyCollection([polygons[i] for i in order], facecolors=colour,
                                         edgecolors=colour, linewidths=0.3))
    canvas.draw()
    return np.asarray(canvas.buffer_rgba())[..., :3].copy()


# --- composition -------------------------------------------------------------------------

LABEL_PX = 30
TITLE_PX = 36


def _compose(images: list[np.ndarray], labels: list[str | None], out_path: str | Path, *,
             cols: int, title: str | None = None) -> None:
    """Tiles in a grid (labels under them, optional title on top) -> one PNG, atomically.

    Composed with Pillow (no matplotlib import: a fit's overlay costs only its renders)."""
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
