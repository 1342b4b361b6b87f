"""``worldagent evaluate random ENV``: a metric over random worlds z ~ N(0, I) (paper §6.1.1, Figure 6a)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import typer

from worldagent.commands.console import console, friendly_errors
from worldagent.commands.options import (
    AGENT_HELP,
    GENERATOR_HELP,
    backend_flag,
    check_counts,
    check_metric,
    check_run_dir,
    check_seed,
    command_setup,
    env_argument,
    metric_help,
    option_flag,
    ray_address_flag,
    stochastic_flag,
)


def normalised_note(setup, metric: str, evaluations) -> str:
    """ ", normalised 0.874" for the main metric (``spec.metrics.normalise``: bounds or the best episode)."""
    spec = setup.spec
    if metric != spec.metrics.main:
        return ""
    episodes = [[float(e[metric]) for e in ev.episodes if e.get(metric) is not None] for ev in evaluations]
    best = max((max(values) for values in episodes if values), default=None)
    means = [np.mean(spec.metrics.normalise(values, setup.params, best_episode=best)) for values in episodes if values]
    value = float(np.nanmean(means)) if means else float("nan")
    return "" if not np.isfinite(value) else f", normalised {value:.3f}"


def register(app: typer.Typer) -> None:
    """Add ``worldagent evaluate`` and its subcommand ``random``."""
    group = typer.Typer(help="Evaluate agents on worlds from the generator.", no_args_is_help=True)
    app.add_typer(group, name="evaluate")

    @group.command("random")
    @friendly_errors
    def evaluate_random(
        env: str = env_argument(),
        agent: str = typer.Option(..., "--agent", help=AGENT_HELP),
        generator: Path = typer.Option(..., "--generator", help=GENERATOR_HELP),
        worlds: int = typer.Option(1000, "--worlds", help="Worlds z ~ N(0, I) to evaluate (the paper: 1,000)."),
        metric: str = typer.Option("reward", "--metric", help=metric_help()),
        repeats: int = typer.Option(8, "--repeats", help="Episodes per world (the paper: 8)."),
        seed: int = typer.Option(0, "--seed", help="Seed of the latents and episodes."),
        out: Path = typer.Option(Path("runs/evaluate"), "--out", help="Run directory (store.sqlite and the histogram); a rerun resumes."),
        option: list[str] = option_flag(),
        greedy: bool = typer.Option(False, "--greedy", help="Trained actor-critics act by argmax instead of sampling."),
        stochastic: bool = stochastic_flag(),
        backend_name: str = backend_flag(),
        ray_address: str = ray_address_flag(),
        quiet: bool = typer.Option(False, "--quiet", help="No progress bar."),
    ) -> None:
        """The distribution of a metric over randomly generated worlds (paper §6.1.1, Figure 6a)."""
        from worldagent import experiments
        from worldagent.reports.figures import distribution_figure
        from worldagent.store import RunStore

        check_counts(worlds=worlds, repeats=repeats)
        check_seed(seed)
        metric = check_metric(env, metric)
        check_run_dir(out)
        setup = command_setup(
            env, agent, generator, option, greedy=greedy, stochastic=stochastic, repeats=repeats, backend_name=backend_name, ray_address=ray_address
        )
        with RunStore(out) as store:
            evaluations = experiments.random_evaluation(store, setup, metric, worlds=worlds, seed=seed, progress=not quiet)
        name = experiments.campaign_names(metric, seed)["random"]
        scores = np.array([e.score for e in evaluations])
        figure = distribution_figure({"random worlds": scores}, metric, out / f"{name}.png", f"{env}: {metric} over {len(scores)} random worlds")
        line = f"{name}: {len(scores)} worlds x {repeats} episodes; {metric} mean {np.nanmean(scores):.4g} (sd {np.nanstd(scores):.3g})"
        console.print(f"{line}{normalised_note(setup, metric, evaluations)} -> {figure}")
