"""The scan experiment's driver: virtual scans, rows per method, and the same rows in parallel."""

import csv

import pytest
import torch

from jsrte.experiments.scans import run_scan_experiment, virtual_cases
from jsrte.model.checkpoint import DeepSdfModel
from jsrte.model.decoder import Decoder, DecoderConfig


@pytest.fixture(scope="module")
def tiny_model():
    torch.manual_seed(3)
    config = DecoderConfig(latent_size=8, hidden=32, depth=4, skip_layer=2, weight_norm=True)
    return DeepSdfModel(Decoder(config), torch.randn(2, 8) * 0.01,
                        {"name": "tiny", "category": "chair", "canonical_height": 1.0, "canonical_radius": 1.0})


@pytest.fixture(scope="module")
def cases(tmp_path_factory):
    return virtual_cases("chair", 3, tmp_path_factory.mktemp("scans"), seed=2)


def read_rows(path):
    with open(path) as f:
        return list(csv.DictReader(f))


def test_worker_processes_give_the_rows_of_one_process(tmp_path, tiny_model, cases):
    serial, parallel = tmp_path / "serial", tmp_path / "parallel"
    serial.mkdir(), parallel.mkdir()
    run_scan_experiment(cases, ["jsrte"], serial, model=tiny_model, preset="smoke", figure_scans=1,
                        progress=False)
    run_scan_experiment(cases, ["jsrte"], parallel, model=tiny_model, preset="smoke", figure_scans=1,
                        progress=False, jobs=2, threads=2)
    a, b = read_rows(serial / "results.csv"), read_rows(parallel / "results.csv")
    assert [r["scan"] for r in a] == [r["scan"] for r in b] == [c.name for c in cases]
    for key in ("status", "truth_fscore", "truth_rotation_error_deg", "scan_fscore"):
        assert [r.get(key) for r in a] == [r.get(key) for r in b], key
    assert (parallel / "table.md").is_file() and len(list(parallel.glob("figure_*.png"))) == 1
    page = (serial / "report.html").read_text()  # beside results.csv: each scan's fit, truth and thumbnail
    assert all(f'"name": "{c.name}"' in page for c in cases) and page.count("data:image/png;base64,") == 3


def test_experiment_cli_refuses_zero_jobs(tmp_path, run_cli):
    code, _, stderr = run_cli(["experiment", "scans", "--out", str(tmp_path / "o"), "--jobs", "0"])
    assert code != 0 and "--jobs" in stderr


def test_own_sizes_stand_each_shape_at_its_own_size_in_the_same_pose(tmp_path):
    from jsrte.geometry.mesh import unit_sphere_normalization
    from jsrte.shapes import EVAL_SET_SEED, generate_shape, shape_seed

    drawn = virtual_cases("bed", 1, tmp_path / "drawn", seed=2)[0].truth
    own = virtual_cases("bed", 1, tmp_path / "own", seed=2, sizes="own")[0].truth
    bed = generate_shape("bed", shape_seed(EVAL_SET_SEED, 0)).mesh
    radius = unit_sphere_normalization(bed).scale  # metres
    assert own.scan_from_canonical.s == pytest.approx(radius, rel=1e-9)  # scale 1: the bed's own metres
    assert abs(drawn.scan_from_canonical.s / radius - 1.0) > 0.02  # drawn 0.6-1.2 m tall instead
    assert own.scan_from_canonical.R == pytest.approx(drawn.scan_from_canonical.R)  # the same pose


def test_experiment_cli_refuses_own_sizes_in_rooms(tmp_path, run_cli):
    code, _, stderr = run_cli(["experiment", "scans", "--out", str(tmp_path / "o"), "--clutter",
                               "--sizes", "own"])
    assert code == 2 and "--sizes" in stderr and stderr.count("\n") == 1 and not (tmp_path / "o").exists()


def test_the_experiment_fits_with_the_arithmetic_asked_for(tiny_model, cases):
    from jsrte.experiments.scans import run_method

    kwargs = dict(model=tiny_model, database=None, preset="smoke", seed=0)
    assert run_method("jsrte", cases[0], **kwargs).info["decoder_dtype"] == "float32"  # smoke's own
    assert run_method("jsrte", cases[0], dtype="bfloat16", **kwargs).info["decoder_dtype"] == "bfloat16"
