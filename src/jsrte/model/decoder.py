"""The DeepSDF decoder f(x, z): an MLP on [z, x] with the input re-injected at a middle layer.

Architecture as DeepSDF (Park et al. 2019): weight-normalized linear layers, ReLU, dropout in
training, the latent code and point concatenated again at ``skip_layer``, tanh output.
Optional Fourier features of x (``pe_frequencies``) help thin parts at a small cost.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from contextlib import contextmanager
from functools import cache

import torch
from torch import nn
from torch.nn.utils.parametrizations import weight_norm

from jsrte.model.config import ARCHITECTURES, DecoderConfig
from jsrte.timing import count_evaluations

__all__ = ["ARCHITECTURES", "Decoder", "DecoderConfig", "count_parameters", "decoder_device", "denormals_flushed",
           "flush_denormals", "flushing_denormals", "native_bfloat16", "uses_bfloat16"]


class Decoder(nn.Module):
    """f(x, z) -> sdf. Input points (n, 3) canonical units, codes (n, d); output (n,)."""

    def __init__(self, config: DecoderConfig) -> None:
        super().__init__()
        self.config = config
        point_dim = 3 * (1 + 2 * config.pe_frequencies)
        self.input_dim = config.latent_size + point_dim
        widths = [config.hidden] * config.depth
        if 0 < config.skip_layer < config.depth and config.hidden > self.input_dim:
            widths[config.skip_layer - 1] = config.hidden - self.input_dim  # DeepSDF's layout
        layers = []
        for i in range(config.depth):
            in_dim = self.input_dim if i == 0 else widths[i - 1]
            if i == config.skip_layer:
                in_dim += self.input_dim
            layers.append(self._linear(in_dim, widths[i]))
        self.layers = nn.ModuleList(layers)
        self.head = nn.Linear(config.hidden, 1)
        self.dropout = nn.Dropout(config.dropout) if config.dropout > 0 else nn.Identity()
        if config.pe_frequencies:
            freqs = (2.0 ** torch.arange(config.pe_frequencies)) * math.pi
            self.register_buffer("frequencies", freqs, persistent=False)

    def _linear(self, in_dim: int, out_dim: int) -> nn.Module:
        layer = nn.Linear(in_dim, out_dim)
        return weight_norm(layer) if self.config.weight_norm else layer

    def fold_weight_norm(self) -> Decoder:
        """Fold weight normalization into plain weights (faster inference); returns self."""
        from torch.nn.utils import parametrize

        for layer in self.layers:
            if parametrize.is_parametrized(layer):
                parametrize.remove_parametrizations(layer, "weight")
        return self

    def encode_points(self, points: torch.Tensor) -> torch.Tensor:
        """Points (n, 3) -> features (n, 3 (1 + 2F)): xyz and its Fourier features."""
        if not self.config.pe_frequencies:
            return points
        angles = points[..., None] * self.frequencies  # (n, 3, F)
        return torch.cat([points, angles.sin().flatten(-2), angles.cos().flatten(-2)], dim=-1)

    def forward(self, points: torch.Tensor, codes: torch.Tensor) -> torch.Tensor:
        """SDF (n,) at ``points`` (n, 3) for per-point latent ``codes`` (n, d) or one code (d,)."""
        count_evaluations(points.shape[:-1].numel())
        if codes.dim() == 1:
            codes = codes.expand(points.shape[0], -1)
        inputs = torch.cat([codes, self.encode_points(points)], dim=-1)
        h = inputs
        for i, layer in enumerate(self.layers):
            if i == self.config.skip_layer:
                h = torch.cat([h, inputs], dim=-1)
            h = self.dropout(torch.relu(layer(h)))
        return torch.tanh(self.head(h)).squeeze(-1)


def decoder_device(module: nn.Module) -> torch.device:
    """The device of ``module``'s parameters or buffers (where its inputs must be); CPU if it has none."""
    for tensor in (*module.parameters(), *module.buffers()):
        return tensor.device
    return torch.device("cpu")


def count_parameters(module: nn.Module) -> int:
    """The number of scalar parameters of ``module``."""
    return sum(p.numel() for p in module.parameters())


@cache
def native_bfloat16(device_type: str) -> bool:
    """Whether a device of this type ("cpu", "cuda") multiplies bfloat16 matrices natively: a
    CUDA GPU that supports them, a CPU with AVX-512 BF16 or AMX. Elsewhere bfloat16 is emulated
    and slower than float32."""
    if device_type == "cuda":
        return torch.cuda.is_available() and torch.cuda.is_bf16_supported()
    if device_type != "cpu":
        return False
    checks = [getattr(torch.cpu, name, None) for name in ("_is_avx512_bf16_supported", "_is_amx_tile_supported")]
    return any(check() for check in checks if check is not None)


def flush_denormals() -> bool:
    """Flush denormal floats (under 1.2e-38 in float32) to zero on the calling thread and the
    threads it starts from now on; False where the CPU cannot. A fit's float32 decoder passes
    meet enough of them to run 2.8 times slower on an Intel Xeon (docs/speed.md), and no SDF,
    code or pose means anything at that size. The commands call it once, before their threads
    start; a library fit flushes only while it runs (:func:`denormals_flushed`)."""
    return bool(torch.set_flush_denormal(True))


def flushing_denormals() -> bool:
    """Whether the calling thread flushes denormal floats to zero now."""
    return torch.tensor(1e-39, dtype=torch.float32).item() == 0.0


@contextmanager
def denormals_flushed() -> Iterator[None]:
    """Denormal floats flushed to zero on the calling thread inside the block
    (:func:`flush_denormals`), as they were after it."""
    before = flushing_denormals()
    flush_denormals()
    try:
        yield
    finally:
        if not before:
            torch.set_flush_denormal(False)


def uses_bfloat16(decoder_dtype: str, device: torch.device) -> bool:
    """Whether the fit setting ``decoder_dtype`` ("float32", "bfloat16" or "auto": bfloat16 where
    :func:`native_bfloat16`) means bfloat16 matrix products on ``device``."""
    return decoder_dtype == "bfloat16" or (decoder_dtype == "auto" and native_bfloat16(device.type))
