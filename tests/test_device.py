"""Devices: choosing one, clear errors for one this machine lacks; models that cross processes."""

import pickle

import pytest
import torch

from jsrte.cli.common import resolve_device
from jsrte.errors import JsrteError
from jsrte.model.checkpoint import DeepSdfModel
from jsrte.model.decoder import Decoder, DecoderConfig, decoder_device
from jsrte.model.meshing import sdf_function

NO_GPU = not torch.cuda.is_available()


def test_cpu_is_always_there():
    assert resolve_device("cpu") == torch.device("cpu")


@pytest.mark.parametrize("name, message", [
    ("mps", "not supported"), ("tpu", "unknown device"), ("gpu:x", "unknown device")])
def test_unknown_devices_are_refused(name, message):
    with pytest.raises(JsrteError, match=message):
        resolve_device(name)


@pytest.mark.skipif(not NO_GPU, reason="this machine has a CUDA GPU")
def test_cuda_without_a_gpu_says_so():
    with pytest.raises(JsrteError, match="sees no CUDA GPU"):
        resolve_device("cuda")


@pytest.mark.skipif(not NO_GPU, reason="this machine has a CUDA GPU")
def test_fit_cli_refuses_cuda_without_a_gpu_before_writing(tmp_path, run_cli):
    scan = tmp_path / "scan.xyz"
    scan.write_text("0 0 0\n1 0 0\n0 1 0\n")
    code, _, stderr = run_cli(["fit", str(scan), "--out", str(tmp_path / "out"), "--device", "cuda"])
    assert code != 0 and "no CUDA GPU" in stderr and "--device cpu" in stderr
    assert not (tmp_path / "out").exists()


def test_weight_normed_model_survives_pickling():
    torch.manual_seed(0)
    config = DecoderConfig(latent_size=8, hidden=32, depth=4, skip_layer=2, weight_norm=True)
    model = DeepSdfModel(Decoder(config), torch.randn(3, 8), {"name": "tiny", "category": "chair"})
    back = pickle.loads(pickle.dumps(model))
    points, z = torch.randn(100, 3), torch.randn(8)
    assert back.meta == model.meta and torch.equal(back.codes, model.codes)
    assert torch.allclose(sdf_function(back.decoder, z)(points), sdf_function(model.decoder, z)(points))


def test_decoder_device_of_a_module_without_weights_is_the_cpu():
    assert decoder_device(torch.nn.Identity()) == torch.device("cpu")
