"""``worldagent strategic`` and ``worldagent compare``: the paper's §6.1.2 and §6.1.3 from the shell.

Both resume by default: their campaigns live in the run store under fixed names, so a rerun
evaluates nothing new and only redraws the figures. Both confirm the worlds they report on fresh
episodes (``--confirm N``, 64 by default; 0 skips) and print the found figure (the selection's)
beside the confirmed one; the confirmations are stored too and read back on a rerun.
"""

from __future__ import annotations

from pathlib import Path

import typer

from worldagent.commands.console import console, friendly_errors
from worldagent.commands.options import (
    AGENT_HELP,
    GENERATOR_HELP,
    backend_flag,
    budget_help,
    check_counts,
    check_metric,
    check_run_dir,
    check_seed,
    command_setup,
    env_argument,
    metric_help,
    optimiser_help,
    option_flag,
    ray_address_flag,
    search_settings,
    stochastic_flag,
)
from worldagent.errors import WorldagentError


def optimiser_names(text: str) -> tuple[str, ...]:
    """``"cmaes,bo"`` -> ("cmaes", "bo"); unknown or repeated names are refused."""
    from worldagent.search.optimisers import OPTIMISERS

    names = [name.strip() for name in text.split(",") if name.strip()]
    if not names or any(name not in OPTIMISERS for name in names):
        raise WorldagentError(f"--optimisers {text!r}: use a comma-separated list of {', '.join(OPTIMISERS)}.")
    if len(set(names)) != len(names):
        raise WorldagentError(f"--optimisers {text!r} names an optimiser twice; list each once.")
    return tuple(names)


def confirm_flag():
    """``--confirm N``: fresh episodes per reported world (``analysis.confirm.REPEATS`` by default; 0 skips)."""
    from worldagent.analysis.confirm import REPEATS

    return typer.Option(
        REPEATS,
        "--confirm",
        help="Fresh episodes (from keys no search draws) to confirm each reported world on; 0 skips. A found world's score is "
        "the best of many noisy ones (partly luck); the confirmed one is the world's.",
    )


def prior_bound_flag():
    """``--prior-bound``: where a search may go in latent space (``search.prior``; issue 48)."""
    return typer.Option(
        "typical",
        "--prior-bound",
        help="Where the search may go: typical (the default: the prior's typical set |z| <= r, r the 99.9% quantile of |z| under "
        "N(0, I), 5.44 for 10-d latents), none (beyond it: only the optimiser's box |z_i| <= 3), or a radius. Recorded in the campaign; "
        "a resumed campaign must use its own.",
    )


def check_prior_bound(text: str) -> str:
    """``--prior-bound`` names a bound (``search.prior.prior_bound``), refused in one line before anything loads."""
    from worldagent.search.prior import prior_bound

    prior_bound(text, 1)
    return text


def check_confirm(confirm: int) -> int:
    """``--confirm`` must be a count of episodes (0: skip)."""
    if confirm < 0:
        raise WorldagentError(f"--confirm {confirm}; pass a number of fresh episodes per reported world (64 by default), or 0 to skip.")
    return confirm


def register(app: typer.Typer) -> None:
    """Add ``strategic`` and ``compare`` to ``app``."""

    @app.command()
    @friendly_errors
    def strategic(
        env: str = env_argument(),
        agent: str = typer.Option(..., "--agent", help=AGENT_HELP),
        generator: Path = typer.Option(..., "--generator", help=GENERATOR_HELP),
        budget: int = typer.Option(None, "--budget", help=f"Per direction. {budget_help()}", show_default=False),
        metric: str = typer.Option("reward", "--metric", help=metric_help()),
        random_worlds: int = typer.Option(1000, "--random-worlds", help="Random worlds for the reference distribution (the paper: 1,000)."),
        optimiser: str = typer.Option(None, "--optimiser", help=optimiser_help(), show_default=False),
        repeats: int = typer.Option(8, "--repeats", help="Episodes per world (the paper: 8)."),
        confirm: int = confirm_flag(),
        prior: str = prior_bound_flag(),
        seed: int = typer.Option(0, "--seed", help="Seed of the campaigns and of every episode."),
        out: Path = typer.Option(Path("runs/strategic"), "--out", help="Run directory: store.sqlite, the figure and its JSON."),
        option: list[str] = option_flag(),
        greedy: bool = typer.Option(False, "--greedy", help="Trained actor-critics act by argmax instead of sampling."),
        stochastic: bool = stochastic_flag(),
        backend_name: str = backend_flag(),
        ray_address: str = ray_address_flag(),
        quiet: bool = typer.Option(False, "--quiet", help="No progress bars."),
    ) -> None:
        """Find the worlds where the agents do worst and best, and draw them (paper §6.1.2, Figures 1 and 6b)."""
        import numpy as np

        from worldagent import experiments
        from worldagent.reports.strategic import draw_strategic, strategic_lines, write_strategic_json
        from worldagent.store import RunStore

        optimiser, budget = search_settings(env, optimiser, budget)
        check_counts(budget=budget, random_worlds=random_worlds, repeats=repeats)
        check_confirm(confirm)
        check_prior_bound(prior)
        check_seed(seed)
        metric = check_metric(env, metric)
        check_run_dir(out)
        setup = command_setup(
            env, agent, generator, option, greedy=greedy, stochastic=stochastic, repeats=repeats, backend_name=backend_name, ray_address=ray_address
        )
        with RunStore(out) as store:
            randoms = experiments.random_evaluation(store, setup, metric, worlds=random_worlds, seed=seed, progress=not quiet)
            found = experiments.strategic_evaluation(
                store, setup, metric, budget=budget, seed=seed, optimiser=optimiser, progress=not quiet, confirm=confirm, prior_bound=prior
            )
        scores = np.array([e.score for e in randoms])
        figure = draw_strategic(setup, found, scores, metric, out / f"strategic-{found['metric']}-s{seed}.png")
        summary = write_strategic_json(setup.spec, found, randoms, out / f"strategic-{found['metric']}-s{seed}.json")
        console.print(f"{env} {found['metric']} ({optimiser}, {budget} worlds each way):", markup=False)
        for line in strategic_lines(setup.spec, found):
            console.print(f"  {line}", markup=False)
        console.print(
            f"  random mean {np.nanmean(scores):.4g} (sd {np.nanstd(scores):.3g}, {len(scores)} worlds) -> {figure}, {summary}", markup=False
        )

    @app.command()
    @friendly_errors
    def compare(
        env: str = env_argument(),
        agent: str = typer.Option(..., "--agent", help=AGENT_HELP),
        generator: Path = typer.Option(..., "--generator", help=GENERATOR_HELP),
        budget: int = typer.Option(210, "--budget", help="Worlds each optimiser evaluates per seed."),
        seeds: int = typer.Option(3, "--seeds", help="Seeds per optimiser (0, 1, ...)."),
        optimisers: str = typer.Option("cmaes,bo,random", "--optimisers", help="Comma-separated: cmaes, bo, random."),
        minimize: bool = typer.Option(True, "--minimize/--maximize", help="Direction (the paper's Figure 7 minimises reward)."),
        metric: str = typer.Option("reward", "--metric", help=metric_help()),
        random_worlds: int = typer.Option(1000, "--random-worlds", help="Random worlds for the reference distribution."),
        random_seed: int = typer.Option(
            1000, "--random-seed", help="Seed of the reference random worlds (not one of the optimisers' seeds, so random search never replays them)."
        ),
        repeats: int = typer.Option(8, "--repeats", help="Episodes per world (the paper: 8)."),
        confirm: int = confirm_flag(),
        prior: str = prior_bound_flag(),
        out: Path = typer.Option(
            Path("runs/compare"), "--out", help="Run directory: store.sqlite, comparison.png/.md/.csv (and with --confirm, .json and -confirmed.csv)."
        ),
        option: list[str] = option_flag(),
        greedy: bool = typer.Option(False, "--greedy", help="Trained actor-critics act by argmax instead of sampling."),
        stochastic: bool = stochastic_flag(),
        backend_name: str = backend_flag(),
        ray_address: str = ray_address_flag(),
        quiet: bool = typer.Option(False, "--quiet", help="No progress bars."),
    ) -> None:
        """Compare the optimisers' sample efficiency against random worlds (paper §6.1.3, Figure 7)."""
        import numpy as np

        from worldagent import experiments
        from worldagent.reports.comparison import (
            comparison_figure,
            comparison_table_markdown,
            confirmed_efficiency,
            confirmed_table_markdown,
            ordering,
            sample_efficiency,
            write_comparison,
        )
        from worldagent.store import RunStore

        check_counts(budget=budget, seeds=seeds, random_worlds=random_worlds, repeats=repeats)
        check_confirm(confirm)
        check_prior_bound(prior)
        names = optimiser_names(optimisers)
        check_seed(random_seed, "--random-seed")
        if random_seed < seeds:
            raise WorldagentError(f"--random-seed {random_seed} is one of the optimisers' seeds (0 to {seeds - 1}); pick one outside them.")
        metric = check_metric(env, metric)
        check_run_dir(out)
        setup = command_setup(
            env, agent, generator, option, greedy=greedy, stochastic=stochastic, repeats=repeats, backend_name=backend_name, ray_address=ray_address
        )
        maximize = not minimize
        with RunStore(out) as store:
            randoms = experiments.random_evaluation(store, setup, metric, worlds=random_worlds, seed=random_seed, progress=not quiet)
            arguments = {"maximize": maximize, "optimisers": names, "budget": budget, "seeds": tuple(range(seeds)), "progress": not quiet}
            runs = experiments.compare_optimisers(store, setup, metric, **arguments, prior_bound=prior)
            confirmed = experiments.confirm_optimisers(store, setup, metric, repeats=confirm, **arguments)
        random_scores = np.array([e.score for e in randoms])
        rows = sample_efficiency(runs, random_scores, maximize=maximize)
        figure = comparison_figure(runs, random_scores, metric, out / "comparison.png", maximize=maximize)
        typer.echo(comparison_table_markdown(rows, metric, maximize))
        checked, verdict = None, None
        if confirmed:
            checked = confirmed_efficiency(runs, confirmed, metric, maximize)
            verdict = ordering(checked, confirmed, metric, maximize)
            typer.echo(confirmed_table_markdown(checked, verdict, metric, maximize))
        written = write_comparison(rows, out, metric, maximize, checked, verdict)
        console.print(f"wrote {figure}, {', '.join(map(str, written))}", markup=False)
