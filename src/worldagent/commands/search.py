"""``worldagent search ENV``: one campaign over the generator's latent space (paper §4.4)."""

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
from worldagent.commands.strategic import check_confirm, check_prior_bound, confirm_flag, prior_bound_flag


def register(app: typer.Typer) -> None:
    """Add ``worldagent search``."""

    @app.command()
    @friendly_errors
    def search(
        env: str = env_argument(),
        agent: str = typer.Option(..., "--agent", help=AGENT_HELP),
        generator: Path = typer.Option(..., "--generator", help=GENERATOR_HELP),
        objective: str = typer.Option("reward", "--objective", help=metric_help()),
        minimize: bool = typer.Option(False, "--minimize/--maximize", help="Direction of the search."),
        optimiser: str = typer.Option(None, "--optimiser", help=optimiser_help(), show_default=False),
        budget: int = typer.Option(None, "--budget", help=budget_help(), show_default=False),
        repeats: int = typer.Option(8, "--repeats", help="Episodes per world (the paper: 8)."),
        confirm: int = confirm_flag(),
        prior: str = prior_bound_flag(),
        seed: int = typer.Option(0, "--seed", help="Seed of the optimiser and of every episode."),
        out: Path = typer.Option(Path("runs/search"), "--out", help="Run directory; its store.sqlite may hold many campaigns."),
        name: str = typer.Option(None, "--name", help="Campaign name (default: optimiser-direction-objective-seed)."),
        resume: bool = typer.Option(False, "--resume", help="Continue a killed campaign of the same name."),
        option: list[str] = option_flag(),
        greedy: bool = typer.Option(False, "--greedy", help="Trained actor-critics act by argmax instead of sampling."),
        stochastic: bool = stochastic_flag(),
        backend_name: str = backend_flag(),
        ray_address: str = ray_address_flag(),
        quiet: bool = typer.Option(False, "--quiet", help="No progress bar."),
    ) -> None:
        """Search the generator's latent space for worlds that minimise or maximise an agent metric (paper §4.4)."""
        import numpy as np

        from worldagent import experiments
        from worldagent.reports.strategic import reported_line, winners_curse
        from worldagent.search.campaign import searched_where
        from worldagent.search.prior import prior_text
        from worldagent.store import RunStore

        optimiser, budget = search_settings(env, optimiser, budget)
        check_counts(budget=budget, repeats=repeats)
        check_confirm(confirm)
        check_prior_bound(prior)
        check_seed(seed)
        check_metric(env, objective)
        check_run_dir(out)
        setup = command_setup(
            env, agent, generator, option, greedy=greedy, stochastic=stochastic, repeats=repeats, backend_name=backend_name, ray_address=ray_address
        )
        with RunStore(out) as store:
            evaluations, spec = experiments.search(
                store,
                setup,
                objective,
                maximize=not minimize,
                optimiser=optimiser,
                budget=budget,
                seed=seed,
                name=name,
                resume=resume,
                progress=not quiet,
                prior_bound=prior,
            )
            best = experiments.best(evaluations, maximize=not minimize)
            where = searched_where(store.campaign(spec.name))
            name = experiments.selection_name("search", spec.name)
            confirmed = experiments.confirm_reported(store, setup, best, name, repeats=confirm, seed=seed, progress=not quiet)
        scores = np.array([e.score for e in evaluations])
        direction = "min" if minimize else "max"
        console.print(
            f"{spec.name}: {len(evaluations)} worlds; {spec.objective} mean {np.nanmean(scores):.4g}; {direction} world "
            f"(generation {best.generation}, slot {best.slot}): {reported_line(setup.spec, best, confirmed, spec.objective)} -> {out / 'store.sqlite'}",
            markup=False,
        )
        console.print(f"  {direction} world under the prior: {prior_text(best.latent)}; {where}", markup=False)
        caveat = winners_curse(confirmed, spec.objective, direction, not minimize)
        if caveat:
            console.print(f"  {caveat}", markup=False)
