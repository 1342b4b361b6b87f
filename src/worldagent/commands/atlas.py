"""``worldagent atlas ENV``: a failure atlas, the worst world of every kind of world (quality diversity)."""

from __future__ import annotations

import json
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
from worldagent.commands.strategic import check_prior_bound, prior_bound_flag

CONFIRM_HELP = (
    "Fresh episodes on which every elite (the best world of each filled cell) is replayed, from keys no search draws "
    "(default: analysis.confirm.ELITE_REPEATS, 32; 0 skips): the corrected archive's QD-score and failing cells are printed "
    "beside the found ones."
)


def check_atlas_request(
    env: str, objective: str, budget: int, names, cells: int, failure: str | None, repeats: int, seed: int, out: Path, confirm: int | None = None
) -> None:
    """Every check of an atlas's options that needs neither the agent nor the generator, run
    before they load (one line naming the fix)."""
    from worldagent import experiments
    from worldagent.envs import registry
    from worldagent.errors import WorldagentError
    from worldagent.search.atlas import check_descriptors

    if confirm is not None and confirm < 0:
        raise WorldagentError(f"--confirm {confirm}; pass fresh episodes per elite (32 by default), or 0 to skip.")
    check_counts(budget=budget, repeats=repeats)
    check_seed(seed)
    check_metric(env, objective)
    check_descriptors(registry.get(env), names, cells, budget)
    experiments.failure_selection(failure, env)
    check_run_dir(out)


def confirmed_lines(confirmed: dict | None, descriptors, shown: int = 5) -> list[str]:
    """Found beside confirmed for an atlas's corrected archive (``search.corrected_atlas.corrected_summary``), and the cells
    found failing that the confirmation does not confirm (the first ``shown``)."""
    from worldagent.search.corrected_atlas import cell_line

    if confirmed is None:
        return ["  elites not confirmed (--confirm 0): every figure above is the search's own, biased by its selection"]
    found, fresh = confirmed["found"], confirmed["confirmed"]
    lines = [
        f"  corrected archive ({confirmed['elites']} elites, {confirmed['distinct_worlds']} distinct worlds, each on {confirmed['repeats']} "
        f"fresh episodes): QD-score found {found['qd_score']:.4g} (the search's), confirmed {fresh['qd_score']:.4g}; "
        f"coverage found {found['coverage']:.2f}, confirmed {fresh['coverage']:.2f}"
    ]
    if "event" in confirmed:
        gone = confirmed["no_longer_failing"]
        lines.append(
            f"  failing cells ({confirmed['event']}): found {found['failing_cells']} ({found['failing_worlds']} distinct worlds), "
            f"confirmed {fresh['failing_cells']} ({fresh['failing_worlds']} distinct worlds; the confirmed interval beyond the threshold); "
            f"{len(gone)} no longer failing"
        )
        rows = {row["cell"]: row for row in confirmed["cells"]}
        metric = confirmed_metric(confirmed)
        lines += [f"    no longer failing: {cell_line(rows[cell], descriptors, metric)}" for cell in gone[:shown]]
        if len(gone) > shown:
            lines.append(f"    ({shown} of {len(gone)} shown; every cell is in the JSON)")
    return lines


def confirmed_metric(confirmed: dict) -> str:
    """The metric a failing cell is shown by: the failure's first one (the archive's when it reads none)."""
    row = confirmed["cells"][0]
    reads = [m for m in row["found"] if m != confirmed["metric"]]
    return reads[0] if reads else confirmed["metric"]


def elites_prior(found: dict) -> dict:
    """Where the found archive's elites (each filled cell's best world) lie under the prior (``search.prior.norms_summary``)."""
    from worldagent.search.prior import norms_summary

    evaluations = found["evaluations"]
    return norms_summary([evaluations[i].latent for i in found["archive"].best])


def atlas_json(found: dict) -> dict:
    """What ``worldagent atlas`` writes beside its figure: the found archive's figures and the corrected one's, and
    where its elites lie under the prior."""
    grid = found["grid"]
    return {
        "campaign": found["evaluations"][0].campaign,
        "grid": grid.record(),
        "evaluations": len(found["evaluations"]),
        "found": {
            "coverage": found["coverage"],
            "qd_score": found["qd_score"],
            "qd_offset": found["qd_offset"],
            "failing_evaluations": found["failing"],
            "distinct_failing_worlds": found["distinct_failing"],
        },
        "confirmed": found["confirmed"],
        "elites_prior": elites_prior(found),
        "searched": found.get("searched"),
    }


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
        confirm: int = typer.Option(None, "--confirm", help=CONFIRM_HELP),
        prior: str = prior_bound_flag(),
        quiet: bool = typer.Option(False, "--quiet", help="No progress bar."),
    ) -> None:
        """The worst (or best) world of every cell of a descriptor grid, found by CMA-ME, drawn as a heat map; every
        elite confirmed on fresh episodes (the corrected archive), found beside confirmed."""
        from worldagent import experiments
        from worldagent.files import write_text
        from worldagent.reports.atlas import atlas_figure, counterfactual_figure
        from worldagent.search.campaign import searched_where
        from worldagent.search.prior import norms_text
        from worldagent.store import RunStore

        names = [n.strip() for n in descriptors.split(",")] if descriptors else None
        check_atlas_request(env, objective, budget, names, cells, failure, repeats, seed, out, confirm)
        check_prior_bound(prior)
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
                confirm=confirm,
                prior_bound=prior,
            )
            name = found["evaluations"][0].campaign
            found["searched"] = searched_where(store.campaign(name))
            loaded = lambda e: (experiments.with_world(store, e), experiments.scored_keys_of(store, e))  # noqa: E731
            figure = atlas_figure(found, setup, setup.metric(objective), not minimize, loaded, out / f"{name}.png")
        grid = found["grid"]
        failing = (
            "" if found["distinct_failing"] is None else f"; {found['failing']} failing evaluations of {found['distinct_failing']} distinct worlds"
        )
        console.print(
            f"{name}: {len(found['evaluations'])} worlds on a {'x'.join(map(str, grid.cells))} grid of {', '.join(grid.descriptors)}; "
            f"coverage {found['coverage']:.2f}, QD-score {found['qd_score']:.4g} (found){failing} -> {figure}",
            markup=False,
        )
        console.print(f"  elites under the prior: {norms_text(elites_prior(found))}; {found['searched']}", markup=False, highlight=False)
        for line in confirmed_lines(found["confirmed"], grid.descriptors):
            console.print(line, markup=False, highlight=False)
        summary = out / f"{name}.json"
        write_text(summary, json.dumps(atlas_json(found), indent=1, default=float) + "\n")
        console.print(f"  -> {summary}", markup=False, highlight=False)
        if failure and explain:
            explained = experiments.explain_failures(setup, found, experiments.failure_selection(failure, env), seed=seed)
            pairs = counterfactual_figure(setup, explained["pairs"], out / f"{name}-counterfactuals.png")
            for number, cluster in enumerate(explained["clusters"], 1):
                centre = ", ".join(f"{n} {v:.3g}" for n, v in zip(grid.descriptors, cluster.centre))
                console.print(f"  failure group {number}: {len(cluster.members)} worlds around {centre}")
            console.print(f"  {len(explained['pairs'])} failing worlds beside their nearest passing world -> {pairs}")
