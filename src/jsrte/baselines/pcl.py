"""PCL's Harris3D, SHOT and OUR-CVFH through a small pybind11 binding (``pcl_binding.cpp``).

The paper's baselines used these very implementations (PCL, Rusu & Cousins 2011). Debian
ships PCL 1.13 (``libpcl-dev``); the binding is compiled with the system C++ compiler against
it the first time it is needed (about 40-75 s on 2 cores) and kept in the user cache
(``<cache>/pcl/``, keyed by the source, the PCL version and the Python ABI). Prebuild it at
install time with ``python -m jsrte.baselines.pcl``.

Needs: ``apt-get install libpcl-dev pybind11-dev g++ pkg-config`` (about 300 MB to download,
1.6 GB installed with VTK/Qt/Boost, 3-4 minutes here). Without it, the two PCL baselines
raise a ``JsrteError`` that says so; the other baselines do not need PCL.
"""

from __future__ import annotations

import hashlib
import importlib.util
import shutil
import subprocess
import sys
import sysconfig
from dataclasses import dataclass
from functools import cache
from pathlib import Path
from types import ModuleType

import numpy as np

from jsrte.errors import JsrteError

SOURCE = Path(__file__).with_name("pcl_binding.cpp")
MODULE = "_jsrte_pcl"
PKG_CONFIG = ("pcl_features", "pcl_keypoints", "pcl_search", "pcl_kdtree", "pcl_common")
INSTALL_HINT = "install PCL with 'apt-get install libpcl-dev pybind11-dev g++ pkg-config'"


@dataclass(frozen=True)
class Toolchain:
    """What the build needs: compiler, flags from pkg-config, the pybind11 headers."""

    compiler: str
    pcl_version: str
    flags: list[str]


def find_toolchain() -> Toolchain | None:
    """The compiler and PCL flags, or None when PCL or a compiler is missing."""
    compiler = shutil.which("g++") or shutil.which("c++")
    if compiler is None or shutil.which("pkg-config") is None:
        return None
    try:
        version = _run(["pkg-config", "--modversion", "pcl_common"]).strip()
        flags = _run(["pkg-config", "--cflags", "--libs", *PKG_CONFIG]).split()
    except (OSError, subprocess.CalledProcessError):
        return None
    pybind = _pybind11_include()
    if pybind is None:
        return None
    includes = [f"-I{sysconfig.get_paths()['include']}", f"-I{pybind}"]
    return Toolchain(compiler, version, includes + flags)


def _pybind11_include() -> str | None:
    try:
        import pybind11

        return pybind11.get_include()
    except ImportError:
        pass
    if Path("/usr/include/pybind11/pybind11.h").is_file():
        return "/usr/include"
    import torch

    torch_include = Path(torch.__file__).parent / "include"
    return str(torch_include) if (torch_include / "pybind11" / "pybind11.h").is_file() else None


def _run(cmd: list[str]) -> str:
    return subprocess.run(cmd, check=True, capture_output=True, text=True).stdout


def build_dir(toolchain: Toolchain) -> Path:
    """The cache folder of the compiled module for this source, PCL and Python."""
    from jsrte.baselines.cache import cache_dir

    h = hashlib.sha256(SOURCE.read_bytes())
    h.update(f"{toolchain.pcl_version} {sys.version} {sysconfig.get_config_var('EXT_SUFFIX')}".encode())
    return cache_dir("pcl", h.hexdigest()[:16])


def build(toolchain: Toolchain, *, verbose: bool = False) -> Path:
    """Compile the binding into the cache (atomically); returns the module file."""
    folder = build_dir(toolchain)
    target = folder / f"{MODULE}{sysconfig.get_config_var('EXT_SUFFIX')}"
    if target.is_file():
        return target
    tmp = target.with_name(f".{target.name}.building")
    cmd = [toolchain.compiler, "-O2", "-shared", "-fPIC", "-std=c++17", "-fopenmp", "-w", str(SOURCE),
           "-o", str(tmp), *toolchain.flags]
    if verbose:
        sys.stderr.write(" ".join(cmd) + "\n")
    done = subprocess.run(cmd, capture_output=True, text=True)
    if done.returncode != 0:
        tmp.unlink(missing_ok=True)
        last = (done.stderr.strip().splitlines() or ["?"])[-1]
        raise JsrteError(f"building the PCL binding failed ({last}); {INSTALL_HINT}", SOURCE)
    tmp.replace(target)
    return target


@cache
def load() -> ModuleType:
    """The compiled binding (built on first use). Raises ``JsrteError`` when PCL is missing."""
    toolchain = find_toolchain()
    if toolchain is None:
        raise JsrteError(f"this baseline needs PCL's Harris3D/SHOT/OUR-CVFH: {INSTALL_HINT}")
    path = build(toolchain)
    spec = importlib.util.spec_from_file_location(MODULE, path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def available() -> bool:
    """Whether PCL and a compiler are installed (the binding can be built)."""
    return find_toolchain() is not None


def _f32(a: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(a, dtype=np.float32)


# --- the three features ---------------------------------------------------------------------------


def harris3d(points: np.ndarray, normals: np.ndarray, *, radius: float, threshold: float,
             refine: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """PCL ``HarrisKeypoint3D`` (HARRIS response, non-maximum suppression within ``radius``).

    Returns keypoint positions (k, 3) float64 and the indices (k,) of the points they were
    detected at (-1 where PCL does not say).
    """
    pos, idx = load().harris3d(_f32(points), _f32(normals), float(radius), float(threshold), bool(refine))
    return np.asarray(pos, dtype=np.float64), np.asarray(idx, dtype=np.int64)


def shot(surface: np.ndarray, normals: np.ndarray, keypoints: np.ndarray, *, radius: float,
         threads: int = 0) -> np.ndarray:
    """PCL ``SHOTEstimationOMP`` descriptors (k, 352) at ``keypoints`` (k, 3) over ``surface``
    (n, 3) with ``normals`` (n, 3); rows of NaN where no local reference frame was found."""
    return np.asarray(load().shot(_f32(surface), _f32(normals), _f32(keypoints), float(radius), int(threads)))


def ourcvfh(points: np.ndarray, normals: np.ndarray, *, eps_angle: float, curvature_threshold: float,
            cluster_tolerance: float, radius_normals: float, min_points: int, axis_ratio: float,
            min_axis_value: float, normalize_bins: bool, refine_clusters: float
            ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """PCL ``OURCVFHEstimation``: signatures (m, 308), SGURF transforms (m, 4, 4), valid (m,)."""
    desc, frames, valid = load().ourcvfh(
        _f32(points), _f32(normals), float(eps_angle), float(curvature_threshold), float(cluster_tolerance),
        float(radius_normals), int(min_points), float(axis_ratio), float(min_axis_value),
        bool(normalize_bins), float(refine_clusters))
    return np.asarray(desc), np.asarray(frames), np.asarray(valid)


if __name__ == "__main__":  # python -m jsrte.baselines.pcl: prebuild at install time
    found = find_toolchain()
    if found is None:
        sys.stderr.write(f"PCL binding not built: {INSTALL_HINT}\n")
        sys.exit(1)
    sys.stdout.write(f"PCL {found.pcl_version}: {build(found, verbose=True)}\n")
