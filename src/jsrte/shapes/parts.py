"""Solid parts in metres (boxes, rods, discs) and their watertight union.

Furniture generators collect parts in a :class:`Parts` list: parts on the centre plane
(``add``) must themselves be symmetric about the y-z plane; side parts (``add_pair``) are
built for the right side (+x) and mirrored. The union (manifold3d) is one closed,
oriented body; :meth:`Parts.to_trimesh` cuts it at the floor ``y = 0`` (so splayed legs get
flat feet), centres it at ``x = z = 0`` and checks that it is one connected solid.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import trimesh
from manifold3d import Manifold, OpType

SEGMENTS = 24
"""Segments around every round part (even, so round parts are mirror-symmetric in x)."""
FLOOR_SINK_M = 0.01
"""Parts meant to stand on the floor reach this far below it; the floor cut removes it."""
OVERLAP_M = 0.005
"""How far parts reach into their neighbours so that the union is one body."""
CLEARANCE_M = 0.001
"""How far a face stays off a neighbour it would otherwise only touch along a line (a flat
face tangent to a round part, two faces flush at a corner): such contact gives edges shared
by four faces, so the mesh would not be watertight once its coincident vertices are merged."""

Vec = Sequence[float] | np.ndarray


def rot_x(deg: float) -> np.ndarray:
    """(3, 3) rotation about +x by ``deg`` degrees (positive turns +y towards +z)."""
    a = np.radians(deg)
    c, s = np.cos(a), np.sin(a)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def rot_y(deg: float) -> np.ndarray:
    """(3, 3) rotation about +y by ``deg`` degrees (positive turns +z towards +x)."""
    a = np.radians(deg)
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def rot_z(deg: float) -> np.ndarray:
    """(3, 3) rotation about +z by ``deg`` degrees (positive turns +x towards +y)."""
    a = np.radians(deg)
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def placed(solid: Manifold, rotation: np.ndarray | None = None, centre: Vec = (0, 0, 0)) -> Manifold:
    """``solid`` rotated by ``rotation`` (3, 3) about the origin, then moved to ``centre`` (3,)."""
    matrix = np.zeros((3, 4))
    matrix[:, :3] = np.eye(3) if rotation is None else rotation
    matrix[:, 3] = np.asarray(centre, dtype=np.float64)
    return solid.transform(matrix)


def box(size: Vec, centre: Vec, rotation: np.ndarray | None = None) -> Manifold:
    """A box of extents ``size`` (3,) m centred at ``centre`` (3,), optionally rotated about it."""
    return placed(Manifold.cube(tuple(float(s) for s in size), center=True), rotation, centre)


def span_box(lo: Vec, hi: Vec) -> Manifold:
    """An axis-aligned box between corners ``lo`` (3,) and ``hi`` (3,)."""
    lo, hi = np.asarray(lo, np.float64), np.asarray(hi, np.float64)
    return box(hi - lo, (lo + hi) / 2)


def _frame_along(direction: np.ndarray) -> np.ndarray:
    """A rotation (3, 3) taking +z to the unit vector ``direction``, keeping x horizontal-ish."""
    d = direction / np.linalg.norm(direction)
    helper = np.array([1.0, 0.0, 0.0]) if abs(d[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    u = helper - d * (helper @ d)
    u /= np.linalg.norm(u)
    return np.column_stack([u, np.cross(d, u), d])


def rod(p0: Vec, p1: Vec, r0: float, r1: float | None = None, *, segments: int = SEGMENTS) -> Manifold:
    """A (tapered) round rod from ``p0`` (3,) with radius ``r0`` to ``p1`` (3,) with ``r1`` (m)."""
    p0, p1 = np.asarray(p0, np.float64), np.asarray(p1, np.float64)
    axis = p1 - p0
    solid = Manifold.cylinder(float(np.linalg.norm(axis)), float(r0), float(r0 if r1 is None else r1),
                              segments)
    return placed(solid, _frame_along(axis), p0)


def bar(p0: Vec, p1: Vec, width: float, depth: float | None = None) -> Manifold:
    """A square-section bar from ``p0`` (3,) to ``p1`` (3,): ``width`` (x-ish) by ``depth`` (m)."""
    p0, p1 = np.asarray(p0, np.float64), np.asarray(p1, np.float64)
    axis = p1 - p0
    length = float(np.linalg.norm(axis))
    size = (width, width if depth is None else depth, length)
    return placed(Manifold.cube(size, center=True), _frame_along(axis), (p0 + p1) / 2)


def disc(centre: Vec, radius: float, thickness: float, *, segments: int = 2 * SEGMENTS) -> Manifold:
    """A horizontal round slab (axis +y) of ``radius`` and ``thickness`` centred at ``centre``."""
    solid = Manifold.cylinder(float(thickness), float(radius), float(radius), segments, True)
    return placed(solid, rot_x(-90.0), centre)


def ball(centre: Vec, radius: float) -> Manifold:
    """A sphere of ``radius`` m at ``centre`` (3,)."""
    return Manifold.sphere(float(radius), SEGMENTS).translate(tuple(float(c) for c in centre))


def rounded_slab(size: Vec, centre: Vec, radius: float) -> Manifold:
    """A box ``size`` (3,) whose four vertical-ish edges along z are rounded by ``radius`` (m).

    Used for cushions: the rounding runs along x and y edges (a hull of four rods along x).
    """
    sx, sy, sz = (float(s) for s in size)
    r = min(radius, sy / 2 - 1e-4, sz / 2 - 1e-4)
    rods = [Manifold.cylinder(sx, r, r, SEGMENTS, True).transform(
        np.column_stack([rot_y(90.0), [0.0, y, z]])) for y in (-sy / 2 + r, sy / 2 - r)
        for z in (-sz / 2 + r, sz / 2 - r)]
    return Manifold.batch_hull(rods).translate(tuple(float(c) for c in centre))


class Parts:
    """The parts of one piece of furniture, mirrored where asked, unioned into one body."""

    def __init__(self) -> None:
        self.solids: list[Manifold] = []

    def add(self, *solids: Manifold) -> None:
        """Add parts that are symmetric about the y-z plane themselves."""
        self.solids.extend(solids)

    def add_pair(self, *solids: Manifold) -> None:
        """Add right-side parts and their mirror images across the y-z plane."""
        for solid in solids:
            self.solids.extend([solid, solid.mirror((1.0, 0.0, 0.0))])

    def union(self) -> Manifold:
        """The boolean union of all parts, cut at the floor ``y = 0``."""
        solid = Manifold.batch_boolean(self.solids, OpType.Add)
        return solid.trim_by_plane((0.0, 1.0, 0.0), 0.0)

    def to_trimesh(self) -> trimesh.Trimesh:
        """The union as a watertight trimesh, standing on ``y = 0``, centred at ``x = z = 0``.

        A closed pocket of air enclosed by the parts (cushions meeting around a gap) is filled:
        only the outer surface is kept.

        Raises ``RuntimeError`` (a generator bug, not bad input) if the parts do not form
        exactly one connected body.
        """
        bodies = [body for body in self.union().decompose() if body.volume() > 0]  # < 0: an enclosed void
        if len(bodies) != 1:
            raise RuntimeError(f"procedural shape has {len(bodies)} bodies; parts must overlap")
        mesh = bodies[0].to_mesh64()
        vertices = np.asarray(mesh.vert_properties, dtype=np.float64)[:, :3]
        lo, hi = vertices.min(axis=0), vertices.max(axis=0)
        vertices = vertices - np.array([0.0, lo[1], (lo[2] + hi[2]) / 2])
        faces = np.asarray(mesh.tri_verts, dtype=np.int64)
        return trimesh.Trimesh(vertices, faces, process=False)
