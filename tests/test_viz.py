"""Figures: PNGs are written, non-empty, with gray mesh pixels and red point pixels."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from PIL import Image

from jsrte import viz


def imread(path) -> np.ndarray:
    """(h, w, 3) floats in [0, 1] of a PNG."""
    with Image.open(path) as image:
        return np.asarray(image.convert("RGB"), dtype=np.float64) / 255.0


def pixel_kinds(path) -> tuple[int, int]:
    """Counts of (red, gray) pixels of a PNG."""
    image = imread(path)[..., :3]
    r, g, b = image[..., 0], image[..., 1], image[..., 2]
    red = (r > 0.6) & (g < 0.3) & (b < 0.3)
    gray = (np.abs(r - g) < 0.04) & (np.abs(g - b) < 0.04) & (r > 0.2) & (r < 0.9)
    return int(red.sum()), int(gray.sum())


@pytest.fixture(scope="module")
def scene() -> tuple[trimesh.Trimesh, np.ndarray]:
    mesh = trimesh.creation.box((0.8, 1.2, 0.6))
    rng = np.random.default_rng(0)
    points, _ = trimesh.sample.sample_surface(mesh, 1500, seed=1)
    return mesh, np.asarray(points) * 1.02 + rng.normal(0.0, 0.005, (1500, 3))


def test_overlay_has_gray_mesh_and_red_points(tmp_path, scene):
    mesh, points = scene
    out = tmp_path / "overlay.png"
    viz.render_overlay(mesh, points, out, views=2, size=(200, 160), title="box")
    assert out.stat().st_size > 0
    image = imread(out)
    assert image.shape[1] == 400 and image.shape[0] > 160
    red, gray = pixel_kinds(out)
    assert red > 200 and gray > 2000
    assert not list(tmp_path.glob(".*tmp*"))  # written atomically, nothing left behind


def test_overlay_without_mesh_and_other_up_axis(tmp_path, scene):
    _, points = scene
    out = tmp_path / "points.png"
    viz.render_overlay(None, points, out, up=(0.0, 0.0, 1.0), views=1, size=(160, 120))
    red, gray = pixel_kinds(out)
    assert red > 100 and gray == 0


def test_mesh_grid_titles_and_tiles(tmp_path):
    meshes = [trimesh.creation.icosphere(2), trimesh.creation.box((1.0, 0.5, 0.3)),
              trimesh.creation.cylinder(0.3, 1.0)]
    out = tmp_path / "grid.png"
    viz.render_mesh_grid(meshes, ["sphere", "box", "cylinder"], out, cols=2, tile=(120, 120))
    image = imread(out)
    assert image.shape[1] == 240 and image.shape[0] == 2 * (120 + viz.LABEL_PX)
    _, gray = pixel_kinds(out)
    assert gray > 3000
    with pytest.raises(ValueError):
        viz.render_mesh_grid(meshes, ["one title"], out)


def test_panels_row(tmp_path, scene):
    mesh, points = scene
    out = tmp_path / "panels.png"
    viz.render_panels([("scan", None, points), ("method", mesh, points), ("empty", None, None)],
                      out, up=(0.0, 1.0, 0.0), tile=(150, 150))
    image = imread(out)
    assert image.shape[1] == 450
    red, gray = pixel_kinds(out)
    assert red > 200 and gray > 1000


def test_points_behind_the_mesh_are_hidden_in_the_overlay(tmp_path, scene):
    """Points on the box's faces turned away from the view do not show through it."""
    mesh, points = scene
    half = np.array([0.4, 0.6, 0.3])
    axis = np.argmax(np.abs(points) / half, axis=1)
    normals = np.zeros_like(points)
    normals[np.arange(len(points)), axis] = np.sign(points[np.arange(len(points)), axis])
    towards_camera = viz._orbit_camera(np.zeros(3), 1.0, (0.0, 1.0, 0.0), viz.FRONT_LEFT_AZIMUTH_DEG,
                                       (200, 160)).pose[:3, 2]
    seen = normals @ towards_camera > 0
    assert 0.3 < seen.mean() < 0.7
    out_all, out_front = tmp_path / "all.png", tmp_path / "front.png"
    viz.render_overlay(mesh, points, out_all, views=1, size=(200, 160))
    viz.render_overlay(mesh, points[seen], out_front, views=1, size=(200, 160))
    red_all, _ = pixel_kinds(out_all)
    red_front, _ = pixel_kinds(out_front)
    assert red_front > 200 and abs(red_all - red_front) < 0.1 * red_front


def test_contact_sheet_tiles_and_titles(tmp_path, scene):
    from jsrte.shapes.sheet import TILE_PX, render_sheet

    mesh, _ = scene
    out = render_sheet([mesh, mesh.copy()], ["box", "again"], tmp_path / "sheet.png")
    image = imread(out)
    assert image.shape[1] == 2 * TILE_PX and image.shape[0] == TILE_PX + viz.LABEL_PX
    _, gray = pixel_kinds(out)
    assert gray > 2 * 3000
