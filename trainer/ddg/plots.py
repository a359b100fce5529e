"""PNG figures of the realism metrics: a grid of depth images per source and a t-SNE like paper Fig. 4."""

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
