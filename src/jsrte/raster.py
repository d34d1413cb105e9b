"""A small software renderer in NumPy: shaded gray triangle meshes and points drawn as discs.

Used by every figure of :mod:`jsrte.viz` (a fit's ``overlay.png``, method panels, mesh grids)
and by the contact sheets; it needs no OpenGL, EGL or matplotlib. Triangles are rasterized
exactly (a pixel is covered when its centre is inside the projected triangle), vectorized over
triangles grouped by the size of their pixel bounding boxes; a z-buffer keeps the nearest
triangle at each pixel. Faces are shaded flat and two-sided: an ambient term, a light at the
camera and a key light above and to the side of it. Points are discs tested against the
z-buffer: a point more than ``point_tolerance`` behind the surface at a pixel is hidden there.
Images are rendered at ``supersample`` times the size and reduced with a box filter (Pillow),
which anti-aliases edges.

Conventions: a camera pose is (4, 4) camera-to-world, the camera looking along its -z with +y
up (as OpenGL); pixel (i, j) is column i, row j (row 0 on top) with its centre at (i + 0.5,
j + 0.5); depth is the distance along the viewing direction, in the world's units.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

MESH_RGB = (0.6, 0.6, 0.6)
"""Base gray of meshes (0-1 floats)."""
POINTS_RGB = (0.9, 0.05, 0.05)
"""Red of points."""
BACKGROUND_RGB = (1.0, 1.0, 1.0)
KEY_LIGHT_PITCH_DEG = -35.0
KEY_LIGHT_YAW_DEG = 30.0
CANDIDATES_PER_CHUNK = 1 << 20
"""Candidate pixels tested at once (memory: about 40 bytes each)."""


@dataclass(frozen=True)
class Camera:
    """A camera: ``pose`` (4, 4) camera-to-world (looks along its -z, +y up).

    Perspective with vertical field of view ``yfov`` (radians), or orthographic when
    ``half_height`` (world units from the image's centre to its top edge) is given."""

    pose: np.ndarray
    yfov: float = math.radians(35.0)
    half_height: float | None = None

    @property
    def orthographic(self) -> bool:
        """True for an orthographic camera."""
        return self.half_height is not None


# --- projection --------------------------------------------------------------------------


def project(points: np.ndarray, camera: Camera, size: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """World points (n, 3) -> pixel coordinates (n, 2) (x right, y down) and depth (n,).

    Points at or behind the camera's plane (depth <= 0, perspective) get non-finite pixels."""
    width, height = size
    world_to_camera = np.linalg.inv(camera.pose)
    local = np.asarray(points, np.float64) @ world_to_camera[:3, :3].T + world_to_camera[:3, 3]
    depth = -local[:, 2]
    if camera.orthographic:
        scale = np.full(len(local), (height / 2.0) / camera.half_height)
    else:
        with np.errstate(divide="ignore", invalid="ignore"):
            scale = np.where(depth > 0, (height / 2.0) / math.tan(camera.yfov / 2.0) / depth, np.nan)
    pixels = np.stack([width / 2.0 + scale * local[:, 0], height / 2.0 - scale * local[:, 1]], axis=1)
    return pixels, depth


def _nearness(depth: np.ndarray, orthographic: bool) -> np.ndarray:
    """A quantity affine in screen space that grows towards the camera: 1/depth (perspective)
    or -depth (orthographic), so it can be interpolated linearly across a projected triangle."""
    if orthographic:
        return -depth
    with np.errstate(divide="ignore"):
        return 1.0 / depth


def _depth_from_nearness(nearness: np.ndarray, orthographic: bool) -> np.ndarray:
    """Inverse of :func:`_nearness`; -inf nearness (nothing drawn) gives +inf depth."""
    if orthographic:
        return -nearness
    with np.errstate(divide="ignore"):
        return 1.0 / nearness


# --- triangles ---------------------------------------------------------------------------


def _plane_coefficients(xy: np.ndarray, values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Barycentric and value planes of triangles.

    ``xy`` (f, 3, 2) pixel corners, ``values`` (f, 3) a quantity at the corners. Returns
    ``edges`` (f, 2, 3): rows (a, b, c) such that a*x + b*y + c is the barycentric weight of
    corners 0 and 1 at pixel point (x, y); and ``plane`` (f, 3): (a, b, c) of the value."""
    x0, y0, x1, y1, x2, y2 = (xy[:, k, d] for k in range(3) for d in range(2))
    area2 = (x1 - x0) * (y2 - y0) - (x2 - x0) * (y1 - y0)
    w0 = np.stack([y1 - y2, x2 - x1, x1 * y2 - x2 * y1], axis=1) / area2[:, None]
    w1 = np.stack([y2 - y0, x0 - x2, x2 * y0 - x0 * y2], axis=1) / area2[:, None]
    w2 = np.stack([-w0[:, 0] - w1[:, 0], -w0[:, 1] - w1[:, 1], 1.0 - w0[:, 2] - w1[:, 2]], axis=1)
    plane = w0 * values[:, :1] + w1 * values[:, 1:2] + w2 * values[:, 2:]
    return np.stack([w0, w1], axis=1), plane


def _covered(boxes: np.ndarray, edges: np.ndarray, plane: np.ndarray, box_w: int, box_h: int,
             width: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Pixels covered by triangles whose bounding boxes fit in ``box_w`` x ``box_h`` pixels.

    ``boxes`` (k, 4) int (first column, first row, last column, last row), ``edges`` (k, 2, 3)
    and ``plane`` (k, 3) from :func:`_plane_coefficients`. Returns the flat pixel index
    (row * width + column), the interpolated value and the triangle's row in these arrays,
    one entry per covered (triangle, pixel) pair."""
    oy, ox = np.divmod(np.arange(box_w * box_h, dtype=np.int32), box_w)
    boxes = boxes.astype(np.int32)
    cols = boxes[:, :1] + ox[None, :]
    rows = boxes[:, 1:2] + oy[None, :]
    x, y = (cols + np.float32(0.5)).astype(np.float32), (rows + np.float32(0.5)).astype(np.float32)
    e = edges.astype(np.float32)
    l0 = e[:, 0, :1] * x + e[:, 0, 1:2] * y + e[:, 0, 2:]
    l1 = e[:, 1, :1] * x + e[:, 1, 1:2] * y + e[:, 1, 2:]
    inside = (l0 >= 0) & (l1 >= 0) & (l0 + l1 <= 1)
    if box_w > 1:
        inside &= cols <= boxes[:, 2:3]
    if box_h > 1:
        inside &= rows <= boxes[:, 3:4]
    tri, cand = np.nonzero(inside)
    col, row = cols[tri, cand].astype(np.int64), rows[tri, cand].astype(np.int64)
    value = plane[tri, 0] * (col + 0.5) + plane[tri, 1] * (row + 0.5) + plane[tri, 2]
    return row * width + col, value, tri


def rasterize(pixels: np.ndarray, depth: np.ndarray, faces: np.ndarray, size: tuple[int, int], *,
              orthographic: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Z-buffer rasterization of triangles.

    Parameters
    ----------
    pixels : (n, 2) float, projected vertices (:func:`project`)
    depth : (n,) float, their depths (world units)
    faces : (f, 3) int, vertex indices
    size : (width, height) of the image in pixels
    orthographic : whether depth is interpolated linearly (else its inverse is)

    Returns
    -------
    face : (height, width) int32, the nearest face at each pixel, -1 where none
    zbuffer : (height, width) float32, its depth there, +inf where none
    """
    width, height = size
    face_buf = np.full(height * width, -1, np.int32)
    near_buf = np.full(height * width, -np.inf, np.float32)
    index, boxes, edges, plane = _setup(np.asarray(pixels, np.float64), np.asarray(depth, np.float64),
                                        np.asarray(faces, np.int64).reshape(-1, 3), size, orthographic)
    if not len(index):
        return face_buf.reshape(height, width), np.full((height, width), np.inf)
    box_w, box_h = boxes[:, 2] - boxes[:, 0] + 1, boxes[:, 3] - boxes[:, 1] + 1
    bin_w, bin_h = _size_class(box_w), _size_class(box_h)
    key = bin_w * (2 * height + 2) + bin_h
    order = np.argsort(key, kind="stable")
    starts = np.flatnonzero(np.diff(key[order], prepend=-1))
    entries: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []
    for group in np.split(order, starts[1:]):
        bw, bh = int(bin_w[group[0]]), int(bin_h[group[0]])
        step = max(1, CANDIDATES_PER_CHUNK // (bw * bh))
        for start in range(0, len(group), step):
            part = group[start:start + step]
            pix, value, tri = _covered(boxes[part], edges[part], plane[part], bw, bh, width)
            entries.append((pix, value, index[part[tri]].astype(np.int32)))
    pix, value, fid = (np.concatenate(column) for column in zip(*entries, strict=True))
    value = value.astype(np.float32)
    np.maximum.at(near_buf, pix, value)
    nearest = value >= near_buf[pix]
    face_buf[pix[nearest]] = fid[nearest]
    zbuffer = np.full(height * width, np.inf, np.float32)
    drawn = face_buf >= 0
    zbuffer[drawn] = _depth_from_nearness(near_buf[drawn], orthographic)
    return face_buf.reshape(height, width), zbuffer.reshape(height, width)


def _setup(pixels: np.ndarray, depth: np.ndarray, faces: np.ndarray, size: tuple[int, int],
           orthographic: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The triangles that may cover a pixel centre, and what rasterizing them needs.

    Returns their indices into ``faces`` (k,), pixel bounding boxes (k, 4) int (first column,
    first row, last column, last row, inside the image), and :func:`_plane_coefficients` of
    the barycentric weights and of the nearness (k, 2, 3) and (k, 3). Triangles with a corner
    behind a perspective camera, off the image, or degenerate are left out."""
    width, height = size
    near = _nearness(depth, orthographic)
    valid = np.all(np.isfinite(pixels), axis=1) & np.isfinite(near)
    if not orthographic:
        valid &= depth > 0
    f0, f1, f2 = faces[:, 0], faces[:, 1], faces[:, 2]
    keep = valid[f0] & valid[f1] & valid[f2]
    p0, p1, p2 = pixels[f0], pixels[f1], pixels[f2]
    lo = np.ceil(np.minimum(np.minimum(p0, p1), p2) - 0.5)
    hi = np.floor(np.maximum(np.maximum(p0, p1), p2) - 0.5)
    with np.errstate(invalid="ignore"):
        keep &= (hi[:, 0] >= 0) & (lo[:, 0] <= width - 1) & (hi[:, 1] >= 0) & (lo[:, 1] <= height - 1)
        keep &= (lo[:, 0] <= hi[:, 0]) & (lo[:, 1] <= hi[:, 1])  # some pixel centre in the box
    index = np.flatnonzero(keep)
    lo = np.maximum(lo[index], 0)
    hi = np.minimum(hi[index], [width - 1, height - 1])
    boxes = np.concatenate([lo, hi], axis=1).astype(np.int64)
    xy = np.stack([p0[index], p1[index], p2[index]], axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        edges, plane = _plane_coefficients(xy, np.stack([near[f0[index]], near[f1[index]], near[f2[index]]], axis=1))
    finite = np.isfinite(edges).all(axis=(1, 2)) & np.isfinite(plane).all(axis=1)
    return index[finite], boxes[finite], edges[finite], plane[finite]


def _size_class(n: np.ndarray) -> np.ndarray:
    """Bounding-box sides (k,) int >= 1 -> the side tested: exact up to 8 pixels, then rounded
    up to a multiple of a quarter of the next power of two (at most 25% more candidates)."""
    n = np.maximum(n, 1)
    quarter = np.maximum(1, (1 << np.ceil(np.log2(n)).astype(np.int64)) // 4)
    return np.where(n <= 8, n, -(-n // quarter) * quarter)


# --- shading -----------------------------------------------------------------------------


def face_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Unit normals (f, 3) of triangles (zero for degenerate ones)."""
    corners = np.asarray(vertices, np.float64)[np.asarray(faces, np.int64)]
    normals = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    length = np.linalg.norm(normals, axis=1, keepdims=True)
    return np.divide(normals, length, out=np.zeros_like(normals), where=length > 0)


def key_light_direction(camera: Camera) -> np.ndarray:
    """Unit vector (3,) towards the key light: above and to the side of the camera's view."""
    pitch, yaw = math.radians(KEY_LIGHT_PITCH_DEG), math.radians(KEY_LIGHT_YAW_DEG)
    rot_x = np.array([[1.0, 0.0, 0.0], [0.0, math.cos(pitch), -math.sin(pitch)],
                      [0.0, math.sin(pitch), math.cos(pitch)]])
    rot_y = np.array([[math.cos(yaw), 0.0, math.sin(yaw)], [0.0, 1.0, 0.0],
                      [-math.sin(yaw), 0.0, math.cos(yaw)]])
    return (camera.pose[:3, :3] @ rot_x @ rot_y)[:, 2]


def shade_faces(normals: np.ndarray, camera: Camera, rgb: tuple[float, float, float] = MESH_RGB) -> np.ndarray:
    """Two-sided Lambert shading: normals (f, 3) -> RGB (f, 3) floats in [0, 1].

    Each face is lit on the side the camera sees: ambient + a light at the camera + the key
    light (:func:`key_light_direction`); a face squarely lit by both is near white."""
    towards_camera = camera.pose[:3, 2]
    facing = np.where((normals @ towards_camera)[:, None] < 0, -normals, normals)
    shade = 0.65 + 0.35 * np.clip(facing @ towards_camera, 0.0, None)
    shade += 0.5 * np.clip(facing @ key_light_direction(camera), 0.0, None)
    return np.clip(np.asarray(rgb)[None, :] * shade[:, None], 0.0, 1.0)


# --- points ------------------------------------------------------------------------------


def splat_points(image: np.ndarray, zbuffer: np.ndarray, pixels: np.ndarray, depth: np.ndarray,
                 radius: float, rgb: tuple[float, ...] = POINTS_RGB, *, tolerance: float = 0.0) -> None:
    """Draw points as discs of ``radius`` pixels of colour ``rgb`` on ``image`` (h, w, 3), in place
    (``rgb`` in the image's scale: 0-1 floats for a float image, 0-255 for uint8).

    ``pixels`` (n, 2) and ``depth`` (n,) from :func:`project`; a disc pixel is drawn where the
    point is at most ``tolerance`` (world units) behind the surface in ``zbuffer`` (h, w)."""
    height, width = zbuffer.shape
    ok = np.all(np.isfinite(pixels), axis=1) & (depth > 0)
    pixels, depth = pixels[ok], depth[ok]
    if not len(pixels):
        return
    reach = int(math.ceil(radius))
    oy, ox = np.mgrid[-reach:reach + 1, -reach:reach + 1]
    disc = ox**2 + oy**2 <= radius**2  # offsets from the pixel holding the point
    base = np.floor(pixels).astype(np.int64)
    cols = base[:, :1] + ox[disc][None, :]
    rows = base[:, 1:] + oy[disc][None, :]
    inside = (cols >= 0) & (cols < width) & (rows >= 0) & (rows < height)
    point, offset = np.nonzero(inside)
    cols, rows = cols[point, offset], rows[point, offset]
    visible = depth[point] <= zbuffer[rows, cols] + tolerance
    image[rows[visible], cols[visible]] = rgb


# --- one image ---------------------------------------------------------------------------


def render(vertices: np.ndarray | None, faces: np.ndarray | None, points: np.ndarray | None, camera: Camera,
           size: tuple[int, int], *, point_radius: float | None = None, point_tolerance: float = 0.0,
           supersample: int = 2, mesh_rgb: tuple[float, float, float] = MESH_RGB) -> np.ndarray:
    """One image (height, width, 3) uint8: the mesh shaded gray, the points red, white behind.

    Parameters
    ----------
    vertices : (n, 3) float or None, mesh vertices in world units
    faces : (f, 3) int or None (None or empty: no mesh)
    points : (m, 3) float or None, drawn as discs
    camera : the view
    size : (width, height) pixels of the image
    point_radius : disc radius in output pixels (default: about 1/300 of the smaller side, >= 1.25)
    point_tolerance : world units a point may lie behind the surface and still be drawn
    supersample : rendered at this many times the size, then box-filtered down (anti-aliasing)
    """
    width, height = size
    factor = max(1, int(supersample))
    big = (width * factor, height * factor)
    background = _to_uint8(np.asarray([BACKGROUND_RGB]))
    if vertices is not None and faces is not None and len(faces):
        pixels, depth = project(vertices, camera, big)
        face, zbuffer = rasterize(pixels, depth, faces, big, orthographic=camera.orthographic)
        colours = _to_uint8(shade_faces(face_normals(vertices, faces), camera, mesh_rgb))
        image = np.concatenate([background, colours])[face + 1]  # face -1: the background
    else:
        image = np.broadcast_to(background[0], (big[1], big[0], 3)).copy()
        zbuffer = np.full((big[1], big[0]), np.inf)
    if points is not None and len(points):
        radius = max(1.25, min(width, height) / 300.0) if point_radius is None else point_radius
        pixels, depth = project(np.asarray(points, np.float64).reshape(-1, 3), camera, big)
        splat_points(image, zbuffer, pixels, depth, radius * factor, tuple(_to_uint8(np.asarray([POINTS_RGB]))[0]),
                     tolerance=point_tolerance)
    return _downsample(image, factor)


def _to_uint8(rgb: np.ndarray) -> np.ndarray:
    """(k, 3) floats in [0, 1] -> (k, 3) uint8."""
    return np.round(np.clip(rgb, 0.0, 1.0) * 255.0).astype(np.uint8)


def _downsample(image: np.ndarray, factor: int) -> np.ndarray:
    """Box-filter (h * factor, w * factor, 3) uint8 down to (h, w, 3)."""
    if factor == 1:
        return image
    from PIL import Image

    return np.asarray(Image.fromarray(image).reduce(factor))
