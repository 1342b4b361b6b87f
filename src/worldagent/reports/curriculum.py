"""The curriculum figure: what a curriculum steered training toward, from its buffer snapshots.

Left: the buffer's scores over training (median, 90th percentile and maximum of the latents it
held at each checkpoint) and how full it was. Middle: the last buffer's latents on a 2-D
projection (the two principal axes of the latents), coloured by score. Right: the worlds it
favoured most at the end (highest replay probability), decoded by the generator and drawn as
the environment draws worlds.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from worldagent.files import write_atomically


def score_trace(snapshots: list[dict]) -> dict[str, np.ndarray]:
    """{update, filled, median, p90, max}: f64[S] per snapshot (NaN scores where the buffer was empty)."""
    quantile = lambda s, q: float(np.quantile(s["score"], q)) if len(s["score"]) else np.nan  # noqa: E731
    return {
        "update": np.array([int(s["update"]) for s in snapshots], np.float64),
        "filled": np.array([len(s["score"]) for s in snapshots], np.float64),
        "median": np.array([quantile(s, 0.5) for s in snapshots]),
        "p90": np.array([quantile(s, 0.9) for s in snapshots]),
        "max": np.array([quantile(s, 1.0) for s in snapshots]),
    }


def principal_plane(z: np.ndarray) -> np.ndarray:
    """f64[M, 2]: latents ``z`` f[M, D] on their two principal axes (centred; fewer axes are zero-padded)."""
    z = np.asarray(z, np.float64)
    centred = z - z.mean(axis=0)
    if len(z) < 2:
        return np.zeros((len(z), 2))
    _, _, axes = np.linalg.svd(centred, full_matrices=False)
    plane = centred @ axes[:2].T
    return np.pad(plane, ((0, 0), (0, 2 - plane.shape[1])))


def favourite_latents(snapshot: dict, count: int) -> np.ndarray:
    """f32[k, D]: the ``count`` latents of highest score in a snapshot (best first)."""
    order = np.argsort(-np.asarray(snapshot["score"]), kind="stable")[:count]
    return np.asarray(snapshot["z"], np.float32)[order]


def curriculum_figure(snapshots: list[dict], spec: Any, generator: Any, out: Path | str, count: int = 4, title: str = "") -> Path:
    """Draw the curriculum figure (see module docstring) of a run's ``snapshots`` to ``out`` (PNG).

    Args:
        snapshots: ``curricula.snapshots.load_snapshots(run_dir)`` (at least one).
        spec: the env spec (its pictures draw the favoured worlds).
        generator: the ``Generator`` the latents decode with (None: no pictures).
        count: favoured worlds drawn.
    """
    import jax
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    trace, last = score_trace(snapshots), snapshots[-1]
    favourites = favourite_latents(last, count) if generator is not None else np.zeros((0, 0))
    columns = 2 + len(favourites)
    figure = plt.figure(figsize=(4.0 * 2 + 2.2 * len(favourites), 3.6))
    grid = figure.add_gridspec(1, columns, width_ratios=[4, 4] + [2.2] * len(favourites))

    ax = figure.add_subplot(grid[0, 0])
    for name, style in (("median", "-"), ("p90", "--"), ("max", ":")):
        ax.plot(trace["update"], trace[name], style, label=name)
    ax.set_xlabel("update")
    ax.set_ylabel("buffer score")
    ax.legend(fontsize=7, loc="best")
    filled = ax.twinx()
    filled.plot(trace["update"], trace["filled"], color="0.7", lw=1)
    filled.set_ylabel("latents held", color="0.5")

    ax = figure.add_subplot(grid[0, 1])
    plane = principal_plane(last["z"])
    points = ax.scatter(plane[:, 0], plane[:, 1], c=last["score"], s=8, cmap="viridis")
    figure.colorbar(points, ax=ax, label="score")
    ax.set_title(f"buffer at update {int(last['update'])}", fontsize=9)
    ax.set_xlabel("latent PC 1")
    ax.set_ylabel("latent PC 2")

    if len(favourites):
        worlds = generator(jax.numpy.asarray(favourites))
        scores = np.sort(np.asarray(last["score"]))[::-1]
        for i in range(len(favourites)):
            ax = figure.add_subplot(grid[0, 2 + i])
            ax.imshow(spec.pictures.world(jax.tree_util.tree_map(lambda leaf, i=i: leaf[i], worlds), 128))
            ax.set_title(f"favoured #{i + 1}\nscore {scores[i]:.3g}", fontsize=8)
            ax.axis("off")
    if title:
        figure.suptitle(title, fontsize=10)
    figure.tight_layout()

    def save(tmp: Path) -> None:
        figure.savefig(tmp, format="png", dpi=110)

    try:
        return write_atomically(out, save)
    finally:
        plt.close(figure)
