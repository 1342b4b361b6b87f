"""``worldagent influence ENV``: retrain agents on worlds with a desired property (paper §6.2, Figure 8)."""

from __future__ import annotations

from pathlib import Path

import typer

from worldagent.commands.common import AGENT_HELP, ENV_HELP, console, friendly_errors
from worldagent.errors import WorldagentError

ALGORITHMS = {"racing": ("acktr", "ppo"), "harvest": ("dqn",)}
SELECT_HELP = (
    "The property of the new training worlds: METRIC OP NUMBER joined by 'and', OP one of < <= > >= == !=, "
    "e.g. 'crash_rate > 0.5' (racing) or 'conflict == 0' (harvest). Metrics are averaged over a world's episodes: "
    "racing: return, normalised_return, crashed, lap_completed, progress, steps; harvest: group_reward, conflict, "
    "equality, sustainability, peace; aliases: crash_rate, lap_rate, reward."
)


def format_interval(entry: dict) -> str:
    """``mean ± half-width`` (``± n/a`` when one seed leaves the interval undefined)."""
    ci = entry.get("ci95")
    spread = "n/a" if ci is None or ci != ci else f"{ci:.3g}"
    return f"{entry['mean']:.4g} ± {spread}"


def result_table(result: dict):
    """A rich table: one row per metric, default and influenced mean ± 95% CI over seeds."""
    from rich.table import Table

    from worldagent.reports.influence import metric_label

    seeds = len(result["config"]["seeds"])
    spread = "mean ± 95% CI" if seeds > 1 else "one seed: no CI"
    table = Table(title=f"{result['env']}: default vs influenced ({seeds} seed{'s' if seeds != 1 else ''}, {spread})")
    table.add_column("metric")
    table.add_column("default", justify="right")
    table.add_column("influenced", justify="right")
    for metric in result["metrics"]:
        row = result["summary"][metric]
        table.add_row(metric_label(metric), format_interval(row["default"]), format_interval(row["influenced"]))
    return table


def influence_command(
    env: str = typer.Argument(..., help=ENV_HELP),
    agent: str = typer.Option(..., "--agent", help=AGENT_HELP),
    generator: Path = typer.Option(..., "--generator", help="Generator directory (from `worldagent generator train`)."),
    select: str = typer.Option(..., "--select", help=SELECT_HELP),
    algo: str = typer.Option(None, "--algo", help="racing: acktr (the paper's) or ppo; harvest: dqn."),
    episodes: int = typer.Option(None, "--episodes", help="Training episodes per agent (default: the paper's budget, racing 10,000, harvest 5,000)."),
    seeds: int = typer.Option(3, "--seeds", help="Training seeds 0..N-1: one default and one influenced agent each."),
    candidates: int = typer.Option(500, "--candidates", help="Random G(z) worlds evaluated with --agent to find the property."),
    search_budget: int = typer.Option(0, "--search-budget", help="Extra worlds a CMA-ES search evaluates, pushing toward the property (0: none)."),
    eval_worlds: int = typer.Option(200, "--eval-worlds", help="Random G(z) worlds every trained agent is evaluated on (the same for all)."),
    repeats: int = typer.Option(8, "--repeats", help="Episodes per world (the paper: 8)."),
    tagger: int = typer.Option(None, "--tagger", help="Harvest: the agent allowed to TAG (the paper: 0)."),
    seed: int = typer.Option(0, "--seed", help="Seed of the candidate, search and evaluation worlds."),
    out: Path = typer.Option(Path("runs/influence"), "--out", help="Run directory; rerun to resume or reuse finished steps."),
    greedy: bool = typer.Option(False, "--greedy", help="Actor-critics act by argmax instead of sampling."),
    quiet: bool = typer.Option(False, "--quiet", help="No progress bars."),
) -> None:
    """Train agents on worlds with a desired property and compare them with default training (paper §6.2, Figure 8)."""
    from worldagent.influence.selection import parse_selection

    if env not in ALGORITHMS:
        raise WorldagentError(f"unknown environment {env!r}; use racing or harvest.")
    selection = parse_selection(select, env)  # before anything slow: a typo costs nothing
    algo = algo or ALGORITHMS[env][0]
    if algo not in ALGORITHMS[env]:
        raise WorldagentError(f"unknown algorithm {algo!r} for {env}; use one of: {', '.join(ALGORITHMS[env])}.")
    if seeds < 1:
        raise WorldagentError(f"--seeds {seeds}; train at least one seed.")
    if env == "racing" and tagger is not None:
        raise WorldagentError("--tagger applies to harvest only.")

    import jax
    import numpy as np
    from rich.console import Console

    from worldagent.commands.common import agent_policy, env_and_params
    from worldagent.influence.experiment import RESULT_FILE, example_indices, influence, load_influenced_worlds
    from worldagent.reports.influence import influence_figure
    from worldagent.worlds.generator import load_generator

    _, params = env_and_params(env, [tagger] if tagger is not None else [])
    policy = agent_policy(env, agent, greedy)
    G, _, _ = load_generator(generator)
    result = influence(
        out,
        env,
        policy,
        G,
        params,
        selection,
        algo=algo,
        episodes=episodes,
        seeds=tuple(range(seeds)),
        candidates=candidates,
        search_budget=search_budget,
        eval_worlds=eval_worlds,
        repeats=repeats,
        tagger=tagger,
        progress=not quiet,
        seed=seed,
        greedy=greedy,
    )
    worlds, _, values = load_influenced_worlds(out, env)
    picks = example_indices(values, 4)
    examples = jax.tree_util.tree_map(lambda leaf: np.asarray(leaf)[picks], worlds)
    figure = influence_figure(result, examples, env, out / "influence.png")
    Console().print(result_table(result))
    counts = result["worlds"]
    console.print(
        f"{counts['selected']} of {counts['tried']} worlds have {selection.describe()}; "
        f"{2 * seeds} agents compared on {eval_worlds} worlds x {repeats} episodes (this run: {result['wall_seconds']['total']:.0f} s) "
        f"-> {figure}, {out / RESULT_FILE}"
    )


def register(app: typer.Typer) -> None:
    """Add ``worldagent influence``."""
    app.command("influence")(friendly_errors(influence_command))
