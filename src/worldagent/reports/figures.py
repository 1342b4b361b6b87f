"""Figures in the spirit of the paper's: metric distributions over worlds (Figure 6a); legends and rows of panels laid
out so that no text overprints another (``fit_legend``, ``space_rows``)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

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


MIN_LEGEND_POINTS = 6.0  # the smallest type a narrowed legend is set in
ROW_GAP_POINTS = 6.0  # clear space between one row's lowest text and the next row's titles


def fit_legend(axis: Any) -> None:
    """Narrow ``axis``'s legend until it spans no wider than the axis, so legends of panels side by side never overprint.

    An env's picture (``spec.pictures.episodes``) sets its legend for a panel of its own; in a row of panels that
    legend may be wider than its panel. A legend that already lies within its axis's width is kept as drawn;
    another is set again below the axis with fewer columns, then in smaller type (down to ``MIN_LEGEND_POINTS``).
    """
    legend = axis.get_legend()
    if legend is None:
        return
    renderer = axis.figure.canvas.get_renderer()
    if _within_width(legend, axis, renderer):
        return
    handles, labels = legend.legend_handles, [text.get_text() for text in legend.get_texts()]
    size, frame = legend.get_texts()[0].get_fontsize(), legend.get_frame_on()
    while True:
        for columns in range(len(labels), 0, -1):
            legend.remove()
            legend = axis.legend(
                handles=handles, labels=labels, loc="upper center", bbox_to_anchor=(0.5, -0.02), ncol=columns, fontsize=size, frameon=frame
            )
            if _within_width(legend, axis, renderer):
                return
        if size <= MIN_LEGEND_POINTS:
            return  # one column at the smallest type: the labels themselves are wider than the panel
        size = max(size - 1.0, MIN_LEGEND_POINTS)


def _within_width(legend: Any, axis: Any, renderer: Any) -> bool:
    drawn, frame = legend.get_window_extent(renderer), axis.get_window_extent(renderer)
    return drawn.x0 >= frame.x0 - 1.0 and drawn.x1 <= frame.x1 + 1.0


def space_rows(figure: Any, rows: list[list[Any]], tries: int = 6) -> None:
    """Widen the space between rows of panels (``subplots_adjust(hspace=...)``) until each row's lowest text (a legend
    below its panels) clears the next row's titles by ``ROW_GAP_POINTS``."""
    renderer = figure.canvas.get_renderer()
    for _ in range(tries):
        overlap = max((_row_overlap(upper, lower, renderer) for upper, lower in zip(rows, rows[1:])), default=0.0)
        if overlap <= 0:
            return
        height = np.mean([axis.get_window_extent(renderer).height for row in rows for axis in row])
        figure.subplots_adjust(hspace=figure.subplotpars.hspace + overlap / height)


def _row_overlap(upper: list[Any], lower: list[Any], renderer: Any) -> float:
    """Pixels by which the lowest text of ``upper`` reaches into the titles of ``lower`` (plus the gap); <= 0: clear."""
    bottom = min(axis.get_tightbbox(renderer).y0 for axis in upper)
    top = max(axis.get_tightbbox(renderer).y1 for axis in lower)
    return top - bottom + ROW_GAP_POINTS * lower[0].figure.dpi / 72.0
