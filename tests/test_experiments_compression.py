"""The compression experiment: the dense original, the simplifications, the stated mesh format,
and a tiny end-to-end run (library and CLI) that writes Table 3 and the rate–distortion plot."""

import csv

import numpy as np
import pytest
import trimesh

from analytic import octahedron_model
from cli_runner import run_cli
from jsrte.codec import encoded_size
from jsrte.experiments.compression import (
    CompressionConfig,
    densify,
    ply_bytes,
    quadric_decimation,
    random_pose,
    run_compression,
    vertex_clustering,
)
from jsrte.experiments.settings import PAPER_TABLE3, CompressionSettings
from jsrte.metrics.surface import fscore
from jsrte.presets import SMOKE


def test_densify_rebuilds_the_same_surface_with_about_the_target_faces():
    box = trimesh.creation.box(extents=(1.0, 0.5, 0.3))
    box.vertices += [2.0, 1.0, -1.0]  # any frame
    dense = densify(box, target_faces=4000)
    assert 2000 <= len(dense.faces) <= 8000
    assert dense.is_watertight
    assert np.allclose(dense.bounds, box.bounds, atol=0.03)
    assert fscore(dense, box, rng=np.random.default_rng(0)).fscore > 0.95  # edges rounded within a cell


def test_quadric_decimation_and_vertex_clustering():
    sphere = trimesh.creation.icosphere(subdivisions=4)  # 5120 faces, radius 1
    qe = quadric_decimation(sphere, 100)
    assert 5120 // 100 - 2 <= len(qe.faces) <= 5120 // 100  # an edge collapse removes two faces
    assert np.allclose(np.linalg.norm(qe.vertices, axis=1), 1.0, atol=0.1)
    assert len(quadric_decimation(sphere, 100_000).faces) <= 4
    coarse, fine = vertex_clustering(sphere, 0.2), vertex_clustering(sphere, 0.1)
    assert len(coarse.vertices) < len(fine.vertices) < len(sphere.vertices)
    # averaged clusters of cells 0.2 wide lie within a cell diagonal of the sphere
    assert np.all(np.abs(np.linalg.norm(coarse.vertices, axis=1) - 1.0) < 0.2 * np.sqrt(3))


def test_meshes_are_stored_as_plain_binary_ply():
    mesh = trimesh.creation.icosphere(subdivisions=2)
    data = ply_bytes(mesh)
    header = data[: data.index(b"end_header\n") + len(b"end_header\n")]
    assert b"binary_little_endian" in header and b"comment" not in header and b"normal" not in header
    assert b"property float x" in header and b"property list uchar int vertex_indices" in header
    assert len(data) == len(header) + 12 * len(mesh.vertices) + 13 * len(mesh.faces)
    back = trimesh.load(trimesh.util.wrap_as_stream(data), file_type="ply", process=False)
    assert np.allclose(back.vertices, mesh.vertices, atol=1e-6) and np.array_equal(back.faces, mesh.faces)


def test_random_pose_is_rigid_and_reports_the_objects_up_axis():
    pose, up = random_pose(np.random.default_rng(0))
    assert pose.s == 1.0 and np.allclose(pose.R.T @ pose.R, np.eye(3)) and np.linalg.det(pose.R) > 0
    assert np.allclose(pose.R @ [0.0, 1.0, 0.0], up)
    assert np.linalg.norm(pose.t) < 4.0


@pytest.fixture(scope="module")
def tiny_model_path(tmp_path_factory):
    from jsrte.model.checkpoint import load_model, save_model

    path = tmp_path_factory.mktemp("model") / "tiny.safetensors"
    save_model(octahedron_model(name="tiny"), path)
    load_model(path)
    return path


def read_csv(path):
    with open(path) as fh:
        return list(csv.DictReader(fh))


def test_tiny_run_writes_table3_codes_meshes_and_plot(tmp_path, tiny_model_path):
    from dataclasses import replace

    from jsrte.model.checkpoint import load_model

    model = load_model(tiny_model_path)
    preset = replace(SMOKE, sampling=replace(SMOKE.sampling, n_points=3000))
    config = CompressionConfig(category="chair", n=1, source="meshes", preset=preset,
                               settings=CompressionSettings(dense_faces=3000))
    report = run_compression(config, model, tmp_path)
    methods = [r["method"] for r in report.table]
    assert methods == ["Original", "Fit", "Ours (fp32)", "Ours (fp16)", "Ours (int8)", "QE-100", "QE-1000",
                       "VC-0.1", "VC-0.2"]
    rows = {r["method"]: r for r in read_csv(tmp_path / "objects.csv")}
    for fmt in ("fp32", "fp16", "int8"):  # code sizes are the codec's, to the byte
        row = rows[f"Ours ({fmt})"]
        assert int(row["size_bytes"]) == encoded_size(8, fmt, name_bytes=len("tiny"))
        assert (tmp_path / row["file"]).stat().st_size == int(row["size_bytes"])
    assert abs(float(rows["Ours (fp32)"]["fscore"]) - float(rows["Fit"]["fscore"])) <= 0.01
    for label in ("QE-100", "QE-1000", "VC-0.1", "VC-0.2"):
        path = tmp_path / rows[label]["file"]
        assert path.suffix == ".ply" and path.stat().st_size == int(rows[label]["size_bytes"])
        assert len(trimesh.load(path, process=False).faces) == int(rows[label]["faces"])
    # an edge collapse may not split a part: a small original stops above 1/100 of its faces
    assert int(rows["QE-1000"]["faces"]) <= int(rows["QE-100"]["faces"]) < int(rows["Original"]["faces"]) // 10
    assert float(rows["Fit"]["rotation_error_deg"]) >= 0.0 and float(rows["Fit"]["scale_error_rel"]) >= 0.0
    assert 2000 < int(rows["Original"]["faces"]) < 6000  # densified from a few hundred faces
    table = {r["method"]: r for r in read_csv(tmp_path / "table3.csv")}
    assert float(table["QE-100"]["paper_size_kb"]) == PAPER_TABLE3["QE-100"]["size_kb"]
    assert float(table["Ours (fp32)"]["paper_fscore"]) == PAPER_TABLE3["Ours"]["fscore"]
    md = (tmp_path / "table3.md").read_text()
    assert "| Average F-score (paper) |" in md and "20.120" in md and "0.902" in md
    assert "binary little-endian PLY" in md and "held-out" in md and "re-meshed" in md
    assert (tmp_path / "rate_distortion.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_cli_compression_from_scans_and_refusals(tmp_path, monkeypatch, capsys, tiny_model_path):
    out = tmp_path / "comp"
    args = ["experiment", "compression", "--out", out, "--category", "chair", "--model", tiny_model_path,
            "--n", "1", "--source", "scans", "--preset", "smoke", "--dense-faces", "2000", "--threads", "1"]
    rc, stdout, err = run_cli(monkeypatch, capsys, *args)
    assert rc == 0, err
    assert "Ours (int8)" in stdout and "VC-0.2" in stdout
    for name in ("table3.md", "table3.csv", "objects.csv", "rate_distortion.png"):
        assert (out / name).is_file()
    assert "virtual depth scans" in (out / "table3.md").read_text()
    rc, _, err = run_cli(monkeypatch, capsys, *args)
    assert rc == 2 and "--overwrite" in err
    bad = tmp_path / "bad"
    rc, _, err = run_cli(monkeypatch, capsys, "experiment", "compression", "--out", bad, "--model",
                         tiny_model_path, "--source", "photos")
    assert rc == 2 and "photos" in err
    rc, _, err = run_cli(monkeypatch, capsys, "experiment", "compression", "--out", bad, "--model",
                         tmp_path / "missing.safetensors")
    assert rc == 2 and "missing.safetensors" in err
    assert not bad.exists()
