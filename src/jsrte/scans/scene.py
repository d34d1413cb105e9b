"""A virtual room scanner: an object among walls and other objects, as real scans come.

The object of interest (the *target*) stands on a floor as in :mod:`jsrte.scans.scanner`
(same real-world height, random yaw and place, random world frame). Around it: one to three
walls (a back wall, then side walls), other objects (procedural furniture of other classes and
boxes) a few centimetres from it or from each other, so that they touch the target's cluster.
A short arc of depth views looks at the target from the open side of the room; the objects
occlude each other. Beyond the scanner's Kinect-like depth noise and flying pixels: random
dropouts, dropouts at grazing angles, mixed pixels at depth edges (a flying pixel between the
foreground and the background) and extra noise on the estimated normals.

Frames as in :mod:`jsrte.scans.scanner`: the *level* frame (metres, floor y = 0, +y up) where
the room is built, and the *scan* frame (the level frame through a random world transform) in
which every output lives. Every object's truth is ``scan_from_mesh`` (a Sim3 from its mesh's
coordinates to scan metres).
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import trimesh

from jsrte.errors import JsrteError
from jsrte.geometry.mesh import validate_mesh
from jsrte.geometry.sim3 import Sim3
from jsrte.scans.scanner import (
    FLOOR_COLOR,
    OBJECT_COLOR,
    UP_LEVEL,
    ScannerSettings,
    VirtualScan,
    _camera_facing_normals,
    _cameras,
    _check_settings,
    _place_object,
    _world_frame,
    _yaw,
    at_own_size,
    render_view,
)

FLOOR_LABEL = -1
"""Point label of the floor (objects are labelled 0, 1, ...; 0 is the target)."""
WALL_LABEL = -2
"""Point label of the walls."""
NOTHING_LABEL = -3
"""Point label of a mixed pixel that lies between surfaces (on none of them)."""
WALL_COLOR = (215, 205, 185)
CLUTTER_COLORS = ((70, 120, 200), (90, 170, 90), (190, 170, 60), (150, 90, 170), (60, 170, 170))
OTHER_KINDS = ("table", "sofa", "box")
"""What may stand beside the target: procedural furniture of another class, or a box."""


@dataclass(frozen=True)
class SceneSettings:
    """What the room scanner draws; lengths in metres, angles in degrees."""

    scanner: ScannerSettings = ScannerSettings(views=4, arc_deg=90.0, outlier_fraction=0.005)
    """The camera, its noise and the target's size (its floor crop is not used)."""
    camera_height_jitter_m: float = 0.02
    """The cameras are carried at one height and one distance from the target (their means),
    each height off by this std: a scan walked round the object."""
    walls: tuple[int, int] = (1, 3)
    """Number of walls, drawn uniformly in this range: a back wall, then one or two sides."""
    wall_gap_m: tuple[float, float] = (0.05, 0.5)
    """Gap between the target and the back wall (and the side walls, unless a camera is in
    the way: then the side wall moves behind the cameras)."""
    wall_height_m: float = 2.5
    wall_length_m: float = 8.0
    wall_thickness_m: float = 0.1
    others: tuple[int, int] = (1, 3)
    """Number of other objects, drawn uniformly in this range (fewer if they do not fit)."""
    other_kinds: tuple[str, ...] = OTHER_KINDS
    first_neighbour_gap_m: tuple[float, float] = (0.01, 0.08)
    """The first other object stands this close to the target (horizontally): one cluster."""
    neighbour_gap_m: tuple[float, float] = (0.02, 0.4)
    """The further ones stand this far from everything already placed."""
    box_size_m: tuple[float, float] = (0.25, 0.7)
    """Side lengths of a box, each drawn in this range."""
    front_clearance_deg: float = 70.0
    """No other object stands within this azimuth of the cameras' direction, seen from the
    target (it would hide it): they stand beside or behind it."""
    max_depth_m: float = 6.0
    """The sensor's range: farther hits are lost."""
    dropout_fraction: float = 0.03
    """Fraction of the hits lost at random."""
    grazing_cos: float = 0.2
    """Hits whose ray meets the surface at a cosine below this are lost (grazing angles)."""
    mixed_pixel_fraction: float = 0.2
    mixed_pixel_jump_m: float = 0.05
    """This fraction of the pixels at a depth edge (a neighbour this much nearer or farther)
    take a depth between the two surfaces (flying pixels along silhouettes)."""
    normal_noise_deg: float = 8.0
    """Std of a random tilt added to each estimated normal."""
    behind_clearance_deg: float = 0.0
    """Nor within this azimuth of the direction away from the cameras (0: behind is allowed)."""
    frame_all: bool = False
    """Room mode, for scenes of several objects of interest: the target keeps its own size (its
    mesh in metres, as the other objects); the other objects are placed first; then the camera
    sweeps past them all, ``views_per_object`` level views looking at each object from the
    cameras' side; the walls stand behind and beside all of them. False: the target is sized
    as ``jsrte scan`` sizes it and a short arc of views frames it alone."""
    views_per_object: int = 2
    object_arc_deg: float = 40.0
    """Room mode: views looking at each object, spread over this azimuth span."""
    place_tries: int = 24
    """Random positions tried for each other object before it is left out."""


@dataclass(frozen=True)
class SceneObject:
    """One object of a room: its class ("box" for a box), mesh (its own coordinates) and truth."""

    kind: str
    mesh: trimesh.Trimesh
    scan_from_mesh: Sim3
    style: str = ""


@dataclass(frozen=True)
class VirtualRoom:
    """A simulated scan of a room, in the scan frame (metres).

    Attributes
    ----------
    scan : the scan as :class:`VirtualScan` (``is_object``: the target's points, ``scan_from_mesh``:
        the target's truth), so everything written for a single-object scan holds
    labels : (n,) int64 per point: the object's index in ``objects`` (0: the target),
        ``FLOOR_LABEL``, ``WALL_LABEL`` or ``NOTHING_LABEL`` (a mixed pixel)
    objects : every object, the target first
    walls : (w, 4) float64, each wall's face towards the room as a plane ``n . x = d`` (n, d)
    settings : SceneSettings used
    """

    scan: VirtualScan
    labels: np.ndarray
    objects: list[SceneObject]
    walls: np.ndarray
    settings: SceneSettings = field(default_factory=SceneSettings)


def scan_room(
    target: trimesh.Trimesh, *, rng: np.random.Generator, settings: SceneSettings = SceneSettings(),
    target_kind: str = "object", others: list[tuple[str, trimesh.Trimesh]] | None = None,
) -> VirtualRoom:
    """Scan ``target`` (canonical orientation, any units) in a room with walls and other objects.

    Parameters
    ----------
    target : the object of interest; only its orientation matters (scaled as the scanner does)
    rng : the only source of randomness (same seed, same room)
    settings : ranges and camera model
    target_kind : the target's class, recorded in the truth
    others : the other objects as (kind, mesh in metres standing on y = 0, style), default drawn from
        ``settings.other_kinds`` (procedural shapes of the evaluation set, boxes)

    Returns
    -------
    VirtualRoom in metres, in a random world frame unless ``settings.scanner.random_world_frame``
    is False.
    """
    s = settings
    _check_settings(s.scanner)
    validate_mesh(target)
    level_from_mesh, _ = _place_object(target, rng, at_own_size(target, s.scanner) if s.frame_all else s.scanner)
    target_level = level_from_mesh.apply(target.vertices)
    centre, sphere_radius = _bounding_sphere(target_level)
    facing = float(rng.uniform(0.0, 2.0 * math.pi))  # azimuth of the cameras, seen from the target
    placed = [(target_level, target.faces)]
    objects_level = [SceneObject(target_kind, target, level_from_mesh)]
    looks = None
    if s.frame_all:  # the objects first, then a sweep of views past them and walls round them all
        _place_others(placed, objects_level, others, np.zeros((0, 4)), facing, rng, s)
        everything = np.concatenate([vertices for vertices, _ in placed])
        centre, _ = _bounding_sphere(everything)
        cameras, looks = _sweep(placed, facing, rng, s)
        walls = _walls(everything, cameras, facing, rng, s)
    else:
        cameras = _cameras(centre, sphere_radius, rng, s.scanner, azimuth=facing)
        cameras = _walked_level(cameras, centre, rng, s)
        walls = _walls(target_level, cameras, facing, rng, s)
        _place_others(placed, objects_level, others, walls, facing, rng, s)
    points, labels, outlier, view = _render_room(placed, walls, cameras, centre, rng, s, looks=looks)
    world_from_level = _world_frame(rng, s.scanner)
    normals = _noisy_normals(_camera_facing_normals(points, cameras[view], s.scanner), rng, s)
    scan = VirtualScan(
        points=world_from_level.apply(points), normals=world_from_level.apply_vectors(normals),
        is_object=labels == 0, is_outlier=outlier,
        scan_from_mesh=world_from_level @ level_from_mesh, up=world_from_level.R @ UP_LEVEL,
        floor_offset=float(UP_LEVEL @ world_from_level.R.T @ world_from_level.t),
        cameras=world_from_level.apply(cameras), view=view, settings=s.scanner)
    objects = [replace(o, scan_from_mesh=world_from_level @ o.scan_from_mesh) for o in objects_level]
    return VirtualRoom(scan=scan, labels=labels, objects=objects,
                       walls=_planes_to_world(walls, world_from_level), settings=s)


def _place_others(placed: list[tuple[np.ndarray, np.ndarray]], objects: list[SceneObject],
                  others: list[tuple[str, trimesh.Trimesh, str]] | None, walls: np.ndarray, facing: float,
                  rng: np.random.Generator, s: SceneSettings) -> None:
    """Place the other objects (given, or drawn from ``s.other_kinds``) beside what is placed;
    appends to ``placed`` ((vertices (k, 3) level frame, faces) each) and ``objects``. An object
    that fits nowhere in ``s.place_tries`` tries is left out."""
    footprints = [_footprint(trimesh.Trimesh(v, f, process=False), rng) for v, f in placed]
    for kind, mesh, style in others if others is not None else _draw_others(rng, s):
        where = _place_beside(mesh, footprints, walls, facing, rng, s, first=len(placed) == 1,
                              tries=s.place_tries)
        if where is not None:
            placed.append((where.apply(mesh.vertices), mesh.faces))
            footprints.append(_footprint(trimesh.Trimesh(placed[-1][0], mesh.faces, process=False), rng))
            objects.append(SceneObject(kind, mesh, where, style))


def _sweep(placed: list[tuple[np.ndarray, np.ndarray]], facing: float, rng: np.random.Generator,
           s: SceneSettings) -> tuple[np.ndarray, np.ndarray]:
    """Room mode's cameras (k, 3) and the points they look at (k, 3): ``s.views_per_object``
    views of each placed object (vertices (m, 3) level frame), on an arc of ``s.object_arc_deg``
    centred on ``facing``, at the scanner's distance (raised until the object fits the image);
    all at one height (the mean, off by ``camera_height_jitter_m``): a scan walked past the room."""
    one = replace(s.scanner, views=s.views_per_object, arc_deg=s.object_arc_deg)
    cameras, looks = [], []
    for vertices, _ in placed:
        centre, radius = _bounding_sphere(vertices)
        views = _cameras(centre, radius, rng, one, azimuth=facing)
        cameras.append(views)
        looks.append(np.broadcast_to(centre, views.shape))
    cameras = np.concatenate(cameras)
    cameras[:, 1] = cameras[:, 1].mean() + rng.normal(scale=s.camera_height_jitter_m, size=len(cameras))
    return cameras, np.concatenate(looks)


def _bounding_sphere(vertices: np.ndarray) -> tuple[np.ndarray, float]:
    """Centre (3,) of the bounding box of ``vertices`` (k, 3) and the largest distance from it."""
    centre = (vertices.min(0) + vertices.max(0)) / 2.0
    return centre, float(np.linalg.norm(vertices - centre, axis=1).max())


def write_room(room: VirtualRoom, out_dir: str | Path, *, seed: int | None = None) -> Path:
    """Write ``room`` into ``out_dir``: ``scan.ply`` (points, normals, colours by object),
    ``scan.json`` (up, floor, cameras, the target's truth: what ``jsrte fit`` reads),
    ``labels.npy`` ((n,) int16 per point, as ``VirtualRoom.labels``), ``meshes/NN_kind.ply``
    (every object in its own coordinates) and ``scene.json`` (every object's class, mesh file
    and ``scan_from_mesh``; the walls; the cameras). Returns the path of ``scan.ply``."""
    from jsrte.atomic import write_json_atomic, write_with
    from jsrte.geometry.mesh import save_mesh
    from jsrte.scans.scanner import write_scan

    out_dir = Path(out_dir)
    (out_dir / "meshes").mkdir(parents=True, exist_ok=True)
    entries = []
    for k, obj in enumerate(room.objects):
        mesh_path = out_dir / "meshes" / f"{k:02d}_{obj.kind}.ply"
        save_mesh(obj.mesh, mesh_path)
        inside = room.labels == k
        entries.append({"index": k, "class": obj.kind, "style": obj.style, "target": k == 0,
                        "mesh": str(mesh_path.relative_to(out_dir)),
                        "scan_from_mesh": obj.scan_from_mesh.to_dict(),
                        "points": int(inside.sum()),
                        "centre": _centre(room.scan.points[inside]),
                        "height_m": float(obj.scan_from_mesh.s * np.ptp(obj.mesh.vertices[:, 1]))})

    def save_labels(tmp: Path) -> None:
        with open(tmp, "wb") as f:
            np.save(f, room.labels.astype(np.int16))

    write_with(out_dir / "labels.npy", save_labels)
    ply = write_scan(room.scan, out_dir / "scan.ply", seed=seed, mesh=out_dir / entries[0]["mesh"],
                     colors=_colors(room.labels))
    write_json_atomic(out_dir / "scene.json", {
        "scan": "scan.ply", "labels": "labels.npy", "seed": seed,
        "label_codes": {"floor": FLOOR_LABEL, "wall": WALL_LABEL, "between surfaces": NOTHING_LABEL},
        "objects": entries,
        "walls": [{"normal": w[:3].tolist(), "offset": float(w[3]),
                   "points": int((room.labels == WALL_LABEL).sum())} for w in room.walls],
        "floor": {"normal": room.scan.up.tolist(), "offset": room.scan.floor_offset},
        "cameras": room.scan.cameras.tolist(),
        "settings": _settings_json(room.settings)})
    return ply


def read_room_labels(scan_path: str | Path) -> np.ndarray | None:
    """The per-point labels written beside a room's ``scan.ply`` (``labels.npy``), or None."""
    path = Path(scan_path).with_name("labels.npy")
    return np.load(path) if path.is_file() else None


def _centre(points: np.ndarray) -> list[float] | None:
    return None if not len(points) else ((points.min(0) + points.max(0)) / 2.0).tolist()


def _settings_json(s: SceneSettings) -> dict[str, Any]:
    return json.loads(json.dumps(asdict(s)))


def _colors(labels: np.ndarray) -> np.ndarray:
    """(n, 3) uint8 RGB: the target, the floor, the walls, the other objects by index."""
    colors = np.empty((len(labels), 3), dtype=np.uint8)
    colors[:] = FLOOR_COLOR
    colors[labels == WALL_LABEL] = WALL_COLOR
    colors[labels == 0] = OBJECT_COLOR
    for k in np.unique(labels[labels > 0]):
        colors[labels == k] = CLUTTER_COLORS[(int(k) - 1) % len(CLUTTER_COLORS)]
    return colors


# --- the room --------------------------------------------------------------------------------


def _draw_others(rng: np.random.Generator, s: SceneSettings) -> list[tuple[str, trimesh.Trimesh, str]]:
    """Other objects (kind, mesh in metres on y = 0, style): evaluation-set furniture and boxes."""
    from jsrte.shapes import EVAL_SET_SEED, generate_shape, shape_seed

    n = int(rng.integers(s.others[0], s.others[1] + 1))
    drawn = []
    for _ in range(n):
        kind = str(rng.choice(list(s.other_kinds)))
        if kind == "box":
            size = rng.uniform(*s.box_size_m, size=3)
            mesh = trimesh.creation.box(extents=size)
            mesh.apply_translation([0.0, size[1] / 2.0, 0.0])
            style = "box"
        else:
            shape = generate_shape(kind, shape_seed(EVAL_SET_SEED, 1000 + int(rng.integers(10_000))))
            mesh, style = shape.mesh, shape.style
        drawn.append((kind, mesh, style))
    return drawn


def _walked_level(cameras: np.ndarray, centre: np.ndarray, rng: np.random.Generator,
                  s: SceneSettings) -> np.ndarray:
    """``cameras`` (k, 3) moved to one height and one horizontal distance from ``centre`` (their
    means), each height off by ``camera_height_jitter_m`` (std): a scan walked round the object."""
    flat = cameras[:, [0, 2]] - centre[[0, 2]]
    radius = np.linalg.norm(flat, axis=1)
    walked = cameras.copy()
    walked[:, [0, 2]] = centre[[0, 2]] + flat * (radius.mean() / radius)[:, None]
    walked[:, 1] = cameras[:, 1].mean() + rng.normal(scale=s.camera_height_jitter_m, size=len(cameras))
    return walked


def _walls(target: np.ndarray, cameras: np.ndarray, facing: float, rng: np.random.Generator,
           s: SceneSettings) -> np.ndarray:
    """(w, 4) wall planes ``n . x = d`` in the level frame, ``n`` horizontal towards the room: a
    back wall behind the target (away from the cameras), then side walls. Every camera and the
    target stay on the room's side."""
    n = int(rng.integers(s.walls[0], s.walls[1] + 1))
    side = 1.0 if rng.random() < 0.5 else -1.0
    planes = []
    for k in range(n):
        azimuth = facing + math.pi + (0.0 if k == 0 else side * (1 if k == 1 else -1) * math.pi / 2)
        outward = np.array([math.cos(azimuth), 0.0, math.sin(azimuth)])  # from the room to the wall
        reach = float((target @ outward).max()) + float(rng.uniform(*s.wall_gap_m))
        reach = max(reach, float((cameras @ outward).max()) + 0.3)
        planes.append(np.append(-outward, -reach))
    return np.array(planes)


def _wall_mesh(plane: np.ndarray, centre: np.ndarray, s: SceneSettings) -> trimesh.Trimesh:
    """A slab ``wall_length_m`` long whose room-side face is ``plane``, centred near ``centre``."""
    inward, d = plane[:3], plane[3]
    along = np.cross(UP_LEVEL, inward)
    foot = centre - (centre @ inward - d) * inward
    foot[1] = 0.0
    box = trimesh.creation.box(extents=[s.wall_length_m, s.wall_height_m, s.wall_thickness_m])
    frame = np.eye(4)
    frame[:3, 0], frame[:3, 1], frame[:3, 2] = along, UP_LEVEL, -inward
    frame[:3, 3] = foot + UP_LEVEL * s.wall_height_m / 2.0 - inward * s.wall_thickness_m / 2.0
    box.apply_transform(frame)
    return box


def _footprint(mesh: trimesh.Trimesh, rng: np.random.Generator, n: int = 3000) -> np.ndarray:
    """(m, 2) horizontal (x, z) positions of ``mesh``'s vertices and of ``n`` surface samples."""
    samples = mesh.sample(n, seed=int(rng.integers(2**31)))
    return np.concatenate([mesh.vertices, samples])[:, [0, 2]]


def _place_beside(mesh: trimesh.Trimesh, footprints: list[np.ndarray], walls: np.ndarray,
                  facing: float, rng: np.random.Generator, s: SceneSettings, *, first: bool,
                  tries: int = 24) -> Sim3 | None:
    """``level_from_mesh`` of ``mesh`` (metres, on y = 0) at a random yaw beside the target, at a
    drawn horizontal gap from everything placed (the first one beside the target itself), inside
    the walls and out of the cameras' way; None if no try fits."""
    from pykdtree.kdtree import KDTree

    centre = (footprints[0].min(0) + footprints[0].max(0)) / 2.0
    tree = KDTree(np.ascontiguousarray(np.concatenate(footprints)))
    own = _footprint(mesh, rng)
    own3 = np.column_stack([own[:, 0], np.zeros(len(own)), own[:, 1]])
    clearance = math.radians(s.front_clearance_deg)
    behind = math.radians(s.behind_clearance_deg)
    gap_range = s.first_neighbour_gap_m if first else s.neighbour_gap_m
    for _ in range(tries):
        yaw = Sim3(1.0, _yaw(float(rng.uniform(0.0, 2.0 * math.pi))), np.zeros(3))
        lo, hi = mesh.bounds
        anchor = np.array([(lo[0] + hi[0]) / 2.0, lo[1], (lo[2] + hi[2]) / 2.0])
        local = (yaw @ Sim3(1.0, np.eye(3), -anchor)).apply(own3)
        azimuth = facing + _beside_azimuth(clearance, behind, rng)
        direction = np.array([math.cos(azimuth), math.sin(azimuth)])
        gap = float(rng.uniform(*gap_range))
        offset = _distance_for_gap(local[:, [0, 2]], centre, direction, tree, gap)
        if offset is None:
            continue
        where = Sim3(1.0, np.eye(3), np.array([offset[0], 0.0, offset[1]])) @ yaw @ Sim3(1.0, np.eye(3), -anchor)
        vertices = where.apply(mesh.vertices)
        inside = all(float((vertices @ w[:3] - w[3]).min()) > 0.02 for w in walls)
        if inside:
            return where
    return None


def _beside_azimuth(front: float, behind: float, rng: np.random.Generator) -> float:
    """An azimuth (radians, from the cameras' direction) uniform over [front, pi - behind] and
    [pi + behind, 2 pi - front]."""
    azimuth = float(rng.uniform(front, 2.0 * math.pi - front - 2.0 * behind))
    return azimuth + 2.0 * behind if azimuth > math.pi - behind else azimuth


def _distance_for_gap(footprint: np.ndarray, centre: np.ndarray, direction: np.ndarray, tree: Any,
                      gap: float) -> np.ndarray | None:
    """Horizontal position (2,) on the ray ``centre + r * direction`` where ``footprint`` (m, 2)
    lies ``gap`` from the nearest placed point (bisection on r); None if it cannot."""

    def clearance(r: float) -> float:
        moved = np.ascontiguousarray(footprint + centre + r * direction)
        return float(tree.query(moved, k=1)[0].min())

    lo, hi = 0.0, 0.5
    while clearance(hi) < gap:
        lo, hi = hi, hi * 2.0
        if hi > 20.0:
            return None
    for _ in range(20):
        mid = (lo + hi) / 2.0
        lo, hi = (mid, hi) if clearance(mid) < gap else (lo, mid)
    return centre + hi * direction


def _render_room(placed: list[tuple[np.ndarray, np.ndarray]], walls: np.ndarray, cameras: np.ndarray,
                 centre: np.ndarray, rng: np.random.Generator, s: SceneSettings, *,
                 looks: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Points (n, 3), labels (n,), outlier flags (n,) and view index (n,) of every camera; each
    camera looks at ``centre``, or at its row of ``looks`` (k, 3)."""
    import open3d as o3d

    scene = o3d.t.geometry.RaycastingScene()
    label_of = []
    for k, (vertices, faces) in enumerate(placed):
        scene.add_triangles(o3d.core.Tensor(np.asarray(vertices, np.float32)),
                            o3d.core.Tensor(np.asarray(faces, np.uint32)))
        label_of.append(k)
    for plane in walls:
        wall = _wall_mesh(plane, centre, s)
        scene.add_triangles(o3d.core.Tensor(np.asarray(wall.vertices, np.float32)),
                            o3d.core.Tensor(np.asarray(wall.faces, np.uint32)))
        label_of.append(WALL_LABEL)
    r = s.max_depth_m + 2.0
    x, z = centre[0], centre[2]
    quad = np.array([[x - r, 0, z - r], [x + r, 0, z - r], [x + r, 0, z + r], [x - r, 0, z + r]])
    scene.add_triangles(o3d.core.Tensor(quad.astype(np.float32)),
                        o3d.core.Tensor(np.array([[0, 2, 1], [0, 3, 2]], np.uint32)))
    label_of.append(FLOOR_LABEL)
    label_of = np.array(label_of + [NOTHING_LABEL])  # index -1: a pixel that hit nothing
    points, labels, outliers, views = [], [], [], []
    for k, camera in enumerate(cameras):
        view = render_view(scene, camera, centre if looks is None else looks[k], rng, s.scanner)
        depth, label = _mixed_pixels(view.depth, label_of[view.geometry], rng, s)
        keep = np.isfinite(depth) & (depth < s.max_depth_m) & (view.incidence >= s.grazing_cos)
        keep |= np.isfinite(depth) & (label == NOTHING_LABEL) & (depth < s.max_depth_m)
        keep &= rng.random(len(depth)) >= s.dropout_fraction
        points.append(camera + depth[keep, None] * view.directions[keep])
        labels.append(label[keep])
        outliers.append(view.outlier[keep] | (label[keep] == NOTHING_LABEL))
        views.append(np.full(int(keep.sum()), k))
    if not sum(len(p) for p in points):
        raise JsrteError("the room scanner saw nothing")
    return (np.concatenate(points), np.concatenate(labels), np.concatenate(outliers),
            np.concatenate(views))


def _mixed_pixels(depth: np.ndarray, labels: np.ndarray, rng: np.random.Generator, s: SceneSettings
                  ) -> tuple[np.ndarray, np.ndarray]:
    """Depth (p,) and labels (p,) with mixed pixels: at a depth edge (a 4-neighbour more than
    ``mixed_pixel_jump_m`` farther), a share of the near pixels take a depth between the two
    surfaces and the label ``NOTHING_LABEL``."""
    h, w = s.scanner.height, s.scanner.width
    image = depth.reshape(h, w)
    far = np.where(np.isfinite(image), image, np.nan)
    neighbour = np.full((4, h, w), np.nan)
    neighbour[0, 1:], neighbour[1, :-1] = far[:-1], far[1:]
    neighbour[2, :, 1:], neighbour[3, :, :-1] = far[:, :-1], far[:, 1:]
    with np.errstate(invalid="ignore"):
        behind = np.nanmax(np.where(np.isfinite(neighbour), neighbour, -np.inf), axis=0)
        edge = np.isfinite(far) & np.isfinite(behind) & (behind - far > s.mixed_pixel_jump_m)
    edge = edge.reshape(-1) & (rng.random(h * w) < s.mixed_pixel_fraction)
    mixed = depth.copy()
    between = rng.uniform(0.2, 0.8, size=int(edge.sum()))
    mixed[edge] = depth[edge] + between * (behind.reshape(-1)[edge] - depth[edge])
    labels = labels.copy()
    labels[edge] = NOTHING_LABEL
    return mixed, labels


def _noisy_normals(normals: np.ndarray, rng: np.random.Generator, s: SceneSettings) -> np.ndarray:
    """``normals`` (n, 3) tilted by a random angle of std ``normal_noise_deg``, still unit and on
    the same side (they face the camera)."""
    if s.normal_noise_deg <= 0:
        return normals
    tilted = normals + rng.normal(scale=math.radians(s.normal_noise_deg), size=normals.shape)
    tilted /= np.linalg.norm(tilted, axis=1, keepdims=True)
    flip = np.einsum("ij,ij->i", tilted, normals) < 0
    tilted[flip] *= -1.0
    return tilted


def _planes_to_world(planes: np.ndarray, world_from_level: Sim3) -> np.ndarray:
    """Planes ``n . x = d`` (w, 4) of the level frame, in the world frame."""
    out = []
    for plane in planes:
        normal = world_from_level.R @ plane[:3]
        point = world_from_level.apply((plane[3] * plane[:3])[None])[0]
        out.append(np.append(normal, normal @ point))
    return np.array(out).reshape(-1, 4)
