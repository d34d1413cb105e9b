"""DeepSDF-style SDF samples of a mesh, signed by generalized winding numbers.

Samples live in the normalized canonical frame (jsrte.geometry.mesh.Normalization):
``mesh_point = points * scale + centre``. SDF is negative inside.
"""

from __future__ import annotations

import hashlib
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import point_cloud_utils as pcu
import trimesh

from jsrte.atomic import write_with
from jsrte.errors import JsrteError
from jsrte.geometry.mesh import Normalization, unit_sphere_normalization, validate_mesh
from jsrte.presets import SdfSampling


@dataclass(frozen=True)
class SdfSamples:
    """SDF samples of one shape.

    Attributes
    ----------
    points : (n, 3) float32, normalized canonical frame
    sdf : (n,) float32, canonical units, negative inside
    centre : (3,) float64, mesh units
    scale : float, mesh units per canonical unit
    """

    points: np.ndarray
    sdf: np.ndarray
    centre: np.ndarray
    scale: float

    def save(self, path: str | Path) -> None:
        """Write an ``.npz`` (points, sdf, centre, scale) atomically."""

        def write(tmp: Path) -> None:
            with open(tmp, "wb") as f:
                np.savez(f, points=self.points, sdf=self.sdf, centre=self.centre,
                         scale=np.float64(self.scale))

        write_with(path, write)

    @staticmethod
    def load(path: str | Path) -> SdfSamples:
        """Read an ``.npz`` written by :meth:`save`; JsrteError if it is not one."""
        try:
            with np.load(path) as data:
                pts, sdf = data["points"], data["sdf"]
                centre, scale = data["centre"], float(data["scale"])
        except FileNotFoundError:
            raise JsrteError("no such file", path) from None
        except Exception as exc:
            raise JsrteError(f"not an SDF sample file ({type(exc).__name__}: {exc})", path) from exc
        if pts.ndim != 2 or pts.shape[1] != 3 or sdf.shape != (len(pts),):
            raise JsrteError(f"points {pts.shape} and sdf {sdf.shape} do not match", path)
        if len(pts) == 0:
            raise JsrteError("holds no samples", path)
        if not all(np.issubdtype(a.dtype, np.number) for a in (pts, sdf, centre)):
            raise JsrteError("points, sdf and centre must be numbers", path)
        if not (np.isfinite(pts).all() and np.isfinite(sdf).all()):
            raise JsrteError("holds NaN or infinite samples", path)
        centre = np.asarray(centre, dtype=np.float64)
        if centre.shape != (3,) or not np.isfinite(centre).all() or not (np.isfinite(scale) and scale > 0):
            raise JsrteError(f"bad normalization (centre {centre.tolist()}, scale {scale}): centre must be 3 "
                             "finite numbers and scale positive", path)
        return SdfSamples(pts.astype(np.float32), sdf.astype(np.float32), centre, scale)


def signed_distance(mesh: trimesh.Trimesh, points: np.ndarray) -> np.ndarray:
    """Signed distance (n,) from ``points`` (n, 3) to ``mesh``; negative inside.

    Sign by fast generalized winding numbers (point-cloud-utils), so open meshes get
    the right sign too.
    """
    v = np.ascontiguousarray(mesh.vertices, dtype=np.float64)
    f = np.ascontiguousarray(mesh.faces, dtype=np.int32)
    d, _, _ = pcu.signed_distance_to_mesh(np.ascontiguousarray(points, dtype=np.float64), v, f)
    return d


def sample_sdf(
    mesh: trimesh.Trimesh,
    *,
    rng: np.random.Generator,
    settings: SdfSampling = SdfSampling(),
    normalization: Normalization | None = None,
) -> SdfSamples:
    """DeepSDF-style samples: surface points perturbed by two Gaussians, plus uniform ones.

    ``settings.near_fraction`` of the samples are near the surface, split evenly between the
    wide and the narrow Gaussian; the rest are uniform in the cube [-extent, extent]^3.
    """
    validate_mesh(mesh)
    norm = normalization or unit_sphere_normalization(mesh, settings.normalization_padding)
    canon = trimesh.Trimesh(norm.to_canonical(mesh.vertices), mesh.faces, process=False)
    n_near = int(round(settings.n_points * settings.near_fraction))
    n_wide = n_near // 2
    n_uniform = settings.n_points - n_near
    surface = _sample_surface(canon, n_near, rng)
    std = np.full((n_near, 1), settings.near_std_narrow)
    std[:n_wide] = settings.near_std_wide
    near = surface + rng.normal(size=(n_near, 3)) * std
    uniform = rng.uniform(-settings.uniform_extent, settings.uniform_extent, size=(n_uniform, 3))
    points = np.concatenate([near, uniform])
    sdf = signed_distance(canon, points)
    return SdfSamples(points.astype(np.float32), sdf.astype(np.float32), norm.centre, norm.scale)


def _sample_surface(mesh: trimesh.Trimesh, n: int, rng: np.random.Generator) -> np.ndarray:
    """``n`` points (n, 3) uniformly on the surface (area-weighted), seeded by ``rng``."""
    areas = mesh.area_faces
    faces = rng.choice(len(areas), size=n, p=areas / areas.sum())
    u, v = rng.random(n), rng.random(n)
    flip = u + v > 1
    u[flip], v[flip] = 1 - u[flip], 1 - v[flip]
    tri = mesh.triangles[faces]
    return tri[:, 0] + u[:, None] * (tri[:, 1] - tri[:, 0]) + v[:, None] * (tri[:, 2] - tri[:, 0])


def sample_cache_key(mesh_path: str | Path, settings: SdfSampling, seed: int) -> str:
    """A hash of the mesh file's bytes, the settings and the seed: the dataset cache key."""
    h = hashlib.sha256(Path(mesh_path).read_bytes())
    h.update(repr(sorted(asdict(settings).items())).encode())
    h.update(str(seed).encode())
    return h.hexdigest()[:20]
