"""Where a scan's cameras saw through a fitted surface: a depth image of a ball before a wall,
fitted right, too close to the camera, and too big."""

from __future__ import annotations

import numpy as np
import pytest

from jsrte.fit.quality import seen_through_share
from jsrte.geometry.sim3 import Sim3
from jsrte.scans.views import CameraViews

BALL_CENTRE = np.array([0.0, 0.0, 3.0])
BALL_RADIUS = 0.5
WALL_DEPTH = 5.0


def ball_before_wall(camera: np.ndarray, pixels: int = 160, focal: float = 300.0,
                     radius: float = BALL_RADIUS) -> np.ndarray:
    """A noiseless depth image (``pixels`` square, ``focal`` pixels per unit of image plane) from
    ``camera`` looking along +z: a ball of ``radius`` (0: none) at (0, 0, 3) before a wall at
    z = 5. Returns the readings (p, 3), metres."""
    u, v = np.meshgrid((np.arange(pixels) - pixels / 2 + 0.5) / focal, (np.arange(pixels) - pixels / 2 + 0.5) / focal)
    rays = np.stack([u, v, np.ones_like(u)], axis=-1).reshape(-1, 3)
    rays /= np.linalg.norm(rays, axis=1, keepdims=True)
    along = rays @ (BALL_CENTRE - camera)
    gap = along**2 - (np.sum((BALL_CENTRE - camera) ** 2) - radius**2)
    wall = (WALL_DEPTH - camera[2]) / rays[:, 2]
    depth = np.where(gap > 0, along - np.sqrt(np.maximum(gap, 0.0)), wall)
    return camera + depth[:, None] * rays


CAMERAS = np.array([[-0.2, 0.0, 0.0], [0.2, 0.0, 0.0]])
"""Two cameras 0.4 m apart, each with its own depth image."""


def views_of(radius: float = BALL_RADIUS) -> CameraViews:
    """The readings of :data:`CAMERAS` of a ball of ``radius`` before the wall."""
    readings = [ball_before_wall(c, radius=radius) for c in CAMERAS]
    view = np.concatenate([np.full(len(r), k) for k, r in enumerate(readings)])
    return CameraViews.of_scan(np.concatenate(readings), view, CAMERAS)


@pytest.fixture(scope="module")
def views() -> CameraViews:
    return views_of()


def test_points_before_a_reading_are_seen_through_those_behind_or_on_it_are_not(views):
    """Halfway to the wall beside the ball: seen through. Behind the wall, inside the ball's
    hidden half, on the ball's surface: not. Outside both images: not (nothing was seen there)."""
    points = np.array([
        [0.5, 0.0, 2.5],    # before the wall, beside the ball
        [0.0, 0.0, 1.5],    # between the cameras and the ball
        [1.0, 0.0, 6.0],    # behind the wall
        [0.0, 0.0, 3.4],    # behind the ball's front, hidden by it
        [0.0, 0.0, 2.5],    # on the ball's front (a reading there)
        [5.0, 0.0, 1.0],    # out of both images
    ])
    assert views.seen_through(points).tolist() == [True, True, False, False, False, False]


def test_a_right_fit_is_not_seen_through_a_wrong_one_is(views):
    """The ball's own surface (its back unseen) is hardly seen through; the same ball 1 m nearer
    the cameras mostly is, and so is a ball twice its size at its place, all round its
    silhouette. Without the cameras the share is unknown."""
    import trimesh

    sphere = trimesh.creation.icosphere(subdivisions=4)
    right = Sim3(BALL_RADIUS, np.eye(3), BALL_CENTRE)
    nearer = Sim3(BALL_RADIUS, np.eye(3), BALL_CENTRE - [0.0, 0.0, 1.0])
    bigger = Sim3(2 * BALL_RADIUS, np.eye(3), BALL_CENTRE)
    assert seen_through_share(sphere, right, views) < 0.02
    assert seen_through_share(sphere, nearer, views) > 0.4
    assert seen_through_share(sphere, bigger, views) > 0.4
    assert seen_through_share(sphere, right, None) is None
    assert CameraViews.of_scan(np.zeros((3, 3)), None, np.zeros((1, 3))) is None


def ball_fitted_as_bed(seen_by: CameraViews | None) -> object:
    """The ball fitted as a found bed on the points of its seen front (0.4 of its surface),
    flagged and checked as a scene object whose scan's cameras are ``seen_by``
    (``jsrte.fit.scene.SceneObject``)."""
    from types import SimpleNamespace

    import trimesh

    from jsrte.fit.scene import SceneObject
    from jsrte.fit.scene_checks import flag_scene_object

    readings = np.concatenate([ball_before_wall(c) for c in CAMERAS])
    front = readings[np.linalg.norm(readings - BALL_CENTRE, axis=1) < BALL_RADIUS + 0.01]
    result = SimpleNamespace(quality={"inlier_share": 0.95}, transform=Sim3(BALL_RADIUS, np.eye(3), BALL_CENTRE),
                             mesh_canonical=trimesh.creation.icosphere(subdivisions=4), flag="ok")
    obj = SceneObject(0, 0, front, model="bed", result=result, views=seen_by)
    flag_scene_object(obj, seed=0)
    return obj


def test_a_scene_fit_the_cameras_saw_through_is_doubtful(views):
    """The ball fitted as a bed: with the cameras that saw the ball it is ``ok`` (the share seen
    through, not the bed's coverage bound, judges it); with cameras that saw the wall where the
    ball is fitted, ``doubtful``; without the cameras, the bed's coverage bound makes it
    ``doubtful``."""
    from jsrte.fit.scene_checks import CLASS_COVERED_MIN, COVERED_MIN, SEEN_THROUGH_MAX

    seen = ball_fitted_as_bed(views).result
    assert COVERED_MIN < seen.quality["surface_coverage"] < CLASS_COVERED_MIN["bed"]
    assert seen.quality["seen_through"] < SEEN_THROUGH_MAX and seen.flag == "ok"
    through = ball_fitted_as_bed(views_of(radius=0.0)).result
    assert through.quality["seen_through"] > SEEN_THROUGH_MAX and through.flag == "doubtful"
    unknown = ball_fitted_as_bed(None).result
    assert unknown.quality["seen_through"] is None and unknown.flag == "doubtful"


def test_a_found_object_the_cameras_saw_through_is_no_object(views):
    """The ball fitted as a bed where cameras saw the wall through it (more than
    SEEN_THROUGH_FOUND_MAX of it) is dropped as ``unexplained``; where they saw the ball, or
    where the scan does not say which camera saw each point, it stays found."""
    from jsrte.fit.scene_checks import SEEN_THROUGH_FOUND_MAX, drop_seen_through

    seen, through, unknown = (ball_fitted_as_bed(v) for v in (views, views_of(radius=0.0), None))
    drop_seen_through([seen, through, unknown])
    assert through.result.quality["seen_through"] > SEEN_THROUGH_FOUND_MAX
    assert through.status == "unexplained" and through.unexplained_by == "seen through"
    assert "no bed stands there: the cameras saw through" in through.reason
    assert seen.status == unknown.status == "ok" and seen.unexplained_by == unknown.unexplained_by == ""
