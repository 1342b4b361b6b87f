"""The strategic evaluation figure (paper §6.1.2, Figures 1 and 6b).

Three panels: the world that minimises the metric and the one that maximises it, each drawn
with the agents' trajectories as the environment draws them (``spec.pictures.episodes``; e.g.
racing: one path per episode, crashes marked with a red cross), and the random
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

from worldagent.envs import registry
from worldagent.envs.registry import EnvSpec
from worldagent.errors import WorldagentError
from worldagent.evaluation.trajectories import Episodes, replay
from worldagent.files import write_atomically
from worldagent.store import Evaluation

# Points: the figure is 1,500 px wide and shown at the report's ~1,050 px, so text is drawn at 0.7 of its size;
# these stay readable there (titles and legends at 7-9 pt were not).
TEXT, SMALL = 13, 11


def episode_keys_for(key: Any, index: int, repeats: int) -> jax.Array:
    """``[repeats]`` keys for world ``index`` (0 low, 1 high) from ``strategic_figure``'s ``key``."""
    if isinstance(key, (tuple, list)):
        if len(key) != 2:
            raise WorldagentError(f"key holds {len(key)} entries; pass (keys_low, keys_high) or one key.")
        return key[index]
    key = jax.random.key(0) if key is None else key
    return jax.random.split(jax.random.fold_in(key, index), repeats)


def drawn_scores(spec: EnvSpec, episodes: Episodes, metric: str, params: Any) -> np.ndarray:
    """f[E] the metric of each replayed episode (derived metrics such as normalised return included)."""
    metrics = spec.metrics.with_derived({k: v[None] for k, v in episodes.metrics.items()}, params)
    if metric not in metrics:
        raise WorldagentError(f"{spec.name} episodes have no metric {metric!r}; use one of: {', '.join(metrics)}.")
    return np.asarray(metrics[metric][0], np.float64)


def ending_summary(spec: EnvSpec, episodes: Episodes) -> str:
    """ "8 episodes (steps 41–400), 6/8 episodes crashed": their lengths and what the env says of them."""
    steps = np.asarray(episodes.steps)
    span = f"{steps.min()}" if steps.min() == steps.max() else f"{steps.min()}–{steps.max()}"
    note = spec.episode_note({k: np.asarray(v) for k, v in episodes.metrics.items()}) if spec.episode_note else ""
    return f"{len(episodes)} episode{'s' if len(episodes) != 1 else ''} (steps {span}){note}"


def _world_panel(axis, spec: EnvSpec, env, policy, params, evaluation: Evaluation, keys, metric: str, label: str) -> Episodes:
    """Replay and draw one world (``spec.pictures.episodes``); the title gives the stored score and what was drawn."""
    world = spec.world_from_arrays(evaluation.world)
    episodes = replay(spec, env, policy, world, keys, params)
    drawn = drawn_scores(spec, episodes, metric, params)
    if spec.pictures.episodes is None:
        axis.imshow(np.asarray(spec.pictures.world(world, 480)), interpolation="nearest")
    else:
        spec.pictures.episodes(axis, world, episodes)
    scored = np.isclose(drawn.mean(), evaluation.score, rtol=1e-4, atol=1e-3) and len(drawn) == len(evaluation.episodes)
    drawn_note = "the scored episodes" if scored else f"fresh episodes, mean {drawn.mean():.4g}"
    extra = _normalised_note(spec, metric, evaluation, params)
    axis.set_title(f"{label} {metric}: {evaluation.score:.4g}{extra}\n{ending_summary(spec, episodes)}\n(drawn: {drawn_note})", fontsize=TEXT)
    axis.set_xticks([])
    axis.set_yticks([])
    return episodes


def _normalised_note(spec: EnvSpec, metric: str, evaluation: Evaluation, params: Any) -> str:
    """ " (normalised 0.13)" for the main metric of an env with bounds, the scale the paper reports (§6)."""
    if metric != spec.metrics.main or spec.metrics.bounds is None or not evaluation.episodes:
        return ""
    values = [e.get(metric) for e in evaluation.episodes]
    if any(v is None for v in values):
        return ""
    return f" (normalised {np.mean(spec.metrics.normalise(values, params)):.2f})"


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
    axis.set_xlabel(metric, fontsize=TEXT)
    axis.set_ylabel("random worlds", fontsize=TEXT)
    axis.set_title(f"{metric} of the optimised worlds vs random worlds", fontsize=TEXT)
    axis.tick_params(labelsize=SMALL)
    axis.legend(fontsize=SMALL, loc="upper left")
    bulk = np.quantile(scores, [0.05, 0.95])
    if bulk[1] - bulk[0] < 0.2 * (bins[-1] - bins[0]):
        axis.set_yscale("log")
        axis.set_ylabel("random worlds (log scale)", fontsize=TEXT)
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
    inset.set_title(f"zoom: {len(inside)} of {len(scores)} random worlds", fontsize=SMALL)
    inset.tick_params(labelsize=SMALL - 1)


def strategic_figure(
    spec: str | EnvSpec, env, policy, params, low: Evaluation, high: Evaluation, random_scores, metric: str, out: Path | str, key: Any = None
) -> Path:
    """Draw the minimising and maximising worlds and their scores against random ones, to PNG.

    Args:
        spec: the environment (its name or ``EnvSpec``); ``env``, ``params`` the env and its parameters.
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
    spec = registry.get(spec)
    plt = _pyplot()
    params = env.default_params if params is None else params
    figure, axes = plt.subplots(1, 3, figsize=(15, 6.2), dpi=100, gridspec_kw={"width_ratios": [1, 1, 1.25]})
    for index, (evaluation, label) in enumerate(((low, "minimum"), (high, "maximum"))):
        keys = episode_keys_for(key, index, max(len(evaluation.episodes), 1))
        _world_panel(axes[index], spec, env, policy, params, evaluation, keys, metric, label)
    _distribution_panel(axes[2], random_scores, low, high, metric)
    figure.suptitle(f"{spec.name}: strategic evaluation of {getattr(policy, 'name', 'the agents')} ({metric})", fontsize=TEXT + 2)
    figure.tight_layout(rect=(0, 0, 1, 0.95))
    path = write_atomically(out, lambda tmp: figure.savefig(tmp, format="png"))
    plt.close(figure)
    return path


def draw_strategic(setup: Any, result: dict, random_scores, metric: str, out: Path | str) -> Path:
    """``strategic_figure`` of an ``experiments.strategic_evaluation`` result, for its ``experiments.Setup``."""
    return strategic_figure(
        setup.spec, setup.env, setup.policy, setup.params, result["min"], result["max"], random_scores, metric, out, key=result.get("keys")
    )
