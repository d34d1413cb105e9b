"""Write a scene's files: objects/NN/ (one fit's files each), scene.json, scene.ply, overlay.png."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import trimesh

from jsrte.atomic import write_json_atomic
from jsrte.fit.scene import SceneResult
from jsrte.timing import timed_stage

SCENE_NAME = "scene.json"
OBJECTS_DIR = "objects"
OVERLAY_POINTS = 30_000
"""At most this many object points are drawn in the overlay (a random subset)."""

CLASS_COLORS = {"chair": (214, 69, 65), "table": (52, 120, 198), "sofa": (67, 160, 71), "bed": (243, 156, 18)}
"""RGB of each shipped class in scene.ply; other classes take ``OTHER_COLORS`` in turn."""
OTHER_COLORS = ((142, 68, 173), (22, 160, 133), (127, 140, 141), (211, 84, 0))
BOX_COLOR = (149, 117, 87)
"""RGB of the boxes' cuboids in scene.ply."""


@timed_stage("outputs")
def write_scene_outputs(scene: SceneResult, out_dir: Path, *, extra: dict | None = None) -> list[Path]:
    """Write ``scene`` into ``out_dir`` (each file atomically; scene.json last): every fitted
    object's files in ``objects/NN/`` (``jsrte.fit.outputs.write_fit_outputs``; unexplained
    objects' too), ``scene.ply`` (every found object's retrieved mesh in the scan's frame,
    coloured by class, and the boxes' cuboids), ``overlay.png`` (the scan's points and those
    meshes) and ``scene.json``.
    Returns the paths written."""
    from jsrte.fit.outputs import write_fit_outputs
    from jsrte.geometry.mesh import save_mesh
    from jsrte.viz import render_overlay

    written: list[Path] = []
    for obj in scene.fitted:
        folder = out_dir / OBJECTS_DIR / f"{obj.index:02d}"
        folder.mkdir(parents=True, exist_ok=True)
        written += write_fit_outputs(obj.result, folder, query_points=obj.result.query_points,
                                     up=obj.result.info.get("up"), extra=(extra or {}) | {"scene_object": obj.index})
    mesh = scene_mesh(scene)
    if mesh is not None:
        save_mesh(mesh, out_dir / "scene.ply")
        written.append(out_dir / "scene.ply")
    up = (0.0, 1.0, 0.0) if scene.up is None else tuple(float(v) for v in scene.up)
    points = np.concatenate([o.points for o in scene.objects]) if scene.objects else scene.scan_points
    if len(points) > OVERLAY_POINTS:
        points = points[np.random.default_rng(0).choice(len(points), OVERLAY_POINTS, replace=False)]
    boxes = f", {len(scene.boxes)} box(es)" if scene.boxes else ""
    render_overlay(mesh, points, out_dir / "overlay.png", up=up,
                   title=f"{len(scene.found)} object(s){boxes}: " + ", ".join(o.model or "?" for o in scene.found))
    written.append(out_dir / "overlay.png")
    write_json_atomic(out_dir / SCENE_NAME, scene.to_json() | (extra or {}))
    written.append(out_dir / SCENE_NAME)
    return written


def scene_mesh(scene: SceneResult) -> trimesh.Trimesh | None:
    """Every found object's retrieved mesh in the scan's frame as one mesh, its vertices coloured
    by the object's class (:data:`CLASS_COLORS`), and every box's cuboid (:data:`BOX_COLOR`);
    None when there is neither. Unexplained objects are left out: their meshes are not what was
    scanned."""
    palette = dict(CLASS_COLORS)
    parts = []
    for obj in scene.found:
        mesh = obj.result.mesh
        if mesh is None or not len(mesh.faces):
            continue
        name = obj.model or "?"
        if name not in palette:
            palette[name] = OTHER_COLORS[(len(palette) - len(CLASS_COLORS)) % len(OTHER_COLORS)]
        colors = np.tile(np.array([*palette[name], 255], np.uint8), (len(mesh.vertices), 1))
        parts.append(trimesh.Trimesh(np.asarray(mesh.vertices), np.asarray(mesh.faces), vertex_colors=colors,
                                     process=False))
    for obj in scene.boxes:
        cuboid = obj.box.cuboid.mesh()
        colors = np.tile(np.array([*BOX_COLOR, 255], np.uint8), (len(cuboid.vertices), 1))
        parts.append(trimesh.Trimesh(cuboid.vertices, cuboid.faces, vertex_colors=colors, process=False))
    return trimesh.util.concatenate(parts) if parts else None
