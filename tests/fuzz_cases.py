"""Damaged files for every reader, and what each reader must do with them.

A case is a valid file of one format, mutated (cut short, bytes flipped, inserted or deleted,
a token of a text format replaced by an odd number or word). Reading it must end in a result
that is sane (finite, consistent shapes) or in one ``JsrteError``: never another exception, a
hang, or a result that is silently wrong.

Used by ``tests/test_fuzz_readers.py`` (a few examples per format, in CI) and by
``benchmarks/bench_fuzz.py`` (many, with a table of outcomes per format).
"""

from __future__ import annotations

import atexit
import json
import re
import resource
import shutil
import signal
import tempfile
from collections.abc import Callable
from contextlib import contextmanager
from functools import cache
from pathlib import Path

import numpy as np
import torch
from hypothesis import strategies as st

from jsrte.errors import JsrteError

CASE_SECONDS = 30
"""A case running longer than this counts as a hang."""
CASE_MEMORY = 4 << 30
"""Bytes of address space a case may add; an allocation beyond fails (a file of a few kB once
made Open3D fill 22 GB before the kernel killed the test process)."""
ODD_TOKENS = ("nan", "-nan", "inf", "-inf", "-1", "0", "1e308", "-1e308", "1e-320", "99999999999999999999",
              "abc", "", "0x10", "3.5", "-0")


# --- valid files ---------------------------------------------------------------------------------


@cache
def originals() -> dict[str, Path]:
    """One small valid file of every format (made once per process), by format name."""
    import open3d as o3d
    import trimesh

    from analytic import octahedron_model
    from jsrte.atomic import write_json_atomic
    from jsrte.codec.format import ShapeCode, encode
    from jsrte.fit.query import SdfQuery, save_query
    from jsrte.geometry.sim3 import Sim3
    from jsrte.model.checkpoint import file_hash, save_model
    from jsrte.result import FitResult
    from jsrte.sdf.mesh_sdf import SdfSamples

    root = Path(tempfile.mkdtemp(prefix="jsrte-fuzz-originals-"))
    atexit.register(shutil.rmtree, root, ignore_errors=True)
    rng = np.random.default_rng(0)
    points = rng.uniform(-0.5, 0.5, (60, 3))
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
    cloud.normals = o3d.utility.Vector3dVector(points / np.linalg.norm(points, axis=1, keepdims=True))
    paths = {}
    for name, file, ascii in (("ply-binary", "cloud.ply", False), ("ply-ascii", "cloud_ascii.ply", True),
                              ("pcd-binary", "cloud.pcd", False), ("pcd-ascii", "cloud_ascii.pcd", True),
                              ("xyz", "cloud.xyz", True)):
        paths[name] = root / file
        o3d.io.write_point_cloud(str(paths[name]), cloud, write_ascii=ascii)
    mesh = trimesh.creation.icosphere(subdivisions=1, radius=0.4)
    for name, file in (("obj", "mesh.obj"), ("off", "mesh.off"), ("stl", "mesh.stl"), ("glb", "mesh.glb"),
                       ("ply-mesh", "mesh.ply")):
        paths[name] = root / file
        mesh.export(paths[name])
    paths["sample-npz"] = root / "samples.npz"
    SdfSamples(points.astype(np.float32), (np.linalg.norm(points, axis=1) - 0.3).astype(np.float32),
               np.zeros(3), 1.0).save(paths["sample-npz"])
    paths["query-npz"] = root / "query.npz"
    save_query(SdfQuery(points, np.linalg.norm(points, axis=1) - 0.3, points[:20], up=np.array([0.0, 1, 0]),
                        floor_offset=-0.5, info={"input": "test"}), paths["query-npz"])
    model = octahedron_model()
    paths["model"] = root / "model.safetensors"
    save_model(model, paths["model"])
    paths["train-state"] = root / "run" / "train_state.safetensors"
    _training_state(paths["train-state"].parent)
    paths["jsrte"] = root / "code.jsrte"
    transform = Sim3(1.5, Sim3.identity().R, np.array([0.5, 0.0, -1.0]))
    code = ShapeCode(np.linspace(-0.3, 0.3, 8).astype(np.float32), transform, "octa", bytes(16))
    paths["jsrte"].write_bytes(encode(code))
    fit_dir = root / "fit"
    fit_dir.mkdir()
    result = FitResult(method="jsrte", transform=transform, latent=np.zeros(8, np.float32), mesh_canonical=None,
                       loss=0.1, criterion={"name": "loss", "value": 0.1}, angles={"psi": 0, "rho": 0, "theta": 0},
                       hypotheses=[], timing={}, info={"model": "octa", "model_sha256": file_hash(paths["model"])})
    write_json_atomic(fit_dir / "fit.json", result.to_json())
    paths["fit-json"] = fit_dir / "fit.json"
    return paths


def _training_state(run: Path) -> None:
    from jsrte.model.decoder import DecoderConfig
    from jsrte.model.train import Trainer, TrainingData, TrainSettings

    g = torch.Generator().manual_seed(0)
    pts = torch.rand(2, 100, 3, generator=g) * 2 - 1
    data = TrainingData(pts, pts.norm(dim=-1) - 0.5, {"source": "test"})
    settings = TrainSettings(steps=2, shapes_per_batch=2, points_per_shape=32, checkpoint_every=2)
    Trainer(DecoderConfig(latent_size=4, hidden=8, depth=2, skip_layer=1), settings, data, run, {}).run(
        progress=False)


# --- readers and what their results must satisfy ---------------------------------------------------


def _scan(path: Path) -> None:
    from jsrte.scans.io import load_scan

    cloud = load_scan(path, dense_points=200)
    assert cloud.points.ndim == 2 and cloud.points.shape[1] == 3 and len(cloud.points) > 0
    assert np.isfinite(cloud.points).all()
    assert cloud.normals is None or (cloud.normals.shape == cloud.points.shape and np.isfinite(cloud.normals).all())


def _mesh(path: Path) -> None:
    from jsrte.geometry.mesh import load_mesh

    mesh = load_mesh(path)
    assert np.isfinite(mesh.vertices).all() and len(mesh.faces) > 0
    assert mesh.faces.min() >= 0 and mesh.faces.max() < len(mesh.vertices)


def _samples(path: Path) -> None:
    from jsrte.sdf.mesh_sdf import SdfSamples

    s = SdfSamples.load(path)
    assert s.points.shape == (len(s.sdf), 3) and np.isfinite(s.points).all() and np.isfinite(s.sdf).all()
    assert np.isfinite(s.centre).all() and s.scale > 0


def _query(path: Path) -> None:
    from jsrte.fit.query import load_query

    q = load_query(path, rng=np.random.default_rng(0))
    assert q.points.shape == (len(q.sdf), 3) and np.isfinite(q.points).all() and np.isfinite(q.sdf).all()


def _code(path: Path) -> None:
    from jsrte.codec.convert import read_code

    code = read_code(path)
    assert np.isfinite(code.latent).all() and code.transform.s > 0


def _model(path: Path) -> None:
    from jsrte.model.checkpoint import load_model

    model = load_model(path)
    assert all(torch.isfinite(t).all() for t in model.decoder.state_dict().values())
    assert torch.isfinite(model.codes).all()


def _train_state(path: Path) -> None:
    from jsrte.model.decoder import DecoderConfig
    from jsrte.model.train import Trainer, TrainingData, TrainSettings

    g = torch.Generator().manual_seed(0)
    pts = torch.rand(2, 100, 3, generator=g) * 2 - 1
    data = TrainingData(pts, pts.norm(dim=-1) - 0.5, {"source": "test"})
    settings = TrainSettings(steps=2, shapes_per_batch=2, points_per_shape=32, checkpoint_every=2)
    trainer = Trainer(DecoderConfig(latent_size=4, hidden=8, depth=2, skip_layer=1), settings, data, path.parent,
                      {})
    trainer.load_checkpoint()
    assert trainer.step >= 0


def _fit_json(path: Path) -> None:
    from jsrte.codec.convert import code_from_fit_dir

    code = code_from_fit_dir(path.parent)
    assert np.isfinite(code.latent).all() and code.transform.s > 0


READERS: dict[str, Callable[[Path], None]] = {
    "ply-binary": _scan, "ply-ascii": _scan, "pcd-binary": _scan, "pcd-ascii": _scan, "xyz": _scan,
    "obj": _mesh, "off": _mesh, "stl": _mesh, "glb": _mesh, "ply-mesh": _mesh,
    "sample-npz": _samples, "query-npz": _query, "jsrte": _code, "model": _model, "train-state": _train_state,
    "fit-json": _fit_json,
}
"""Format -> the reader of files of that format, checking its result."""
TEXT_FORMATS = frozenset({"ply-ascii", "pcd-ascii", "xyz", "obj", "off", "fit-json"})


# --- mutations ---------------------------------------------------------------------------------------


def mutations(fmt: str) -> st.SearchStrategy:
    """A list of 1 to 4 edits of a file: (kind, position in [0, 1), a byte or a token)."""
    kinds = ["truncate", "flip", "insert", "delete", "zero-tail"] + (["token"] * 3 if fmt in TEXT_FORMATS else [])
    edit = st.tuples(st.sampled_from(kinds), st.floats(0.0, 0.999), st.integers(0, 255),
                     st.sampled_from(ODD_TOKENS))
    return st.lists(edit, min_size=1, max_size=4)


def mutate(data: bytes, edits: list[tuple[str, float, int, str]]) -> bytes:
    """``data`` with ``edits`` applied in turn."""
    out = bytearray(data)
    for kind, where, byte, token in edits:
        at = int(where * len(out)) if out else 0
        if kind == "truncate":
            del out[at:]
        elif kind == "flip" and out:
            out[at] ^= byte or 1
        elif kind == "insert":
            out[at:at] = bytes([byte]) * (1 + byte % 7)
        elif kind == "delete":
            del out[at:at + 1 + byte % 13]
        elif kind == "zero-tail":
            out[at:] = bytes(len(out) - at)
        elif kind == "token":
            out = bytearray(_replace_token(bytes(out), where, token))
    return bytes(out)


def _replace_token(data: bytes, where: float, token: str) -> bytes:
    tokens = list(re.finditer(rb"[^\s,\[\]{}:\"]+", data))
    if not tokens:
        return data
    m = tokens[int(where * len(tokens))]
    return data[:m.start()] + token.encode() + data[m.end():]


# --- one case --------------------------------------------------------------------------------------


@contextmanager
def _time_limit(seconds: int):
    def hang(signum, frame):  # noqa: ANN001
        raise TimeoutError(f"no answer within {seconds} s")

    previous = signal.signal(signal.SIGALRM, hang)
    signal.alarm(seconds)
    try:
        yield
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, previous)


@contextmanager
def _memory_limit(extra: int):
    """Address space capped at its current size plus ``extra`` bytes (Linux; no cap elsewhere)."""
    try:
        with open("/proc/self/statm") as f:
            used = int(f.read().split()[0]) * resource.getpagesize()
    except OSError:
        yield
        return
    previous = resource.getrlimit(resource.RLIMIT_AS)
    cap = used + extra if previous[0] == resource.RLIM_INFINITY else min(previous[0], used + extra)
    resource.setrlimit(resource.RLIMIT_AS, (cap, previous[1]))
    try:
        yield
    finally:
        resource.setrlimit(resource.RLIMIT_AS, previous)


def run_case(fmt: str, data: bytes) -> str:
    """Read ``data`` as a file of ``fmt``: "result" or "error" (a JsrteError). Anything else (another
    exception, a hang, a result failing its checks) raises AssertionError naming the case."""
    source = originals()[fmt]
    work = Path(tempfile.mkdtemp(prefix="jsrte-fuzz-"))
    try:
        if fmt == "train-state":
            path = work / source.name
        elif fmt == "fit-json":
            path = work / "fit" / source.name
            path.parent.mkdir()
        else:
            path = work / source.name
        path.write_bytes(data)
        if fmt == "model":  # the readable description beside it, as save_model writes it
            shutil.copy(source.with_suffix(".json"), path.with_suffix(".json"))
        try:
            with _time_limit(CASE_SECONDS), _memory_limit(CASE_MEMORY):
                READERS[fmt](path)
        except JsrteError as exc:
            assert "\n" not in str(exc) and str(exc), f"{fmt}: a JsrteError must be one non-empty line"
            assert "bad_alloc" not in str(exc), f"{fmt}: over {CASE_MEMORY >> 30} GB allocated for {data[:200]!r}"
            return "error"
        except AssertionError as exc:
            raise AssertionError(f"{fmt}: a wrong result was returned ({exc}) for {data[:200]!r}") from None
        except Exception as exc:
            raise AssertionError(f"{fmt}: {type(exc).__name__}: {exc} for {data[:200]!r}") from exc
        return "result"
    finally:
        shutil.rmtree(work, ignore_errors=True)


def original_bytes(fmt: str) -> bytes:
    return originals()[fmt].read_bytes()


def summary_line(fmt: str, counts: dict[str, int]) -> str:
    return json.dumps({"format": fmt, **counts})
