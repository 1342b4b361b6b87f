"""The strategic evaluation figure (paper §6.1.2, Figures 1 and 6b).

Three panels: the world that minimises the metric and the one that maximises it, each drawn
with the agents' trajectories as the environment draws them (``spec.pictures.episodes``; e.g.
racing: one path per episode, crashes marked with a red cross), and the random
distribution (Figure 6a) with both scores and the random mean marked, so the reader sees how far
the optimised worlds sit from what random sampling reports.

The drawn episodes are replayed (``evaluation.trajectories.replay``). With the keys the campaign
scored the worlds with (``search.experiments.strategic_evaluation`` returns them), they are the
scored episodes; otherwise they are fresh ones, and the panel says so.

A found world's score is the selection's figure: the best of many noisy scores, partly luck (the
winner's curse). Where the world was confirmed on fresh episodes (``analysis.confirm``), every panel
and line gives the confirmed figure, with its interval, beside the found one (``reported_line``,
``winners_curse``, ``strategic_json``).
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
from worldagent.files import write_atomically, write_text
from worldagent.store import Evaluation

# Points: the figure is about 1,500 px wide (cropped to what it draws) and shown at the report's ~1,050 px, so text is drawn at 0.7 of its size;
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


def confirmed_text(spec: EnvSpec, confirmed: Any, metric: str) -> str:
    """ "confirmed -184.6 [-224.7, -144.6] (64 fresh episodes, 45/64 episodes crashed)": a ``ConfirmedWorld``'s figure."""
    from worldagent.experiments import episodes_note

    interval = confirmed.confirmed(metric)
    return f"confirmed {interval.text()} ({interval.n} fresh episodes{episodes_note(spec, confirmed.episodes)})"


def found_text(spec: EnvSpec, evaluation: Evaluation) -> str:
    """ "found -281.7 (the selection's, 8 episodes, 8/8 episodes crashed)": a found world's score, labelled as the selection's."""
    from worldagent.experiments import episodes_note

    count = len(evaluation.episodes)
    return f"found {evaluation.score:.4g} (the selection's, {count} episode{'s' if count != 1 else ''}{episodes_note(spec, evaluation.episodes)})"


def reported_line(spec: EnvSpec, evaluation: Evaluation, confirmed: Any, metric: str) -> str:
    """Found beside confirmed (``found_text``; ``confirmed_text``), or the found figure alone when it was not confirmed."""
    found = found_text(spec, evaluation)
    return found if confirmed is None else f"{found}; {confirmed_text(spec, confirmed, metric)}"


def winners_curse(confirmed: Any, metric: str, label: str, maximize: bool) -> str:
    """One line when the found figure lies outside its confirmed interval ("" otherwise, or when not confirmed): beyond
    it the way the search pushed, the winner's curse; the other way, the few episodes it was found on were unlucky."""
    if confirmed is None:
        return ""
    found, fresh = confirmed.found(metric).mean, confirmed.confirmed(metric)
    if fresh.n == 0 or fresh.low <= found <= fresh.high:
        return ""
    above = found > fresh.high
    where = f"the found {label} ({found:.4g}) lies {'above' if above else 'below'} its confirmed interval [{fresh.low:.4g}, {fresh.high:.4g}]"
    if above == maximize:
        return f"{where}: the selection's figure is partly luck (the winner's curse); the confirmed one is the world's."
    return (
        f"{where}: the few episodes it was found on were unluckier than the world (noise, against the selection); the confirmed one is the world's."
    )


def _world_panel(axis, spec: EnvSpec, env, policy, params, evaluation: Evaluation, keys, metric: str, label: str, confirmed: Any = None) -> Episodes:
    """Replay and draw one world (``spec.pictures.episodes``); the title gives the found score (the selection's), the
    confirmed one where there is one, and what was drawn."""
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
    lines = [f"{label} {metric}: found {evaluation.score:.4g}{extra}"]
    if confirmed is not None:  # the found figure labelled as the selection's, the confirmed one beneath it
        from worldagent.experiments import episodes_note

        interval = confirmed.confirmed(metric)
        lines += [
            f"(the selection's, on {len(evaluation.episodes)} episodes{episodes_note(spec, evaluation.episodes)})",
            f"confirmed {interval.text()}",
            f"(on {interval.n} fresh episodes{episodes_note(spec, confirmed.episodes)})",
            f"drawn: {drawn_note}",
        ]
    else:
        lines += [ending_summary(spec, episodes), f"(drawn: {drawn_note})"]
    axis.set_title("\n".join(lines), fontsize=TEXT if confirmed is None else SMALL)
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


def _distribution_panel(axis, random_scores: np.ndarray, low: Evaluation, high: Evaluation, metric: str, confirmed: tuple = (None, None)) -> None:
    """Histogram of random-world scores with the two optimised scores (found; confirmed with its interval
    shaded, where confirmed) and the random mean.

    When the random worlds crowd into a small part of the axis (racing: nearly every world is
    lapped, a few crash 300 below), the counts go on a log scale and an inset zooms on the crowd.
    """
    scores = np.asarray(random_scores, np.float64)
    scores = scores[np.isfinite(scores)]
    mean = scores.mean()
    intervals = [c.confirmed(metric) for c in confirmed if c is not None]
    low_edge = min(scores.min(), low.score, *[i.low for i in intervals if np.isfinite(i.low)])
    high_edge = max(scores.max(), high.score, *[i.high for i in intervals if np.isfinite(i.high)])
    margin = 0.05 * max(high_edge - low_edge, 1e-9)
    bins = np.linspace(low_edge - margin, high_edge + margin, 61)
    axis.hist(scores, bins=bins, color="0.6", alpha=0.8, label=f"random worlds (n={len(scores)})")
    marks = _score_marks(scores, low, high, mean) + _confirmed_marks(confirmed, metric)
    for value, style in marks:
        axis.axvline(value, **style)
    for mark, colour in zip(confirmed, (LOW_COLOUR, HIGH_COLOUR)):
        if mark is not None:
            interval = mark.confirmed(metric)
            axis.axvspan(interval.low, interval.high, color=colour, alpha=0.12, linewidth=0)
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


LOW_COLOUR, HIGH_COLOUR = (0.85, 0.1, 0.1), (0.1, 0.35, 0.9)


def _score_marks(scores: np.ndarray, low: Evaluation, high: Evaluation, mean: float) -> list[tuple[float, dict]]:
    """Vertical lines: the random mean and the two optimised (found) scores, labelled with their rank."""
    below, above = np.mean(scores <= low.score), np.mean(scores >= high.score)
    return [
        (mean, {"color": "black", "linestyle": "--", "linewidth": 1.5, "label": f"random mean {mean:.4g}"}),
        (low.score, {"color": LOW_COLOUR, "linewidth": 2.5, "label": f"min world, found {low.score:.4g} ({below:.1%} of random ≤)"}),
        (high.score, {"color": HIGH_COLOUR, "linewidth": 2.5, "label": f"max world, found {high.score:.4g} ({above:.1%} of random ≥)"}),
    ]


def _confirmed_marks(confirmed: tuple, metric: str) -> list[tuple[float, dict]]:
    """Dotted lines at the confirmed figures (their 95% intervals are shaded by the caller)."""
    marks = []
    for mark, colour, label in zip(confirmed, (LOW_COLOUR, HIGH_COLOUR), ("min", "max")):
        if mark is not None:
            interval = mark.confirmed(metric)
            text = f"{label} world, confirmed {interval.text()} ({interval.n} fresh)"
            marks.append((interval.mean, {"color": colour, "linestyle": ":", "linewidth": 2.5, "label": text}))
    return marks


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
    spec: str | EnvSpec,
    env,
    policy,
    params,
    low: Evaluation,
    high: Evaluation,
    random_scores,
    metric: str,
    out: Path | str,
    key: Any = None,
    confirmed: Any = None,
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
        confirmed: (low, high) ``analysis.confirm.ConfirmedWorld`` or None each (``strategic_evaluation``'s
            "confirmed"): their figures are labelled beside the found ones.

    Returns:
        The PNG's path.
    """
    from worldagent.reports.figures import _pyplot, fit_legend

    if len(np.asarray(random_scores)) == 0:
        raise WorldagentError("no random-world scores to compare with; evaluate random worlds first.")
    spec = registry.get(spec)
    plt = _pyplot()
    params = env.default_params if params is None else params
    confirmed = tuple(confirmed) if confirmed is not None else (None, None)
    height = 6.2 if confirmed == (None, None) else 6.8  # two more title lines: found beside confirmed
    figure, axes = plt.subplots(1, 3, figsize=(15, height), dpi=100, gridspec_kw={"width_ratios": [1, 1, 1.25]})
    for index, (evaluation, label) in enumerate(((low, "minimum"), (high, "maximum"))):
        keys = episode_keys_for(key, index, max(len(evaluation.episodes), 1))
        _world_panel(axes[index], spec, env, policy, params, evaluation, keys, metric, label, confirmed[index])
    _distribution_panel(axes[2], random_scores, low, high, metric, confirmed)
    figure.suptitle(f"{spec.name}: strategic evaluation of {getattr(policy, 'name', 'the agents')} ({metric})", fontsize=TEXT + 2)
    figure.tight_layout(rect=(0, 0, 1, 0.95))
    for axis in axes[:2]:  # the env draws its legend for a panel of its own: here it must fit its panel's width
        fit_legend(axis)
    figure.tight_layout(rect=(0, 0, 1, 0.95))
    path = write_atomically(out, lambda tmp: figure.savefig(tmp, format="png", bbox_inches="tight"))  # legends below the panels kept
    plt.close(figure)
    return path


def draw_strategic(setup: Any, result: dict, random_scores, metric: str, out: Path | str) -> Path:
    """``strategic_figure`` of an ``experiments.strategic_evaluation`` result, for its ``experiments.Setup``."""
    return strategic_figure(
        setup.spec,
        setup.env,
        setup.policy,
        setup.params,
        result["min"],
        result["max"],
        random_scores,
        metric,
        out,
        key=result.get("keys"),
        confirmed=result.get("confirmed"),
    )


def strategic_lines(spec: EnvSpec, result: dict) -> list[str]:
    """The CLI's lines of a ``strategic_evaluation`` result: each direction's found beside confirmed and where its
    latent lies under the prior (``search.prior.prior_text``), and a winner's-curse caveat for each found figure
    outside its confirmed interval."""
    from worldagent.search.prior import prior_text

    metric, confirmed = result["metric"], result.get("confirmed") or (None, None)
    lines = []
    for label, c, where in zip(("min", "max"), confirmed, result.get("searched") or ("", "")):
        lines.append(f"{label} world: {reported_line(spec, result[label], c, metric)}")
        lines.append(f"  under the prior: {prior_text(result[label].latent)}" + (f"; {where}" if where else ""))
    caveats = (winners_curse(c, metric, label, label == "max") for label, c in zip(("min", "max"), confirmed))
    return lines + [line for line in caveats if line]


def strategic_json(spec: EnvSpec, result: dict, randoms: list[Evaluation]) -> dict:
    """The strategic evaluation for JSON: per direction the campaign, the found figures and (where confirmed) the
    confirmed ones beside them, for the metric, the env's highlighted metrics and its failure event (strict JSON: NaN as null)."""
    from worldagent.analysis.confirm import random_failure_rate
    from worldagent.events import parse_selection
    from worldagent.influence.statistics import json_safe
    from worldagent.search.prior import prior_summary

    metric = result["metric"]
    metrics = list(dict.fromkeys([metric, *spec.metrics.highlighted]))
    failure = parse_selection(spec.failure, spec.name) if spec.failure else None
    baseline = random_failure_rate(randoms, failure) if failure is not None and randoms else None
    scores = np.array([e.score for e in randoms], np.float64)
    out: dict = {
        "env": spec.name,
        "metric": metric,
        "campaigns": list(result["campaigns"]),
        "confirm": result.get("confirm", 0),
        "random": {"worlds": len(scores), "mean": float(np.nanmean(scores)) if len(scores) else None},
        "searched": list(result.get("searched") or ()),
    }
    for label, confirmed, selection in zip(("min", "max"), result.get("confirmed") or (None, None), result.get("selections") or (None, None)):
        evaluation = result[label]
        row = {"campaign": evaluation.campaign, "generation": evaluation.generation, "slot": evaluation.slot, "found_score": evaluation.score}
        row["prior"] = prior_summary(evaluation.latent) if np.size(evaluation.latent) else None  # issue 48: |z| under G's prior
        if confirmed is not None:
            row |= {"selection": selection, **confirmed.as_dict(metrics, failure, baseline)}
            row["winners_curse"] = winners_curse(confirmed, metric, label, label == "max")
        out[label] = row
    return json_safe(out)


def write_strategic_json(spec: EnvSpec, result: dict, randoms: list[Evaluation], out: Path | str) -> Path:
    """``strategic_json`` to ``out`` (atomically)."""
    import json

    return write_text(out, json.dumps(strategic_json(spec, result, randoms), indent=2, default=float) + "\n")
