"""Auto-decoder training (DeepSDF): decoder weights and one latent code per shape, jointly.

Deterministic and resumable: the batch of step k depends only on (seed, k), and the training
state (weights, codes, Adam moments, step) is one safetensors file written atomically, so
``resume`` after a kill continues exactly as an uninterrupted run would.
"""

from __future__ import annotations

import csv
import json
import math
import os
import time
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
import torch
from safetensors import SafetensorError
from safetensors.torch import load_file, save_file
from tqdm import tqdm

from jsrte.atomic import atomic_path
from jsrte.errors import JsrteError
from jsrte.model.checkpoint import DeepSdfModel, non_finite_tensors, read_metadata, save_model, tensors_of
from jsrte.model.config import LOG_NAME, MODEL_NAME, PREVIOUS_STATE_NAME, STATE_NAME, TrainSettings
from jsrte.model.decoder import Decoder, DecoderConfig
from jsrte.model.distributed import DROPOUT_RANK_STRIDE, DistContext, average_gradient, sum_over_ranks


@dataclass
class TrainingData:
    """SDF samples of the training shapes, in memory.

    Attributes
    ----------
    points : (n_shapes, m, 3) float32, canonical frame
    sdf : (n_shapes, m) float32
    summary : dict, what the data is (class, source, seeds, count), stored in the model
    """

    points: torch.Tensor
    sdf: torch.Tensor
    summary: dict[str, Any]

    @staticmethod
    def from_samples(samples: list, summary: dict[str, Any]) -> TrainingData:
        """Stack SdfSamples (each with >= m points; all cut to the smallest m)."""
        if not samples:
            raise JsrteError("no training shapes")
        m = min(len(s.sdf) for s in samples)
        pts = torch.stack([torch.from_numpy(s.points[:m]) for s in samples])
        sdf = torch.stack([torch.from_numpy(s.sdf[:m]) for s in samples])
        return TrainingData(pts, sdf, summary)

    @property
    def n_shapes(self) -> int:
        return int(self.points.shape[0])


def batch_indices(settings: TrainSettings, n_shapes: int, m: int,
                  step: int) -> tuple[torch.Tensor, torch.Tensor]:
    """The (shape, sample) indices of step ``step``: (B,) and (B, K); a function of (seed, step) only.

    Shapes run through a fresh permutation each epoch, so every code is updated equally often.
    """
    b = min(settings.shapes_per_batch, n_shapes)
    start = step * b
    epoch, offset = divmod(start, n_shapes)
    shapes = []
    while len(shapes) < b:
        generator = torch.Generator().manual_seed(settings.seed * 1_000_003 + epoch)
        perm = torch.randperm(n_shapes, generator=generator)
        shapes.extend(perm[offset:offset + b - len(shapes)].tolist())
        epoch, offset = epoch + 1, 0
    g = torch.Generator().manual_seed(settings.seed * 7_919 + step + 1)
    samples = torch.randint(m, (b, settings.points_per_shape), generator=g)
    return torch.tensor(shapes), samples


def clamped_l1(pred: torch.Tensor, target: torch.Tensor, clamp: float) -> torch.Tensor:
    """DeepSDF's loss: mean |clamp(pred) - clamp(target)|."""
    return (pred.clamp(-clamp, clamp) - target.clamp(-clamp, clamp)).abs().mean()


class Trainer:
    """Trains a decoder and codes on ``data``; checkpoints to ``out_dir``.

    With ``dist`` (a torchrun job, :mod:`jsrte.model.distributed`) each rank computes its block
    of every step's batch; only rank 0 writes checkpoints and the log.
    """

    def __init__(self, config: DecoderConfig, settings: TrainSettings, data: TrainingData,
                 out_dir: Path, meta: dict[str, Any], *, dist: DistContext | None = None) -> None:
        self.config, self.settings, self.data, self.out_dir = config, settings, data, Path(out_dir)
        self.meta = meta
        self.dist = dist
        torch.manual_seed(settings.seed)
        self.decoder = Decoder(config)
        g = torch.Generator().manual_seed(settings.seed)
        init = torch.randn(data.n_shapes, config.latent_size, generator=g) * settings.code_init_std
        if dist is not None:
            if min(settings.shapes_per_batch, data.n_shapes) < dist.world_size:
                b = min(settings.shapes_per_batch, data.n_shapes)
                raise JsrteError(f"a batch of {b} shapes cannot be split across {dist.world_size} processes")
            self.decoder.to(dist.device)
            init = init.to(dist.device)
        self.codes = torch.nn.Parameter(init)
        self.network = self.decoder if dist is None else _data_parallel(self.decoder, dist)
        self.optimizer = torch.optim.Adam([
            {"params": list(self.decoder.parameters()), "lr": settings.lr_net},
            {"params": [self.codes], "lr": settings.lr_codes},
        ])
        self.step = 0
        self.elapsed = 0.0
        self.saved_step: int | None = None
        """Step of the last checkpoint written or resumed from (None: none yet)."""
        self.resumed_from: Path | None = None

    # -- one step ---------------------------------------------------------------------------
    def train_step(self) -> dict[str, float]:
        s = self.settings
        factor = s.lr_factor(self.step)
        self.optimizer.param_groups[0]["lr"] = s.lr_net * factor
        self.optimizer.param_groups[1]["lr"] = s.lr_codes * factor
        shapes, samples = batch_indices(s, self.data.n_shapes, self.data.points.shape[1], self.step)
        if self.dist is not None:
            return self._distributed_step(shapes, samples, factor)
        pts = self.data.points[shapes[:, None], samples].reshape(-1, 3)
        target = self.data.sdf[shapes[:, None], samples].reshape(-1)
        codes = self.codes[shapes]
        per_point = codes[:, None, :].expand(-1, s.points_per_shape, -1).reshape(-1, self.config.latent_size)
        torch.manual_seed(s.seed * 104_729 + self.step)  # dropout masks depend on the step only
        self.decoder.train()
        pred = self.decoder(pts, per_point)
        l1 = clamped_l1(pred, target, s.clamp)
        reg = s.code_reg * codes.pow(2).sum(-1).mean()
        loss = l1 + reg
        self._check_loss(float(loss.detach()))
        self.optimizer.zero_grad(set_to_none=True)
        loss.backward()
        self.optimizer.step()
        self.step += 1
        return {"loss": loss.item(), "l1": l1.item(), "code_norm": float(codes.detach().norm(dim=-1).mean()),
                "lr_net": s.lr_net * factor}

    def _distributed_step(self, shapes: torch.Tensor, samples: torch.Tensor,
                          factor: float) -> dict[str, float]:
        """This rank's block of the global batch; the same update as :meth:`train_step` on one process.

        The rank's loss is its share of the global loss (l1 summed over its points / (B K), the
        code term summed over its shapes / B), so the shares add up to the single-process loss.
        DDP averages gradients over ranks, hence ``backward`` on world_size x the share; the code
        table's gradient is averaged the same way.
        """
        s, d = self.settings, self.dist
        mine = d.shard(len(shapes))
        local_shapes, local_samples = shapes[mine], samples[mine]
        pts = self.data.points[local_shapes[:, None], local_samples].reshape(-1, 3).to(d.device)
        target = self.data.sdf[local_shapes[:, None], local_samples].reshape(-1).to(d.device)
        codes = self.codes[local_shapes.to(d.device)]
        per_point = codes[:, None, :].expand(-1, s.points_per_shape, -1).reshape(-1, self.config.latent_size)
        code_norm = float(self.codes.detach()[shapes.to(d.device)].norm(dim=-1).mean())
        torch.manual_seed(s.seed * 104_729 + self.step + DROPOUT_RANK_STRIDE * d.rank)
        self.decoder.train()
        pred = self.network(pts, per_point)
        l1 = (pred.clamp(-s.clamp, s.clamp) - target.clamp(-s.clamp, s.clamp)).abs().sum() / samples.numel()
        loss = l1 + s.code_reg * codes.pow(2).sum() / len(shapes)
        self.optimizer.zero_grad(set_to_none=True)
        (loss * d.world_size).backward()
        average_gradient(self.codes, d)
        self.optimizer.step()
        self.step += 1
        total_loss, total_l1 = sum_over_ranks(torch.stack([loss, l1])).tolist()
        self._check_loss(total_loss, step=self.step)  # the same sum on every rank: all stop together
        return {"loss": total_loss, "l1": total_l1, "code_norm": code_norm, "lr_net": s.lr_net * factor}

    def _check_loss(self, loss: float, step: int | None = None) -> None:
        """JsrteError when the loss is NaN or infinite: training diverged; nothing more is written."""
        if math.isfinite(loss):
            return
        kept = ("no checkpoint was written" if self.saved_step is None
                else f"the checkpoint of step {self.saved_step} is kept")
        raise JsrteError(f"training diverged: the loss is {loss} at step {(step or self.step) + 1}; {kept}; "
                         "lower the learning rates (--lr-net, --lr-codes)", self.out_dir)

    @property
    def is_main(self) -> bool:
        """Whether this process writes checkpoints and logs (always, unless rank > 0 under torchrun)."""
        return self.dist is None or self.dist.is_main

    # -- running ----------------------------------------------------------------------------
    def run(self, *, until: int | None = None, progress: bool = True) -> DeepSdfModel:
        """Train up to step ``until`` (default: all steps), checkpointing on the way."""
        s = self.settings
        until = s.steps if until is None else min(until, s.steps)
        bar = tqdm(total=s.steps, initial=self.step, desc="training", disable=not (progress and self.is_main))
        log_rows: list[dict[str, float]] = []
        t0 = time.perf_counter()
        while self.step < until:
            row = self.train_step()
            row["step"] = self.step
            log_rows.append(row)
            bar.update(1)
            if self.step % 20 == 0:
                bar.set_postfix(loss=f"{row['l1']:.4f}", z=f"{row['code_norm']:.3f}")
            if self.step % s.checkpoint_every == 0 or self.step == until:
                self.elapsed += time.perf_counter() - t0
                t0 = time.perf_counter()
                if self.is_main:
                    self.save_checkpoint(log_rows)
                log_rows = []
        bar.close()
        return self.model()

    def model(self) -> DeepSdfModel:
        meta = dict(self.meta)
        meta.update(training=dict(asdict(self.settings), steps_done=self.step,
                                  seconds=round(self.elapsed, 1), threads=torch.get_num_threads()),
                    data=self.data.summary)
        if self.dist is not None:
            meta["training"].update(world_size=self.dist.world_size, device=self.dist.device.type)
        return DeepSdfModel(decoder=self.decoder, codes=self.codes.detach().clone(), meta=meta)

    # -- checkpoints ------------------------------------------------------------------------
    def save_checkpoint(self, log_rows: list[dict[str, float]]) -> None:
        """Append the log, then write the training state and the usable model, each atomically."""
        model = self.model()
        tensors = tensors_of(model)
        for i, state in self.optimizer.state_dict()["state"].items():
            for key, value in state.items():
                tensors[f"optimizer.{i}.{key}"] = torch.as_tensor(value).contiguous()
        bad = non_finite_tensors(tensors)
        if bad:
            self._check_loss(math.nan, step=self.step - 1)
        self.out_dir.mkdir(parents=True, exist_ok=True)
        _append_log(self.out_dir / LOG_NAME, log_rows)
        meta = {"format": "jsrte-train-state", "step": self.step, "elapsed": self.elapsed,
                "architecture": self.config.to_dict(), "settings": asdict(self.settings),
                "model_meta": model.meta}
        state_path = self.out_dir / STATE_NAME
        with atomic_path(state_path) as tmp:
            save_file(tensors, str(tmp), metadata={"jsrte": json.dumps(meta)})
            if state_path.exists():  # keep the one before, in case this one is damaged later
                os.replace(state_path, self.out_dir / PREVIOUS_STATE_NAME)
        save_model(model, self.out_dir / MODEL_NAME)
        self.saved_step = self.step

    def load_checkpoint(self) -> None:
        """Restore the state written by :meth:`save_checkpoint` (for ``--resume``); if the last
        checkpoint is unreadable, the one before it (``resumed_from`` says which was read)."""
        path, meta, tensors = readable_state(self.out_dir)
        self._restore(path, meta, tensors)
        self.resumed_from = path

    def _restore(self, path: Path, meta: dict[str, Any], tensors: dict[str, torch.Tensor]) -> None:
        """Load a readable training state; JsrteError if it belongs to another run."""
        if DecoderConfig.from_dict(meta["architecture"]) != self.config:
            raise JsrteError("architecture differs from the run being resumed", path)
        saved = TrainSettings(**meta["settings"])
        if replace(saved, steps=self.settings.steps) != replace(self.settings, steps=self.settings.steps):
            raise JsrteError("training settings differ from the run being resumed", path)
        codes = tensors["latent_codes"]
        if codes.shape != self.codes.shape:
            raise JsrteError(f"has {codes.shape[0]} codes but the data has {self.codes.shape[0]} shapes",
                             path)
        try:
            self.decoder.load_state_dict({k[8:]: v for k, v in tensors.items() if k.startswith("decoder.")})
            state = self.optimizer.state_dict()
            for name, value in tensors.items():
                if name.startswith("optimizer."):
                    _, i, key = name.split(".", 2)
                    state["state"].setdefault(int(i), {})[key] = value
            self.optimizer.load_state_dict(state)
        except (RuntimeError, ValueError, KeyError) as exc:
            raise JsrteError(f"does not fit the run being resumed ({str(exc).splitlines()[0]})", path) from exc
        with torch.no_grad():
            self.codes.copy_(codes)
        self.step = int(meta["step"])
        self.elapsed = float(meta.get("elapsed", 0.0))
        self.saved_step = self.step
        if self.is_main:
            _truncate_log(self.out_dir / LOG_NAME, self.step)


def readable_state(out_dir: Path) -> tuple[Path, dict[str, Any], dict[str, torch.Tensor]]:
    """The last readable training state in ``out_dir`` (the last checkpoint, else the one before):
    its path, metadata and tensors; JsrteError saying what to delete when neither reads."""
    problems = []
    for name in (STATE_NAME, PREVIOUS_STATE_NAME):
        path = Path(out_dir) / name
        if not path.is_file():
            continue
        try:
            return (path, *_read_state(path))
        except JsrteError as exc:
            problems.append(str(exc))
    found = "; ".join(problems) or f"no {STATE_NAME}"
    raise JsrteError(f"cannot resume ({found}); to start this run over, delete {STATE_NAME}, "
                     f"{PREVIOUS_STATE_NAME} and {LOG_NAME} (the sampled shapes in data/ are kept)", out_dir)


def _read_state(path: Path) -> tuple[dict[str, Any], dict[str, torch.Tensor]]:
    """The metadata and tensors of a training state file; JsrteError if it is damaged."""
    meta = read_metadata(path)
    if meta.get("format") != "jsrte-train-state":
        raise JsrteError("not a training state file", path)
    try:
        DecoderConfig.from_dict(meta["architecture"])
        TrainSettings(**meta["settings"])
        int(meta["step"])
        tensors = load_file(str(path))
    except (SafetensorError, OSError, KeyError, TypeError, ValueError) as exc:
        raise JsrteError(f"damaged training state ({type(exc).__name__}: {exc})", path) from exc
    if "latent_codes" not in tensors or not any(k.startswith("decoder.") for k in tensors):
        raise JsrteError("damaged training state (weights or codes missing)", path)
    bad = non_finite_tensors(tensors)
    if bad:
        raise JsrteError(f"damaged training state (NaN or infinite values in {', '.join(bad[:3])})", path)
    return meta, tensors


def _data_parallel(decoder: Decoder, ctx: DistContext) -> torch.nn.Module:
    """``decoder`` in DistributedDataParallel (its weights broadcast from rank 0)."""
    from torch.nn.parallel import DistributedDataParallel

    device_ids = [ctx.device] if ctx.device.type == "cuda" else None
    return DistributedDataParallel(decoder, device_ids=device_ids)


def _append_log(path: Path, rows: list[dict[str, float]]) -> None:
    if not rows:
        return
    new = not path.exists()
    with open(path, "a", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=["step", "loss", "l1", "code_norm", "lr_net"])
        if new:
            writer.writeheader()
        writer.writerows(rows)


def _truncate_log(path: Path, step: int) -> None:
    """Drop log rows past ``step`` (written after the last checkpoint by a killed run)."""
    if not path.exists():
        return
    with open(path, newline="") as f:
        rows = [r for r in csv.DictReader(f) if int(r["step"]) <= step]
    path.unlink()
    _append_log(path, [{k: float(v) for k, v in r.items()} | {"step": int(r["step"])} for r in rows])


def seed_everything(seed: int) -> np.random.Generator:
    """Seed PyTorch with ``seed``; returns a NumPy generator seeded the same."""
    torch.manual_seed(seed)
    return np.random.default_rng(seed)
