"""The strategic evaluation figure (paper §6.1.2, Figures 1 and 6b).

Three panels: the world that minimises the metric and the one that maximises it, each drawn
with the agents' trajectories (racing: one path per episode, crashes marked with a red cross;
harvest: each cell tinted with the colour of the agent that stood on it most, brighter the more
often, under the walls and the apple sites; squares mark the spawn corners), and the random
distribution (Figure 6a) with both scores and the random mean marked, so the reader sees how far
the optimised worlds sit from what random sampling reports.

The drawn episodes are replayed (``evaluation.trajectories.replay``). With the keys the campaign
scored the worlds with (``search.experiments.strategic_evaluation`` returns them), they are the
scored episodes; otherwise they are fresh ones, and the panel says so.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import jax
import numpy as np

from worldagent.errors import WorldagentError
from worldagent.evaluation.trajectories import Episodes, replay, world_from_arrays
from worldagent.files import write_atomically
from worldagent.store import Evaluation

HARVEST_AGENT_COLOURS = ((0.95, 0.25, 0.25), (0.25, 0.55, 1.0), (1.0, 0.65, 0.1), (0.85, 0.35, 0.95))  # TL, TR, BL, BR


def episode_keys_for(key: Any, index: int, repeats: int) -> jax.Array:
    """``[repeats]`` keys for world ``index`` (0 low, 1 high) from ``strategic_figure``'s ``key``."""
    if isinstance(key, (tuple, list)):
        if len(key) != 2:
            raise WorldagentError(f"key holds {len(key)} entries; pass (keys_low, keys_high) or one key.")
        return key[index]
    key = jax.random.key(0) if key is None else key
    return jax.random.split(jax.random.fold_in(key, index), repeats)


def drawn_scores(env_name: str, episodes: Episodes, metric: str, params: Any) -> np.ndarray:
    """f[E] the metric of each replayed episode (derived metrics such as normalised return included)."""
    from worldagent.search.objectives import with_derived_metrics

    metrics = with_derived_metrics(env_name, {k: v[None] for k, v in episodes.metrics.items()}, params)
    if metric not in metrics:
        raise WorldagentError(f"{env_name} episodes have no metric {metric!r}; use one of: {', '.join(metrics)}.")
    return np.asarray(metrics[metric][0], np.float64)


def ending_summary(episodes: Episodes) -> str:
    """ "8 episodes: 6 crashed (steps 41–57), 2 lapped" — how racing episodes ended."""
    endings = np.array(episodes.endings())
    parts = []
    for kind, verb in (("crash", "crashed"), ("lap", "lapped"), ("timeout", "timed out")):
        steps = episodes.steps[endings == kind]
        if len(steps):
            span = f"{steps.min()}" if steps.min() == steps.max() else f"{steps.min()}–{steps.max()}"
            parts.append(f"{len(steps)} {verb} (step {span})")
    return f"{len(episodes)} episodes: " + ", ".join(parts)


def _draw_racing(axis, world, episodes: Episodes, plt) -> None:
    """The track with one path per episode (coloured by episode) and crash points marked."""
    from worldagent.envs.racing.render import VIEW_EXTENT, track_image

    extent = (-VIEW_EXTENT, VIEW_EXTENT, -VIEW_EXTENT, VIEW_EXTENT)
    axis.imshow(np.asarray(track_image(world, 480)), extent=extent, origin="upper", interpolation="bilinear")
    colours = plt.get_cmap("plasma")
    count = len(episodes)
    for e in range(count):
        path = episodes.path(e)
        axis.plot(path[:, 0], path[:, 1], color=colours(0.1 + 0.75 * e / max(count - 1, 1)), linewidth=1.3, alpha=0.85)
    crashed = [episodes.path(e)[-1] for e, ending in enumerate(episodes.endings()) if ending == "crash"]
    if crashed:
        points = np.array(crashed)
        axis.scatter(
            points[:, 0], points[:, 1], marker="X", s=110, color=(0.9, 0.1, 0.1), edgecolors="white", linewidths=1.2, zorder=5, label="crash"
        )
    centreline = np.asarray(world.centreline)
    start, ahead = centreline[0], centreline[min(6, len(centreline) - 1)]
    axis.scatter([start[0]], [start[1]], marker="o", s=45, color="white", edgecolors="black", zorder=6, label="start")
    axis.annotate("", xy=tuple(ahead), xytext=tuple(start), arrowprops={"arrowstyle": "->", "color": "white", "linewidth": 1.5}, zorder=6)
    axis.legend(loc="lower right", fontsize=7, framealpha=0.8)
    lower, upper = track_view(centreline, VIEW_EXTENT)
    axis.set_xlim(lower[0], upper[0])
    axis.set_ylim(lower[1], upper[1])


def track_view(centreline: np.ndarray, extent: float, margin: float = 0.08) -> tuple[np.ndarray, np.ndarray]:
    """A square view (lower, upper corners) around the track: small tracks are drawn large."""
    low, high = centreline.min(axis=0), centreline.max(axis=0)
    centre, half = (low + high) / 2, max(high - low) / 2 + margin
    half = min(half, extent)
    centre = np.clip(centre, -extent + half, extent - half)
    return centre - half, centre + half


def visit_counts(episodes: Episodes, shape: tuple[int, int]) -> np.ndarray:
    """i64[N, H, W]: how many steps each agent stood on each cell, over all episodes, while on the map."""
    counts = None
    for e in range(len(episodes)):
        path, present = episodes.path(e), episodes.present[e, : int(episodes.steps[e]) + 1]
        agents = path.shape[1]
        counts = np.zeros((agents, *shape), np.int64) if counts is None else counts
        for a in range(agents):
            cells = path[present[:, a], a]
            np.add.at(counts[a], (cells[:, 0], cells[:, 1]), 1)
    return counts


def _draw_harvest(axis, world, episodes: Episodes) -> None:
    """The map with each cell tinted by the agent that occupied it most (brighter: more often).

    The tint goes under the walls and apples, so the map itself stays readable.
    """
    from matplotlib.patches import Patch

    from worldagent.envs.harvest.render import APPLE, BACKGROUND, WALL
    from worldagent.envs.harvest.world import spawn_corners

    walls, apples = np.asarray(world.walls, bool), np.asarray(world.apples, bool)
    height, width = walls.shape
    extent = (0, width, height, 0)
    counts = visit_counts(episodes, (height, width))
    owner, total = counts.argmax(axis=0), counts.sum(axis=0)
    strength = np.log1p(total) / max(np.log1p(total.max()), 1e-9)
    tint = np.asarray(HARVEST_AGENT_COLOURS)[owner] * np.where(total > 0, 0.2 + 0.6 * strength, 0.0)[..., None]
    tint = np.where(total[..., None] > 0, tint, np.asarray(BACKGROUND) / 255)
    axis.imshow(tint, extent=extent, interpolation="nearest")
    wall_layer = np.zeros((height, width, 4))
    wall_layer[walls] = (*(np.asarray(WALL) / 255), 1.0)
    axis.imshow(wall_layer, extent=extent, interpolation="nearest")
    rows, cols = np.nonzero(apples)
    axis.scatter(cols + 0.5, rows + 0.5, s=22, color=np.asarray(APPLE) / 255, edgecolors="black", linewidths=0.4, zorder=4)
    for a, (row, col) in enumerate(spawn_corners(height, width)):
        axis.scatter([col + 0.5], [row + 0.5], marker="s", s=60, color=HARVEST_AGENT_COLOURS[a], edgecolors="white", linewidths=1.2, zorder=5)
    axis.set_xlim(0, width)
    axis.set_ylim(height, 0)
    returns = np.asarray(episodes.metrics.get("returns", np.zeros((len(episodes), counts.shape[0]))), np.float64)
    handles = [Patch(color=HARVEST_AGENT_COLOURS[a], label=f"agent {a}: return {returns[:, a].mean():.1f}") for a in range(counts.shape[0])]
    handles.append(Patch(color=np.asarray(APPLE) / 255, label="apple site"))
    axis.legend(handles=handles, loc="upper center", bbox_to_anchor=(0.5, -0.02), ncol=3, fontsize=7, frameon=False)


def _world_panel(axis, env_name, env, policy, params, evaluation: Evaluation, keys, metric: str, label: str, plt) -> Episodes:
    """Replay and draw one world; the title gives the stored score and what was drawn."""
    world = world_from_arrays(env_name, evaluation.world)
    episodes = replay(env, policy, world, keys, params)
    drawn = drawn_scores(env_name, episodes, metric, params)
    if env_name == "racing":
        _draw_racing(axis, world, episodes, plt)
        detail = ending_summary(episodes)
    else:
        _draw_harvest(axis, world, episodes)
        detail = f"{len(episodes)} episodes of {int(episodes.steps.max())} steps"
    scored = np.isclose(drawn.mean(), evaluation.score, rtol=1e-4, atol=1e-3) and len(drawn) == len(evaluation.episodes)
    drawn_note = "the scored episodes" if scored else f"fresh episodes, mean {drawn.mean():.4g}"
    extra = _normalised_note(env_name, metric, evaluation)
    axis.set_title(f"{label} {metric}: {evaluation.score:.4g}{extra}\n{detail}\n(drawn: {drawn_note})", fontsize=9)
    axis.set_xticks([])
    axis.set_yticks([])
    return episodes


def _normalised_note(env_name: str, metric: str, evaluation: Evaluation) -> str:
    """ " (normalised 0.13)" for racing returns, the scale the paper reports (§6)."""
    if env_name != "racing" or metric != "return" or not evaluation.episodes:
        return ""
    values = [e.get("normalised_return") for e in evaluation.episodes]
    if any(v is None for v in values):
        return ""
    return f" (normalised {np.mean(values):.2f})"


def _distribution_panel(axis, random_scores: np.ndarray, low: Evaluation, high: Evaluation, metric: str) -> None:
    """Histogram of random-world scores with the two optimised scores and the random mean.

    When the random worlds crowd into a small part of the axis (racing: nearly every world is
    lapped, a few crash 300 below), the counts go on a log scale and an inset zooms on the crowd.
    """
    scores = np.asarray(random_scores, np.float64)
    scores = scores[np.isfinite(scores)]
    mean = scores.mean()
    low_edge, high_edge = min(scores.min(), low.score), max(scores.max(), high.score)
    margin = 0.05 * max(high_edge - low_edge, 1e-9)
    bins = np.linspace(low_edge - margin, high_edge + margin, 61)
    axis.hist(scores, bins=bins, color="0.6", alpha=0.8, label=f"random worlds (n={len(scores)})")
    marks = _score_marks(scores, low, high, mean)
    for value, style in marks:
        axis.axvline(value, **style)
    axis.set_xlim(bins[0], bins[-1])
    axis.set_xlabel(metric)
    axis.set_ylabel("random worlds")
    axis.set_title(f"{metric} of the optimised worlds vs random worlds", fontsize=9)
    axis.legend(fontsize=7, loc="upper left")
    bulk = np.quantile(scores, [0.05, 0.95])
    if bulk[1] - bulk[0] < 0.2 * (bins[-1] - bins[0]):
        axis.set_yscale("log")
        axis.set_ylabel("random worlds (log scale)")
        _zoom_inset(axis, scores, bulk, marks)


def _score_marks(scores: np.ndarray, low: Evaluation, high: Evaluation, mean: float) -> list[tuple[float, dict]]:
    """Vertical lines: the random mean and the two optimised scores, labelled with their rank."""
    below, above = np.mean(scores <= low.score), np.mean(scores >= high.score)
    return [
        (mean, {"color": "black", "linestyle": "--", "linewidth": 1.5, "label": f"random mean {mean:.4g}"}),
        (low.score, {"color": (0.85, 0.1, 0.1), "linewidth": 2.5, "label": f"min world {low.score:.4g} ({below:.1%} of random ≤)"}),
        (high.score, {"color": (0.1, 0.35, 0.9), "linewidth": 2.5, "label": f"max world {high.score:.4g} ({above:.1%} of random ≥)"}),
    ]


def _zoom_inset(axis, scores: np.ndarray, bulk: np.ndarray, marks) -> None:
    """An inset histogram of the central random worlds, with the marks that fall inside it."""
    width = max(bulk[1] - bulk[0], 1e-9)
    lo, hi = bulk[0] - 0.5 * width, bulk[1] + 0.5 * width
    for value, _ in marks[1:]:  # widen to include an optimised score just outside the crowd
        if lo - width < value < lo:
            lo = value - 0.05 * width
        if hi < value < hi + width:
            hi = value + 0.05 * width
    inset = axis.inset_axes([0.27, 0.12, 0.48, 0.5])  # over the empty middle between the tails
    inside = scores[(scores >= lo) & (scores <= hi)]
    inset.hist(inside, bins=30, range=(lo, hi), color="0.6", alpha=0.8)
    for value, style in marks:
        if lo <= value <= hi:
            inset.axvline(value, **{k: v for k, v in style.items() if k != "label"})
    inset.set_xlim(lo, hi)
    inset.set_title(f"zoom: {len(inside)} of {len(scores)} random worlds", fontsize=7)
    inset.tick_params(labelsize=6)


def strategic_figure(
    env_name: str, env, policy, params, low: Evaluation, high: Evaluation, random_scores, metric: str, out: Path | str, key: Any = None
) -> Path:
    """Draw the minimising and maximising worlds and their scores against random ones, to PNG.

    Args:
        env_name: "racing" or "harvest"; ``env``, ``params`` the environment and its parameters.
        policy: the agents whose trajectories are drawn.
        low, high: the minimising and maximising evaluations, with their worlds
            (``strategic_evaluation``'s "min" and "max").
        random_scores: f[m] the metric on random worlds (Figure 6a).
        metric: the metric's name (the score's).
        out: PNG path.
        key: the episodes' keys: ``(keys_low, keys_high)``, each ``[E]`` (``strategic_evaluation``'s
            "keys": the scored episodes), or one key (fresh episodes; None: key 0).

    Returns:
        The PNG's path.
    """
    from worldagent.reports.figures import _pyplot

    if len(np.asarray(random_scores)) == 0:
        raise WorldagentError("no random-world scores to compare with; evaluate random worlds first.")
    plt = _pyplot()
    params = env.default_params if params is None else params
    figure, axes = plt.subplots(1, 3, figsize=(15, 5.6), dpi=120, gridspec_kw={"width_ratios": [1, 1, 1.25]})
    for index, (evaluation, label) in enumerate(((low, "minimum"), (high, "maximum"))):
        keys = episode_keys_for(key, index, max(len(evaluation.episodes), 1))
        _world_panel(axes[index], env_name, env, policy, params, evaluation, keys, metric, label, plt)
    _distribution_panel(axes[2], random_scores, low, high, metric)
    figure.suptitle(f"{env_name}: strategic evaluation of {getattr(policy, 'name', 'the agents')} ({metric})", fontsize=11)
    figure.tight_layout(rect=(0, 0, 1, 0.95))
    path = write_atomically(out, lambda tmp: figure.savefig(tmp, format="png"))
    plt.close(figure)
    return path
