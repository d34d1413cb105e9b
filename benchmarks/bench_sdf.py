"""SDF sampling speed and sign correctness.

Run: .venv/bin/python benchmarks/bench_sdf.py
- time of 250 000 DeepSDF samples of a ~20k-face mesh: ours (point-cloud-utils fast winding
  numbers) and libigl's signed_distance (exact winding number signs) on the same points;
- sign agreement with an exact inside test (libigl winding number, |w| > 0.5) on the watertight
  mesh, and on the same mesh with 2% of its faces removed (holes).
"""

from __future__ import annotations

import time

import igl
import numpy as np
import trimesh

from jsrte.geometry.mesh import normalized
from jsrte.presets import SdfSampling
from jsrte.sdf.mesh_sdf import sample_sdf, signed_distance
from jsrte.shapes import generate_shape


def twenty_k_face_chair() -> trimesh.Trimesh:
    mesh = normalized(generate_shape("chair", 3).mesh)
    while len(mesh.faces) < 20_000:
        mesh = mesh.subdivide()
    return mesh


def main() -> None:
    mesh = twenty_k_face_chair()
    print(f"mesh: {len(mesh.faces)} faces, watertight {mesh.is_watertight}")
    rng = np.random.default_rng(0)
    t = time.perf_counter()
    samples = sample_sdf(mesh, rng=rng, settings=SdfSampling())
    ours = time.perf_counter() - t
    pts = samples.points.astype(np.float64)
    v, f = mesh.vertices, mesh.faces.astype(np.int64)
    t = time.perf_counter()
    igl_d = igl.signed_distance(pts, v, f, sign_type=igl.SIGNED_DISTANCE_TYPE_WINDING_NUMBER)[0]
    alt = time.perf_counter() - t
    inside = np.abs(igl.winding_number(v, f, pts)) > 0.5
    exact_sign = np.where(inside, -1.0, 1.0)
    agree = float((np.sign(samples.sdf) == exact_sign).mean())
    diff = float(np.abs(np.abs(igl_d) - np.abs(samples.sdf)).max())
    keep = np.ones(len(f), bool)
    keep[rng.choice(len(f), size=len(f) // 50, replace=False)] = False
    holed = trimesh.Trimesh(v, f[keep], process=False)
    holed_sign = np.sign(signed_distance(holed, pts))
    agree_holed = float((holed_sign == exact_sign).mean())
    print("| measure | value |\n|---|---|")
    print(f"| ours: 250k samples incl. surface sampling (pcu fast winding numbers) | {ours:.2f} s |")
    print(f"| libigl signed_distance, winding-number signs, same points | {alt:.2f} s |")
    print(f"| max |distance| difference ours vs libigl | {diff:.2e} |")
    print(f"| sign agreement with exact winding number, watertight | {100 * agree:.3f}% |")
    print(f"| sign agreement, 2% of faces removed | {100 * agree_holed:.3f}% |")


if __name__ == "__main__":
    main()
