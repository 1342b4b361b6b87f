"""``worldagent strategic`` and ``worldagent compare``: the paper's §6.1.2 and §6.1.3 from the shell.

Both resume by default: their campaigns live in the run store under fixed names, so a rerun
evaluates nothing new and only redraws the figures.
"""

from __future__ import annotations

from pathlib import Path

import typer

from worldagent.commands.common import AGENT_HELP, ENV_HELP, console, friendly_errors
from worldagent.errors import WorldagentError

GENERATOR_HELP = "Generator directory (from `worldagent generator train`)."
METRIC_HELP = "Metric: reward (the paper's), or racing return|normalised_return|crashed|lap_completed|progress|steps, harvest group_reward|conflict|equality|sustainability|peace."


def _setup(env: str, agent: str, generator: Path, metric: str, tagger: list[int], greedy: bool):
    """(env object, params, policy, G, canonical metric) from CLI options, checked up front."""
    from worldagent.commands.common import agent_policy, env_and_params
    from worldagent.search.objectives import Objective, metric_name
    from worldagent.worlds.generator import load_generator

    env_obj, params = env_and_params(env, tagger)
    metric = metric_name(env, metric)
    Objective(env, metric, False)  # an unknown metric fails here, before any work
    policy = agent_policy(env, agent, greedy)
    G, _, _ = load_generator(generator)
    if G.env != env:
        raise WorldagentError(f"the generator in {generator} makes {G.env} worlds; pass a {env} generator.")
    return env_obj, params, policy, G, metric


def _check_counts(**counts: int) -> None:
    """Each named count must be at least 1 (one-line error naming the option)."""
    for option, value in counts.items():
        if value < 1:
            raise WorldagentError(f"--{option.replace('_', '-')} is {value}; it must be at least 1.")


def _crash_note(evaluation) -> str:
    """ ", 8/8 episodes crashed" for a racing evaluation."""
    crashed = sum(bool(e.get("crashed")) for e in evaluation.episodes)
    return f", {crashed}/{len(evaluation.episodes)} episodes crashed"


def register(app: typer.Typer) -> None:
    """Add ``strategic`` and ``compare`` to ``app``."""

    @app.command()
    @friendly_errors
    def strategic(
        env: str = typer.Argument(..., help=ENV_HELP),
        agent: str = typer.Option(..., "--agent", help=AGENT_HELP),
        generator: Path = typer.Option(..., "--generator", help=GENERATOR_HELP),
        budget: int = typer.Option(2000, "--budget", help="Worlds to evaluate per direction (rounded up to whole CMA-ES generations)."),
        metric: str = typer.Option("reward", "--metric", help=METRIC_HELP),
        random_worlds: int = typer.Option(1000, "--random-worlds", help="Random worlds for the reference distribution (the paper: 1,000)."),
        optimiser: str = typer.Option("cmaes", "--optimiser", help="cmaes (the paper's), bo or random."),
        repeats: int = typer.Option(8, "--repeats", help="Episodes per world (the paper: 8)."),
        seed: int = typer.Option(0, "--seed", help="Seed of the campaigns and of every episode."),
        out: Path = typer.Option(Path("runs/strategic"), "--out", help="Run directory: store.sqlite and the figure."),
        tagger: list[int] = typer.Option([], "--tagger", help="Harvest: an agent allowed to TAG (repeatable)."),
        greedy: bool = typer.Option(False, "--greedy", help="Trained actor-critics act by argmax instead of sampling."),
        quiet: bool = typer.Option(False, "--quiet", help="No progress bars."),
    ) -> None:
        """Find the worlds where the agents do worst and best, and draw them (paper §6.1.2, Figures 1 and 6b)."""
        import numpy as np

        from worldagent.reports.strategic import strategic_figure
        from worldagent.search.experiments import random_evaluation, strategic_evaluation
        from worldagent.store import RunStore

        _check_counts(budget=budget, random_worlds=random_worlds, repeats=repeats)
        env_obj, params, policy, G, metric = _setup(env, agent, generator, metric, tagger, greedy)
        with RunStore(out) as store:
            randoms = random_evaluation(
                store, env, env_obj, policy, G, params, metric, worlds=random_worlds, repeats=repeats, seed=seed, progress=not quiet
            )
            found = strategic_evaluation(
                store, env, env_obj, policy, G, params, metric, budget=budget, repeats=repeats, seed=seed, optimiser=optimiser, progress=not quiet
            )
        scores = np.array([e.score for e in randoms])
        figure = strategic_figure(
            env, env_obj, policy, params, found["min"], found["max"], scores, metric, out / f"strategic-{metric}-s{seed}.png", key=found["keys"]
        )
        low, high = found["min"], found["max"]
        crashes = (_crash_note(low), _crash_note(high)) if env == "racing" else ("", "")
        console.print(
            f"{env} {metric}: min {low.score:.4g}{crashes[0]}; max {high.score:.4g}{crashes[1]}; "
            f"random mean {np.nanmean(scores):.4g} (sd {np.nanstd(scores):.3g}, {len(scores)} worlds) -> {figure}"
        )

    @app.command()
    @friendly_errors
    def compare(
        env: str = typer.Argument(..., help=ENV_HELP),
        agent: str = typer.Option(..., "--agent", help=AGENT_HELP),
        generator: Path = typer.Option(..., "--generator", help=GENERATOR_HELP),
        budget: int = typer.Option(210, "--budget", help="Worlds each optimiser evaluates per seed."),
        seeds: int = typer.Option(3, "--seeds", help="Seeds per optimiser (0, 1, ...)."),
        optimisers: str = typer.Option("cmaes,bo,random", "--optimisers", help="Comma-separated: cmaes, bo, random."),
        minimize: bool = typer.Option(True, "--minimize/--maximize", help="Direction (the paper's Figure 7 minimises reward)."),
        metric: str = typer.Option("reward", "--metric", help=METRIC_HELP),
        random_worlds: int = typer.Option(1000, "--random-worlds", help="Random worlds for the reference distribution."),
        random_seed: int = typer.Option(
            1000, "--random-seed", help="Seed of the reference random worlds (not one of the optimisers' seeds, so random search never replays them)."
        ),
        repeats: int = typer.Option(8, "--repeats", help="Episodes per world (the paper: 8)."),
        out: Path = typer.Option(Path("runs/compare"), "--out", help="Run directory: store.sqlite, comparison.png/.md/.csv."),
        tagger: list[int] = typer.Option([], "--tagger", help="Harvest: an agent allowed to TAG (repeatable)."),
        greedy: bool = typer.Option(False, "--greedy", help="Trained actor-critics act by argmax instead of sampling."),
        quiet: bool = typer.Option(False, "--quiet", help="No progress bars."),
    ) -> None:
        """Compare the optimisers' sample efficiency against random worlds (paper §6.1.3, Figure 7)."""
        import numpy as np

        from worldagent.reports.comparison import comparison_figure, comparison_table_markdown, sample_efficiency, write_comparison
        from worldagent.search.experiments import compare_optimisers, random_evaluation
        from worldagent.search.optimisers import OPTIMISERS
        from worldagent.store import RunStore

        _check_counts(budget=budget, seeds=seeds, random_worlds=random_worlds, repeats=repeats)
        names = [name.strip() for name in optimisers.split(",") if name.strip()]
        unknown = [name for name in names if name not in OPTIMISERS]
        if not names or unknown:
            raise WorldagentError(f"--optimisers {optimisers!r}: use a comma-separated list of {', '.join(OPTIMISERS)}.")
        if len(set(names)) != len(names):
            raise WorldagentError(f"--optimisers {optimisers!r} names an optimiser twice; list each once.")
        if 0 <= random_seed < seeds:
            raise WorldagentError(f"--random-seed {random_seed} is one of the optimisers' seeds (0 to {seeds - 1}); pick one outside them.")
        env_obj, params, policy, G, metric = _setup(env, agent, generator, metric, tagger, greedy)
        maximize = not minimize
        with RunStore(out) as store:
            randoms = random_evaluation(
                store, env, env_obj, policy, G, params, metric, worlds=random_worlds, repeats=repeats, seed=random_seed, progress=not quiet
            )
            runs = compare_optimisers(
                store,
                env,
                env_obj,
                policy,
                G,
                params,
                metric,
                maximize=maximize,
                optimisers=tuple(names),
                budget=budget,
                seeds=tuple(range(seeds)),
                repeats=repeats,
                progress=not quiet,
            )
        random_scores = np.array([e.score for e in randoms])
        rows = sample_efficiency(runs, random_scores, maximize=maximize)
        figure = comparison_figure(runs, random_scores, metric, out / "comparison.png", maximize=maximize)
        table, csv_path = write_comparison(rows, out, metric, maximize)
        typer.echo(comparison_table_markdown(rows, metric, maximize))
        console.print(f"wrote {figure}, {table}, {csv_path}")
