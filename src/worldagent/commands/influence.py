"""``worldagent influence ENV``: retrain agents on worlds with a desired property (paper §6.2, Figure 8)."""

from __future__ import annotations

from pathlib import Path

import typer

from worldagent.commands.console import console, friendly_errors
from worldagent.commands.options import (
    AGENT_HELP,
    GENERATOR_HELP,
    algo_help,
    algorithm,
    backend,
    check_counts,
    check_run_dir,
    check_seed,
    check_training_episodes,
    env_argument,
    given_options,
    option_flag,
    ray_address_flag,
    set_flag,
    stochastic_flag,
)
from worldagent.errors import WorldagentError

RESULT_FILE = "influence.json"  # what ``experiments.influence`` writes in its run directory
SELECT_HELP = (
    "The property of the new training worlds: METRIC OP NUMBER joined by 'and', OP one of < <= > >= == !=, "
    "e.g. 'crash_rate > 0.5' (racing) or 'conflict == 0' (harvest). Metrics are averaged over a world's episodes; "
    "`worldagent envs` lists each environment's metrics and aliases; reward is the main one."
)


def format_interval(entry: dict) -> str:
    """``mean ± half-width`` (``± n/a`` when one seed leaves the interval undefined)."""
    ci = entry.get("ci95")
    spread = "n/a" if ci is None or ci != ci else f"{ci:.3g}"
    return f"{entry['mean']:.4g} ± {spread}"


def result_table(result: dict, title: str = ""):
    """A rich table: one row per metric, default and influenced mean ± 95% CI over seeds (``title``: a prefix)."""
    from rich.table import Table

    from worldagent.reports.influence import metric_label

    seeds = len(result["config"]["seeds"])
    spread = "mean ± 95% CI" if seeds > 1 else "one seed: no CI"
    table = Table(title=f"{title}{result['env']}: default vs influenced ({seeds} seed{'s' if seeds != 1 else ''}, {spread})")
    table.add_column("metric")
    table.add_column("default", justify="right")
    table.add_column("influenced", justify="right")
    for metric in result["metrics"]:
        row = result["summary"][metric]
        table.add_row(metric_label(metric), format_interval(row["default"]), format_interval(row["influenced"]))
    return table


def check_influence_counts(search_budget: int, **counts: int) -> None:
    """The counts of ``influence``: ``--search-budget`` may be 0 (no search), the others at least 1; all capped."""
    if search_budget < 0:
        raise WorldagentError(f"--search-budget is {search_budget}; pass 0 (no search) or more.")
    check_counts(**counts, **({"search_budget": search_budget} if search_budget else {}))


def check_search(search: str) -> None:
    """``--search``: one of the influence experiment's searches."""
    from worldagent.influence.experiment import SEARCHES

    if search not in SEARCHES:
        raise WorldagentError(f"unknown --search {search!r}; use one of: {', '.join(SEARCHES)}.")


def influence_command(
    env: str,
    agent: str,
    generator: Path,
    select: str,
    algo: str | None,
    episodes: int | None,
    seeds: int,
    candidates: int,
    search_budget: int,
    eval_worlds: int,
    repeats: int,
    option: list[str],
    seed: int,
    out: Path,
    greedy: bool,
    quiet: bool,
    stochastic: bool = False,
    search: str = "cmaes",
    settings: list[str] | tuple[str, ...] = (),
    rounds: int = 1,
    runs_per_program: int | None = None,
    backend_name: str = "local",
    ray_address: str | None = None,
    confirm: int = 32,
) -> None:
    """Train agents on worlds with a desired property and compare them with default training (paper §6.2, Figure 8)."""
    from worldagent.agents.algorithms import parse_settings, training_config
    from worldagent.events import parse_selection

    selection = parse_selection(select, env)  # before anything slow: a typo costs nothing
    algo = algorithm(env, algo)
    check_influence_counts(seeds=seeds, candidates=candidates, search_budget=search_budget, eval_worlds=eval_worlds, repeats=repeats)
    check_training_episodes(episodes)
    check_seed(seed)
    check_search(search)
    if confirm < 0:
        raise WorldagentError(f"--confirm is {confirm}; pass the fresh episodes each selected world is replayed on, or 0 for the raw selection.")
    if rounds < 1:
        raise WorldagentError(f"--rounds is {rounds}; pass 1 (the paper's single retrain) or more.")
    if runs_per_program is not None and runs_per_program < 1:
        raise WorldagentError(f"--runs-per-program is {runs_per_program}; pass at least 1 (or leave it out: chosen from the device).")
    check_run_dir(out)
    options = given_options(env, option)
    chosen = parse_settings(settings, [algo])[algo]
    training_config(env, algo, episodes, options=options, **chosen)  # a bad value is refused before the agent and generator load

    from rich.console import Console

    from worldagent import experiments
    from worldagent.influence.confirmation import confirmation_line
    from worldagent.reports.influence import influence_figure

    where = backend(backend_name, ray_address)
    setup = experiments.setup(env, agent, generator, options=options, greedy=greedy, stochastic=stochastic, repeats=repeats, backend=where)
    # with --set, the config of the options the agents train with (the saved agent's fill those not given)
    config = training_config(setup.spec, algo, episodes, options=setup.options, **chosen) if chosen else None
    result = experiments.influence(
        out,
        setup,
        selection,
        algo=algo,
        episodes=episodes,
        seeds=tuple(range(seeds)),
        candidates=candidates,
        search_budget=search_budget,
        search=search,
        eval_worlds=eval_worlds,
        config=config,
        seed=seed,
        greedy=greedy,
        progress=not quiet,
        runs_per_program=runs_per_program,
        rounds=rounds,
        confirm=confirm,
    )
    figure = influence_figure(result, experiments.example_worlds(out, setup.spec), setup.spec, out / "influence.png")
    Console().print(result_table(result))
    counts = result["worlds"]
    if "confirmation" in counts:
        console.print(confirmation_line(counts["confirmation"]))
    console.print(
        f"{counts['selected']} of {counts['tried']} worlds have {selection.describe()}{' (confirmed)' if 'confirmation' in counts else ''}; "
        f"{2 * seeds} agents compared on {eval_worlds} worlds x {repeats} episodes (this run: {result['wall_seconds']['total']:.0f} s) "
        f"-> {figure}, {out / RESULT_FILE}"
    )
    for later in result.get("rounds", []):
        Console().print(result_table({**result, **later}, f"round {later['round']}: "))
        found = later["worlds"]
        survived = found.get("confirmation", {})
        kept = {s: f" ({survived[s]['survived']} of {survived[s]['selected']} confirmed)" if s in survived else "" for s in found["selected"]}
        new = ", ".join(
            f"s{s}: {n} found{kept[s]}, {found['added'][s]} new, {found['training_worlds'][s]} in all" for s, n in found["selected"].items()
        )
        console.print(f"round {later['round']}: worlds with {selection.describe()} ({new}) -> {out / later['dir'] / RESULT_FILE}")


def register(app: typer.Typer) -> None:
    """Add ``worldagent influence``."""

    @app.command("influence")
    @friendly_errors
    def influence(
        env: str = env_argument(),
        agent: str = typer.Option(..., "--agent", help=AGENT_HELP),
        generator: Path = typer.Option(..., "--generator", help=GENERATOR_HELP),
        select: str = typer.Option(..., "--select", help=SELECT_HELP),
        algo: str = typer.Option(None, "--algo", help=algo_help()),
        episodes: int = typer.Option(None, "--episodes", help="Training episodes per agent (default: the algorithm's budget for the env)."),
        seeds: int = typer.Option(3, "--seeds", help="Training seeds 0..N-1: one default and one influenced agent each."),
        candidates: int = typer.Option(500, "--candidates", help="Random G(z) worlds evaluated with --agent to find the property."),
        search_budget: int = typer.Option(0, "--search-budget", help="Extra worlds a search evaluates, pushing toward the property (0: none)."),
        search: str = typer.Option(
            "cmaes", "--search", help="cmaes (the paper's) or atlas (CMA-ME over the env's descriptors: many distinct worlds with the property)."
        ),
        eval_worlds: int = typer.Option(200, "--eval-worlds", help="Random G(z) worlds every trained agent is evaluated on (the same for all)."),
        repeats: int = typer.Option(8, "--repeats", help="Episodes per world (the paper: 8)."),
        option: list[str] = option_flag(),
        settings: list[str] = set_flag(),
        seed: int = typer.Option(0, "--seed", help="Seed of the candidate, search and evaluation worlds."),
        out: Path = typer.Option(Path("runs/influence"), "--out", help="Run directory; rerun to resume or reuse finished steps."),
        greedy: bool = typer.Option(False, "--greedy", help="Actor-critics act by argmax instead of sampling."),
        stochastic: bool = stochastic_flag(),
        quiet: bool = typer.Option(False, "--quiet", help="No progress bars."),
        rounds: int = typer.Option(
            1, "--rounds", help="Rounds of search, select, retrain: round r searches with round r-1's influenced agents (run_dir/round-r/)."
        ),
        runs_per_program: int = typer.Option(
            None, "--runs-per-program", help="Agents trained as one vmapped program at most (memory; default: 2 on a CPU, from memory on a GPU)."
        ),
        backend_name: str = typer.Option("local", "--backend", help="Where the agents train: local, or ray (each program a task on a worker)."),
        ray_address: str = ray_address_flag(),
        confirm: int = typer.Option(
            32,
            "--confirm",
            help="Fresh episodes each selected world is replayed on; only those that keep the property on them are trained on "
            "(0: the raw selection, as found on --repeats episodes).",
        ),
    ) -> None:
        """Train agents on worlds with a desired property and compare them with default training (paper §6.2, Figure 8)."""
        influence_command(
            env,
            agent,
            generator,
            select,
            algo,
            episodes,
            seeds,
            candidates,
            search_budget,
            eval_worlds,
            repeats,
            option,
            seed,
            out,
            greedy,
            quiet,
            stochastic,
            search,
            settings,
            rounds,
            runs_per_program,
            backend_name,
            ray_address,
            confirm,
        )
