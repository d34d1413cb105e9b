"""Figures: PNGs are written, non-empty, with gray mesh pixels and red point pixels."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from matplotlib.image import imread

from jsrte import viz


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


@pytest.mark.parametrize("backend", ["auto", "matplotlib"])
def test_overlay_has_gray_mesh_and_red_points(tmp_path, scene, backend):
    mesh, points = scene
    out = tmp_path / "overlay.png"
    viz.render_overlay(mesh, points, out, views=2, size=(200, 160), title="box", backend=backend)
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


def test_contact_sheet_then_overlay_share_one_gl_context(tmp_path, scene):
    """A contact sheet must not tear down the GL display the overlays render with (a CI failure)."""
    from jsrte.shapes.sheet import render_sheet

    mesh, points = scene
    for name in ("before.png", "after.png"):
        viz.render_overlay(mesh, points, tmp_path / name, views=1, size=(160, 120))
        render_sheet([mesh], ["box"], tmp_path / "sheet.png")
        red, gray = pixel_kinds(tmp_path / name)
        assert red > 100 and gray > 1000


def test_auto_backend_falls_back_when_gl_drawing_fails(tmp_path, scene, monkeypatch):
    mesh, points = scene

    def broken(*args, **kwargs):
        raise RuntimeError("eglMakeCurrent failed")

    monkeypatch.setattr(viz, "_render_pyrender", broken)
    monkeypatch.setattr(viz, "_PYRENDER", {"ok": True, "renderer": object()})
    out = tmp_path / "overlay.png"
    with pytest.warns(RuntimeWarning, match="unavailable"):
        viz.render_overlay(mesh, points, out, views=1, size=(160, 120))
    red, gray = pixel_kinds(out)
    assert red > 100 and gray > 1000
    assert viz._PYRENDER["ok"] is False  # monkeypatch puts the process's real state back
