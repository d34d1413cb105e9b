"""Figures of the experiments: the paper's binned F-score box plots (Fig. 2) and a
rate–distortion plot for the compression experiment (Table 3). PNGs, written atomically."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from jsrte.atomic import write_with

FSCORE_BIN_WIDTH = 0.1
"""Width of the F-score bins of the box plots."""


def fscore_bins(width: float = FSCORE_BIN_WIDTH) -> np.ndarray:
    """Bin edges over [0, 1]: (n_bins + 1,) with ``n_bins = round(1 / width)``."""
    n = int(round(1.0 / width))
    return np.linspace(0.0, 1.0, n + 1)


def binned_counts(fscores_per_shape: Sequence[np.ndarray], *, width: float = FSCORE_BIN_WIDTH) -> np.ndarray:
    """Per shape, how many of its runs fall in each F-score bin: (n_shapes, n_bins) int.

    Bins are [k w, (k + 1) w) except the last, which includes 1.0.
    """
    edges = fscore_bins(width)
    n_bins = len(edges) - 1
    counts = np.zeros((len(fscores_per_shape), n_bins), dtype=int)
    for i, f in enumerate(fscores_per_shape):
        f = np.clip(np.asarray(f, dtype=float), 0.0, 1.0)
        index = np.minimum(np.floor(f / width + 1e-9).astype(int), n_bins - 1)
        counts[i] = np.bincount(index, minlength=n_bins)
    return counts


def _pyplot():  # noqa: ANN202
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def plot_fscore_boxplots(panels: Sequence[tuple[str, Sequence[np.ndarray]]], path: str | Path, *,
                         n_inits: int, title: str | None = None, width: float = FSCORE_BIN_WIDTH) -> None:
    """The paper's Fig. 2: one panel per scenario; for each shape, the count of initializations
    per F-score bin; a box plot of those counts per bin, placed at the bin's right edge.

    ``panels``: (title, per-shape arrays of F@5%) per scenario.
    """
    plt = _pyplot()
    edges = fscore_bins(width)
    fig, axes = plt.subplots(1, len(panels), figsize=(5.0 * len(panels), 4.0), squeeze=False, sharey=True)
    for ax, (panel_title, per_shape) in zip(axes[0], panels, strict=True):
        counts = binned_counts(per_shape, width=width)
        ax.boxplot([counts[:, k] for k in range(counts.shape[1])], positions=edges[1:], widths=0.6 * width,
                   manage_ticks=False)
        ax.set_xticks(edges[1:])
        ax.set_xticklabels([f"{e:.1f}" for e in edges[1:]])
        ax.set_xlim(edges[0] + width / 4, edges[-1] + width / 2)
        ax.set_ylim(-0.5, n_inits + 0.5)
        ax.set_xlabel("F@5% (bin right edge)")
        ax.set_title(f"{panel_title}\n{len(per_shape)} shapes × {n_inits} inits", fontsize=9)
        ax.grid(axis="y", alpha=0.3)
    axes[0][0].set_ylabel(f"initializations per shape (of {n_inits})")
    if title:
        fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    write_with(path, lambda tmp: fig.savefig(tmp, dpi=120))
    plt.close(fig)


def plot_rate_distortion(methods: Sequence[dict], path: str | Path, *,
                         paper: dict[str, dict] | None = None, title: str | None = None) -> None:
    """Size (KB, log x) against F@5%: one marker per method at its mean, faint per-object points.

    ``methods``: dicts with ``label``, ``sizes_kb`` (n,), ``fscores`` (n,), ``ours`` (bool).
    ``paper``: label -> {"size_kb", "fscore"}, drawn as hollow grey markers.
    """
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(6.5, 4.5))
    colors = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for i, m in enumerate(methods):
        sizes, fs = np.asarray(m["sizes_kb"], float), np.asarray(m["fscores"], float)
        color = colors[i % len(colors)]
        ax.scatter(sizes, fs, s=10, alpha=0.3, color=color)
        label = f"{m['label']} ({sizes.mean():.2f} KB, F {fs.mean():.3f})"
        ax.scatter([sizes.mean()], [fs.mean()], s=80, marker="*" if m.get("ours") else "o", color=color,
                   edgecolor="black", zorder=3, label=label)
    if paper:
        for i, (label, v) in enumerate(paper.items()):
            ax.scatter([v["size_kb"]], [v["fscore"]], s=60, facecolor="none", edgecolor="grey", zorder=2,
                       label="the paper (Redwood meshes)" if i == 0 else None)
            ax.annotate(label, (v["size_kb"], v["fscore"]), fontsize=7, color="grey",
                        xytext=(-8, 7 if i % 2 else -11), textcoords="offset points")
    ax.set_xscale("log")
    ax.set_xlabel("file size (KB, log scale)")
    ax.set_ylabel("F@5% against the original")
    ax.set_ylim(0.0, 1.06)
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize=7, loc="lower right")
    ax.set_title(title or "Rate–distortion", fontsize=10)
    fig.tight_layout()
    write_with(path, lambda tmp: fig.savefig(tmp, dpi=120))
    plt.close(fig)
