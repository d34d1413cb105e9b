"""Analytic stand-ins for a trained decoder, so the fit can be tested against exact answers."""

from __future__ import annotations

import numpy as np
import torch
from torch import nn

from jsrte.model.decoder import DecoderConfig


def box_sdf(points: torch.Tensor, centre: tuple[float, float, float], half: tuple[float, float, float]) -> torch.Tensor:
    """Exact SDF (n,) of an axis-aligned box at ``points`` (n, 3)."""
    q = (points - torch.tensor(centre, dtype=points.dtype)).abs() - torch.tensor(half, dtype=points.dtype)
    outside = q.clamp(min=0).norm(dim=-1)
    inside = q.max(dim=-1).values.clamp(max=0)
    return outside + inside


class LShapeDecoder(nn.Module):
    """f(x, z): an asymmetric union of two boxes (no rotational symmetry), ignoring z.

    Quacks like ``jsrte.model.decoder.Decoder`` (``config.latent_size``, ``forward(points, codes)``).
    """

    def __init__(self, latent_size: int = 4) -> None:
        super().__init__()
        self.config = DecoderConfig(latent_size=latent_size, hidden=8, depth=2, skip_layer=1)

    def forward(self, points: torch.Tensor, codes: torch.Tensor) -> torch.Tensor:
        seat = box_sdf(points, (0.0, -0.2, 0.0), (0.35, 0.08, 0.3))
        back = box_sdf(points, (0.0, 0.25, 0.25), (0.35, 0.4, 0.06))
        leg = box_sdf(points, (0.25, -0.55, -0.2), (0.05, 0.3, 0.05))
        return torch.minimum(torch.minimum(seat, back), leg)


class WideningLShapeDecoder(nn.Module):
    """f(x, z): the L-shape of :class:`LShapeDecoder` whose seat and back are 0.35 (1 + z_0)
    wide (half-width along x); its height does not change, so scale and code are not confounded."""

    def __init__(self, latent_size: int = 3) -> None:
        super().__init__()
        self.config = DecoderConfig(latent_size=latent_size, hidden=8, depth=2, skip_layer=1)

    def forward(self, points: torch.Tensor, codes: torch.Tensor) -> torch.Tensor:
        if codes.dim() == 1:
            codes = codes.expand(points.shape[0], -1)
        half_x = 0.35 * (1.0 + codes[:, 0])

        def box(centre: tuple[float, float, float], half_yz: tuple[float, float]) -> torch.Tensor:
            q = (points - torch.tensor(centre, dtype=points.dtype)).abs()
            q = q - torch.stack([half_x, *(torch.full_like(half_x, v) for v in half_yz)], dim=-1)
            return q.clamp(min=0).norm(dim=-1) + q.max(dim=-1).values.clamp(max=0)

        leg = box_sdf(points, (0.25, -0.55, -0.2), (0.05, 0.3, 0.05))
        return torch.minimum(torch.minimum(box((0.0, -0.2, 0.0), (0.08, 0.3)), box((0.0, 0.25, 0.25), (0.4, 0.06))),
                             leg)


class TableDecoder(nn.Module):
    """f(x, z): a rectangular top on four legs, ignoring z: the same shape after half a turn about
    the up axis (y), another after a quarter turn."""

    def __init__(self, latent_size: int = 4) -> None:
        super().__init__()
        self.config = DecoderConfig(latent_size=latent_size, hidden=8, depth=2, skip_layer=1)

    def forward(self, points: torch.Tensor, codes: torch.Tensor) -> torch.Tensor:
        sdf = box_sdf(points, (0.0, 0.3, 0.0), (0.8, 0.04, 0.45))
        for x in (-0.7, 0.7):
            for z in (-0.35, 0.35):
                sdf = torch.minimum(sdf, box_sdf(points, (x, -0.15, z), (0.04, 0.45, 0.04)))
        return sdf


class SphereDecoder(nn.Module):
    """f(x, z) = |x| − (r0 + z_0 + z_1): a sphere whose radius two latent directions change alike."""

    def __init__(self, r0: float = 0.5) -> None:
        super().__init__()
        self.r0 = r0
        self.config = DecoderConfig(latent_size=2, hidden=8, depth=2, skip_layer=1)

    def forward(self, points: torch.Tensor, codes: torch.Tensor) -> torch.Tensor:
        if codes.dim() == 1:
            codes = codes.expand(points.shape[0], -1)
        return points.norm(dim=-1) - (self.r0 + codes[:, 0] + codes[:, 1])


class BallAndBlobDecoder(nn.Module):
    """A ball of radius 0.5 at the origin and one of 0.25 beside it (+x, centre 0.75): a two-piece
    "pair" class for class-choice tests (code ignored)."""

    def __init__(self) -> None:
        super().__init__()
        self.config = SphereDecoder().config

    def forward(self, points: torch.Tensor, codes: torch.Tensor) -> torch.Tensor:
        far = (points - torch.tensor([0.75, 0.0, 0.0], dtype=points.dtype)).norm(dim=-1) - 0.25
        return torch.minimum(points.norm(dim=-1) - 0.5, far)


def octahedron_model(bias: float = -0.5, name: str = "octa", **meta):
    """A hand-set decoder: f(x, z) = tanh(|x|_1 + bias + 0.2 z_0), an octahedron of radius
    -bias - 0.2 z_0 (canonical units) that the latent visibly changes; ``meta`` adds to its metadata."""
    from jsrte.model.checkpoint import DeepSdfModel
    from jsrte.model.decoder import Decoder, DecoderConfig

    d = 8
    config = DecoderConfig(latent_size=d, hidden=16, depth=2, skip_layer=2, weight_norm=False)
    decoder = Decoder(config)
    with torch.no_grad():
        first, second = decoder.layers
        first.weight.zero_()
        first.bias.zero_()
        for i in range(3):
            first.weight[2 * i, d + i] = 1.0
            first.weight[2 * i + 1, d + i] = -1.0
        first.weight[6, 0], first.weight[7, 0] = 1.0, -1.0
        second.weight.copy_(torch.eye(16))
        second.bias.zero_()
        decoder.head.weight.zero_()
        decoder.head.weight[0, :6] = 1.0
        decoder.head.weight[0, 6], decoder.head.weight[0, 7] = 0.2, -0.2
        decoder.head.bias.fill_(bias)
    return DeepSdfModel(decoder=decoder, codes=torch.zeros(2, d), meta={"name": name, "category": "chair", **meta})


def octahedron_query(radius: float = 0.5, n: int = 3000, seed: int = 0):
    """SDF samples (an L1 ball of ``radius``) of the octahedron model's own shape."""
    from jsrte.fit.query import SdfQuery

    rng = np.random.default_rng(seed)
    points = rng.uniform(-1.0, 1.0, (n, 3))
    sdf = np.abs(points).sum(1) - radius
    surface = points[np.abs(sdf) < 0.05]
    return SdfQuery(points, sdf, surface)


def make_query(mesh, truth, up, rng):
    """SDF samples of ``mesh`` placed by ``truth`` (near the surface and 15 cm out), floor under it if ``up``."""
    from jsrte.fit.query import SdfQuery
    from jsrte.sdf.mesh_sdf import signed_distance

    placed = mesh.copy()
    placed.vertices = truth.apply(mesh.vertices)
    surface = np.asarray(placed.sample(3000, seed=1))
    points = np.concatenate([surface + rng.normal(size=surface.shape) * 0.02,
                             surface + rng.normal(size=surface.shape) * 0.15])
    floor = None if up is None else float((placed.vertices @ up).min())
    return SdfQuery(points, signed_distance(placed, points), surface, up=up, floor_offset=floor)


def tilted_truth(theta: float):
    """A Sim3 turning by ``theta`` about a tilted up axis, and that axis (3,)."""
    from jsrte.geometry.sim3 import Sim3, axis_angle_matrix, rotation_between

    up = np.array([0.3, 0.9, -0.2])
    up /= np.linalg.norm(up)
    rotation = axis_angle_matrix(up, theta) @ rotation_between([0, 1, 0], up)
    return Sim3(1.7, rotation, np.array([2.0, -1.0, 0.5])), up


def tall_class_case(mesh, factor: float = 2.5):
    """An object ``factor`` times taller, in its own units, than its class's mean shape (a class
    whose shapes vary in proportions): a query of the L-shape ``mesh`` under a tilted known
    transform, and an L-shape model whose recorded mean height is ``factor`` times the mesh's.
    Returns (query, truth Sim3, model, the mesh's height, its bounding-sphere radius)."""
    from jsrte.metrics.surface import bounding_sphere
    from jsrte.model.checkpoint import DeepSdfModel

    truth, up = tilted_truth(theta=1.0)
    query = make_query(mesh, truth, up, np.random.default_rng(3))
    height = float(np.ptp(mesh.vertices[:, 1]))
    radius = float(bounding_sphere(np.asarray(mesh.vertices))[1])
    model = DeepSdfModel(LShapeDecoder(), torch.zeros(1, 4),
                         {"name": "lshape", "canonical_height": factor * height, "canonical_radius": radius})
    return query, truth, model, height, radius
