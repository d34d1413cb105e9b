"""Fit folders built from an analytic result (no fit is run): a sphere of radius 0.5 m standing on
the floor y = 0 at (x0, 0.5, 0), its scan (points on the sphere and on the floor), the scan's JSON
(true pose, floor, true mesh) and a fit.json whose winner is the true pose."""

import json
from pathlib import Path

import numpy as np
import trimesh

RADIUS = 0.5


def sphere_points(n: int, centre: np.ndarray, radius: float) -> np.ndarray:
    """(n, 3) points spread evenly on a sphere (Fibonacci lattice)."""
    i = np.arange(n) + 0.5
    polar = np.arccos(1 - 2 * i / n)
    azimuth = np.pi * (1 + 5**0.5) * i
    unit = np.stack([np.sin(polar) * np.cos(azimuth), np.cos(polar), np.sin(polar) * np.sin(azimuth)], axis=1)
    return centre + radius * unit


def make_scan(folder: Path, name: str, *, x0: float = 0.0) -> Path:
    """``folder/name.ply`` (sphere + floor points), ``name.json`` and the true mesh ``name_true.ply``."""
    folder.mkdir(parents=True, exist_ok=True)
    centre = np.array([x0, RADIUS, 0.0])
    rng = np.random.default_rng(0)
    floor = np.column_stack([rng.uniform(-1.5, 1.5, 800) + x0, np.zeros(800), rng.uniform(-1.5, 1.5, 800)])
    points = np.vstack([sphere_points(1500, centre, RADIUS), floor])
    trimesh.PointCloud(points).export(folder / f"{name}.ply")
    trimesh.creation.icosphere(subdivisions=3, radius=1.0).export(folder / f"{name}_true.ply")
    info = {"scan_from_mesh": {"scale": RADIUS, "rotation": np.eye(3).tolist(), "translation": centre.tolist()},
            "up": [0.0, 1.0, 0.0], "floor": {"normal": [0.0, 1.0, 0.0], "offset": 0.0},
            "cameras": [[x0, 1.0, -3.0]], "mesh": f"{name}_true.ply"}
    (folder / f"{name}.json").write_text(json.dumps(info))
    return folder / f"{name}.ply"


def make_fit(folder: Path, scan: Path | None, *, x0: float = 0.0, offset: float = 0.0, input_text: str | None = None,
             overlay: bool = True) -> Path:
    """A fit folder whose retrieved sphere is the truth moved by ``offset`` along x (scan frame)."""
    folder.mkdir(parents=True, exist_ok=True)
    centre = [x0 + offset, RADIUS, 0.0]
    mesh = trimesh.creation.icosphere(subdivisions=3, radius=RADIUS)
    mesh.apply_translation(centre)
    mesh.export(folder / "shape.ply")
    other = {"scale": 0.4, "rotation": np.eye(3).tolist(), "translation": [x0 + 0.3, RADIUS, 0.1]}
    fit = {"method": "jsrte", "scale": RADIUS, "rotation": np.eye(3).tolist(), "translation": centre,
           "theta": np.pi / 2, "loss": 0.0123, "model": "chair", "empty_surface": False, "winner_hypothesis": 0,
           "hypotheses": [{"index": 0, "loss": 0.0123, "transform": {"scale": RADIUS, "rotation": np.eye(3).tolist(),
                                                                       "translation": centre}},
                          {"index": 1, "loss": 0.05, "transform": other},
                          {"index": 2, "loss": 0.07, "transform": None, "pruned": True}],
           "up": [0.0, 1.0, 0.0], "timing_s": {"total": 1.5},
           "input": input_text if input_text is not None else (None if scan is None else str(scan))}
    (folder / "fit.json").write_text(json.dumps(fit))
    if overlay:
        from PIL import Image

        Image.new("RGB", (640, 240), (200, 120, 60)).save(folder / "overlay.png")
    return folder


def make_batch(root: Path, n: int = 2) -> Path:
    """``root/out`` as fit-many leaves it: one fit folder per scan (and summary.csv)."""
    scans = root / "scans"
    out = root / "out"
    for i in range(n):
        scan = make_scan(scans, f"s{i}", x0=0.0)
        make_fit(out / f"s{i}", scan, offset=0.0)
    (out / "summary.csv").write_text("scan,result,status\n")
    return out
