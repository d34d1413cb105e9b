"""The .jsrte shape code: exact/bounded round trips, sizes, refusals, a fuzzed parser, the CLI."""

from __future__ import annotations

import struct
import zlib

import numpy as np
import pytest
import trimesh
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from analytic import octahedron_model
from cli_runner import run_cli
from jsrte.codec.format import (
    FIXED_BYTES,
    ShapeCode,
    decode,
    dequantize_int8,
    encode,
    encoded_size,
    quantize_int8,
)
from jsrte.errors import JsrteError
from jsrte.geometry.sim3 import Sim3, axis_angle_matrix

FORMATS = ("fp32", "fp16", "int8")


def fp32_transform(s: float, axis, theta: float, t) -> Sim3:
    """A Sim3 whose values are fp32 numbers (what the file stores exactly)."""
    r = axis_angle_matrix(np.asarray(axis, float) / np.linalg.norm(axis), theta)
    return Sim3(np.float32(s), r.astype(np.float32), np.asarray(t, np.float32))


def make_code(d: int = 64, seed: int = 0, name: str = "chair") -> ShapeCode:
    rng = np.random.default_rng(seed)
    latent = rng.normal(0.0, 0.1, d).astype(np.float32)
    return ShapeCode(latent, fp32_transform(1.7, [0.2, 1.0, 0.1], 2.1, [0.5, -1.25, 3.0]), name,
                     bytes(range(16)))


def with_crc(body: bytes) -> bytes:
    return body + struct.pack("<I", zlib.crc32(body))


# --- round trips --------------------------------------------------------------------------


def test_fp32_round_trip_is_bit_exact():
    code = make_code()
    data = encode(code, latent_format="fp32")
    back = decode(data)
    assert back == code
    assert back.latent.dtype == np.float32 and back.latent.tobytes() == code.latent.tobytes()
    assert back.transform.s == code.transform.s
    assert back.transform.R.tobytes() == code.transform.R.tobytes()
    assert back.transform.t.tobytes() == code.transform.t.tobytes()
    assert encode(back) == data


def test_float64_transform_is_rounded_to_fp32_once():
    code = make_code()
    code.transform = Sim3(1.3, axis_angle_matrix(np.array([0.0, 1.0, 0.0]), 0.7), [0.1, 0.2, 0.3])
    back = decode(encode(code))
    assert back.transform.s == np.float32(1.3)
    np.testing.assert_allclose(back.transform.R, code.transform.R, atol=1e-7)
    np.testing.assert_allclose(back.transform.t, code.transform.t, rtol=1e-7)
    assert encode(back) == encode(code)  # stable after the first rounding


def test_fp16_within_stated_bound():
    code = make_code(256, seed=1)
    back = decode(encode(code, latent_format="fp16"))
    z = code.latent.astype(np.float64)
    bound = np.maximum(np.abs(z) * 2.0**-11, 2.0**-25)
    assert np.all(np.abs(back.latent - z) <= bound)
    assert back.transform.s == code.transform.s and back.model_hash == code.model_hash


def test_int8_within_stated_bound():
    code = make_code(256, seed=2)
    scale, offset, _ = quantize_int8(code.latent)
    assert scale * 255 >= code.latent.max() - code.latent.min()
    assert scale == pytest.approx((code.latent.max() - code.latent.min()) / 255, rel=1e-6)
    back = decode(encode(code, latent_format="int8"))
    err = np.abs(back.latent.astype(np.float64) - code.latent)
    assert err.max() <= scale / 2 + np.spacing(np.abs(code.latent)).max()
    assert err.max() > scale / 10  # really quantized


@settings(max_examples=100, deadline=None)
@given(arrays(np.float32, st.integers(1, 300), elements=st.floats(-1e4, 1e4, width=32)))
def test_int8_bound_holds_for_any_vector(z):
    scale, offset, q = quantize_int8(z)
    back = dequantize_int8(scale, offset, q)
    err = np.abs(back.astype(np.float64) - z.astype(np.float64))
    assert np.all(err <= scale / 2 + np.spacing(np.abs(back)))
    code = ShapeCode(z, Sim3.identity(), "m", bytes(16))
    np.testing.assert_array_equal(decode(encode(code, latent_format="int8")).latent, back)


def test_constant_latent_quantizes_exactly():
    code = ShapeCode(np.full(64, 0.25, np.float32), Sim3.identity(), "chair", bytes(16))
    assert np.array_equal(decode(encode(code, latent_format="int8")).latent, code.latent)


# --- sizes ------------------------------------------------------------------------------


@pytest.mark.parametrize(("d", "fmt", "size"), [
    (64, "fp32", 343), (64, "fp16", 215), (64, "int8", 159),
    (256, "fp32", 1111), (256, "fp16", 599), (256, "int8", 351),
])
def test_sizes_as_documented(d, fmt, size):
    assert encoded_size(d, fmt) == size
    assert len(encode(make_code(d), latent_format=fmt)) == size
    assert FIXED_BYTES == 82


def test_name_is_utf8_and_limited():
    code = make_code(name="stoel-ü")
    assert decode(encode(code)).model_name == "stoel-ü"
    code.model_name = "x" * 65
    with pytest.raises(JsrteError, match="at most 64"):
        encode(code)


def test_encoder_refuses_what_the_format_cannot_hold():
    code = make_code()
    code.latent[3] = np.nan
    with pytest.raises(JsrteError, match="non-finite"):
        encode(code)
    code = make_code()
    code.latent[0] = 70000.0
    with pytest.raises(JsrteError, match="fp16"):
        encode(code, latent_format="fp16")
    with pytest.raises(JsrteError, match="not a rotation"):
        encode(ShapeCode(np.zeros(4), Sim3(1.0, np.diag([1.0, 1.0, -1.0]), np.zeros(3)), "m", bytes(16)))
    code.latent[0] = 65504.0  # the largest fp16: a decoded fp16 code always re-encodes
    assert decode(encode(code, latent_format="fp16")).latent[0] == 65504.0
    with pytest.raises(JsrteError, match="unknown latent format"):
        encode(make_code(), latent_format="bf16")


# --- refusals -----------------------------------------------------------------------------


def test_flipped_byte_is_refused_naming_the_file():
    data = bytearray(encode(make_code()))
    data[100] ^= 0x10
    with pytest.raises(JsrteError, match=r"obj\.jsrte.*checksum"):
        decode(bytes(data), source="obj.jsrte")


def test_truncated_file_is_refused():
    data = encode(make_code())
    for n in (0, 3, 9, 50, len(data) - 1):
        with pytest.raises(JsrteError, match="truncated"):
            decode(data[:n], source="obj.jsrte")


def test_trailing_bytes_are_refused():
    with pytest.raises(JsrteError, match="corrupt"):
        decode(encode(make_code()) + b"\0")


def test_foreign_file_is_refused():
    with pytest.raises(JsrteError, match="not a jsrte shape code"):
        decode(b"PK\x03\x04" + bytes(400), source="x.zip")
    with pytest.raises(JsrteError, match="not a jsrte shape code"):
        decode(b"ply\nformat ascii 1.0\n")


def test_future_version_is_refused():
    data = bytearray(encode(make_code()))
    data[4] = 2
    with pytest.raises(JsrteError, match="version 2 is not supported.*newer jsrte"):
        decode(with_crc(bytes(data[:-4])), source="new.jsrte")


def test_unknown_flags_are_refused():
    data = bytearray(encode(make_code()))
    data[5] = 0x01
    with pytest.raises(JsrteError, match="unknown flags"):
        decode(with_crc(bytes(data[:-4])))


def test_checksummed_but_invalid_values_are_refused():
    good = encode(make_code())
    n = 5  # len("chair")
    transform_at = 26 + n
    bad_scale = bytearray(good[:-4])
    bad_scale[transform_at: transform_at + 4] = struct.pack("<f", -1.0)
    with pytest.raises(JsrteError, match="positive scale"):
        decode(with_crc(bytes(bad_scale)))
    bad_rotation = bytearray(good[:-4])
    bad_rotation[transform_at + 4: transform_at + 8] = struct.pack("<f", 2.0)
    with pytest.raises(JsrteError, match="not a rotation"):
        decode(with_crc(bytes(bad_rotation)))
    nan_latent = bytearray(good[:-4])
    nan_latent[78 + n: 82 + n] = struct.pack("<f", float("nan"))
    with pytest.raises(JsrteError, match="non-finite"):
        decode(with_crc(bytes(nan_latent)))
    bad_name = bytearray(good[:-4])
    bad_name[10] = 0xFF
    with pytest.raises(JsrteError, match="UTF-8"):
        decode(with_crc(bytes(bad_name)))


# --- fuzzing ------------------------------------------------------------------------------

VALID = {fmt: encode(make_code(), latent_format=fmt) for fmt in FORMATS}


def decode_or_refuse(data: bytes) -> ShapeCode | None:
    """Decode; a JsrteError is an acceptable answer, any other exception fails the test."""
    try:
        code = decode(data, source="fuzz.jsrte")
    except JsrteError as exc:
        assert "fuzz.jsrte" in str(exc) and "\n" not in str(exc)
        return None
    assert np.all(np.isfinite(code.latent)) and code.transform.s > 0
    np.testing.assert_allclose(code.transform.R.T @ code.transform.R, np.eye(3), atol=1e-4)
    return code


@settings(max_examples=300, deadline=None)
@given(st.binary(max_size=2000))
def test_fuzz_random_bytes(data):
    decode_or_refuse(data)


@settings(max_examples=300, deadline=None)
@given(st.sampled_from(FORMATS), st.binary(max_size=400))
def test_fuzz_valid_header_random_rest(fmt, rest):
    decode_or_refuse(VALID[fmt][:10] + rest)


@settings(max_examples=200, deadline=None)
@given(st.sampled_from(FORMATS), st.data())
def test_fuzz_truncations_are_refused(fmt, data):
    valid = VALID[fmt]
    n = data.draw(st.integers(0, len(valid) - 1))
    assert decode_or_refuse(valid[:n]) is None


@settings(max_examples=150, deadline=None)
@given(st.sampled_from(FORMATS), st.data())
def test_fuzz_byte_flips_are_refused(fmt, data):
    valid = bytearray(VALID[fmt])
    positions = data.draw(st.lists(st.integers(0, len(valid) - 1), min_size=1, max_size=8, unique=True))
    for p in positions:
        valid[p] ^= data.draw(st.integers(1, 255))
    assert decode_or_refuse(bytes(valid)) is None  # the CRC catches it (or the header checks)


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.sampled_from(FORMATS), st.data())
def test_fuzz_mutations_with_a_valid_checksum(fmt, data):
    """Past the CRC (a crafted file): the value checks still refuse or give a sane code."""
    body = bytearray(VALID[fmt][:-4])
    positions = data.draw(st.lists(st.integers(4, len(body) - 1), min_size=1, max_size=6, unique=True))
    for p in positions:
        body[p] = data.draw(st.integers(0, 255))
    code = decode_or_refuse(with_crc(bytes(body)))
    if code is not None:
        assert decode(encode(code, latent_format=fmt)) == code or fmt != "fp32"


# --- CLI end to end -----------------------------------------------------------------------


@pytest.fixture
def models(tmp_path):
    from jsrte.model.checkpoint import save_model

    paths = {}
    for key, bias in (("good", -0.5), ("other", -0.6)):
        paths[key] = tmp_path / key / "model.safetensors"
        save_model(octahedron_model(bias), paths[key])
    return paths


def fit_folder(tmp_path, model_path, latent, name="fit"):
    """A folder as 'jsrte fit' writes it (fit.json only), for ``latent`` and a float64 transform."""
    from jsrte.atomic import write_json_atomic
    from jsrte.fit.outputs import RESULT_NAME
    from jsrte.model.checkpoint import file_hash
    from jsrte.result import FitResult

    transform = Sim3(0.8, axis_angle_matrix(np.array([0.0, 1.0, 0.0]), 1.1), [0.3, 0.4, -2.0])
    result = FitResult("jsrte", transform, np.asarray(latent, np.float32), None, 0.01, {"name": "loss"},
                       info={"model": "octa", "model_sha256": file_hash(model_path), "preset": "fast"})
    folder = tmp_path / name
    folder.mkdir()
    write_json_atomic(folder / RESULT_NAME, result.to_json())
    return folder, result


def direct_mesh(model_path, latent, transform, resolution):
    from jsrte.model.checkpoint import load_model
    from jsrte.model.meshing import decode_mesh

    mesh = decode_mesh(load_model(model_path).decoder, latent, resolution=resolution).mesh
    return transform.apply(mesh.vertices), mesh.faces


def test_encode_decode_cli_end_to_end(tmp_path, monkeypatch, capsys, models):
    latent = np.zeros(8, np.float32)
    latent[0] = 0.5  # radius 0.4
    folder, result = fit_folder(tmp_path, models["good"], latent)
    code_path, mesh_path = tmp_path / "obj.jsrte", tmp_path / "mesh.ply"
    rc, out, err = run_cli(monkeypatch, capsys, "encode", folder, "--out", code_path)
    assert rc == 0, err
    assert code_path.stat().st_size == encoded_size(8, "fp32", name_bytes=4)
    rc, out, err = run_cli(monkeypatch, capsys, "decode", code_path, "--out", mesh_path,
                           "--model", models["good"], "--resolution", "32")
    assert rc == 0, err
    written = trimesh.load(mesh_path, process=False)
    vertices, faces = direct_mesh(models["good"], latent, result.transform, 32)
    np.testing.assert_allclose(written.vertices, vertices, atol=1e-5)
    np.testing.assert_array_equal(written.faces, faces)
    # the octahedron |x|_1 = 0.4, scaled by 0.8 about the translation
    local = result.transform.inverse().apply(written.vertices)
    np.testing.assert_allclose(np.abs(local).sum(1), 0.4, atol=0.02)

    rc, _, err = run_cli(monkeypatch, capsys, "decode", code_path, "--out", tmp_path / "canon.ply",
                         "--model", models["good"], "--resolution", "32", "--canonical")
    assert rc == 0, err
    canon = trimesh.load(tmp_path / "canon.ply", process=False)
    np.testing.assert_allclose(np.abs(canon.vertices).sum(1), 0.4, atol=0.02)


def test_int8_cli_round_trip_close_to_exact(tmp_path, monkeypatch, capsys, models):
    latent = np.linspace(-0.3, 0.5, 8).astype(np.float32)[::-1].copy()
    folder, result = fit_folder(tmp_path, models["good"], latent)
    code_path = tmp_path / "obj.jsrte"
    rc, _, err = run_cli(monkeypatch, capsys, "encode", folder, "--out", code_path, "--latent", "int8",
                         "--model", models["good"])
    assert rc == 0, err
    assert code_path.stat().st_size == encoded_size(8, "int8", name_bytes=4)
    rc, _, err = run_cli(monkeypatch, capsys, "decode", code_path, "--out", tmp_path / "m.ply",
                         "--model", models["good"], "--resolution", "32")
    assert rc == 0, err
    local = result.transform.inverse().apply(trimesh.load(tmp_path / "m.ply", process=False).vertices)
    np.testing.assert_allclose(np.abs(local).sum(1), 0.5 - 0.2 * 0.5, atol=0.02)


def test_decode_refuses_the_wrong_model_and_writes_nothing(tmp_path, monkeypatch, capsys, models):
    folder, _ = fit_folder(tmp_path, models["good"], np.zeros(8, np.float32))
    code_path, mesh_path = tmp_path / "obj.jsrte", tmp_path / "mesh.ply"
    assert run_cli(monkeypatch, capsys, "encode", folder, "--out", code_path)[0] == 0
    rc, _, err = run_cli(monkeypatch, capsys, "decode", code_path, "--out", mesh_path,
                         "--model", models["other"], "--resolution", "32")
    assert rc == 2
    assert "this code was made with model 'octa' (hash" in err and "the model given" in err
    assert "obj.jsrte" in err and not mesh_path.exists()
    rc, _, err = run_cli(monkeypatch, capsys, "decode", code_path, "--out", mesh_path)
    assert rc == 2 and "not shipped" in err and "--model" in err and not mesh_path.exists()


def test_encode_refuses_a_model_other_than_the_fits(tmp_path, monkeypatch, capsys, models):
    folder, _ = fit_folder(tmp_path, models["good"], np.zeros(8, np.float32))
    code_path = tmp_path / "obj.jsrte"
    rc, _, err = run_cli(monkeypatch, capsys, "encode", folder, "--out", code_path,
                         "--model", models["other"])
    assert rc == 2 and "this fit was made with model 'octa'" in err and not code_path.exists()


def test_cli_refuses_overwrite_corrupt_input_and_empty_surface(tmp_path, monkeypatch, capsys, models):
    latent = np.zeros(8, np.float32)
    folder, _ = fit_folder(tmp_path, models["good"], latent)
    code_path, mesh_path = tmp_path / "obj.jsrte", tmp_path / "mesh.ply"
    assert run_cli(monkeypatch, capsys, "encode", folder, "--out", code_path)[0] == 0
    before = code_path.read_bytes()
    rc, _, err = run_cli(monkeypatch, capsys, "encode", folder, "--out", code_path, "--latent", "int8")
    assert rc == 2 and "--overwrite" in err and code_path.read_bytes() == before
    assert run_cli(monkeypatch, capsys, "encode", folder, "--out", code_path, "--latent", "int8",
                   "--overwrite")[0] == 0
    assert len(code_path.read_bytes()) < len(before)

    corrupt = tmp_path / "corrupt.jsrte"
    corrupt.write_bytes(before[:-1] + bytes([before[-1] ^ 1]))
    rc, _, err = run_cli(monkeypatch, capsys, "decode", corrupt, "--out", mesh_path,
                         "--model", models["good"])
    assert rc == 2 and "corrupt.jsrte" in err and "checksum" in err and not mesh_path.exists()

    empty_latent = np.zeros(8, np.float32)
    empty_latent[0] = 5.0  # radius 0.5 - 1.0 < 0: no surface
    empty_folder, _ = fit_folder(tmp_path, models["good"], empty_latent, name="empty_fit")
    empty_code = tmp_path / "empty.jsrte"
    assert run_cli(monkeypatch, capsys, "encode", empty_folder, "--out", empty_code)[0] == 0
    rc, _, err = run_cli(monkeypatch, capsys, "decode", empty_code, "--out", mesh_path,
                         "--model", models["good"], "--resolution", "16")
    assert rc == 2 and "empty" in err and not mesh_path.exists()
    assert not list(tmp_path.glob(".*tmp*"))  # no temporary files left behind


def test_encode_a_scan_runs_the_fit(tmp_path, monkeypatch, capsys, models):
    """A scan file goes through jsrte.fit.fit (stubbed here: the fit has its own tests)."""
    import importlib

    from jsrte.result import FitResult

    fit_module = importlib.import_module("jsrte.fit")  # the subpackage (``jsrte.fit`` is the function)

    latent = np.full(8, 0.1, np.float32)
    transform = fp32_transform(2.0, [0, 1, 0], 0.3, [1, 0, 0])
    calls = {}

    def fake_fit(scan, *, model, preset, up, seed):
        calls.update(scan=scan, model=model.name, preset=preset)
        return FitResult("jsrte", transform, latent, None, 0.0, {"name": "loss"})

    monkeypatch.setattr(fit_module, "fit", fake_fit)
    scan = tmp_path / "scan.ply"
    trimesh.creation.icosphere(1).export(scan)
    code_path = tmp_path / "obj.jsrte"
    rc, _, err = run_cli(monkeypatch, capsys, "encode", scan, "--model", models["good"], "--out", code_path,
                         "--preset", "paper")
    assert rc == 0, err
    assert calls == {"scan": scan, "model": "octa", "preset": "paper"}
    code = decode(code_path.read_bytes())
    from jsrte.model.checkpoint import file_hash

    assert code == ShapeCode(latent, transform, "octa", bytes.fromhex(file_hash(models["good"]))[:16])


def test_the_name_in_a_code_is_never_opened_as_a_path(tmp_path, monkeypatch, capsys, models):
    """Without --model only shipped models are looked up by the stored name, even if it is a path."""
    from jsrte.model.checkpoint import file_hash

    monkeypatch.chdir(tmp_path)  # "good" is a folder holding model.safetensors here
    code = ShapeCode(np.zeros(8, np.float32), Sim3.identity(), "good",
                     bytes.fromhex(file_hash(models["good"]))[:16])
    code_path = tmp_path / "obj.jsrte"
    code_path.write_bytes(encode(code))
    rc, _, err = run_cli(monkeypatch, capsys, "decode", code_path, "--out", tmp_path / "m.ply")
    assert rc == 2 and "not shipped" in err and not (tmp_path / "m.ply").exists()


def test_decode_finds_the_shipped_model_by_name(tmp_path, monkeypatch, capsys, models):
    import jsrte.model.registry as registry

    latent = np.zeros(8, np.float32)
    folder, result = fit_folder(tmp_path, models["good"], latent)
    code_path = tmp_path / "obj.jsrte"
    assert run_cli(monkeypatch, capsys, "encode", folder, "--out", code_path, "--latent", "fp16")[0] == 0
    monkeypatch.setattr(registry, "shipped_models", lambda: {"octa": models["other"]})
    rc, _, err = run_cli(monkeypatch, capsys, "decode", code_path, "--out", tmp_path / "a.ply")
    assert rc == 2 and "this code was made with model 'octa'" in err and not (tmp_path / "a.ply").exists()
    monkeypatch.setattr(registry, "shipped_models", lambda: {"octa": models["good"]})
    rc, _, err = run_cli(monkeypatch, capsys, "decode", code_path, "--out", tmp_path / "a.ply",
                         "--resolution", "32")
    assert rc == 0, err
    vertices, _ = direct_mesh(models["good"], latent, result.transform, 32)
    np.testing.assert_allclose(trimesh.load(tmp_path / "a.ply", process=False).vertices, vertices, atol=1e-5)
