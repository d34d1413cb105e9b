"""Drawing the parameters of one procedural shape, recording each one as it is drawn."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np


class ParamSampler:
    """Draws named parameters from ``rng`` and records them in ``params``.

    Lengths are rounded to 0.1 mm and angles to 0.01 degree so that the recorded values
    rebuild the same shape.
    """

    def __init__(self, rng: np.random.Generator) -> None:
        self.rng = rng
        self.params: dict[str, Any] = {}

    def uniform(self, name: str, lo: float, hi: float, *, digits: int = 4) -> float:
        """A value uniform in ``[lo, hi]``, recorded as ``name``."""
        value = round(float(self.rng.uniform(lo, hi)), digits)
        self.params[name] = value
        return value

    def integer(self, name: str, lo: int, hi: int) -> int:
        """An integer uniform in ``lo..hi`` (both included), recorded as ``name``."""
        value = int(self.rng.integers(lo, hi + 1))
        self.params[name] = value
        return value

    def choice(self, name: str, options: Sequence[str], p: Sequence[float] | None = None) -> str:
        """One of ``options`` (probabilities ``p``, default uniform), recorded as ``name``."""
        value = str(options[int(self.rng.choice(len(options), p=p))])
        self.params[name] = value
        return value

    def flag(self, name: str, probability: float) -> bool:
        """True with ``probability``, recorded as ``name``."""
        value = bool(self.rng.random() < probability)
        self.params[name] = value
        return value

    def set(self, name: str, value: Any) -> Any:
        """Record a derived or fixed value."""
        self.params[name] = value
        return value
