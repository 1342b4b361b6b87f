"""``worldagent diff ENV --agent A --agent B``: which worlds got worse? Two agents world by world, a
differential search for where B is worse, and a ``--fail-if`` gate a pipeline can run (exit 0 / 1 / 2)."""

from __future__ import annotations

import json
import math
import numbers
from pathlib import Path

import typer

from worldagent.commands.console import console, friendly_errors, status_line
from worldagent.commands.options import (
    AGENT_HELP,
    GENERATOR_HELP,
    backend,
    check_counts,
    check_metric,
    check_run_dir,
    check_seed,
    env_argument,
    given_options,
    metric_help,
    option_flag,
    ray_address_flag,
    stochastic_flag,
)
from worldagent.commands.strategic import check_prior_bound, prior_bound_flag
from worldagent.errors import WorldagentError

FAIL_IF_HELP = (
    "Fail (exit 1) when this holds, e.g. 'p_failure_increase > 0.005', 'regressed > 0', 'return_drop > 2' (repeatable; any one fails). "
    "Quantities: p_failure_increase, p_failure_a, p_failure_b, regressed, improved, METRIC_drop, METRIC_increase, cvar_drop, "
    "search_regressed, search_drop; _low/_high read the 95% interval's bounds. The world-set quantities are the paired statistics "
    "as measured (every sampled world counts); the search's are its reported worlds confirmed for A and B on fresh episodes "
    "(distinct worlds; found with --confirm 0). Checked before any episode runs."
)
CONFIRM_HELP = (
    "Fresh episodes on which each reported world (the regressed worlds, likeliest first, at most 50 distinct; the search's "
    "regressed and most extreme worlds) is replayed for A and for B, from keys no search draws; A and B share them (common "
    "random numbers, by design). A world is confirmed regressed when B's confirmed interval fails and A's passes. Default 64; 0 skips."
)


def plain(value):
    """``value`` for JSON: NaN and infinities as null (JSON has no NaN), numpy numbers as Python ones."""
    if isinstance(value, dict):
        return {key: plain(item) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return [plain(item) for item in value]
    if isinstance(value, (bool, str)) or value is None:
        return value
    if isinstance(value, numbers.Integral):
        return int(value)
    number = float(value)
    return number if math.isfinite(number) else None


def world_source(worlds: int | None, campaign: str | None, store: Path | None, dataset: list[Path], search: str | None) -> str | None:
    """Which world set ``--worlds`` / ``--campaign`` / ``--dataset`` names (at most one; or none with ``--search``)."""
    given = [name for name, value in (("--worlds", worlds is not None), ("--campaign", campaign is not None), ("--dataset", bool(dataset))) if value]
    if len(given) > 1:
        raise WorldagentError(f"{' and '.join(given)} both name worlds; compare on one world set at a time.")
    if (store is None) != (campaign is None):
        raise WorldagentError("--campaign and --store go together: --campaign NAME --store RUN_DIR (or its store.sqlite).")
    if not given and search is None:
        raise WorldagentError(
            "nothing to compare on: pass --worlds N (with --generator), --campaign NAME --store RUN_DIR, --dataset FILE, or --search."
        )
    return given[0] if given else None


def check_request(
    env, agents, generator, source, worlds, search, budget, objective, failure, metric, fail_if, descriptors, cells, repeats, seed, out, confirm=None
):
    """Every check that needs neither agent nor generator loaded, run first (one line naming the fix); returns the gate."""
    from worldagent.analysis.gate import parse_gate
    from worldagent.envs import registry
    from worldagent.events import parse_selection

    if confirm is not None and confirm < 0:
        raise WorldagentError(f"--confirm {confirm}; pass fresh episodes per reported world (64 by default), or 0 to skip.")
    spec = registry.get(env)
    if len(agents) != 2:
        raise WorldagentError(f"--agent given {len(agents)} time(s); pass it twice: --agent OLD --agent NEW (A, then B).")
    check_counts(repeats=repeats, **({"worlds": worlds} if worlds is not None else {}), **({"budget": budget} if search else {}))
    check_seed(seed)
    check_metric(env, metric)
    check_metric(env, objective)
    gate = parse_gate(fail_if, spec.metrics) if fail_if else None
    if gate is not None and gate.needs_search and search is None:
        raise WorldagentError("--fail-if reads search_regressed/search_drop; add --search cmaes (or atlas).")
    if gate is not None and gate.needs_worlds and source is None:
        raise WorldagentError("--fail-if reads a world set's statistics; add --worlds N, --campaign NAME --store RUN_DIR or --dataset FILE.")
    parse_selection(failure or spec.failure or "", env)
    if search is not None:
        from worldagent.differential import SEARCHES
        from worldagent.search.atlas import check_descriptors

        if search not in SEARCHES:
            raise WorldagentError(f"--search {search!r}; use one of: {', '.join(SEARCHES)}.")
        if search == "atlas":
            check_descriptors(spec, descriptors, cells, budget)
    if (search is not None or source == "--worlds") and generator is None:
        raise WorldagentError("worlds G(z) (--worlds, --search) need --generator DIR.")
    check_run_dir(out)
    return gate


def register(app: typer.Typer) -> None:
    """Add ``worldagent diff``."""

    @app.command()
    @friendly_errors
    def diff(
        env: str = env_argument(),
        agent: list[str] = typer.Option(..., "--agent", help=f"Twice: the old agent A, then the new agent B. {AGENT_HELP}"),
        generator: Path = typer.Option(None, "--generator", help=f"{GENERATOR_HELP} Needed for --worlds and --search."),
        worlds: int = typer.Option(None, "--worlds", help="Compare on N worlds G(z), z ~ N(0, I)."),
        campaign: str = typer.Option(None, "--campaign", help="Compare on the worlds of a stored campaign (with --store)."),
        store: Path = typer.Option(None, "--store", help="With --campaign: the run directory (or store.sqlite) holding it."),
        dataset: list[Path] = typer.Option([], "--dataset", help="Compare on a dataset file's worlds (repeatable; the explorer's saved worlds too)."),
        search: str = typer.Option(None, "--search", help="Also search z for where B is worse: cmaes, or atlas (CMA-ME over the env's descriptors)."),
        budget: int = typer.Option(420, "--budget", help="Worlds the search evaluates (whole generations of 21)."),
        objective: str = typer.Option("reward", "--objective", help="The search's metric, scored as metric(B) − metric(A)."),
        minimize: bool = typer.Option(True, "--minimize/--maximize", help="Search where B is lowest against A (a reward) or highest (a crash rate)."),
        descriptors: str = typer.Option(None, "--descriptors", help="--search atlas: 1-3 comma-separated descriptors (default: the env's)."),
        cells: int = typer.Option(10, "--cells", help="--search atlas: cells per descriptor."),
        failure: str = typer.Option(None, "--failure", help="Which worlds fail, e.g. 'crash_rate > 0.5' (default: the env's; `worldagent envs`)."),
        metric: str = typer.Option("reward", "--metric", help=f"The α-CVaR's metric, higher is better. {metric_help()}"),
        fail_if: list[str] = typer.Option([], "--fail-if", help=FAIL_IF_HELP),
        repeats: int = typer.Option(8, "--repeats", help="Episodes per world, the same keys for both agents (the paper: 8)."),
        seed: int = typer.Option(0, "--seed", help="Seed of the worlds, the episodes, the search and the bootstrap."),
        out: Path = typer.Option(Path("runs/diff"), "--out", help="Run directory: store.sqlite, diff.json, diff.md; a rerun resumes."),
        option: list[str] = option_flag(),
        greedy: bool = typer.Option(False, "--greedy", help="Trained actor-critics act by argmax instead of sampling."),
        stochastic: bool = stochastic_flag(),
        backend_name: str = typer.Option("local", "--backend", help="Where world batches are evaluated: local or ray (extra `ray`)."),
        ray_address: str = ray_address_flag(),
        confirm: int = typer.Option(None, "--confirm", help=CONFIRM_HELP),
        prior: str = prior_bound_flag(),
        quiet: bool = typer.Option(False, "--quiet", help="No progress bars."),
    ) -> None:
        """Which worlds got worse? A and B on the same worlds with the same episode keys: paired differences, P(failure),
        α-CVaR, the regressed worlds; optionally a differential search; exit 1 when --fail-if holds."""
        from worldagent import differential
        from worldagent.files import write_text
        from worldagent.reports.diff import console_lines, markdown
        from worldagent.store import RunStore

        names = [n.strip() for n in descriptors.split(",")] if descriptors else None
        source = world_source(worlds, campaign, store, dataset, search)
        args = (env, agent, generator, source, worlds, search, budget, objective, failure, metric, fail_if, names, cells, repeats, seed, out, confirm)
        gate = check_request(*args)
        check_prior_bound(prior)
        setup = differential.diff_setup(
            env, agent[0], agent[1], generator, options=given_options(env, option), greedy=greedy, stochastic=stochastic,
            repeats=repeats, backend=backend(backend_name, ray_address),
        )  # fmt: skip
        chosen = {"--worlds": lambda: worlds, "--campaign": lambda: differential.campaign_worlds(setup.spec, store, campaign, setup.generator)}
        chosen["--dataset"] = lambda: differential.dataset_worlds(setup.spec, dataset)
        world_set = chosen[source]() if source else None
        with RunStore(out) as run_store:
            result = differential.diff(
                run_store, setup, worlds=world_set, search=search, budget=budget, objective=objective, maximize=not minimize,
                descriptors=names, cells=cells, failure=failure, metric=metric, gate=gate, seed=seed, progress=not quiet, prior_bound=prior,
                **({} if confirm is None else {"confirm": confirm}),
            )  # fmt: skip
        result["generator"] = str(generator.resolve()) if generator else None  # `worldagent explore OUT` opens it
        write_text(out / "diff.json", json.dumps(plain(result), indent=1))
        write_text(out / "diff.md", markdown(result))
        for line in console_lines(result):
            status_line(line)
        console.print(f"-> {out / 'diff.json'}, {out / 'diff.md'}")
        if result["gate"] is not None and result["gate"]["failed"]:
            raise typer.Exit(code=1)
