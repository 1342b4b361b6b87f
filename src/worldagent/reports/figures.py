"""Figures in the spirit of the paper's: metric distributions over worlds (Figure 6a)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from worldagent.files import write_atomically


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")  # files only, no display
    import matplotlib.pyplot as plt

    return plt


def distribution_figure(samples: dict[str, np.ndarray], metric: str, out: Path | str, title: str = "", bins: int = 30) -> Path:
    """Histogram of per-world scores, one series per label (e.g. random / ES / BO), to PNG.

    Args:
        samples: {label: f[n] per-world scores}.
        metric: the axis label.
        out: PNG path.
    """
    plt = _pyplot()
    finite = {label: np.asarray(v, np.float64)[np.isfinite(v)] for label, v in samples.items()}
    values = np.concatenate([v for v in finite.values() if len(v)]) if any(len(v) for v in finite.values()) else np.zeros(1)
    edges = np.histogram_bin_edges(values, bins=bins)
    figure, axis = plt.subplots(figsize=(6, 3.5), dpi=120)
    for label, v in finite.items():
        axis.hist(v, bins=edges, alpha=0.55, density=True, label=f"{label} (n={len(v)}, mean {v.mean():.3g})" if len(v) else label)
    axis.set_xlabel(metric)
    axis.set_ylabel("density of worlds")
    axis.set_title(title)
    axis.legend(fontsize=8)
    figure.tight_layout()
    path = write_atomically(out, lambda tmp: figure.savefig(tmp, format="png"))
    plt.close(figure)
    return path
