"""Query files (`jsrte prepare`): a scan preprocessed once, fitted later or elsewhere."""

import numpy as np
import pytest
import torch

from analytic import LShapeDecoder
from jsrte.errors import JsrteError
from jsrte.fit import fit
from jsrte.fit.query import SdfQuery, is_query_file, load_query, read_query_file, save_query
from jsrte.model.checkpoint import DeepSdfModel
from jsrte.model.meshing import decode_mesh
from jsrte.scans.scanner import scan_mesh, write_scan


@pytest.fixture(scope="module")
def lshape():
    return DeepSdfModel(LShapeDecoder(), torch.zeros(1, 4), {"name": "lshape", "canonical_height": 1.5,
                                                             "canonical_radius": 0.95})


@pytest.fixture(scope="module")
def scan_file(tmp_path_factory, lshape):
    mesh = decode_mesh(lshape.decoder, torch.zeros(4), resolution=40).mesh
    path = tmp_path_factory.mktemp("scan") / "lshape.ply"
    return write_scan(scan_mesh(mesh, rng=np.random.default_rng(5)), path, seed=5)


def test_round_trip_keeps_every_field(tmp_path):
    rng = np.random.default_rng(0)
    query = SdfQuery(rng.normal(size=(50, 3)), rng.normal(size=50), rng.normal(size=(20, 3)),
                     up=np.array([0.0, 0.6, 0.8]), floor_offset=-0.25, info={"input": "scan", "n": 3},
                     n_refine_only=7, lower_bound=rng.random(50) < 0.3)
    path = tmp_path / "q.npz"
    save_query(query, path)
    back = read_query_file(path)
    assert is_query_file(path)
    np.testing.assert_array_equal(back.points, query.points)
    np.testing.assert_array_equal(back.sdf, query.sdf)
    np.testing.assert_array_equal(back.surface, query.surface)
    np.testing.assert_array_equal(back.up, query.up)
    np.testing.assert_array_equal(back.lower_bound, query.lower_bound)
    assert (back.floor_offset, back.info, back.n_refine_only) == (-0.25, {"input": "scan", "n": 3}, 7)


def test_no_up_and_no_floor_stay_none(tmp_path):
    query = SdfQuery(np.zeros((3, 3)), np.zeros(3), np.zeros((2, 3)))
    save_query(query, tmp_path / "q.npz")
    back = read_query_file(tmp_path / "q.npz")
    assert back.up is None and back.floor_offset is None and back.lower_bound is None


def test_fitting_the_prepared_query_equals_fitting_the_scan(tmp_path, lshape, scan_file):
    prepared = load_query(scan_file, rng=np.random.default_rng(0))
    save_query(prepared, tmp_path / "q.npz")
    direct = fit(scan_file, model=lshape, preset="smoke", seed=0)
    later = fit(tmp_path / "q.npz", model=lshape, preset="smoke", seed=0)
    np.testing.assert_allclose(later.transform.matrix(), direct.transform.matrix())
    np.testing.assert_allclose(later.latent, direct.latent)


def test_sample_files_are_not_query_files(tmp_path):
    np.savez(tmp_path / "s.npz", points=np.zeros((4, 3), np.float32), sdf=np.zeros(4, np.float32),
             centre=np.zeros(3), scale=np.float64(1.0))
    assert not is_query_file(tmp_path / "s.npz")


@pytest.mark.parametrize("content, message", [
    (b"not a zip", "not a jsrte query file"),
    (None, "do not fit"),
    ("lower_bound", "lower_bound .* does not fit"),
])
def test_bad_query_files_are_refused_naming_the_file(tmp_path, content, message):
    path = tmp_path / "bad.npz"
    if content is None:
        save_query(SdfQuery(np.zeros((5, 3)), np.zeros(4), np.zeros((2, 3))), path)
    elif content == "lower_bound":
        save_query(SdfQuery(np.zeros((5, 3)), np.zeros(5), np.zeros((2, 3)), lower_bound=np.ones(4, bool)), path)
    else:
        path.write_bytes(content)
    with pytest.raises(JsrteError, match=message) as info:
        read_query_file(path)
    assert "bad.npz" in str(info.value)


def test_prepare_cli_writes_a_query_and_refuses_to_overwrite(tmp_path, run_cli, scan_file):
    out = tmp_path / "q.npz"
    code, stdout, _ = run_cli(["prepare", str(scan_file), "--out", str(out)])
    assert code == 0 and "SDF samples" in stdout
    query = read_query_file(out)
    assert query.up is not None and query.info["source"] == "lshape.ply" and len(query.sdf) > 1000
    code, _, stderr = run_cli(["prepare", str(scan_file), "--out", str(out)])
    assert code != 0 and "--overwrite" in stderr
    code, _, stderr = run_cli(["prepare", str(scan_file), "--out", str(tmp_path / "q.txt")])
    assert code != 0 and ".npz" in stderr
