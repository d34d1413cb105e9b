"""Model files: one safetensors file holding decoder weights, latent codes and JSON metadata.

The metadata (architecture, latent size, class, canonical-frame convention, training-data
summary, metrics, library version) is embedded in the safetensors header under ``jsrte``,
so weights and description can never disagree; a readable ``.json`` copy is written beside it.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import torch
from safetensors import SafetensorError
from safetensors.torch import load_file, save_file

import jsrte
from jsrte.atomic import write_json_atomic, write_with
from jsrte.errors import JsrteError
from jsrte.model.decoder import Decoder, DecoderConfig

FORMAT = "jsrte-model"
FORMAT_VERSION = 1
CONVENTION = "ShapeNetCore v2 canonical frame (+y up, front -z), DeepSDF unit-sphere normalization, SDF negative inside"
CODES_KEY = "latent_codes"


@dataclass
class DeepSdfModel:
    """A trained auto-decoder: the decoder, the training shapes' codes, and what it is.

    Attributes
    ----------
    decoder : Decoder
    codes : (n_shapes, d) float32, latent codes of the training shapes
    meta : dict, JSON-serializable description (see module docstring)
    distilled : its distilled decoder (``jsrte distill``) once a fit has looked it up
        (``jsrte.model.registry.distilled_decoder``), else None
    """

    decoder: Decoder
    codes: torch.Tensor
    meta: dict[str, Any] = field(default_factory=dict)
    distilled: DeepSdfModel | None = field(default=None, repr=False, compare=False)

    @property
    def name(self) -> str:
        return str(self.meta.get("name", "unnamed"))

    @property
    def latent_size(self) -> int:
        return self.decoder.config.latent_size

    def mean_code(self) -> torch.Tensor:
        """The mean of the training codes (d,)."""
        return self.codes.mean(0)

    def to(self, device: torch.device | str) -> DeepSdfModel:
        """Move the decoder to ``device`` (in place; the codes stay on the CPU); returns self.

        Fits, reconstructions and mesh extraction run where the decoder is.
        """
        self.decoder.to(device)
        return self

    def __getstate__(self) -> dict[str, Any]:
        """Pickling (worker processes): a weight-normed decoder pickles only through its state dict."""
        if type(self.decoder) is Decoder:
            weights = {k: v.detach().cpu() for k, v in self.decoder.state_dict().items()}
            return {"config": self.decoder.config.to_dict(), "weights": weights, "codes": self.codes,
                    "meta": self.meta}
        return dict(self.__dict__)

    def __setstate__(self, state: dict[str, Any]) -> None:
        if "config" in state:
            decoder = Decoder(DecoderConfig.from_dict(state["config"]))
            decoder.load_state_dict(state["weights"])
            decoder.eval()
            state = {"decoder": decoder, "codes": state["codes"], "meta": state["meta"]}
        self.__dict__.update(state)


def tensors_of(model: DeepSdfModel) -> dict[str, torch.Tensor]:
    """The tensors a model file stores: the decoder's weights and the (n, d) latent codes."""
    tensors = {f"decoder.{k}": v.detach().contiguous() for k, v in model.decoder.state_dict().items()}
    tensors[CODES_KEY] = model.codes.detach().contiguous()
    return tensors


def model_metadata(model: DeepSdfModel) -> dict[str, Any]:
    """The JSON description stored with a model (architecture, class, data, settings, metrics)."""
    meta = dict(model.meta)
    meta.update(
        format=FORMAT,
        format_version=FORMAT_VERSION,
        architecture=model.decoder.config.to_dict(),
        n_shapes=int(model.codes.shape[0]),
        convention=CONVENTION,
        jsrte_version=jsrte.__version__,
    )
    return meta


def save_model(model: DeepSdfModel, path: str | Path) -> None:
    """Write ``path`` (.safetensors) and ``path.json`` atomically; JsrteError (nothing written) if
    a weight or code is NaN or infinite."""
    path = Path(path)
    meta = model_metadata(model)
    tensors = tensors_of(model)
    bad = non_finite_tensors(tensors)
    if bad:
        raise JsrteError(f"refusing to write a model with NaN or infinite values (in {', '.join(bad[:3])})", path)
    write_with(path, lambda tmp: save_file(tensors, str(tmp), metadata={"jsrte": json.dumps(meta)}))
    meta["sha256"] = file_hash(path)
    write_json_atomic(path.with_suffix(".json"), meta)


def non_finite_tensors(tensors: dict[str, torch.Tensor]) -> list[str]:
    """Names of the floating-point tensors holding NaN or infinite values."""
    return [name for name, t in tensors.items() if t.is_floating_point() and not bool(torch.isfinite(t).all())]


def check_recorded_hash(path: Path, sha256: str) -> None:
    """JsrteError if the ``.json`` beside the model file records another SHA-256 than ``sha256``."""
    record = path.with_suffix(".json")
    try:
        recorded = json.loads(record.read_text()).get("sha256")
    except (OSError, UnicodeDecodeError, ValueError, AttributeError):
        return  # no readable description beside it: nothing to compare with
    if isinstance(recorded, str) and recorded != sha256:
        raise JsrteError(f"the file's SHA-256 ({sha256[:16]}…) differs from the one {record.name} records "
                         f"({recorded[:16]}…): the weights were altered or damaged", path)


def file_hash(path: str | Path) -> str:
    """SHA-256 (hex) of a file's bytes: the model's identity in codes and results."""
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def read_metadata(path: str | Path) -> dict[str, Any]:
    """The JSON metadata embedded in a model or training-state file."""
    from safetensors import safe_open

    path = Path(path)
    if not path.is_file():
        raise JsrteError("no such model file", path)
    try:
        with safe_open(str(path), framework="pt") as f:
            raw = (f.metadata() or {}).get("jsrte")
    except (SafetensorError, OSError, ValueError, RuntimeError) as exc:
        # safetensors reports a file that vanished after the check above as a RuntimeError
        if not path.is_file():
            raise JsrteError("no such model file", path) from exc
        raise JsrteError(f"corrupt or not a safetensors model file ({exc})", path) from exc
    if raw is None:
        raise JsrteError("is a safetensors file but not a jsrte model (no 'jsrte' metadata)", path)
    try:
        return json.loads(raw)
    except json.JSONDecodeError as exc:
        raise JsrteError(f"model metadata is not valid JSON ({exc})", path) from exc


def load_model(path: str | Path, *, expect: DecoderConfig | None = None) -> DeepSdfModel:
    """Load a model file; clear errors for a corrupt file, missing keys or a wrong architecture."""
    path = Path(path)
    meta = read_metadata(path)
    if meta.get("format") not in (FORMAT, "jsrte-train-state"):
        raise JsrteError(f"unexpected format {meta.get('format')!r}", path)
    try:
        config = DecoderConfig.from_dict(meta["architecture"])
    except (KeyError, TypeError, ValueError) as exc:
        raise JsrteError(f"bad architecture in metadata ({exc})", path) from exc
    if expect is not None and config != expect:
        raise JsrteError(f"architecture {config} does not match the expected {expect}", path)
    try:
        tensors = load_file(str(path))
    except (SafetensorError, OSError) as exc:
        raise JsrteError(f"corrupt model file ({exc})", path) from exc
    decoder = Decoder(config)
    state = {k.removeprefix("decoder."): v for k, v in tensors.items() if k.startswith("decoder.")}
    try:
        decoder.load_state_dict(state, strict=True)
    except RuntimeError as exc:
        first = str(exc).splitlines()[0]
        raise JsrteError(f"weights do not match the architecture ({first})", path) from exc
    if CODES_KEY not in tensors:
        raise JsrteError(f"missing tensor {CODES_KEY!r}", path)
    codes = tensors[CODES_KEY]
    if codes.ndim != 2 or codes.shape[1] != config.latent_size:
        raise JsrteError(f"latent codes {tuple(codes.shape)} do not match latent size {config.latent_size}", path)
    bad = non_finite_tensors(tensors)
    if bad:
        raise JsrteError(f"holds NaN or infinite values (in {', '.join(bad[:3])}): not a usable model", path)
    sha256 = file_hash(path)
    check_recorded_hash(path, sha256)
    meta.setdefault("sha256", sha256)
    meta["path"] = str(path)
    decoder.eval()
    return DeepSdfModel(decoder=decoder, codes=codes, meta=meta)
