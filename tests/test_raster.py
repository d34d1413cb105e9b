"""The software renderer: exact coverage, z-buffer, shading, point occlusion, empty input."""

from __future__ import annotations

import math

import numpy as np
import pytest
import trimesh

from jsrte.raster import Camera, face_normals, project, rasterize, render, shade_faces

WHITE = (255, 255, 255)


def front_camera(*, half_height: float | None = None, distance: float = 5.0) -> Camera:
    """At +z looking along -z at the origin (+y up): sees the side facing +z."""
    pose = np.eye(4)
    pose[2, 3] = distance
    return Camera(pose=pose, half_height=half_height)


def drawn(image: np.ndarray) -> np.ndarray:
    """(h, w) bool: pixels that are not background white."""
    return np.any(image != WHITE, axis=2)


def test_unit_cube_from_the_front_covers_its_analytic_area() -> None:
    cube = trimesh.creation.box((1.0, 1.0, 1.0))
    camera = front_camera(half_height=1.0)  # 100 px tall -> 50 px per unit
    image = render(cube.vertices, cube.faces, None, camera, (100, 100), supersample=1)
    mask = drawn(image)
    assert 48 * 48 <= mask.sum() <= 52 * 52
    assert mask[26:74, 26:74].all() and not mask[:24].any() and not mask[:, 76:].any()


def test_perspective_square_scales_with_distance() -> None:
    square = trimesh.Trimesh([[-0.5, -0.5, 0], [0.5, -0.5, 0], [0.5, 0.5, 0], [-0.5, 0.5, 0]], [[0, 1, 2], [0, 2, 3]])
    near = drawn(render(square.vertices, square.faces, None, front_camera(distance=2.0), (200, 200),
                        supersample=1)).sum()
    far = drawn(render(square.vertices, square.faces, None, front_camera(distance=4.0), (200, 200),
                       supersample=1)).sum()
    focal = 100.0 / math.tan(math.radians(35.0) / 2.0)
    assert near == pytest.approx((focal / 2.0) ** 2, rel=0.05)
    assert far == pytest.approx((focal / 4.0) ** 2, rel=0.05)


@pytest.mark.parametrize("near_first", [True, False])
def test_near_triangle_occludes_far_one(near_first: bool) -> None:
    near = [[-1.0, -1.0, 0.5], [1.0, -1.0, 0.5], [0.0, 1.0, 0.5]]
    far = [[-1.0, -1.0, -0.5], [1.0, -1.0, -0.5], [0.0, 1.0, -0.5]]
    vertices = np.array(near + far if near_first else far + near)
    faces = np.array([[0, 1, 2], [3, 4, 5]])
    camera = front_camera(half_height=2.0)
    pixels, depth = project(vertices, camera, (64, 64))
    face, zbuffer = rasterize(pixels, depth, faces, (64, 64), orthographic=True)
    near_face = 0 if near_first else 1
    assert face[32, 32] == near_face and zbuffer[32, 32] == pytest.approx(4.5)
    assert face[0, 0] == -1 and np.isinf(zbuffer[0, 0])


def test_face_towards_the_light_is_brighter_than_grazing() -> None:
    camera = front_camera()
    grazing = np.array([math.cos(math.radians(85.0)), 0.0, math.sin(math.radians(85.0))])
    normals = np.array([[0.0, 0.0, 1.0], [grazing[2], 0.0, grazing[0]], [0.0, 0.0, -1.0]])
    colours = shade_faces(normals, camera)
    assert colours[0, 0] > colours[1, 0] + 0.1
    assert colours[2, 0] == pytest.approx(colours[0, 0])  # two-sided: the back is lit as the front


def test_point_behind_mesh_is_hidden_point_in_front_is_drawn() -> None:
    square = trimesh.Trimesh([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], [[0, 1, 2], [0, 2, 3]])
    camera = front_camera(half_height=2.0)
    for z, red in ((-0.5, False), (0.01, True)):
        image = render(square.vertices, square.faces, np.array([[0.0, 0.0, z]]), camera, (80, 80),
                       point_radius=2.0, point_tolerance=0.02)
        r, g = int(image[40, 40, 0]), int(image[40, 40, 1])
        assert (r > 200 and g < 60) is red
    beside = render(square.vertices, square.faces, np.array([[1.5, 0.0, -0.5]]), camera, (80, 80), point_radius=2.0)
    assert beside[40, 70, 0] > 200 and beside[40, 70, 1] < 60  # outside the mesh nothing hides it


def test_empty_mesh_and_no_points_give_background() -> None:
    camera = front_camera()
    for vertices, faces, points in ((None, None, None), (np.zeros((0, 3)), np.zeros((0, 3), int), np.zeros((0, 3)))):
        image = render(vertices, faces, points, camera, (40, 30))
        assert image.shape == (30, 40, 3) and image.dtype == np.uint8 and not drawn(image).any()


def test_faces_behind_the_camera_are_skipped() -> None:
    vertices = np.array([[-1.0, -1.0, 6.0], [1.0, -1.0, 6.0], [0.0, 1.0, 6.0]])  # behind a camera at z=5
    image = render(vertices, np.array([[0, 1, 2]]), None, front_camera(), (40, 40))
    assert not drawn(image).any()


def test_normals_are_unit_or_zero() -> None:
    vertices = np.array([[0, 0, 0], [2, 0, 0], [0, 2, 0], [4, 0, 0]], float)
    normals = face_normals(vertices, np.array([[0, 1, 2], [0, 1, 3]]))
    assert np.allclose(normals[0], [0, 0, 1]) and np.allclose(normals[1], 0)
