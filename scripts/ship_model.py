"""Copy a trained model into the package as a shipped model, with its card figures embedded.

Usage: .venv/bin/python scripts/ship_model.py RUN_DIR NAME [EVAL_JSON]
       .venv/bin/python scripts/ship_model.py --sizes NAME... (the sizes record of shipped models only)
- RUN_DIR: a `jsrte train --out` folder (its model.safetensors);
- NAME: the shipped name (`--model NAME`);
- EVAL_JSON: the output of `jsrte evaluate-model --out` (its means go into meta["metrics"]).
The class's canonical height and radius (used to initialize fits) are measured on the surface
decoded from the mean training code and stored too; the sizes of the training shapes (metres,
procedural data only) go to the shipped sizes record (``jsrte.model.sizes``).
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

from jsrte.fit.solve import class_geometry
from jsrte.model.checkpoint import load_model, save_model
from jsrte.model.registry import PRETRAINED_DIR
from jsrte.model.sizes import record_shipped_sizes, training_sizes


def main(run_dir: str, name: str, eval_json: str | None = None) -> None:
    model = load_model(Path(run_dir) / "model.safetensors")
    for key in ("path", "sha256", "canonical_height", "canonical_radius"):
        model.meta.pop(key, None)
    geometry = class_geometry(model)
    model.meta.update(name=name, canonical_height=geometry.height, canonical_radius=geometry.radius)
    if eval_json:
        model.meta["metrics"] = json.loads(Path(eval_json).read_text())["summary"]
    out = PRETRAINED_DIR / f"{name}.safetensors"
    save_model(model, out)
    print(f"wrote {out} ({out.stat().st_size / 1e6:.2f} MB); geometry {geometry}")
    record_sizes(name)


def record_sizes(name: str) -> None:
    """Record the shipped model ``name``'s class sizes (procedural training data only)."""
    model = load_model(PRETRAINED_DIR / f"{name}.safetensors")
    sizes = training_sizes(model.meta)
    if sizes is not None:
        record_shipped_sizes(name, model.meta["sha256"], sizes)
        print(f"sizes of {name}'s {sizes.shapes} training shapes: {sizes.smallest:.3f}-{sizes.largest:.3f} m")


if __name__ == "__main__":
    if sys.argv[1:2] == ["--sizes"]:  # only the sizes record of shipped models: --sizes NAME...
        for shipped in sys.argv[2:]:
            record_sizes(shipped)
    else:
        main(*sys.argv[1:])
