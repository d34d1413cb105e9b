"""Decoder, auto-decoder training, checkpoints, resume after a kill, mesh extraction."""

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import torch
import trimesh
from safetensors.torch import load_file

from jsrte.errors import JsrteError
from jsrte.metrics.surface import fscore
from jsrte.model.checkpoint import DeepSdfModel, load_model, read_metadata, save_model
from jsrte.model.config import PREVIOUS_STATE_NAME
from jsrte.model.decoder import ARCHITECTURES, Decoder, DecoderConfig
from jsrte.model.meshing import decode_mesh
from jsrte.model.train import STATE_NAME, Trainer, TrainingData, TrainSettings, batch_indices
from jsrte.presets import SdfSampling
from jsrte.sdf.mesh_sdf import sample_sdf

TINY = DecoderConfig(latent_size=8, hidden=64, depth=4, skip_layer=2)
JSRTE = [sys.executable, "-m", "jsrte.cli.__main__"]


@pytest.fixture(scope="module")
def analytic_shapes():
    sphere = trimesh.creation.icosphere(subdivisions=4, radius=0.6)
    box = trimesh.creation.box(extents=(1.0, 0.5, 0.7))
    rng = np.random.default_rng(0)
    settings = SdfSampling(n_points=30_000)
    return [sphere, box], [sample_sdf(m, rng=rng, settings=settings) for m in (sphere, box)]


@pytest.mark.parametrize("name", list(ARCHITECTURES))
def test_architectures_run_and_keep_deepsdf_layout(name):
    config = ARCHITECTURES[name]
    decoder = Decoder(config).eval()
    out = decoder(torch.rand(10, 3) - 0.5, torch.zeros(config.latent_size))
    assert out.shape == (10,) and torch.all(out.abs() <= 1)
    skip_in = decoder.layers[config.skip_layer]
    assert skip_in.weight.shape[1] == config.hidden  # DeepSDF: the skip restores the width


def test_tiny_decoder_learns_sphere_and_box(analytic_shapes, tmp_path):
    meshes, samples = analytic_shapes
    torch.set_num_threads(2)
    data = TrainingData.from_samples(samples, {"source": "test"})
    settings = TrainSettings(steps=500, shapes_per_batch=2, points_per_shape=2048, lr_net=2e-3,
                             lr_codes=1e-2, checkpoint_every=500)
    model = Trainer(TINY, settings, data, tmp_path, {"name": "toy"}).run(progress=False)
    for i, truth in enumerate(meshes):
        norm_truth = truth.copy()
        norm_truth.vertices = (truth.vertices - samples[i].centre) / samples[i].scale
        mesh = decode_mesh(model.decoder, model.codes[i], resolution=64).mesh
        assert mesh is not None
        # 20k points: with 3000, two samplings of one sphere already score only ~0.85 at 5%
        f = fscore(mesh, norm_truth, n_points=20_000, rng=np.random.default_rng(0))
        assert f.fscore > 0.9, f"shape {i}: {f}"


def test_checkpoint_round_trip_and_bad_files(tmp_path):
    model = DeepSdfModel(Decoder(TINY), torch.randn(3, 8), {"name": "toy", "category": "chair"})
    path = tmp_path / "m.safetensors"
    save_model(model, path)
    back = load_model(path)
    x = torch.rand(20, 3)
    torch.testing.assert_close(back.decoder(x, back.codes[1]), model.decoder.eval()(x, model.codes[1]))
    torch.testing.assert_close(back.codes, model.codes)
    assert back.meta["category"] == "chair" and back.meta["architecture"] == TINY.to_dict()
    assert json.loads((tmp_path / "m.json").read_text())["sha256"] == back.meta["sha256"]
    umask = os.umask(0)
    os.umask(umask)
    assert path.stat().st_mode & 0o777 == 0o666 & ~umask  # readable by others as any file (not 0600)
    with pytest.raises(JsrteError, match="does not match the expected"):
        load_model(path, expect=ARCHITECTURES["cpu"])
    corrupt = tmp_path / "corrupt.safetensors"
    corrupt.write_bytes(path.read_bytes()[:200])
    with pytest.raises(JsrteError, match="corrupt.safetensors"):
        load_model(corrupt)
    tensors = load_file(str(path))
    del tensors["latent_codes"]
    from safetensors.torch import save_file

    missing = tmp_path / "missing.safetensors"
    save_file(tensors, str(missing), metadata={"jsrte": json.dumps(read_metadata(path))})
    with pytest.raises(JsrteError, match="latent_codes"):
        load_model(missing)


def test_batches_depend_only_on_seed_and_step():
    s = TrainSettings(shapes_per_batch=3, points_per_shape=5, seed=4)
    a = batch_indices(s, 7, 100, 11)
    b = batch_indices(s, 7, 100, 11)
    assert torch.equal(a[0], b[0]) and torch.equal(a[1], b[1])
    epoch = torch.cat([batch_indices(s, 6, 100, k)[0] for k in range(2)])
    assert sorted(epoch.tolist()) == list(range(6))  # each shape once per epoch


def test_a_model_file_that_vanishes_while_opened_is_reported_missing(tmp_path, monkeypatch):
    # a training run moves its state aside before writing the next one: a reader can see the
    # file in one instant and not in the next
    path = tmp_path / "train_state.safetensors"
    answers = iter([True])  # there at the check, gone at the open and after
    monkeypatch.setattr(Path, "is_file", lambda self: next(answers, False))
    with pytest.raises(JsrteError, match="no such model file"):
        read_metadata(path)


def _train_cmd(out: Path, steps: int) -> list[str]:
    return JSRTE + ["train", "--category", "chair", "--shapes", "3", "--samples", "4000", "--steps", str(steps),
                    "--batch-shapes", "2", "--points", "256", "--checkpoint-every", "10", "--threads", "1",
                    "--out", str(out), "--no-progress"]


def _state_step(out: Path, name: str = STATE_NAME) -> int:
    try:
        return int(read_metadata(out / name)["step"])
    except (JsrteError, KeyError, ValueError):
        return -1


def test_resume_after_kill_matches_uninterrupted_run(tmp_path):
    steps = 400
    env = dict(os.environ, OMP_NUM_THREADS="1")
    reference = tmp_path / "reference"
    subprocess.run(_train_cmd(reference, steps), check=True, env=env, capture_output=True)
    killed = tmp_path / "killed"
    proc = subprocess.Popen(_train_cmd(killed, steps), env=env, stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL, process_group=0)
    deadline = time.time() + 240
    while _state_step(killed) < 30 and time.time() < deadline and proc.poll() is None:
        time.sleep(0.05)
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait()
    # killed between moving the last state aside and writing the next: resume takes the previous
    at_kill = max(_state_step(killed), _state_step(killed, PREVIOUS_STATE_NAME))
    assert 0 < at_kill < steps, "the run must be killed mid-way"
    subprocess.run(_train_cmd(killed, steps) + ["--resume"], check=True, env=env, capture_output=True)
    a, b = load_file(str(reference / "model.safetensors")), load_file(str(killed / "model.safetensors"))
    assert a.keys() == b.keys()
    for key in a:
        torch.testing.assert_close(a[key], b[key], rtol=0, atol=1e-6)
    log = (killed / "train_log.csv").read_text().splitlines()
    assert len(log) == steps + 1  # no duplicated rows from the killed part


def test_train_refuses_existing_run_and_bad_arch(tmp_path):
    out = tmp_path / "run"
    subprocess.run(_train_cmd(out, 10), check=True, capture_output=True)
    again = subprocess.run(_train_cmd(out, 10), capture_output=True, text=True)
    assert again.returncode == 2 and "--resume" in again.stderr
    bad = subprocess.run(JSRTE + ["train", "--arch", "nope", "--out", str(tmp_path / "x")],
                         capture_output=True, text=True)
    assert bad.returncode == 2 and "deepsdf" in bad.stderr and not (tmp_path / "x").exists()


def test_evaluate_model_scores_both_sets_and_never_overwrites_without_asking(tmp_path, run_cli):
    from analytic import octahedron_model

    model_path = tmp_path / "octa.safetensors"
    save_model(octahedron_model(data={"source": "procedural", "category": "chair", "set_seed": 0}), model_path)
    report = tmp_path / "eval.json"
    args = ["evaluate-model", "--model", str(model_path), "--n-train", "1", "--n-heldout", "1",
            "--resolution", "24", "--threads", "1", "--out", str(report)]
    code, stdout, stderr = run_cli(args)
    assert code == 0, stderr
    written = json.loads(report.read_text())
    assert written["summary"]["train_count"] == 1 and written["summary"]["heldout_count"] == 1
    assert 0.0 < written["rows"][0]["fscore"] < 1.0  # an octahedron is some way from any chair
    assert json.loads(stdout) == written["summary"]

    report.write_text("mine")
    code, _, stderr = run_cli(args)
    assert code != 0 and "--overwrite" in stderr and report.read_text() == "mine"
    code, _, stderr = run_cli([*args[:-2], "--out", str(tmp_path)])
    assert code != 0 and "is a folder" in stderr
    code, _, stderr = run_cli([*args, "--n-heldout", "0", "--overwrite"])
    assert code == 0, stderr
    assert json.loads(report.read_text())["rows"] == written["rows"][:1]


def test_denormals_are_flushed_inside_the_block_and_as_before_after_it():
    from jsrte.model.decoder import denormals_flushed, flushing_denormals

    if not torch.set_flush_denormal(False) or flushing_denormals():
        pytest.skip("this CPU cannot flush denormals")
    with denormals_flushed():
        assert flushing_denormals()
        assert (torch.tensor([1e-38, 1.0]) * 0.1).tolist() == [0.0, pytest.approx(0.1)]  # 1e-39: flushed
    assert not flushing_denormals()
    assert (torch.tensor([1e-38]) * 0.1).item() > 0
    torch.set_flush_denormal(True)
    try:
        with denormals_flushed():
            pass
        assert flushing_denormals()  # a caller's own setting is left as it was
    finally:
        torch.set_flush_denormal(False)
