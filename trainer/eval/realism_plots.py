"""PNG figures of the realism metrics: a grid of depth images per source, hole statistics side by side, and a
t-SNE like paper Fig. 4."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402


def plot_grid(sources: dict[str, np.ndarray], path: Path, columns: int = 6) -> None:
    """One row per source, ``columns`` frames each; holes in black."""
    fig, axes = plt.subplots(len(sources), columns, figsize=(1.6 * columns, 1.3 * len(sources)),
                             squeeze=False)
    cmap = matplotlib.colormaps["viridis"].with_extremes(bad="black")
    for r, (name, frames) in enumerate(sources.items()):
        idx = np.linspace(0, len(frames) - 1, columns).astype(int)
        for c, i in enumerate(idx):
            f = frames[i].astype(np.float32)
            valid = f[f > 0]
            lo, hi = np.percentile(valid, [1, 99]) if valid.size else (0, 1)
            axes[r, c].imshow(np.ma.masked_where(f == 0, f), cmap=cmap, vmin=lo, vmax=hi)
            axes[r, c].set_xticks([])
            axes[r, c].set_yticks([])
        axes[r, 0].set_ylabel(name, fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def plot_tsne(real: np.ndarray, sources: dict[str, np.ndarray], path: Path, seed: int = 0) -> None:
    """One t-SNE over every feature set; a panel per source: real (blue) vs that source (orange)."""
    from sklearn.manifold import TSNE

    names = list(sources)
    allf = np.concatenate([real, *sources.values()])
    allf = (allf - allf.mean(0)) / (allf.std(0) + 1e-6)
    tsne = TSNE(n_components=2, perplexity=min(30.0, (len(allf) - 1) / 3), random_state=seed, init="pca")
    emb = tsne.fit_transform(allf)
    bounds = np.cumsum([len(real), *(len(v) for v in sources.values())])
    fig, axes = plt.subplots(1, len(names), figsize=(3 * len(names), 3), squeeze=False)
    for k, name in enumerate(names):
        ax = axes[0, k]
        ax.scatter(*emb[:bounds[0]].T, s=4, c="tab:blue", label="real")
        ax.scatter(*emb[bounds[k]:bounds[k + 1]].T, s=4, c="tab:orange", label=name)
        ax.set_title(name, fontsize=8)
        ax.set_xticks([])
        ax.set_yticks([])
    axes[0, 0].legend(fontsize=6)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def plot_holes(frames: dict[str, np.ndarray], stats: dict[str, dict], path: Path) -> None:
    """Hole statistics per source (``holes.hole_stats`` entries) side by side: per-frame hole fraction,
    hole-size histogram, hole rate near depth edges vs in flat regions, holes per frame."""
    from .holes import SIZE_BINS

    names = list(frames)
    colours = matplotlib.colormaps["tab10"](np.arange(len(names)) % 10)
    fig, ax = plt.subplots(1, 4, figsize=(17, 3.6))
    ax[0].boxplot([100 * (f == 0).mean((1, 2)) for f in frames.values()], showfliers=False)
    ax[0].set_xticks(range(1, len(names) + 1), names, rotation=45, ha="right", fontsize=7)
    ax[0].set(ylabel="hole fraction per frame (%)", title="hole fraction")
    bins = zip(SIZE_BINS[:-1], SIZE_BINS[1:], strict=True)
    labels = [f"{lo}-{hi - 1}" if hi - 1 > lo else str(lo) for lo, hi in bins]
    labels.append(f">{SIZE_BINS[-1] - 1}")
    width = 0.8 / len(names)
    for i, name in enumerate(names):
        x = np.arange(len(labels)) + (i - len(names) / 2 + 0.5) * width
        ax[1].bar(x, stats[name]["hole_size_hist"], width, color=colours[i], label=name)
    ax[1].set_xticks(range(len(labels)), labels, fontsize=7)
    ax[1].set(xlabel="hole size (px, 8-connected)", ylabel="share of holes", title="hole sizes")
    ax[1].legend(fontsize=6)
    x = np.arange(len(names))
    ax[2].bar(x - 0.2, [100 * stats[n]["hole_rate_near_edges"] for n in names], 0.4, label="near depth edges")
    ax[2].bar(x + 0.2, [100 * stats[n]["hole_rate_flat"] for n in names], 0.4, label="flat regions")
    ax[2].set_xticks(x, names, rotation=45, ha="right", fontsize=7)
    ax[2].set(ylabel="pixels that are holes (%)", title="where the holes are")
    ax[2].legend(fontsize=6)
    ax[3].bar(x, [stats[n]["holes_per_frame"] for n in names], color=colours)
    ax[3].set_xticks(x, names, rotation=45, ha="right", fontsize=7)
    ax[3].set(ylabel="hole components per frame", title="hole count")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
