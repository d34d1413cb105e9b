"""Bad input, odd paths, damaged files and stopped runs: each ends in one clean line (or a result).

Every test here reproduces a defect met by trying the commands as a careful user would; the
checks run before any heavy work, so the tests are fast.
"""

from __future__ import annotations

import inspect
import json
import struct
import sys
import zlib

import numpy as np
import open3d as o3d
import pytest
import torch
import trimesh

import jsrte
from analytic import octahedron_model, octahedron_query
from jsrte.errors import JsrteError

# --- the Python API ---------------------------------------------------------------------------


def test_jsrte_fit_stays_the_function_after_the_subpackage_is_imported():
    import jsrte.fit.solve  # noqa: F401
    from jsrte.fit import fit_query  # noqa: F401  (imports the subpackage jsrte.fit)

    assert inspect.isfunction(jsrte.fit)
    model, query = octahedron_model(), octahedron_query()
    first = jsrte.fit(query, model=model, preset="smoke", hypotheses=1)
    second = jsrte.fit(query, model=model, preset="smoke", hypotheses=1)
    assert first.transform.s > 0 and second.transform.s == pytest.approx(first.transform.s)
    assert sys.modules["jsrte.fit"].fit is not jsrte.fit  # the subpackage is still importable as a module


def test_jsrte_fit_shows_the_real_signature():
    real = inspect.signature(sys.modules["jsrte.fit"].fit)
    assert inspect.signature(jsrte.fit) == real
    assert "query" in real.parameters and "options" in real.parameters
    for line in (jsrte.__doc__ or "").split():
        if line.startswith("docs/"):  # every page the package docstring names exists
            from pathlib import Path

            assert (Path(__file__).parents[1] / line.strip("`.,;()")).is_file(), line


# --- damaged scan files ---------------------------------------------------------------------------


def write_cloud(path, n: int = 2000, ascii: bool = False, seed: int = 0) -> np.ndarray:
    points = np.random.default_rng(seed).uniform(-0.5, 0.5, (n, 3))
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
    assert o3d.io.write_point_cloud(str(path), cloud, write_ascii=ascii)
    return points


@pytest.mark.parametrize("name,ascii", [("scan.ply", False), ("scan.ply", True), ("scan.pcd", False),
                                        ("scan.pcd", True)])
def test_a_truncated_point_cloud_is_refused(tmp_path, name, ascii):
    from jsrte.scans.io import load_scan

    path = tmp_path / name
    points = write_cloud(path, ascii=ascii)
    np.testing.assert_allclose(load_scan(path).points, points, atol=1e-5 if ascii else 0)
    data = path.read_bytes()
    path.write_bytes(data[: len(data) * 2 // 3])
    with pytest.raises(JsrteError, match=rf"{name}: truncated"):
        load_scan(path)


@pytest.mark.parametrize("up", [[], ["--up", "0,1,0"]])
def test_cli_fit_of_a_truncated_binary_ply_is_one_line(tmp_path, run_cli, up):
    scan = tmp_path / "cut.ply"
    write_cloud(scan, n=5000)
    scan.write_bytes(scan.read_bytes()[:-7000])
    code, _, err = run_cli(["fit", scan, "--out", tmp_path / "out", "--preset", "smoke", "--threads", "1",
                            "--no-progress", *up])
    assert code == 2 and err.count("\n") == 1 and "cut.ply: truncated" in err
    assert not (tmp_path / "out").exists()


def test_a_folder_given_as_a_scan_or_a_code_says_so(tmp_path, run_cli):
    folder = tmp_path / "scans.ply"
    folder.mkdir()
    code, _, err = run_cli(["fit", folder, "--out", tmp_path / "out"])
    assert code == 2 and "is a folder" in err and "unsupported" not in err
    code, _, err = run_cli(["decode", folder, "--out", tmp_path / "m.ply"])
    assert code == 2 and "is a folder" in err and "no such" not in err


# --- --out and other options, before any work ----------------------------------------------------


def _commands(tmp_path, out):
    """Each writing command with ``out`` as its --out (inputs that exist, where it reads one first);
    a file output gets its suffix when ``out`` lies under the blocking file."""
    scan = tmp_path / "scan.ply"
    if not scan.exists():
        write_cloud(scan, n=200)
    mesh = tmp_path / "box.obj"
    trimesh.creation.box().export(mesh)

    def file(suffix):
        return out if out.name == "blocker" else out.with_suffix(suffix)

    return {
        "fit": ["fit", scan, "--out", out],
        "prepare": ["prepare", scan, "--out", file(".npz")],
        "reconstruct": ["reconstruct", mesh, "--out", out],
        "encode": ["encode", scan, "--out", file(".jsrte")],
        "decode": ["decode", scan, "--out", file(".ply")],
        "sample": ["sample", mesh, "--out", file(".npz")],
        "scan": ["scan", mesh, "--out", file(".ply")],
        "fit-many": ["fit-many", tmp_path, "--out", out],
        "train": ["train", "--out", out, "--shapes", "1"],
        "demo": ["demo", "--out", out],
        "dataset": ["dataset", tmp_path, "--out", out],
        "shapes": ["shapes", "--category", "chair", "--n", "1", "--out", out],
        "baseline": ["baseline", "fpfh-ransac-icp", scan, "--out", out],
        "evaluate-model": ["evaluate-model", "--out", file(".json")],
        "experiment synthetic": ["experiment", "synthetic", "--out", out],
        "experiment compression": ["experiment", "compression", "--out", out],
        "experiment scans": ["experiment", "scans", "--out", out],
    }


@pytest.mark.parametrize("where", ["under a file", "is a file"])
def test_every_command_checks_out_before_working(tmp_path, run_cli, where):
    blocker = tmp_path / "blocker"
    blocker.write_text("a user's file\n")
    out = blocker / "results" if where == "under a file" else blocker
    for name, args in _commands(tmp_path, out).items():
        code, stdout, err = run_cli(args)
        assert code == 2, (name, stdout, err)
        assert err.count("\n") == 1 and "Traceback" not in err, (name, err)
        assert "blocker" in err, (name, err)
    assert blocker.read_text() == "a user's file\n"


@pytest.mark.parametrize("command", [["fit", "SCAN", "--out", "OUT"], ["decode", "SCAN", "--out", "OUT.ply"],
                                     ["train", "--out", "OUT"], ["reconstruct", "SCAN", "--out", "OUT"],
                                     ["demo", "--out", "OUT"], ["encode", "SCAN", "--out", "OUT.jsrte"],
                                     ["fit-many", "TMP", "--out", "OUT", "--workers"]])
def test_negative_threads_is_one_line(tmp_path, run_cli, command):
    scan = tmp_path / "scan.ply"
    write_cloud(scan, n=200)
    args = [str(a).replace("SCAN", str(scan)).replace("OUT", str(tmp_path / "out")).replace("TMP", str(tmp_path))
            for a in command]
    code, _, err = run_cli([*args, "-3"] if args[-1] == "--workers" else [*args, "--threads", "-3"])
    assert code == 2 and err.count("\n") == 1 and "-3" in err, err
    assert not (tmp_path / "out").exists()


def test_train_with_zero_steps_is_refused(tmp_path, run_cli):
    code, out, err = run_cli(["train", "--out", tmp_path / "run", "--steps", "0"])
    assert code == 2 and "--steps must be positive" in err and "wrote" not in out
    assert not (tmp_path / "run").exists()


def test_help_wraps_to_the_terminal_width(run_cli, monkeypatch):
    monkeypatch.setenv("COLUMNS", "80")
    code, out, _ = run_cli(["fit", "--help"])
    assert code == 0
    assert max(len(line) for line in out.splitlines()) <= 80
    assert "Output folder (fit.json, shape.ply," in out  # not squeezed into a 20-character column
    assert "--no-units-check" in out
    for command in ("reconstruct", "demo"):
        code, out, _ = run_cli([command, "--help"])
        assert "--threads" in out
    code, out, _ = run_cli(["reconstruct", "--help"])
    assert "--no-progress" in out


# --- models with NaN or altered weights ------------------------------------------------------------


def tiny_training(tmp_path, **settings):
    from jsrte.model.decoder import DecoderConfig
    from jsrte.model.train import Trainer, TrainingData, TrainSettings

    g = torch.Generator().manual_seed(0)
    points = torch.rand(2, 400, 3, generator=g) * 2 - 1
    data = TrainingData(points, points.norm(dim=-1) - 0.5, {"source": "test"})
    config = DecoderConfig(latent_size=4, hidden=16, depth=2, skip_layer=1)
    values = {"steps": 6, "shapes_per_batch": 2, "points_per_shape": 64, "checkpoint_every": 2} | settings
    return Trainer(config, TrainSettings(**values), data, tmp_path / "run", {"name": "tiny"})


def test_a_diverging_training_stops_and_writes_no_nan_model(tmp_path):
    from jsrte.model.checkpoint import load_model
    from jsrte.model.train import MODEL_NAME

    trainer = tiny_training(tmp_path, lr_net=1e30, lr_codes=1e30, checkpoint_every=1)
    with pytest.raises(JsrteError, match="training diverged: the loss is (nan|inf)"):
        trainer.run(progress=False)
    model = tmp_path / "run" / MODEL_NAME
    if model.exists():  # a checkpoint before the divergence is a usable, finite model
        assert all(torch.isfinite(t).all() for t in load_model(model).decoder.state_dict().values())


def test_saving_or_loading_a_nan_model_is_refused(tmp_path):
    from safetensors.torch import save_file

    from jsrte.model.checkpoint import load_model, model_metadata, save_model, tensors_of

    model = octahedron_model()
    with torch.no_grad():
        model.decoder.head.bias.fill_(float("nan"))
    with pytest.raises(JsrteError, match="NaN or infinite"):
        save_model(model, tmp_path / "nan.safetensors")
    assert not list(tmp_path.iterdir())
    save_file(tensors_of(model), str(tmp_path / "nan.safetensors"),
              metadata={"jsrte": json.dumps(model_metadata(model))})
    with pytest.raises(JsrteError, match=r"nan.safetensors: holds NaN or infinite values"):
        load_model(tmp_path / "nan.safetensors")


def test_altered_weights_are_detected_by_the_recorded_sha256(tmp_path):
    from jsrte.model.checkpoint import load_model, save_model

    path = tmp_path / "m.safetensors"
    save_model(octahedron_model(), path)
    assert load_model(path).meta["sha256"] == json.loads(path.with_suffix(".json").read_text())["sha256"]
    data = bytearray(path.read_bytes())
    data[-3] ^= 0x01  # the last weight's lowest byte: still a finite float, still a valid file
    path.write_bytes(bytes(data))
    with pytest.raises(JsrteError, match="m.safetensors: the file's SHA-256 .* differs .* altered"):
        load_model(path)


def test_fitting_a_model_that_gives_nan_is_a_clean_error():
    from jsrte.fit.solve import fit_query
    from jsrte.presets import get_preset

    model = octahedron_model()
    with torch.no_grad():
        model.decoder.head.bias.fill_(float("nan"))
    with pytest.raises(JsrteError, match="the fit diverged"):
        fit_query(model, octahedron_query(), get_preset("smoke").fit, n_hypotheses=2)


# --- training runs: damaged state, Ctrl-C, progress ------------------------------------------------


def test_resume_falls_back_to_the_previous_checkpoint_then_says_what_to_delete(tmp_path):
    from jsrte.model.train import PREVIOUS_STATE_NAME, STATE_NAME

    straight = tiny_training(tmp_path / "a").run(progress=False)
    first = tiny_training(tmp_path)
    first.run(until=4, progress=False)  # checkpoints at steps 2 and 4
    state = tmp_path / "run" / STATE_NAME
    state.write_bytes(state.read_bytes()[:100])  # damaged
    resumed = tiny_training(tmp_path)
    resumed.load_checkpoint()
    assert resumed.step == 2 and resumed.resumed_from.name == PREVIOUS_STATE_NAME
    model = resumed.run(progress=False)
    for a, b in zip(model.decoder.state_dict().values(), straight.decoder.state_dict().values(), strict=True):
        assert torch.equal(a, b)  # the same model as an uninterrupted run
    for name in (STATE_NAME, PREVIOUS_STATE_NAME):
        (tmp_path / "run" / name).write_bytes(b"damaged")
    with pytest.raises(JsrteError, match=rf"cannot resume .*delete {STATE_NAME}, {PREVIOUS_STATE_NAME}"):
        tiny_training(tmp_path).load_checkpoint()


def test_a_damaged_cached_sample_file_says_to_delete_it(tmp_path):
    from jsrte.model.data import _cached_samples

    bad = tmp_path / "0123.npz"
    bad.write_bytes(b"PK\x03\x04 not really")
    with pytest.raises(JsrteError, match=r"0123.npz: .*delete it"):
        _cached_samples(bad)


def test_ctrl_c_in_train_says_how_to_resume(tmp_path, run_cli, monkeypatch):
    import jsrte.cli.train_cmd as train_cmd

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(train_cmd, "_train", interrupted)
    code, _, err = run_cli(["train", "--out", tmp_path / "run"])
    assert code == 130 and "stopped" in err


def test_train_no_progress_shows_no_bar(tmp_path, run_cli, monkeypatch):
    from jsrte.model import data as data_module

    seen = {}

    def fake_dataset(meshes, out_dir, **kwargs):
        seen.update(kwargs)
        raise JsrteError("stop here")

    monkeypatch.setattr(data_module, "build_sdf_dataset", fake_dataset)
    code, _, err = run_cli(["train", "--out", tmp_path / "run", "--shapes", "1", "--no-progress"])
    assert code == 2 and "stop here" in err and seen["progress"] is False


# --- units: the object, not the room ---------------------------------------------------------------


def test_units_check_uses_the_object_not_the_room():
    from jsrte.scans.io import ScanCloud
    from jsrte.scans.preprocess import PrepareSettings, prepare_scan
    from jsrte.scans.scanner import ScannerSettings, scan_mesh
    from jsrte.shapes import EVAL_SET_SEED, generate_shape, shape_seed

    chair = generate_shape("chair", shape_seed(EVAL_SET_SEED, 0)).mesh
    scan = scan_mesh(chair, rng=np.random.default_rng(0), settings=ScannerSettings(outlier_fraction=0.0))
    rng = np.random.default_rng(1)
    u = np.cross(scan.up, [1.0, 0.0, 0.0] if abs(scan.up[0]) < 0.9 else [0.0, 1.0, 0.0])
    u /= np.linalg.norm(u)
    v = np.cross(scan.up, u)
    centre = scan.points[scan.is_object].mean(0)
    centre = centre - (centre @ scan.up - scan.floor_offset) * scan.up
    a, b = rng.uniform(-7.5, 7.5, (2, 6000))
    room = centre + a[:, None] * u + b[:, None] * v  # 15 m of visible floor around the chair
    points = np.concatenate([scan.points, room])
    prepared = prepare_scan(ScanCloud(points), rng=np.random.default_rng(0))
    assert 0.5 < np.ptp(prepared.points, axis=0).max() < 2.0

    obj = scan.points[scan.is_object] * 20.0  # a 20 m "chair", no floor: refused, unless told
    with pytest.raises(JsrteError, match="no-units-check"):
        prepare_scan(ScanCloud(obj), rng=np.random.default_rng(0), up=scan.up)
    prepared = prepare_scan(ScanCloud(obj), rng=np.random.default_rng(0), up=scan.up,
                            settings=PrepareSettings(units_check=False))
    assert len(prepared.points) > 100


# --- shape codes with absurd values ------------------------------------------------------------------


@pytest.mark.parametrize("field,value", [("scale", 1e-30), ("scale", 1e30), ("translation", 1e30)])
def test_a_code_with_a_valid_crc_but_absurd_values_is_refused(field, value):
    from jsrte.codec.format import _PREFIX, ShapeCode, decode, encode
    from jsrte.geometry.sim3 import Sim3

    code = ShapeCode(np.zeros(8, np.float32), Sim3.identity(), "m", bytes(16))
    body = bytearray(encode(code)[:-4])
    at = _PREFIX.size + 1 + 16 + (0 if field == "scale" else 4 * 10)
    struct.pack_into("<f", body, at, value)
    data = bytes(body) + struct.pack("<I", zlib.crc32(bytes(body)))
    with pytest.raises(JsrteError, match=f"c.jsrte: corrupt shape code: {field}"):
        decode(data, source="c.jsrte")


# --- procedural shapes are watertight ----------------------------------------------------------------


@pytest.mark.parametrize("category,set_seed,index", [
    ("chair", 3, 1), ("chair", 3, 2),  # arms meeting round back posts along a line
    ("sofa", 0, 3),  # an arm post flush with the armrest
    ("table", 1, 112),  # a side panel flush with the top
    ("sofa", 1, 129),  # cushions enclosing a pocket of air (was: "2 bodies")
])
def test_procedural_meshes_are_watertight_once_read_back(tmp_path, category, set_seed, index):
    from jsrte.shapes import generate_shape, shape_seed, write_shape

    path = write_shape(generate_shape(category, shape_seed(set_seed, index)), tmp_path, index)
    mesh = trimesh.load(path, force="mesh")  # vertices merged, as every reader does
    _, counts = np.unique(np.sort(mesh.edges, axis=1), axis=0, return_counts=True)
    assert counts.max() == 2 and mesh.is_watertight


def test_cli_resume_of_a_damaged_state_says_what_to_delete_before_sampling(tmp_path, run_cli):
    from jsrte.model.train import STATE_NAME

    run = tmp_path / "run"
    run.mkdir()
    (run / STATE_NAME).write_bytes(b"\x08\x00\x00\x00\x00\x00\x00\x00{}damaged")
    code, _, err = run_cli(["train", "--out", run, "--resume"])
    assert code == 2 and err.count("\n") == 1 and f"delete {STATE_NAME}" in err
    assert not (run / "data").exists()  # refused before sampling the shapes
    code, _, err = run_cli(["train", "--out", run])
    assert code == 2 and "--resume" in err
