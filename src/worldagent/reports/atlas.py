"""The failure atlas figure: the archive as a heat map, and the worst worlds of distinct cells.

Top: the descriptor grid, each filled cell coloured by the metric of its best (for a
minimising atlas: worst) world; empty cells stay white. With three descriptors the first two
are drawn and each square shows the most extreme value over the third. Below: up to ``count``
cells chosen far apart in descriptor space among the most extreme ones, each world replayed
with the episodes the campaign scored it with and drawn as the environment draws trajectories.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from worldagent.evaluation.trajectories import replay, scored_keys
from worldagent.files import write_atomically
from worldagent.search.atlas import distinct_picks


def heat_grid(archive: Any, grid: Any, maximize: bool) -> np.ndarray:
    """f64[cells_0, cells_1]: each (first two descriptors) cell's extreme score, NaN where empty."""
    shape = tuple(grid.cells) + (1,) * (2 - len(grid.cells))
    index = np.unravel_index(archive.cells, grid.cells)
    flat = np.full(shape[:2], np.nan)
    for i, score in enumerate(archive.scores):
        row, col = index[0][i], index[1][i] if len(grid.cells) > 1 else 0
        current = flat[row, col]
        if np.isnan(current) or (score > current if maximize else score < current):
            flat[row, col] = score
    return flat


def marker_at(measures: np.ndarray, grid: Any) -> tuple[float, float]:
    """Where a world is marked on the heat map: its first two descriptors clipped into the grid's ranges, the
    edge cell ``cell_of`` puts values outside them in (with one descriptor, halfway up the unit height)."""
    ranges = [*grid.ranges[:2], (0.0, 1.0)][:2]
    values = [*np.asarray(measures, np.float64)[:2], 0.5][:2]
    return tuple(float(np.clip(value, low, high)) for value, (low, high) in zip(values, ranges))


def atlas_figure(summary: dict, setup: Any, metric: str, maximize: bool, loaded: Any, out: Path | str, count: int = 4) -> Path:
    """Draw an atlas (``experiments.atlas``'s result) to ``out`` (PNG).

    Args:
        summary: one campaign's entry of ``experiments.atlas_summary``.
        setup: ``experiments.Setup`` (env, policy, params; the worlds are replayed).
        metric: the archive's metric; ``maximize`` its direction.
        loaded: ``evaluation -> (evaluation with its world, [repeats] keys it was scored with)``.
        count: worlds drawn below the heat map.
    """
    from worldagent.reports.figures import _pyplot

    archive, spec = summary["archive"], setup.spec
    picks = distinct_picks(archive, maximize, count) if spec.pictures.episodes is not None else []
    panels = []
    for pick in picks:
        evaluation, keys = loaded(summary["evaluations"][int(archive.best[pick])])
        world = spec.world_from_arrays(evaluation.world)
        panels.append((world, replay(spec, setup.env, setup.policy, world, keys, setup.params)))
    figure = draw_atlas(summary, spec, metric, maximize, dict(zip(picks, panels)))
    path = write_atomically(Path(out), lambda tmp: figure.savefig(tmp, format="png", bbox_inches="tight"))
    _pyplot().close(figure)
    return path


def draw_atlas(summary: dict, spec: Any, metric: str, maximize: bool, panels: dict[int, tuple[Any, Any]]) -> Any:
    """The atlas figure (a matplotlib ``Figure``): the heat map on top, below it one panel per pick.

    Args:
        summary: one campaign's entry of ``experiments.atlas_summary`` (grid, archive, coverage, QD-score).
        spec: the env's ``EnvSpec`` (``pictures.episodes`` draws each panel).
        panels: {archive entry: (its world, its replayed ``Episodes``)}, in the order drawn.
    """
    from worldagent.reports.figures import _pyplot, fit_legend

    plt = _pyplot()
    grid, archive = summary["grid"], summary["archive"]
    figure = plt.figure(figsize=(4.2 * max(len(panels), 2), 8.4), dpi=110)
    figure.subplots_adjust(hspace=0.35)
    top = figure.add_subplot(2, 1, 1)
    heat = heat_grid(archive, grid, maximize)
    (x_low, x_high), (y_low, y_high) = grid.ranges[0], grid.ranges[1] if len(grid.ranges) > 1 else (0.0, 1.0)
    shown = top.imshow(heat.T, origin="lower", aspect="auto", extent=(x_low, x_high, y_low, y_high), cmap="viridis_r" if not maximize else "viridis")
    figure.colorbar(shown, ax=top, label=f"{metric} ({'best' if maximize else 'worst'} world of the cell)")
    top.set_xlabel(grid.descriptors[0])
    top.set_ylabel(grid.descriptors[1] if len(grid.descriptors) > 1 else "")
    failing = "" if summary["distinct_failing"] is None else f"; {summary['distinct_failing']} distinct failing worlds"
    top.set_title(
        f"{spec.name} failure atlas: {len(archive.cells)} of {grid.size} cells filled (coverage {summary['coverage']:.2f}), "
        f"QD-score {summary['qd_score']:.4g}{failing}",
        fontsize=9,
    )
    for slot, (pick, (world, episodes)) in enumerate(panels.items()):
        axis = figure.add_subplot(2, len(panels), len(panels) + slot + 1)
        spec.pictures.episodes(axis, world, episodes)
        fit_legend(axis)  # the env draws its legend for a panel of its own: in this row it must fit its column
        where = marker_at(archive.measures[pick], grid)  # the title below keeps the true values
        top.scatter(*where, marker="o", s=90, facecolors="none", edgecolors="red")
        top.annotate(str(slot + 1), where, color="red", fontsize=9, xytext=(4, 4), textcoords="offset points")
        described = ", ".join(f"{n} {v:.3g}" for n, v in zip(grid.descriptors, archive.measures[pick]))
        axis.set_title(f"{slot + 1}: score {archive.scores[pick]:.4g}\n{described}", fontsize=8)
        axis.set_xticks([])
        axis.set_yticks([])
    return figure


def counterfactual_figure(setup: Any, pairs: list[dict], out: Path | str) -> Path:
    """Each failing world beside the nearest passing one on its segment (``experiments.explain_failures``),
    both replayed with the episodes the failing world was scored with and drawn with the env's
    trajectories (racing marks each crash: the step where the episode fails)."""
    import jax
    import jax.numpy as jnp

    from worldagent.reports.figures import _pyplot
    from worldagent.search.objectives import generate

    spec, rows = setup.spec, []
    for row, pair in enumerate(pairs):
        found = pair["boundary"]
        latents = jnp.asarray(np.stack([found.failing, found.passing]), jnp.float32)
        worlds = jax.tree_util.tree_map(np.asarray, generate(setup.generator, latents))
        drawn = []
        for col, (label, t) in enumerate((("fails", found.t_failing), ("passes", found.t_passing))):
            world = jax.tree_util.tree_map(lambda leaf, col=col: leaf[col], worlds)
            episodes = replay(spec, setup.env, setup.policy, world, scored_keys(pair["seed"], setup.repeats), setup.params)
            note = spec.episode_note({k: np.asarray(v) for k, v in episodes.metrics.items()}) if spec.episode_note else ""
            drawn.append((world, episodes, f"{row + 1}{'ab'[col]}: {label} (t = {t:.3f} on the segment){note}"))
        rows.append(drawn)
    figure = draw_counterfactuals(spec, rows)
    path = write_atomically(Path(out), lambda tmp: figure.savefig(tmp, format="png", bbox_inches="tight"))
    _pyplot().close(figure)
    return path


def draw_counterfactuals(spec: Any, rows: list[list[tuple[Any, Any, str]]]) -> Any:
    """The counterfactual figure (a matplotlib ``Figure``): one row per pair, each panel ``(world, Episodes, title)``;
    legends fitted to their panels and rows spaced so that a row's legends clear the next row's titles."""
    from worldagent.reports.figures import _pyplot, fit_legend, space_rows

    plt = _pyplot()
    figure, axes = plt.subplots(max(len(rows), 1), 2, figsize=(8.4, 4.2 * max(len(rows), 1)), dpi=100, squeeze=False)
    for r, panels in enumerate(rows):
        for c, (world, episodes, title) in enumerate(panels):
            axis = axes[r, c]
            spec.pictures.episodes(axis, world, episodes)
            fit_legend(axis)
            axis.set_title(title, fontsize=8)
            axis.set_xticks([])
            axis.set_yticks([])
    if not rows:
        axes[0, 0].set_title("no failing cell with a passing world to compare", fontsize=9)
    figure.suptitle(f"{spec.name}: each failing world beside the nearest passing one (latent segment bisected)", fontsize=9)
    space_rows(figure, [list(row) for row in axes])
    return figure
