"""One list of input formats (jsrte.formats), and every format in it fits end to end.

The fit test walks the lists themselves, so a format added to them is fitted here too: a format
``--help`` advertises but a later stage cannot read (a GLB once fitted for seconds, then failed
while drawing the overlay) fails this test.
"""

import json

import numpy as np
import pytest
import trimesh

from analytic import octahedron_model
from cli_runner import run_cli
from jsrte.errors import JsrteError
from jsrte.formats import INPUT_SUFFIXES, MESH_SUFFIXES, SCAN_SUFFIXES, input_kind


def test_input_kind_names_each_advertised_suffix_and_refuses_the_rest(tmp_path):
    for suffix in INPUT_SUFFIXES:
        path = tmp_path / f"x{suffix.upper()}"  # suffixes are matched case-blind
        path.write_bytes(b"0")
        expected = "scan" if suffix in SCAN_SUFFIXES else "mesh" if suffix in MESH_SUFFIXES else "npz"
        assert input_kind(path) == expected
    (tmp_path / "x.las").write_bytes(b"0")
    with pytest.raises(JsrteError, match=r"unsupported input '\.las' \(use \.ply.*\.npz\)"):
        input_kind(tmp_path / "x.las")
    with pytest.raises(JsrteError, match="no such file"):
        input_kind(tmp_path / "missing.ply")
    with pytest.raises(JsrteError, match="is a folder"):
        input_kind(tmp_path)
    with pytest.raises(JsrteError, match=r"unsupported input '\.NPZ' \(use \.ply.*\.gltf\)$"):
        input_kind(tmp_path / "x.NPZ", accept=("scan", "mesh"))  # the baselines take no SDF samples


def _scan_files(tmp_path):
    """A virtual scan of a box on a floor, written once in every scan format (PLY with its JSON)."""
    import open3d as o3d

    from jsrte.scans.scanner import ScannerSettings, scan_mesh, write_scan

    box = trimesh.creation.box(extents=(0.6, 0.9, 0.5))
    scan = scan_mesh(box, rng=np.random.default_rng(0), settings=ScannerSettings(outlier_fraction=0.0))
    ply = write_scan(scan, tmp_path / "scan.ply", seed=0)
    cloud = o3d.io.read_point_cloud(str(ply))
    files = {".ply": ply}
    for suffix in SCAN_SUFFIXES:
        if suffix != ".ply":
            files[suffix] = tmp_path / f"scan{suffix}"
            assert o3d.io.write_point_cloud(str(files[suffix]), cloud), suffix
    return files


def test_every_advertised_input_format_fits_through_the_cli(tmp_path, monkeypatch, capsys):
    model = tmp_path / "model.safetensors"
    from jsrte.model.checkpoint import save_model

    save_model(octahedron_model(), model)
    box = trimesh.creation.box(extents=(0.6, 0.9, 0.5))
    inputs = {}
    for suffix in MESH_SUFFIXES:
        inputs[suffix] = tmp_path / f"box{suffix}"
        box.export(inputs[suffix])
    inputs.update(_scan_files(tmp_path))
    code, _, err = run_cli(monkeypatch, capsys, "sample", tmp_path / "box.obj", "--out", tmp_path / "box.npz")
    assert code == 0, err
    inputs[".npz"] = tmp_path / "box.npz"
    assert set(inputs) == set(INPUT_SUFFIXES)

    for suffix, path in inputs.items():
        out = tmp_path / f"fit{suffix[1:]}"
        code, printed, err = run_cli(monkeypatch, capsys, "fit", path, "--model", model, "--preset", "smoke",
                                     "--hypotheses", "2", "--out", out, "--no-progress", "--threads", "1")
        assert code == 0, (suffix, err)
        assert (out / "overlay.png").stat().st_size > 0, suffix
        record = json.loads((out / "fit.json").read_text())
        assert record["input"].endswith(suffix)
        assert record["flag"] in ("ok", "doubtful") and f"flag {record['flag']}: inliers " in printed
        kind = record["query"]["input"]
        assert kind == {"scan": "scan", "mesh": "mesh", "npz": "sdf-samples"}[input_kind(path)], (suffix, kind)
        up = np.asarray(record["up"] or (0.0, 1.0, 0.0))
        height = float(np.ptp(trimesh.load(out / "shape.ply").vertices @ up))
        assert 0.3 < height < 1.8, (suffix, height)  # an object of about the box's size, in scan metres
