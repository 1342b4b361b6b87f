"""``worldagent evaluate random ENV``: a metric over random worlds z ~ N(0, I) (paper §6.1.1, Figure 6a);
``worldagent evaluate worlds ENV --worlds FILE.npz|NAME``: a metric over given worlds (a dataset, explorer exports, a
named set of the env)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import typer

from worldagent.commands.console import console, friendly_errors, status_line
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

WORLDS_HELP = (
    "The worlds: a dataset file (`worldagent dataset`), a world the explorer exported (a one-world .npz; repeatable, "
    "evaluated in order), or the name of one of the env's world sets (`worldagent envs` lists them)."
)
PLACE_HELP = (
    f"Optional. {GENERATOR_HELP} Stores each world at its encoder's mean latent, so `worldagent explore` maps it; "
    "without it the worlds are stored without latents."
)
SHOWN_WORLDS = 12  # a set this small is listed world by world; a larger one by its extremes


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
    """Add ``worldagent evaluate`` and its subcommands ``random`` and ``worlds``."""
    group = typer.Typer(help="Evaluate agents on worlds from the generator, or on given worlds.", no_args_is_help=True)
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
        say_share(setup.spec, evaluations, metric, name, out)

    @group.command("worlds")
    @friendly_errors
    def evaluate_worlds(
        env: str = env_argument(),
        agent: str = typer.Option(..., "--agent", help=AGENT_HELP),
        worlds: list[str] = typer.Option(..., "--worlds", help=WORLDS_HELP),
        generator: Path = typer.Option(None, "--generator", help=PLACE_HELP),
        metric: str = typer.Option("reward", "--metric", help=metric_help()),
        repeats: int = typer.Option(8, "--repeats", help="Episodes per world (the paper: 8)."),
        seed: int = typer.Option(0, "--seed", help="Seed of the episodes (world i plays with the keys of seed, generation 0, slot i)."),
        out: Path = typer.Option(Path("runs/evaluate"), "--out", help="Run directory (store.sqlite and the histogram); a rerun resumes."),
        option: list[str] = option_flag(),
        greedy: bool = typer.Option(False, "--greedy", help="Trained actor-critics act by argmax instead of sampling."),
        stochastic: bool = stochastic_flag(),
        backend_name: str = backend_flag(),
        ray_address: str = ray_address_flag(),
        quiet: bool = typer.Option(False, "--quiet", help="No progress bar."),
    ) -> None:
        """The distribution of a metric over given worlds: a dataset file, the explorer's exports, or a named set of the env."""
        from worldagent import experiments
        from worldagent.envs import registry
        from worldagent.reports.figures import distribution_figure
        from worldagent.search.given import world_set
        from worldagent.store import STORE_FILE, RunStore

        check_counts(repeats=repeats)
        check_seed(seed)
        metric = check_metric(env, metric)
        check_run_dir(out)
        given = world_set(registry.get(env), worlds)
        setup = command_setup(
            env, agent, generator, option, greedy=greedy, stochastic=stochastic, repeats=repeats, backend_name=backend_name, ray_address=ray_address
        )
        with RunStore(out) as store:
            evaluations = experiments.worlds_evaluation(store, setup, given, metric, seed=seed, progress=not quiet)
        name = experiments.worlds_campaign_name(given.tag, metric, seed)
        scores = np.array([e.score for e in evaluations])
        title = f"{env}: {metric} over {len(scores)} given worlds ({given.tag})"
        figure = distribution_figure({given.tag: scores}, metric, out / f"{name}.png", title)
        line = f"{name}: {len(scores)} worlds x {repeats} episodes; {metric} mean {np.nanmean(scores):.4g} (sd {np.nanstd(scores):.3g})"
        console.print(f"{line}{normalised_note(setup, metric, evaluations)} -> {figure}", highlight=False)
        for text in world_lines(setup.spec, given.labels, evaluations, metric):
            status_line(text)
        say_share(setup.spec, evaluations, metric, name, out)
        if generator is None:
            status_line(f"stored in {out / STORE_FILE} without latents; pass --generator DIR to place them on `worldagent explore`'s map.")
        else:
            status_line(f"explore: worldagent explore --store {out / STORE_FILE} --generator {generator} --agent {agent}")


def evaluation_record(spec, evaluations, metric: str, campaign: str) -> dict:
    """What ``OUT/<campaign>.json`` holds: the campaign, its worlds and repeats, the metric's mean and sd over the
    worlds' scores, and the world's share (``reports.results.world_share_summary``: per metric, and of the failure
    event) when every world has at least 2 episodes."""
    from worldagent.influence.statistics import json_safe
    from worldagent.reports.results import world_share_summary

    scores = np.array([e.score for e in evaluations], np.float64)
    repeats = sorted({len(e.episodes) for e in evaluations})
    record = {
        "env": spec.name,
        "campaign": campaign,
        "metric": metric,
        "worlds": len(evaluations),
        "repeats": repeats[0] if len(repeats) == 1 else repeats,
        "mean": float(np.nanmean(scores)) if np.isfinite(scores).any() else None,
        "sd": float(np.nanstd(scores)) if np.isfinite(scores).any() else None,
    }
    return json_safe({**record, **world_share_summary(spec, evaluations, [metric])})


def say_share(spec, evaluations, metric: str, campaign: str, out: Path) -> None:
    """Print the world's share in one line (with 2+ episodes per world) and write ``OUT/<campaign>.json`` beside the histogram."""
    import json

    from worldagent.analysis.noise import share_line
    from worldagent.files import write_text

    record = evaluation_record(spec, evaluations, metric, campaign)
    line = share_line(record if "metrics" in record else {}, metric)
    if line:
        status_line(line)
    status_line(f"-> {write_text(out / f'{campaign}.json', json.dumps(record, indent=1))}")


def world_lines(spec, labels, evaluations, metric: str) -> list[str]:
    """Which worlds failed (``spec.failure``, when its metrics were played), and every world of a small set, or the
    three lowest and highest of a large one, by label."""
    from worldagent.reports.results import played_failure

    lines = []
    selection = played_failure(spec, evaluations)
    if selection is not None:
        failing = np.flatnonzero(selection.mask(evaluations))
        named = ", ".join(labels[i] for i in failing[:SHOWN_WORLDS]) + (", ..." if len(failing) > SHOWN_WORLDS else "")
        lines.append(f"failing ({spec.failure}): {len(failing)} of {len(evaluations)} worlds" + (f": {named}" if len(failing) else ""))
    if len(evaluations) <= SHOWN_WORLDS:
        return lines + [f"  {labels[e.slot]}: {metric} {e.score:.4g}" for e in evaluations]
    ranked = sorted((e for e in evaluations if np.isfinite(e.score)), key=lambda e: e.score)
    listed = lambda chosen: "; ".join(f"{labels[e.slot]} {e.score:.4g}" for e in chosen)  # noqa: E731
    return lines + [f"lowest {metric}: {listed(ranked[:3])}", f"highest {metric}: {listed(ranked[::-1][:3])}"]
