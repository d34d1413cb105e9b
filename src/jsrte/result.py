"""What a fit returns: one named type, the same for JSRTE and for every baseline."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
import trimesh

from jsrte.geometry.sim3 import Sim3


@dataclass
class HypothesisReport:
    """One starting point and where it ended (scan units, radians)."""

    index: int
    init: dict[str, Any]
    loss: float
    transform: Sim3 | None = None
    angles: dict[str, float] | None = None
    fscore: float | None = None
    pruned: bool = False
    failed: str | None = None
    """Why the hypothesis was dropped (its objective turned NaN or infinite), or None."""

    def to_json(self) -> dict[str, Any]:
        return {"index": self.index, "init": self.init,
                "loss": self.loss if np.isfinite(self.loss) else None, "pruned": self.pruned,
                **({"failed": self.failed} if self.failed else {}),
                "fscore_vs_query": self.fscore, "angles": self.angles,
                "transform": None if self.transform is None else self.transform.to_dict()}


@dataclass
class FitResult:
    """The retrieved shape and where it stands.

    Attributes
    ----------
    method : "jsrte" or a baseline's name
    transform : ``scan_from_canonical`` Sim3 (canonical unit-sphere frame -> scan units)
    latent : (d,) float32 latent code (None for retrieval baselines)
    mesh_canonical : retrieved surface in the canonical frame (None if empty)
    loss : final objective of the winner
    criterion : how the winner was chosen ("fscore" or "loss") and its value
    angles : the paper's ψ, ρ, θ of the winner (radians), when it has them
    """

    method: str
    transform: Sim3
    latent: np.ndarray | None
    mesh_canonical: trimesh.Trimesh | None
    loss: float
    criterion: dict[str, Any]
    angles: dict[str, float] | None = None
    hypotheses: list[HypothesisReport] = field(default_factory=list)
    timing: dict[str, float] = field(default_factory=dict)
    info: dict[str, Any] = field(default_factory=dict)
    query_points: np.ndarray | None = None
    """(n, 3) the query's surface points in scan units (a scan's object points), for overlays;
    not part of ``to_json``."""
    quality: dict[str, Any] = field(default_factory=dict)
    """Measures of how well the fit explains the query (jsrte.fit.quality.MEASURES); empty if not assessed."""
    flag: str | None = None
    """"ok" or "doubtful" (jsrte.fit.quality.flag_of); None if not assessed."""

    @property
    def mesh(self) -> trimesh.Trimesh | None:
        """The retrieved surface in the scan's frame."""
        if self.mesh_canonical is None:
            return None
        m = self.mesh_canonical.copy()
        m.vertices = self.transform.apply(m.vertices)
        return m

    def to_json(self) -> dict[str, Any]:
        t = self.transform
        return {
            "method": self.method,
            "scale": t.s,
            "rotation": t.R.tolist(),
            "translation": t.t.tolist(),
            "matrix": t.matrix().tolist(),
            **({"psi": self.angles["psi"], "rho": self.angles["rho"], "theta": self.angles["theta"]}
               if self.angles else {}),
            "latent": None if self.latent is None else np.asarray(self.latent, float).tolist(),
            "loss": self.loss,
            "criterion": self.criterion,
            "empty_surface": self.mesh_canonical is None,
            **({"flag": self.flag, "quality": _finite_or_none(self.quality)} if self.flag is not None else {}),
            "hypotheses": [h.to_json() for h in self.hypotheses],
            "timing_s": self.timing,
            **self.info,
        }


def _finite_or_none(values: dict[str, Any]) -> dict[str, Any]:
    """``values`` with NaN and infinite floats as None (JSON has no NaN)."""
    return {k: None if isinstance(v, float) and not np.isfinite(v) else v for k, v in values.items()}
