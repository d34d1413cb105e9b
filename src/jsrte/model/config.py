"""Decoder architectures and training settings: plain dataclasses, importable without PyTorch.

The command line reads these for its option defaults and help; ``jsrte.model.decoder`` and
``jsrte.model.train`` re-export them.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass


@dataclass(frozen=True)
class DecoderConfig:
    """Decoder architecture (stored in every checkpoint).

    Attributes
    ----------
    latent_size : dimension d of the latent code z
    hidden : width of every hidden layer
    depth : number of hidden layers
    skip_layer : index of the hidden layer whose input is concatenated with [z, x] again
    dropout : dropout probability in training (0 disables)
    weight_norm : weight-normalize the linear layers
    pe_frequencies : number of Fourier-feature octaves of x (0: raw xyz only)
    """

    latent_size: int = 64
    hidden: int = 256
    depth: int = 6
    skip_layer: int = 3
    dropout: float = 0.0
    weight_norm: bool = True
    pe_frequencies: int = 0

    def to_dict(self) -> dict:
        return asdict(self)

    @staticmethod
    def from_dict(d: dict) -> DecoderConfig:
        known = set(DecoderConfig.__dataclass_fields__)
        unknown = set(d) - known
        if unknown:
            raise ValueError(f"unknown decoder config keys: {sorted(unknown)}")
        return DecoderConfig(**d)


ARCHITECTURES: dict[str, DecoderConfig] = {
    # The paper's network (DeepSDF): 8 x 512, latent 256, skip at layer 4, dropout 0.2.
    "deepsdf": DecoderConfig(latent_size=256, hidden=512, depth=8, skip_layer=4, dropout=0.2),
    # CPU default, chosen by measurement on the 2-core machine (docs/models.md).
    "cpu": DecoderConfig(latent_size=64, hidden=256, depth=6, skip_layer=3, dropout=0.0,
                         pe_frequencies=0),
    # Narrower networks, 3.3x and 5x cheaper to evaluate than "cpu". Trained on their own, their
    # fits lose accuracy (docs/speed.md, "A smaller decoder"); distilled from a shipped model
    # (jsrte distill), "tiny" does the search of the express preset.
    "small": DecoderConfig(latent_size=64, hidden=128, depth=6, skip_layer=3, dropout=0.0),
    "tiny": DecoderConfig(latent_size=64, hidden=128, depth=4, skip_layer=2, dropout=0.0),
}


STATE_NAME = "train_state.safetensors"
PREVIOUS_STATE_NAME = "train_state.previous.safetensors"
"""The checkpoint before the last one: ``--resume`` falls back to it if the last one is unreadable."""
MODEL_NAME = "model.safetensors"
LOG_NAME = "train_log.csv"


@dataclass(frozen=True)
class TrainSettings:
    """Auto-decoder training settings (stored in the checkpoint).

    ``clamp`` and ``code_reg`` are DeepSDF's (0.1 and 1e-4). Learning rates follow a cosine
    from their base value to ``final_lr_fraction`` of it over ``steps``.
    """

    steps: int = 4000
    shapes_per_batch: int = 16
    points_per_shape: int = 1024
    lr_net: float = 1e-3
    lr_codes: float = 5e-3
    final_lr_fraction: float = 0.05
    clamp: float = 0.1
    code_reg: float = 1e-4
    code_init_std: float = 0.01
    checkpoint_every: int = 200
    seed: int = 0

    def lr_factor(self, step: int) -> float:
        """Cosine learning-rate factor at ``step`` (1 at step 0, ``final_lr_fraction`` at the end)."""
        return cosine_factor(min(step / max(self.steps, 1), 1.0), self.final_lr_fraction)


def cosine_factor(progress: float, final_fraction: float) -> float:
    """A cosine schedule's factor at ``progress`` in [0, 1]: 1 at 0, ``final_fraction`` at 1."""
    return final_fraction + (1.0 - final_fraction) * 0.5 * (1.0 + math.cos(math.pi * progress))
