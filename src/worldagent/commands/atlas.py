"""``worldagent atlas ENV``: a failure atlas, the worst world of every kind of world (quality diversity)."""

from __future__ import annotations

from pathlib import Path

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


def check_atlas_request(env: str, objective: str, budget: int, names, cells: int, failure: str | None, repeats: int, seed: int, out: Path) -> None:
    """Every check of an atlas's options that needs neither the agent nor the generator, run
    before they load (one line naming the fix)."""
    from worldagent import experiments
    from worldagent.envs import registry
    from worldagent.search.atlas import check_descriptors

    check_counts(budget=budget, repeats=repeats)
    check_seed(seed)
    check_metric(env, objective)
    check_descriptors(registry.get(env), names, cells, budget)
    experiments.failure_selection(failure, env)
    check_run_dir(out)


def register(app: typer.Typer) -> None:
    """Add ``worldagent atlas``."""

    @app.command()
    @friendly_errors
    def atlas(
        env: str = env_argument(),
        agent: str = typer.Option(..., "--agent", help=AGENT_HELP),
        generator: Path = typer.Option(..., "--generator", help=GENERATOR_HELP),
        objective: str = typer.Option("reward", "--objective", help=metric_help()),
        minimize: bool = typer.Option(True, "--minimize/--maximize", help="Keep each cell's lowest (failures) or highest value."),
        budget: int = typer.Option(2100, "--budget", help="Worlds to evaluate (whole generations of 21)."),
        descriptors: str = typer.Option(
            None, "--descriptors", help="1-3 comma-separated world descriptors (default: the env's; `worldagent envs` lists each env's)."
        ),
        cells: int = typer.Option(10, "--cells", help="Cells per descriptor."),
        failure: str = typer.Option(
            None,
            "--failure",
            help='Which worlds fail, e.g. "crash_rate > 0.5" (`worldagent envs` prints each env\'s), to count distinct failing worlds.',
        ),
        repeats: int = typer.Option(8, "--repeats", help="Episodes per world (the paper: 8)."),
        seed: int = typer.Option(0, "--seed", help="Seed of the emitters, the grid and every episode."),
        out: Path = typer.Option(Path("runs/atlas"), "--out", help="Run directory (store.sqlite and atlas PNG); a rerun resumes."),
        option: list[str] = option_flag(),
        stochastic: bool = stochastic_flag(),
        backend_name: str = backend_flag(),
        ray_address: str = ray_address_flag(),
        explain: bool = typer.Option(True, "--explain/--no-explain", help="With --failure: nearest passing worlds and failure groups."),
        quiet: bool = typer.Option(False, "--quiet", help="No progress bar."),
    ) -> None:
        """The worst (or best) world of every cell of a descriptor grid, found by CMA-ME, drawn as a heat map."""
        from worldagent import experiments
        from worldagent.reports.atlas import atlas_figure, counterfactual_figure
        from worldagent.store import RunStore

        names = [n.strip() for n in descriptors.split(",")] if descriptors else None
        check_atlas_request(env, objective, budget, names, cells, failure, repeats, seed, out)
        setup = command_setup(
            env, agent, generator, option, stochastic=stochastic, repeats=repeats, backend_name=backend_name, ray_address=ray_address
        )
        with RunStore(out) as store:
            found = experiments.atlas(
                store,
                setup,
                objective,
                maximize=not minimize,
                budget=budget,
                seed=seed,
                descriptors=names,
                cells=cells,
                failure=failure,
                progress=not quiet,
            )
            name = found["evaluations"][0].campaign
            loaded = lambda e: (experiments.with_world(store, e), experiments.scored_keys_of(store, e))  # noqa: E731
            figure = atlas_figure(found, setup, setup.metric(objective), not minimize, loaded, out / f"{name}.png")
        grid = found["grid"]
        failing = "" if found["distinct_failing"] is None else f"; {found['failing']} failing worlds, {found['distinct_failing']} distinct"
        console.print(
            f"{name}: {len(found['evaluations'])} worlds on a {'x'.join(map(str, grid.cells))} grid of {', '.join(grid.descriptors)}; "
            f"coverage {found['coverage']:.2f}, QD-score {found['qd_score']:.4g}{failing} -> {figure}"
        )
        if failure and explain:
            explained = experiments.explain_failures(setup, found, experiments.failure_selection(failure, env), seed=seed)
            pairs = counterfactual_figure(setup, explained["pairs"], out / f"{name}-counterfactuals.png")
            for number, cluster in enumerate(explained["clusters"], 1):
                centre = ", ".join(f"{n} {v:.3g}" for n, v in zip(grid.descriptors, cluster.centre))
                console.print(f"  failure group {number}: {len(cluster.members)} worlds around {centre}")
            console.print(f"  {len(explained['pairs'])} failing worlds beside their nearest passing world -> {pairs}")
