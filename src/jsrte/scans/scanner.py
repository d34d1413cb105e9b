"""A virtual depth camera: realistic scans of an object standing on a floor.

The Redwood scans cannot be downloaded here, so held-out meshes are scanned instead. The
object is scaled to a real-world height, stood on a floor, turned by a random yaw, placed
metres from the origin and (by default) the whole scene is expressed in a random world frame,
so the up axis must be recovered from the floor as for a real scan. A few pinhole depth views
from an arc above the floor (never from below) are ray-cast with Open3D, with Kinect-like depth
noise along each ray (std ``a + b * depth**2``); normals are estimated from the noisy points and
oriented towards the camera that saw each point, as real scans come.

Frames: the *mesh* frame (input, +y up, front -z, any units), the *level* frame (metres, floor
at y = 0, +y up) where the scene is built and rendered, and the *scan* frame (metres, the
level frame seen through the random world transform) in which every output lives.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import trimesh

from jsrte.atomic import atomic_path
from jsrte.errors import JsrteError
from jsrte.geometry.mesh import validate_mesh
from jsrte.geometry.sim3 import Sim3

UP_LEVEL = np.array([0.0, 1.0, 0.0])

OBJECT_COLOR = (200, 90, 60)
"""PLY colour (uint8 RGB) of points that hit the object."""
FLOOR_COLOR = (150, 150, 150)
"""PLY colour of points that hit the floor."""


@dataclass(frozen=True)
class ScannerSettings:
    """Everything the virtual scanner draws or uses; lengths in metres, angles in degrees."""

    target_height_m: tuple[float, float] = (0.6, 1.2)
    """The object's height is drawn uniformly from this range ..."""
    max_extent_m: float | None = 2.5
    """... and lowered if the object would be longer than this (a flat bed drawn 1 m tall would
    be 4 m long and seen from 7 m, where the depth noise reaches 10 cm). None: no limit."""
    distance_from_origin_m: tuple[float, float] = (1.0, 5.0)
    """Horizontal distance of the object's footprint centre from the world origin."""
    origin_height_m: tuple[float, float] = (0.0, 1.5)
    """The world origin lies this far above the floor (only with ``random_world_frame``)."""
    random_world_frame: bool = True
    """Express the scene in a random rotation (floor not y = 0); False keeps +y up, floor y = 0."""
    views: int = 3
    """Number of depth images."""
    arc_deg: float = 120.0
    """Azimuth span of the camera arc around the object."""
    elevation_deg: tuple[float, float] = (15.0, 45.0)
    """Camera elevation above the horizontal at the object's centre (never from below)."""
    camera_distance_m: tuple[float, float] = (1.5, 3.0)
    """Camera distance from the object's centre (raised if the object would not fit the image)."""
    keep_object_in_view: bool = True
    """Move a camera back until the object's bounding sphere fits the field of view."""
    width: int = 160
    height: int = 120
    """Image size in pixels."""
    fov_deg: float = 60.0
    """Horizontal field of view of the pinhole camera (square pixels)."""
    noise_a_m: float = 0.0015
    noise_b_per_m: float = 0.0019
    """Depth noise std along each ray: ``noise_scale * (a + b * depth**2)`` (Kinect-like)."""
    noise_scale: float = 1.0
    """Multiplier of the depth noise (0: noise-free)."""
    outlier_fraction: float = 0.002
    """Fraction of hits whose depth is thrown off (flying pixels), for outlier removal to find."""
    outlier_depth_m: tuple[float, float] = (0.05, 0.3)
    """Depth error of an outlier, uniform in this range, either sign."""
    floor: bool = True
    """Scan a floor under the object."""
    crop_factor: float = 1.5
    """Keep floor hits within this multiple of the object's footprint radius (horizontally;
    the footprint radius is taken at least half the object's height, so a tall thin object
    still stands on a floor patch bigger than its sides)."""
    normal_radius_m: float = 0.05
    normal_max_nn: int = 30
    """Neighbourhood of the normal estimation (Open3D hybrid search)."""


@dataclass(frozen=True)
class VirtualScan:
    """A simulated scan in the scan frame (metres).

    Attributes
    ----------
    points : (n, 3) float64, noisy surface points
    normals : (n, 3) float64, unit normals estimated from the points, facing their camera
    is_object : (n,) bool, True where the ray hit the object (else the floor)
    is_outlier : (n,) bool, True for flying pixels (depth thrown off on purpose)
    scan_from_mesh : Sim3 mapping input-mesh coordinates to scan metres
    up : (3,) float64, the unit up vector (floor normal, towards the object)
    floor_offset : float, the floor is the plane ``up . x = floor_offset``
    cameras : (k, 3) float64, camera centres
    view : (n,) int, index of the camera that saw each point
    settings : ScannerSettings used
    """

    points: np.ndarray
    normals: np.ndarray
    is_object: np.ndarray
    is_outlier: np.ndarray
    scan_from_mesh: Sim3
    up: np.ndarray
    floor_offset: float
    cameras: np.ndarray
    view: np.ndarray
    settings: ScannerSettings = field(default_factory=ScannerSettings)

    def info(self, *, seed: int | None = None, mesh: str | Path | None = None) -> dict[str, Any]:
        """The JSON-serializable description written beside the PLY."""
        return {
            "scan_from_mesh": self.scan_from_mesh.to_dict(),
            "up": self.up.tolist(),
            "floor": {"normal": self.up.tolist(), "offset": self.floor_offset},
            "cameras": self.cameras.tolist(),
            "n_points": int(len(self.points)),
            "n_object_points": int(self.is_object.sum()),
            "n_outliers": int(self.is_outlier.sum()),
            "colors": {"object": list(OBJECT_COLOR), "floor": list(FLOOR_COLOR)},
            "seed": seed,
            "mesh": None if mesh is None else str(mesh),
            "settings": asdict(self.settings),
        }


def scan_mesh(
    mesh: trimesh.Trimesh,
    *,
    rng: np.random.Generator,
    settings: ScannerSettings = ScannerSettings(),
) -> VirtualScan:
    """Scan ``mesh`` (canonical orientation: +y up, front -z; any units) standing on a floor.

    Parameters
    ----------
    mesh : the object; only its orientation matters, its scale and position are replaced
    rng : the only source of randomness (same seed, same scan)
    settings : ranges and camera model

    Returns
    -------
    VirtualScan in metres, in a random world frame unless ``settings.random_world_frame`` is False.
    """
    _check_settings(settings)
    validate_mesh(mesh)
    level_from_mesh, footprint_radius = _place_object(mesh, rng, settings)
    world_from_level = _world_frame(rng, settings)
    vertices = level_from_mesh.apply(mesh.vertices)
    centre = (vertices.min(0) + vertices.max(0)) / 2.0
    sphere_radius = float(np.linalg.norm(vertices - centre, axis=1).max())
    crop_radius = settings.crop_factor * footprint_radius
    axis_xz = level_from_mesh.t[[0, 2]]

    scene = _scene(vertices, mesh.faces, axis_xz, crop_radius if settings.floor else None)
    cameras = _cameras(centre, sphere_radius, rng, settings)
    points, is_object, view, is_outlier = [], [], [], []
    for k, camera in enumerate(cameras):
        p, obj, out = _render(scene, camera, centre, rng, settings)
        horizontal = np.linalg.norm(p[:, [0, 2]] - axis_xz, axis=1)
        keep = obj | (horizontal <= crop_radius)
        points.append(p[keep])
        is_object.append(obj[keep])
        is_outlier.append(out[keep])
        view.append(np.full(int(keep.sum()), k))
    points_level = np.concatenate(points)
    if len(points_level) == 0:
        raise JsrteError("the virtual scanner saw nothing (is the mesh degenerate?)")
    view_index = np.concatenate(view)
    normals_level = _camera_facing_normals(points_level, cameras[view_index], settings)
    return VirtualScan(
        points=world_from_level.apply(points_level),
        normals=world_from_level.apply_vectors(normals_level),
        is_object=np.concatenate(is_object),
        is_outlier=np.concatenate(is_outlier),
        scan_from_mesh=world_from_level @ level_from_mesh,
        up=world_from_level.R @ UP_LEVEL,
        floor_offset=float(UP_LEVEL @ world_from_level.R.T @ world_from_level.t),
        cameras=world_from_level.apply(cameras),
        view=view_index,
        settings=settings,
    )


def write_scan(
    scan: VirtualScan, ply_path: str | Path, *, seed: int | None = None,
    mesh: str | Path | None = None, colors: np.ndarray | None = None,
) -> Path:
    """Write ``scan`` as a binary PLY with normals, colours and each point's camera index (the
    vertex property ``view``, :mod:`jsrte.scans.ply`), and ``<stem>.json`` beside it.

    Both files are written atomically. Object points are coloured ``OBJECT_COLOR``, floor
    points ``FLOOR_COLOR``, unless ``colors`` ((n, 3) uint8 RGB) are given. Returns
    ``ply_path`` (the JSON is ``ply_path.with_suffix(".json")``).
    """
    import json

    from jsrte.scans.ply import write_ply_scan

    ply_path = Path(ply_path)
    json_path = ply_path.with_suffix(".json")
    if colors is None:
        colors = np.where(scan.is_object[:, None], OBJECT_COLOR, FLOOR_COLOR)
    text = json.dumps(scan.info(seed=seed, mesh=mesh), indent=2) + "\n"
    with atomic_path(ply_path) as tmp_ply, atomic_path(json_path) as tmp_json:
        try:
            write_ply_scan(tmp_ply, scan.points, scan.normals, np.asarray(colors, dtype=np.uint8), scan.view)
        except OSError as exc:
            raise JsrteError(f"could not write point cloud ({exc})", ply_path) from exc
        tmp_json.write_text(text)
    return ply_path


def at_own_size(mesh: trimesh.Trimesh, settings: ScannerSettings) -> ScannerSettings:
    """``settings`` that stand ``mesh`` (metres) at its own size (scale 1) instead of a drawn
    height: for metric meshes such as the procedural furniture, whose sizes tell classes apart."""
    from dataclasses import replace

    height = float(np.ptp(mesh.vertices[:, 1]))
    return replace(settings, target_height_m=(height, height), max_extent_m=None)


# --- scene -----------------------------------------------------------------------------------


def _check_settings(s: ScannerSettings) -> None:
    for name in ("target_height_m", "distance_from_origin_m", "origin_height_m",
                 "elevation_deg", "camera_distance_m", "outlier_depth_m"):
        lo, hi = getattr(s, name)
        if not lo <= hi:
            raise JsrteError(f"scanner setting {name} must be an increasing range, got {lo}, {hi}")
    if s.target_height_m[0] <= 0:
        raise JsrteError("scanner target height must be positive")
    if s.views < 1 or s.width < 2 or s.height < 2:
        raise JsrteError("scanner needs at least one view and an image of at least 2x2 pixels")
    if not (0.0 <= s.elevation_deg[0] and s.elevation_deg[1] < 90.0):
        raise JsrteError("camera elevation must lie in [0, 90) degrees: never from below")
    if not 0.0 < s.fov_deg < 180.0:
        raise JsrteError("field of view must lie in (0, 180) degrees")
    if s.noise_scale < 0 or not 0.0 <= s.outlier_fraction < 1.0:
        raise JsrteError("noise scale must be >= 0 and outlier fraction in [0, 1)")


def _yaw(angle: float) -> np.ndarray:
    """Rotation (3, 3) by ``angle`` radians about +y."""
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def _place_object(
    mesh: trimesh.Trimesh, rng: np.random.Generator, s: ScannerSettings
) -> tuple[Sim3, float]:
    """``level_from_mesh`` (real height, on the floor y = 0, random yaw and position) and the
    footprint radius in metres (largest horizontal vertex distance from the vertical axis, at
    least half the height)."""
    lo, hi = mesh.bounds
    height = float(hi[1] - lo[1])
    if not height > 0:
        raise JsrteError("mesh has zero height (+y): cannot stand it on a floor")
    scale = float(rng.uniform(*s.target_height_m)) / height
    if s.max_extent_m is not None:
        scale = min(scale, s.max_extent_m / float((hi - lo).max()))
    anchor = np.array([(lo[0] + hi[0]) / 2.0, lo[1], (lo[2] + hi[2]) / 2.0])
    to_floor = Sim3(scale, np.eye(3), -scale * anchor)
    yaw = Sim3(1.0, _yaw(float(rng.uniform(0.0, 2.0 * math.pi))), np.zeros(3))
    distance = float(rng.uniform(*s.distance_from_origin_m))
    direction = float(rng.uniform(0.0, 2.0 * math.pi))
    position = np.array([distance * math.cos(direction), 0.0, distance * math.sin(direction)])
    level_from_mesh = Sim3(1.0, np.eye(3), position) @ yaw @ to_floor
    local = to_floor.apply(mesh.vertices)
    footprint = float(np.linalg.norm(local[:, [0, 2]], axis=1).max())
    return level_from_mesh, max(footprint, 0.5 * scale * height)


def _world_frame(rng: np.random.Generator, s: ScannerSettings) -> Sim3:
    """``world_from_level``: a uniformly random rotation about an origin above the floor."""
    if not s.random_world_frame:
        return Sim3.identity()
    from scipy.spatial.transform import Rotation

    rotation = Rotation.random(random_state=rng).as_matrix()
    origin_height = float(rng.uniform(*s.origin_height_m))
    return Sim3(1.0, rotation, -rotation @ (origin_height * UP_LEVEL))


def _scene(vertices: np.ndarray, faces: np.ndarray, axis_xz: np.ndarray,
           floor_radius: float | None) -> Any:
    """An Open3D raycasting scene: the object (geometry id 0) and optionally a floor square."""
    import open3d as o3d

    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(np.asarray(vertices, np.float32)),
                        o3d.core.Tensor(np.asarray(faces, np.uint32)))
    if floor_radius is not None:
        r = 1.05 * floor_radius
        x, z = axis_xz
        quad = np.array([[x - r, 0, z - r], [x + r, 0, z - r], [x + r, 0, z + r], [x - r, 0, z + r]])
        scene.add_triangles(o3d.core.Tensor(quad.astype(np.float32)),
                            o3d.core.Tensor(np.array([[0, 2, 1], [0, 3, 2]], np.uint32)))
    return scene


def _cameras(centre: np.ndarray, sphere_radius: float, rng: np.random.Generator,
             s: ScannerSettings, *, azimuth: float | None = None) -> np.ndarray:
    """Camera centres (k, 3) on an arc of azimuths around ``centre``, above the floor; the arc is
    centred on ``azimuth`` (radians, about +y from +x towards +z) or on a random one."""
    start = float(rng.uniform(0.0, 2.0 * math.pi)) if azimuth is None else float(azimuth)
    arc = math.radians(s.arc_deg)
    offsets = np.linspace(-arc / 2, arc / 2, s.views) if s.views > 1 else np.zeros(1)
    half_fov = min(_half_fovs(s))
    min_distance = 1.05 * sphere_radius / math.sin(half_fov) if s.keep_object_in_view else 0.0
    cameras = []
    for offset in offsets:
        azimuth = start + float(offset)
        elevation = math.radians(float(rng.uniform(*s.elevation_deg)))
        distance = max(float(rng.uniform(*s.camera_distance_m)), min_distance)
        direction = np.array([math.cos(elevation) * math.cos(azimuth), math.sin(elevation),
                              math.cos(elevation) * math.sin(azimuth)])
        cameras.append(centre + distance * direction)
    return np.array(cameras)


def _half_fovs(s: ScannerSettings) -> tuple[float, float]:
    """Horizontal and vertical half fields of view (radians)."""
    tan_h = math.tan(math.radians(s.fov_deg) / 2.0)
    return math.atan(tan_h), math.atan(tan_h * s.height / s.width)


def _render(scene: Any, camera: np.ndarray, target: np.ndarray, rng: np.random.Generator,
            s: ScannerSettings) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Noisy hit points (m, 3), hit-the-object flags (m,) and outlier flags (m,) of one view."""
    view = render_view(scene, camera, target, rng, s)
    hit = view.hit
    return view.points[hit], view.geometry[hit] == 0, view.outlier[hit]


@dataclass(frozen=True)
class DepthView:
    """One depth image, pixel by pixel (row-major, ``height * width`` pixels).

    Attributes
    ----------
    points : (p, 3) float64, the noisy point each pixel saw (NaN where the ray hit nothing)
    depth : (p,) float64, noisy depth along the forward axis (inf: no hit)
    geometry : (p,) int64, Open3D geometry id of the surface hit (-1: none)
    outlier : (p,) bool, flying pixels (depth thrown off on purpose)
    incidence : (p,) float64, |cos| of the angle between the ray and the surface hit
    directions : (p, 3) float64, ray directions with unit forward component
    """

    points: np.ndarray
    depth: np.ndarray
    geometry: np.ndarray
    outlier: np.ndarray
    incidence: np.ndarray
    directions: np.ndarray

    @property
    def hit(self) -> np.ndarray:
        """(p,) bool, pixels whose ray hit a surface."""
        return np.isfinite(self.depth)


def render_view(scene: Any, camera: np.ndarray, target: np.ndarray, rng: np.random.Generator,
                s: ScannerSettings) -> DepthView:
    """Ray-cast one Kinect-like depth image of ``scene`` from ``camera`` looking at ``target``:
    depth noise ``noise_scale * (a + b * depth**2)`` along each ray, and a fraction
    ``outlier_fraction`` of the hits thrown off by ``outlier_depth_m`` (flying pixels)."""
    import open3d as o3d

    directions = _pixel_rays(camera, target, s)
    rays = np.concatenate([np.broadcast_to(camera, directions.shape), directions], axis=1)
    hits = scene.cast_rays(o3d.core.Tensor(rays.astype(np.float32)))
    full = hits["t_hit"].numpy().astype(np.float64)  # along a ray of unit forward component
    hit = np.isfinite(full)
    geometry = np.where(hit, hits["geometry_ids"].numpy().astype(np.int64), -1)
    normals = hits["primitive_normals"].numpy().astype(np.float64)
    unit = directions / np.linalg.norm(directions, axis=1, keepdims=True)
    incidence = np.abs(np.einsum("ij,ij->i", normals, unit))
    depth = full[hit]
    sigma = s.noise_scale * (s.noise_a_m + s.noise_b_per_m * depth**2)
    depth = depth + rng.normal(size=depth.shape) * sigma
    is_outlier = rng.random(depth.shape) < s.outlier_fraction
    jump = rng.uniform(*s.outlier_depth_m, size=int(is_outlier.sum()))
    depth[is_outlier] += jump * rng.choice([-1.0, 1.0], size=jump.shape)
    full[hit] = depth
    outlier = np.zeros(len(full), dtype=bool)
    outlier[hit] = is_outlier
    points = np.where(hit[:, None], camera + np.where(hit, full, 0.0)[:, None] * directions, np.nan)
    return DepthView(points=points, depth=full, geometry=geometry, outlier=outlier,
                     incidence=np.where(hit, incidence, 0.0), directions=directions)


def _pixel_rays(camera: np.ndarray, target: np.ndarray, s: ScannerSettings) -> np.ndarray:
    """Ray directions (h*w, 3) through pixel centres, forward component 1 (so t = depth)."""
    forward = target - camera
    forward /= np.linalg.norm(forward)
    right = np.cross(forward, UP_LEVEL)
    right /= np.linalg.norm(right)
    down = np.cross(forward, right)
    focal = (s.width / 2.0) / math.tan(math.radians(s.fov_deg) / 2.0)
    u = (np.arange(s.width) + 0.5 - s.width / 2.0) / focal
    v = (np.arange(s.height) + 0.5 - s.height / 2.0) / focal
    uu, vv = np.meshgrid(u, v)
    return forward + uu.reshape(-1, 1) * right + vv.reshape(-1, 1) * down


def _camera_facing_normals(points: np.ndarray, seen_from: np.ndarray,
                           s: ScannerSettings) -> np.ndarray:
    """Normals (n, 3) estimated from ``points`` (Open3D), each flipped towards ``seen_from``."""
    import open3d as o3d

    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
    cloud.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(s.normal_radius_m, s.normal_max_nn))
    normals = np.asarray(cloud.normals).copy()
    flip = np.einsum("ij,ij->i", normals, seen_from - points) < 0
    normals[flip] *= -1.0
    return normals
