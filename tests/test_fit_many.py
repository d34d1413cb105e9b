"""``jsrte fit-many``: a folder of virtual scans with a corrupt one, resume, list files, Ray.

The model is tiny and the ``smoke`` preset with two hypotheses keeps every fit under a
second once a worker has imported PyTorch; most of the time here is worker start-up.
"""

import csv
import json
import os
import socket
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from jsrte.batch import COLUMNS, SUMMARY_NAME, find_truth, fit_many, list_scans, result_names
from jsrte.errors import JsrteError
from jsrte.geometry.mesh import save_mesh
from jsrte.model.checkpoint import save_model
from jsrte.model.data import procedural_training_data
from jsrte.model.decoder import DecoderConfig
from jsrte.model.train import Trainer, TrainSettings
from jsrte.options import FitOptions
from jsrte.presets import SdfSampling
from jsrte.scans import ScannerSettings, scan_mesh, write_scan
from jsrte.shapes import EVAL_SET_SEED, generate_shape, shape_seed

JSRTE = [sys.executable, "-m", "jsrte.cli"]
FAST = {"options": FitOptions(preset="smoke", hypotheses=2), "progress": False}
TINY = DecoderConfig(latent_size=8, hidden=32, depth=4, skip_layer=2)
SCANNER = ScannerSettings(views=2, width=64, height=48)


@pytest.fixture(scope="module")
def model_file(tmp_path_factory):
    work = tmp_path_factory.mktemp("model")
    torch.set_num_threads(1)
    data = procedural_training_data("chair", 2, work / "data", settings=SdfSampling(n_points=3000), workers=1)
    settings = TrainSettings(steps=30, shapes_per_batch=2, points_per_shape=256, checkpoint_every=30)
    model = Trainer(TINY, settings, data, work / "run", {"name": "tiny-chair", "category": "chair"}).run(
        progress=False)
    path = work / "tiny.safetensors"
    save_model(model, path)
    return path


@pytest.fixture(scope="module")
def scan_pool(tmp_path_factory):
    """Three virtual scans of held-out chairs (PLY + JSON naming the true mesh) and a corrupt PLY."""
    root = tmp_path_factory.mktemp("scans")
    scans = []
    for i in range(3):
        shape = generate_shape("chair", shape_seed(EVAL_SET_SEED, i))
        mesh_path = root / "meshes" / f"chair_{i}.obj"
        mesh_path.parent.mkdir(exist_ok=True)
        save_mesh(shape.mesh, mesh_path)
        scan = scan_mesh(shape.mesh, rng=np.random.default_rng(i), settings=SCANNER)
        scans.append(write_scan(scan, root / f"chair_{i}.ply", seed=i, mesh=mesh_path))
    corrupt = root / "corrupt.ply"
    corrupt.write_bytes(b"ply\nformat binary_little_endian 1.0\nelement vertex 1000\n" + os.urandom(200))
    return scans, corrupt


def _copy_scan(scan: Path, folder: Path) -> None:
    folder.mkdir(exist_ok=True)
    for path in (scan, scan.with_suffix(".json")):
        (folder / path.name).write_bytes(path.read_bytes())


def _summary(out: Path) -> dict[str, dict]:
    with open(out / SUMMARY_NAME, newline="") as f:
        reader = csv.DictReader(f)
        assert tuple(reader.fieldnames) == COLUMNS
        return {Path(r["scan"]).name: r for r in reader}


@pytest.fixture(scope="module")
def first_run(model_file, scan_pool, tmp_path_factory):
    """fit-many on two scans, a corrupt one and a file that is no scan, on two local workers."""
    scans, corrupt = scan_pool
    root = tmp_path_factory.mktemp("run")
    folder, out = root / "scans", root / "out"
    for scan in scans[:2]:
        _copy_scan(scan, folder)
    (folder / corrupt.name).write_bytes(corrupt.read_bytes())
    (folder / "notes.md").write_text("not a scan")
    report = fit_many(folder, out=out, model=model_file, workers=2, **FAST)
    return folder, out, report


def test_a_corrupt_scan_fails_alone(first_run):
    folder, out, report = first_run
    assert (report.fitted, report.skipped, report.failed) == (2, 0, 1)
    rows = _summary(out)
    assert set(rows) == {"chair_0.ply", "chair_1.ply", "corrupt.ply"}
    assert rows["corrupt.ply"]["status"] == "failed" and "corrupt.ply" in rows["corrupt.ply"]["error"]
    assert not (out / "corrupt").exists()  # nothing written for a failure
    for stem in ("chair_0", "chair_1"):
        row = rows[f"{stem}.ply"]
        assert row["status"] == "ok" and row["error"] == ""
        assert 0.0 <= float(row["fscore"]) <= 1.0 and float(row["scale"]) > 0  # scored against the truth
        assert {p.name for p in (out / stem).iterdir()} >= {"fit.json", "overlay.png"}
        result = json.loads((out / stem / "fit.json").read_text())
        assert result["truth"]["fscore"] == pytest.approx(float(row["fscore"]), abs=1e-4)
        assert result["input"] == str(folder / f"{stem}.ply") and result["preset"] == "smoke"
        assert float(row["scale"]) == pytest.approx(result["scale"], rel=1e-4)
        assert row["flag"] == result["flag"] and row["flag"] in ("ok", "doubtful")
        assert float(row["inlier_share"]) == pytest.approx(result["quality"]["inlier_share"], abs=1e-4)


def test_a_rerun_fits_only_what_is_left(first_run, model_file, scan_pool):
    folder, out, _ = first_run
    stamps = {stem: (out / stem / "fit.json").stat().st_mtime_ns for stem in ("chair_0", "chair_1")}
    _copy_scan(scan_pool[0][2], folder)  # a scan arrives; the corrupt one is still there
    second = fit_many(folder, out=out, model=model_file, workers=1, **FAST)
    assert (second.fitted, second.skipped, second.failed) == (1, 2, 1)
    assert {stem: (out / stem / "fit.json").stat().st_mtime_ns for stem in stamps} == stamps  # not refitted
    rows = _summary(out)
    assert [rows[f"chair_{i}.ply"]["status"] for i in range(3)] == ["ok"] * 3
    assert rows["corrupt.ply"]["status"] == "failed"
    assert not list(out.glob(".*"))  # no lock or temporary file left behind


@pytest.mark.slow  # ~20 s of CPU: Ray's start-up and two Ray workers importing PyTorch
def test_cli_on_a_local_ray_cluster_from_a_list_file(first_run, model_file, scan_pool, tmp_path):
    pytest.importorskip("ray")
    scans, _ = scan_pool
    listing = tmp_path / "scans.txt"
    listing.write_text(f"# two scans and a missing one\n{scans[0]}\n\n{scans[1]}\nnowhere/missing.ply\n")
    out = tmp_path / "ray"
    cmd = JSRTE + ["fit-many", str(listing), "--model", str(model_file), "--preset", "smoke", "--hypotheses",
                   "2", "--no-progress", "--workers", "2", "--ray", "local", "--out", str(out)]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=600,
                          env=dict(os.environ, RAY_AUTH_MODE="disabled"))
    assert proc.returncode == 1, proc.stderr[-3000:]  # the missing scan failed
    assert "2 fitted now" in proc.stdout and "1 failed" in proc.stdout
    rows = _summary(out)
    assert rows["missing.ply"]["status"] == "failed" and "no such file" in rows["missing.ply"]["error"]
    local = _summary(first_run[1])
    for name in ("chair_0.ply", "chair_1.ply"):  # the same fit as on the local pool
        assert rows[name]["status"] == local[name]["status"] == "ok"
        assert rows[name]["scale"] == local[name]["scale"] and rows[name]["fscore"] == local[name]["fscore"]


def test_fit_many_without_ray_installed_says_how_to_get_it(model_file, scan_pool, tmp_path, monkeypatch):
    import builtins

    real_import = builtins.__import__

    def no_ray(name, *args, **kwargs):
        if name == "ray":
            raise ImportError("No module named 'ray'")
        return real_import(name, *args, **kwargs)

    monkeypatch.setattr(builtins, "__import__", no_ray)
    with pytest.raises(JsrteError, match=r"jsrte\[ray\]"):
        fit_many(scan_pool[0][0].parent, out=tmp_path / "out", model=model_file, ray_address="auto", **FAST)
    assert not (tmp_path / "out").exists()


def test_a_bad_model_stops_the_run_before_anything_is_written(scan_pool, tmp_path):
    bad = tmp_path / "bad.safetensors"
    bad.write_bytes(b"not a model")
    with pytest.raises(JsrteError, match="bad.safetensors"):
        fit_many(scan_pool[0][0].parent, out=tmp_path / "out", model=bad, **FAST)
    assert not (tmp_path / "out").exists()


def test_list_files_names_and_truth(tmp_path, scan_pool):
    scans, _ = scan_pool
    (tmp_path / "sub").mkdir()
    listing = tmp_path / "list.txt"
    listing.write_text("# comment\n\nsub/a.ply\n  /abs/b.pcd  \n")
    assert list_scans(listing) == [tmp_path / "sub" / "a.ply", Path("/abs/b.pcd")]
    with pytest.raises(JsrteError, match="holds no scans"):
        list_scans(tmp_path / "sub")
    with pytest.raises(JsrteError, match="no such folder"):
        list_scans(tmp_path / "nope")
    (tmp_path / "empty.txt").write_text("# nothing\n")
    with pytest.raises(JsrteError, match="lists no scans"):
        list_scans(tmp_path / "empty.txt")

    paths = [Path("x/a.ply"), Path("y/a.ply"), Path("a.pcd"), Path("b.npz")]
    assert result_names(paths) == ["a_ply_1", "a_ply_2", "a_pcd", "b"]

    truth = find_truth(scans[0])
    assert truth is not None and truth.mesh.name == "chair_0.obj" and "scale" in truth.scan_from_mesh
    moved = tmp_path / "moved.ply"  # a JSON whose mesh is given relative to the JSON's folder
    moved.write_bytes(scans[0].read_bytes())
    info = json.loads(scans[0].with_suffix(".json").read_text())
    (tmp_path / "m").mkdir()
    (tmp_path / "m" / "c.obj").write_bytes(Path(info["mesh"]).read_bytes())
    moved.with_suffix(".json").write_text(json.dumps(info | {"mesh": "m/c.obj"}))
    assert find_truth(moved).mesh == tmp_path / "m" / "c.obj"
    moved.with_suffix(".json").write_text(json.dumps(info | {"mesh": "m/gone.obj"}))
    assert find_truth(moved) is None


def test_a_second_run_on_the_same_output_is_refused(tmp_path, scan_pool):
    from jsrte.batch.run import LOCK_NAME, _locked

    with _locked(tmp_path):
        with pytest.raises(JsrteError, match="another fit-many"):
            with _locked(tmp_path):
                pass
    assert not (tmp_path / LOCK_NAME).exists()
    (tmp_path / LOCK_NAME).write_text(f"{socket.gethostname()} 999999999\n")  # its process is gone
    with _locked(tmp_path):
        pass


def test_cli_fit_end_to_end_with_viewpoints(model_file, scan_pool, tmp_path, run_cli):
    """``jsrte fit`` on a scan: the files, ``--line-of-sight`` samples from the sidecar's cameras or
    from ``--viewpoint`` (none without the flag in ``smoke``, none after ``--no-line-of-sight``),
    and one-line refusals of a bad viewpoint and of an existing result."""
    scan = scan_pool[0][0]
    common = ["fit", str(scan), "--model", str(model_file), "--preset", "smoke", "--hypotheses", "2",
              "--no-progress", "--threads", "1", "--line-of-sight"]
    out = tmp_path / "sidecar"
    code, stdout, err = run_cli([*common, "--out", str(out)])
    assert code == 0, err
    result = json.loads((out / "fit.json").read_text())
    assert (out / "overlay.png").is_file()
    assert (out / "shape.ply").is_file() != result["empty_surface"]  # a 30-step model may decode empty
    assert result["query"]["ray_freespace_samples"] > 1000
    cameras = json.loads(scan.with_suffix(".json").read_text())["cameras"]
    one = ",".join(str(v) for v in np.asarray(cameras[0], float).reshape(-1)[:3])
    out = tmp_path / "given"
    code, _, err = run_cli([*common, "--out", str(out), "--viewpoint", one])
    assert code == 0, err
    assert json.loads((out / "fit.json").read_text())["query"]["ray_freespace_samples"] > 1000
    code, _, err = run_cli([*common, "--out", str(tmp_path / "bad"), "--viewpoint", "1,2"])
    assert code == 2 and "--viewpoint" in err and not (tmp_path / "bad").exists()
    code, _, err = run_cli([*common, "--out", str(out)])
    assert code == 2 and "--overwrite" in err
    out = tmp_path / "default"
    code, _, err = run_cli([*common[:-1], "--out", str(out)])
    assert code == 0, err
    assert json.loads((out / "fit.json").read_text())["query"]["ray_freespace_samples"] == 0  # smoke: the paper's query
    out = tmp_path / "off"
    code, _, err = run_cli([*common, "--no-line-of-sight", "--out", str(out)])  # the last flag wins
    assert code == 0, err
    assert json.loads((out / "fit.json").read_text())["query"]["ray_freespace_samples"] == 0


def test_summary_records_the_model_and_preset(first_run, model_file):
    from jsrte.model.checkpoint import file_hash

    rows = _summary(first_run[1])
    assert {(r["model"], r["model_sha256"], r["preset"]) for r in rows.values()} == {
        ("tiny-chair", file_hash(model_file), "smoke")}


def test_results_of_another_model_preset_or_options_are_not_reused(first_run, model_file, tmp_path):
    folder, out, _ = first_run
    stamps = {p: p.stat().st_mtime_ns for p in out.glob("*/fit.json")}
    with pytest.raises(JsrteError, match=r"made with model 'tiny-chair' .* preset 'smoke'.*--overwrite"):
        fit_many(folder, out=out, model=model_file, workers=1, **(FAST | {"options": FitOptions(preset="fast")}))
    with pytest.raises(JsrteError, match=r"fitted with other options \(seed 0 there, 3 now\).*--overwrite"):
        fit_many(folder, out=out, model=model_file, workers=1,
                 **(FAST | {"options": FitOptions(preset="smoke", hypotheses=2, seed=3)}))
    from jsrte.model.checkpoint import load_model

    other = tmp_path / "table.safetensors"
    model = load_model(model_file)
    model.meta["name"] = "tiny-table"
    save_model(model, other)
    with pytest.raises(JsrteError, match="this run uses model 'tiny-table'.*another --out"):
        fit_many(folder, out=out, model=other, workers=1, **FAST)
    assert {p: p.stat().st_mtime_ns for p in out.glob("*/fit.json")} == stamps


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
def test_a_killed_run_leaves_no_orphans_and_resumes_to_the_same_results(first_run, model_file, scan_pool,
                                                                         tmp_path):
    from process_tree import kill_all, sigkill_leaves_no_orphans, wait_for_descendants

    scans, _ = scan_pool
    folder, out = tmp_path / "scans", tmp_path / "out"
    for scan in scans[:2]:
        _copy_scan(scan, folder)
    cmd = JSRTE + ["fit-many", str(folder), "--model", str(model_file), "--preset", "smoke", "--hypotheses", "2",
                   "--no-progress", "--workers", "2", "--out", str(out)]
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                            env=dict(os.environ, PYTHONPATH=os.pathsep.join(sys.path)))
    try:
        workers = wait_for_descendants(proc.pid, 3, timeout=120)  # two workers and the resource tracker
        assert len(workers) >= 2, "the workers never started"
        sigkill_leaves_no_orphans(proc, workers)
    finally:
        proc.kill()
        kill_all(wait_for_descendants(proc.pid, 0, 0))
    report = fit_many(folder, out=out, model=model_file, workers=2, **FAST)
    assert report.failed == 0 and report.fitted + report.skipped == 2
    for stem in ("chair_0", "chair_1"):
        resumed = json.loads((out / stem / "fit.json").read_text())
        straight = json.loads((first_run[1] / stem / "fit.json").read_text())
        assert resumed["scale"] == straight["scale"] and resumed["latent"] == straight["latent"]
