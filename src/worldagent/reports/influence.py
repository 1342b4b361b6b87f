"""Figure 8 of the paper: default against influenced training, and worlds of the new distribution.

Left, one small panel per metric (their scales differ: a raw return of -300 next to a crash
rate of 0.1 would flatten the rates) with a bar for each training regime and its 95%
confidence interval over seeds; right, up to four example worlds of the influenced training
distribution, drawn as the environment draws them (``spec.pictures.world``).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import jax
import numpy as np

from worldagent.envs import registry
from worldagent.envs.registry import EnvSpec
from worldagent.errors import WorldagentError
from worldagent.files import write_atomically
from worldagent.reports.figures import _pyplot

LABELS = {
    "return": "reward (raw)",
    "normalised_return": "normalised reward",
    "crashed": "crash rate",
    "lap_completed": "lap rate",
    "group_reward": "group reward",
    "conflict": "conflict",
    "equality": "equality",
}
COLOURS = {"default": "#8c8c8c", "influenced": "#2b6cb0"}
MAX_EXAMPLES = 4
UNIT_METRICS = {"normalised_return", "crashed", "lap_completed", "equality"}  # rates and [0, 1] scores share one scale


def metric_label(metric: str) -> str:
    """The paper's name of a metric (``crashed`` is the crash rate)."""
    return LABELS.get(metric, metric.replace("_", " "))


def world_image(spec: str | EnvSpec, world: Any, size: int = 192) -> np.ndarray:
    """uint8[H, W, 3] picture of one (unbatched) world (``spec.pictures.world``)."""
    return np.asarray(registry.get(spec).pictures.world(world, size).convert("RGB"))


def training_regime(result: dict) -> str:
    """How an influence result's agents trained, in words: the algorithm, the episodes of each agent
    and the settings that differ from the algorithm's own defaults (``agents.algorithms``)."""
    from worldagent.agents.algorithms import get_algorithm
    from worldagent.influence.cache import config_dict

    algo, config = result["algo"], result["config"]
    defaults = config_dict(get_algorithm(algo).config_type())
    budgets = ("total_episodes", "num_episodes")  # the episodes, said first
    changed = [f"{name} {value}" for name, value in config["training"].items() if name not in budgets and defaults.get(name) != value]
    episodes = next((config["training"][name] for name in budgets if name in config["training"]), config.get("episodes"))
    return f"{algo}, {episodes:,} episodes each" + (f"; beside {algo}'s defaults: {', '.join(changed)}" if changed else f"; {algo}'s defaults")


def training_worlds(result: dict) -> str:
    """The influenced training worlds in words: the property, and with a confirmed selection how many of
    the raw selection kept it on fresh episodes ("crash_rate (crashed) > 0.5, 37 of 152 confirmed on 32 fresh episodes")."""
    described = result.get("selection", {}).get("describe", "")
    confirmation = result.get("worlds", {}).get("confirmation")
    if not described or not confirmation:
        return described
    return f"{described}, {confirmation['survived']} of {confirmation['selected']} confirmed on {confirmation['repeats']} fresh episodes"


def confirmation_sentence(result: dict) -> str:
    """A sentence for a report: how many selected worlds survived confirmation and the property's per-episode
    rate on them, found beside confirmed ('' without a confirmation)."""
    confirmation = result.get("worlds", {}).get("confirmation")
    if not confirmation:
        return ""
    rates = confirmation["property"]
    found, raw, kept = rates["selected_found"], rates["selected_confirmed"], rates["kept_confirmed"]
    return (
        f"Of the {confirmation['selected']} distinct worlds selected for {rates['event']} on the candidates' episodes, "
        f"{confirmation['survived']} kept it on {confirmation['repeats']} fresh episodes each and became the influenced training worlds. "
        f"The property's per-episode rate on the selection: found {found['mean']:.3g} (the selection's own episodes), "
        f"confirmed {raw['mean']:.3g} [{raw['low']:.3g}, {raw['high']:.3g}]; on the kept worlds {kept['mean']:.3g} "
        f"[{kept['low']:.3g}, {kept['high']:.3g}] (95% intervals over worlds)."
    )


def _interval(entry: dict) -> float:
    """The CI half-width; NaN (no error bar drawn) when unknown (one seed: NaN in memory, null in JSON)."""
    value = entry.get("ci95")
    return float("nan") if value is None else float(value)


def influence_figure(result: dict, example_worlds: Any, spec: str | EnvSpec, out: Path | str) -> Path:
    """Draw Figure 8 for one environment to ``out`` (PNG, written atomically).

    Args:
        result: what ``influence.influence`` returns (or ``influence.json`` read back):
            its ``metrics``, ``summary`` ({metric: {label: {mean, ci95, seeds}}}) and selection.
        example_worlds: a batched world pytree (leading axis k) of the influenced
            distribution; the first ``min(k, 4)`` are drawn (None: no examples).
        spec: the environment (its name or ``EnvSpec``): it draws the example worlds.
        out: the PNG path.

    Returns:
        ``out``.
    """
    summary, metrics = result.get("summary"), result.get("metrics")
    if not summary or not metrics:
        raise WorldagentError("the result has no summary; pass what influence() returned or influence.json.")
    spec = registry.get(spec)
    examples = _examples(example_worlds)
    plt = _pyplot()
    columns = len(metrics) + (2 if examples else 0)
    figure = plt.figure(figsize=(2.1 * len(metrics) + (4.2 if examples else 0), 3.8), dpi=120)
    grid = figure.add_gridspec(2, columns, wspace=0.55, hspace=0.1)
    labels = [label for label in ("default", "influenced") if all(label in summary[m] for m in metrics)]
    for i, metric in enumerate(metrics):
        axis = figure.add_subplot(grid[:, i])
        entries = [summary[metric][label] for label in labels]
        axis.bar(
            range(len(labels)),
            [e["mean"] for e in entries],
            yerr=[_interval(e) for e in entries],
            capsize=4,
            color=[COLOURS[label] for label in labels],
        )
        axis.set_xticks(range(len(labels)), [label.capitalize() for label in labels], rotation=30, fontsize=8)
        axis.set_title(metric_label(metric), fontsize=9)
        means = [e["mean"] for e in entries]
        if metric in UNIT_METRICS or all(m == 0 for m in means):
            axis.set_ylim(0, 1)
        elif all(m >= 0 for m in means):
            axis.set_ylim(bottom=0)
        axis.tick_params(axis="y", labelsize=7)
    for j, world in enumerate(examples):
        axis = figure.add_subplot(grid[j // 2, len(metrics) + j % 2])
        axis.imshow(world_image(spec, world), interpolation="nearest")
        axis.set_axis_off()
    seeds = max((e.get("seeds", 0) for m in metrics for e in summary[m].values()), default=0)
    selection = training_worlds(result)
    figure.suptitle(
        f"{spec.name}: default vs influenced training "
        + (f"(mean over {seeds} seeds, 95% CI)" if seeds > 1 else "(one seed: no CI)")
        + (f"; new training worlds: {selection}" if selection else ""),
        fontsize=9,
    )
    path = write_atomically(out, lambda tmp: figure.savefig(tmp, format="png", bbox_inches="tight"))
    plt.close(figure)
    return path


def _examples(worlds: Any) -> list:
    """Up to ``MAX_EXAMPLES`` unbatched worlds of a batched world pytree (numpy leaves)."""
    if worlds is None:
        return []
    leaves = jax.tree_util.tree_leaves(worlds)
    if not leaves or np.ndim(leaves[0]) < 1:
        raise WorldagentError("example_worlds must be a batch of worlds (leading axis), e.g. load_influenced_worlds(...)[0].")
    count = min(int(np.shape(leaves[0])[0]), MAX_EXAMPLES)
    return [jax.tree_util.tree_map(lambda leaf: np.asarray(leaf[i]), worlds) for i in range(count)]
