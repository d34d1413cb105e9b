"""A PointNet classifier (Qi et al. 2017) that names the database shape closest to a point cloud.

The supplementary's recipe ('PointNet + ICP'): train the classifier to predict the id of each
training shape from 1024 points sampled from it, with random noise added, the points resampled
every epoch, for 60 epochs; at test time classify 1024 points of the query. Architecture: a
shared per-point MLP 64-64-64-128-1024 (1x1 convolutions, batch norm, ReLU), max-pooling, then
fully connected 512-256-``n_shapes`` with batch norm and dropout (PointNet's classifier without
its input/feature transform networks: they are optional and the up axis is known here).

So that a query in another pose can be classified, every cloud goes through
:func:`canonicalize` first (up axis to +y, bounding-sphere centre to the origin, radius to 1)
and training adds a random rotation about +y and a scale jitter. The trained classifier is
cached per database (``<cache>/pointnet/<key>.safetensors``, the key hashing the database's
identity, e.g. the model's SHA-256, and these settings), so it trains once.

Cost on the 2-core CPU machine: one cloud of 1024 points costs ~0.16 s of forward + backward
(measured with another job loading the machine; several times less on an idle one), so the
paper's recipe on 100 shapes (60 epochs x 100 clouds = 6000 clouds, 190 Adam steps of 32) takes
~20 minutes on a busy machine and a few minutes on an idle one. With so few steps a 100-class
classifier is far from converged (see benchmarks/bench_baselines.py for its training accuracy);
``copies_per_epoch`` buys more steps at proportional cost.
"""

from __future__ import annotations

import json
import sys
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch
from torch import nn

from jsrte.atomic import write_with
from jsrte.baselines.cache import cache_dir, digest
from jsrte.geometry.sim3 import rotation_between
from jsrte.metrics.surface import bounding_sphere

CLASSIFIER_VERSION = 1
"""Part of the cache key: bump it when training changes, so stale classifiers are not reused."""


@dataclass(frozen=True)
class PointNetSettings:
    """The classifier and its training (the supplementary's recipe where it gives one)."""

    points: int = 1024
    """Points per cloud (the paper: 1024)."""
    epochs: int = 60
    """Epochs (the paper: 60)."""
    copies_per_epoch: int = 1
    """Clouds drawn per shape per epoch (each freshly sampled, rotated, jittered and noised);
    1 is the paper's recipe. Training time grows in proportion."""
    batch_size: int = 32
    lr: float = 1e-3
    lr_decay_every: int = 20
    lr_decay: float = 0.5
    noise_std: float = 0.01
    """Gaussian noise added to each point (units of the bounding-sphere radius)."""
    scale_jitter: float = 0.15
    """Each training cloud is scaled by a factor uniform in [1 - j, 1 + j]."""
    yaw_augment: bool = True
    """Rotate each training cloud by a random angle about +y."""
    widths: tuple[int, ...] = (64, 64, 64, 128, 1024)
    head: tuple[int, ...] = (512, 256)
    dropout: float = 0.3
    seed: int = 0


class PointNetClassifier(nn.Module):
    """PointNet classification network: (b, n, 3) points -> (b, classes) logits."""

    def __init__(self, classes: int, *, widths: tuple[int, ...] = PointNetSettings.widths,
                 head: tuple[int, ...] = PointNetSettings.head,
                 dropout: float = PointNetSettings.dropout) -> None:
        super().__init__()
        layers: list[nn.Module] = []
        width = 3
        for w in widths:
            layers += [nn.Conv1d(width, w, 1), nn.BatchNorm1d(w), nn.ReLU()]
            width = w
        self.features = nn.Sequential(*layers)
        fc: list[nn.Module] = []
        for w in head:
            fc += [nn.Linear(width, w), nn.BatchNorm1d(w), nn.ReLU()]
            width = w
        fc += [nn.Dropout(dropout), nn.Linear(width, classes)]
        self.classifier = nn.Sequential(*fc)

    def forward(self, points: torch.Tensor) -> torch.Tensor:
        x = self.features(points.transpose(1, 2))
        return self.classifier(x.max(dim=2).values)


def canonicalize(points: np.ndarray, up: np.ndarray) -> np.ndarray:
    """Rotate ``up`` (3,) onto +y, centre the bounding sphere, scale its radius to 1: (n, 3) -> (n, 3)."""
    p = np.asarray(points, dtype=np.float64) @ rotation_between(up, np.array([0.0, 1.0, 0.0])).T
    centre, radius = bounding_sphere(p)
    return (p - centre) / max(radius, 1e-12)


def _yaw_matrices(angles: np.ndarray) -> np.ndarray:
    c, s = np.cos(angles), np.sin(angles)
    r = np.zeros((len(angles), 3, 3))
    r[:, 0, 0], r[:, 0, 2], r[:, 1, 1], r[:, 2, 0], r[:, 2, 2] = c, s, 1.0, -s, c
    return r


def training_batch(pools: list[np.ndarray], settings: PointNetSettings, rng: np.random.Generator
                   ) -> tuple[np.ndarray, np.ndarray]:
    """One epoch's clouds: ``copies_per_epoch`` per shape from its (m, 3) canonicalized pool.

    Returns ``(clouds (k, points, 3) float32, labels (k,) int64)``, shuffled.
    """
    labels = np.repeat(np.arange(len(pools)), settings.copies_per_epoch)
    n = settings.points
    clouds = np.stack([pools[i][rng.choice(len(pools[i]), n, replace=len(pools[i]) < n)] for i in labels])
    if settings.yaw_augment:
        clouds = np.einsum("kij,knj->kni", _yaw_matrices(rng.uniform(0, 2 * np.pi, len(labels))), clouds)
    clouds *= rng.uniform(1 - settings.scale_jitter, 1 + settings.scale_jitter, (len(labels), 1, 1))
    clouds += rng.normal(0.0, settings.noise_std, clouds.shape)
    order = rng.permutation(len(labels))
    return clouds[order].astype(np.float32), labels[order]


@dataclass
class TrainedClassifier:
    """A trained classifier and how it was made."""

    network: PointNetClassifier
    settings: PointNetSettings
    report: dict

    def predict(self, clouds: np.ndarray) -> np.ndarray:
        """Class probabilities (b, classes) of canonicalized ``clouds`` (b, n, 3)."""
        self.network.eval()
        with torch.no_grad():
            logits = self.network(torch.as_tensor(np.asarray(clouds, dtype=np.float32)))
        return torch.softmax(logits, dim=1).numpy()


def train_classifier(pools: list[np.ndarray], settings: PointNetSettings = PointNetSettings(),  # noqa: B008
                     *, progress: bool = False) -> TrainedClassifier:
    """Train on canonicalized point pools, one (m, 3) array per class (database shape)."""
    rng = np.random.default_rng(settings.seed)
    torch.manual_seed(settings.seed)
    net = PointNetClassifier(len(pools), widths=settings.widths, head=settings.head, dropout=settings.dropout)
    opt = torch.optim.Adam(net.parameters(), lr=settings.lr)
    sched = torch.optim.lr_scheduler.StepLR(opt, settings.lr_decay_every, gamma=settings.lr_decay)
    started, history = time.perf_counter(), []
    for epoch in range(settings.epochs):
        net.train()
        clouds, labels = training_batch(pools, settings, rng)
        total, correct = 0.0, 0
        for lo in range(0, len(labels), settings.batch_size):
            x = torch.as_tensor(clouds[lo:lo + settings.batch_size])
            y = torch.as_tensor(labels[lo:lo + settings.batch_size])
            if len(y) < 2:  # batch norm needs two samples
                continue
            logits = net(x)
            loss = nn.functional.cross_entropy(logits, y)
            opt.zero_grad()
            loss.backward()
            opt.step()
            total += loss.item() * len(y)
            correct += int((logits.argmax(1) == y).sum())
        sched.step()
        history.append({"epoch": epoch + 1, "loss": total / len(labels), "accuracy": correct / len(labels)})
        if progress:
            sys.stderr.write(f"pointnet epoch {epoch + 1}/{settings.epochs}: loss {history[-1]['loss']:.3f} "
                             f"train accuracy {history[-1]['accuracy']:.3f}\n")
    recalibrate_batchnorm(net, training_batch(pools, settings, rng)[0], settings.batch_size)
    report = {"classes": len(pools), "train_seconds": round(time.perf_counter() - started, 1),
              "final_loss": history[-1]["loss"] if history else None,
              "final_train_accuracy": history[-1]["accuracy"] if history else None}
    return TrainedClassifier(net, settings, report)


def recalibrate_batchnorm(net: nn.Module, clouds: np.ndarray, batch_size: int) -> None:
    """Re-estimate every batch-norm layer's statistics as exact averages over ``clouds``
    (k, n, 3) with the final weights (short trainings leave the running averages stale), then
    leave ``net`` in evaluation mode."""
    norms = [m for m in net.modules() if isinstance(m, nn.BatchNorm1d)]
    for m in norms:
        m.reset_running_stats()
        m.momentum = None  # cumulative average
    net.train()
    with torch.no_grad():
        for lo in range(0, len(clouds), batch_size):
            if len(clouds[lo:lo + batch_size]) >= 2:
                net(torch.as_tensor(clouds[lo:lo + batch_size]))
    for m in norms:
        m.momentum = 0.1
    net.eval()


def classifier_path(key: str, settings: PointNetSettings, folder: Path | None = None) -> Path:
    """Where the classifier of database ``key`` trained with ``settings`` is cached."""
    folder = Path(folder) if folder is not None else cache_dir("pointnet")
    return folder / f"{digest([key, asdict(settings), CLASSIFIER_VERSION])}.safetensors"


def save_classifier(trained: TrainedClassifier, path: Path) -> None:
    """Write the weights and their description (safetensors metadata ``jsrte``) atomically."""
    from safetensors.torch import save_file

    meta = {"settings": asdict(trained.settings), "report": trained.report}
    state = {k: v.contiguous() for k, v in trained.network.state_dict().items()}
    path.parent.mkdir(parents=True, exist_ok=True)
    write_with(path, lambda tmp: save_file(state, str(tmp), metadata={"jsrte": json.dumps(meta)}))


def load_classifier(path: Path, classes: int, settings: PointNetSettings) -> TrainedClassifier | None:
    """A cached classifier, or None when absent, unreadable or made for something else."""
    from safetensors import SafetensorError, safe_open
    from safetensors.torch import load_file

    if not path.is_file():
        return None
    try:
        with safe_open(str(path), framework="pt") as f:
            meta = json.loads((f.metadata() or {}).get("jsrte", "{}"))
        state = load_file(str(path))
        net = PointNetClassifier(classes, widths=settings.widths, head=settings.head,
                                 dropout=settings.dropout)
        net.load_state_dict(state, strict=True)
    except (SafetensorError, OSError, ValueError, RuntimeError, json.JSONDecodeError):
        return None
    net.eval()
    return TrainedClassifier(net, settings, meta.get("report", {}))
