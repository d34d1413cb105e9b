"""From a latent code to a mesh: the decoder as an SDF function, and marching cubes."""

from __future__ import annotations

import numpy as np
import torch
import trimesh

from jsrte.extract.marching import Extraction, extract_dense, extract_narrow_band
from jsrte.model.decoder import Decoder, decoder_device


def sdf_function(decoder: Decoder, latent: torch.Tensor | np.ndarray):  # noqa: ANN201
    """A function points (n, 3) float32 canonical -> sdf (n,) for one latent code (d,).

    Evaluates on the decoder's device; the points may be anywhere, the result is on that device.
    """
    device = decoder_device(decoder)
    z = torch.as_tensor(latent, dtype=torch.float32).detach().to(device)

    def evaluate(points: torch.Tensor) -> torch.Tensor:
        with torch.no_grad():
            return decoder(points.to(device, torch.float32), z)

    return evaluate


def decode_mesh(decoder: Decoder, latent: torch.Tensor | np.ndarray, *, resolution: int = 128,
                coarse_to_fine: bool = True) -> Extraction:
    """Marching cubes of f(·, z) = 0 over [-1, 1]^3; mesh in canonical units (or None).

    ``coarse_to_fine`` evaluates the decoder only in a narrow band around the surface
    (:func:`extract_narrow_band`); otherwise on every grid sample.
    """
    was_training = decoder.training
    decoder.eval()
    try:
        fn = sdf_function(decoder, latent)
        if coarse_to_fine:
            return extract_narrow_band(fn, resolution=resolution, coarse_resolution=min(16, resolution))
        return extract_dense(fn, resolution=resolution)
    finally:
        decoder.train(was_training)


def canonical_height(decoder: Decoder, latent: torch.Tensor | np.ndarray, *, resolution: int = 48) -> float:
    """Height (canonical units, along +y) of the surface decoded from ``latent``; 0 if empty."""
    mesh: trimesh.Trimesh | None = decode_mesh(decoder, latent, resolution=resolution).mesh
    if mesh is None:
        return 0.0
    return float(mesh.bounds[1, 1] - mesh.bounds[0, 1])
