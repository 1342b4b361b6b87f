"""``worldagent train ENV``: train agents on a distribution of worlds (paper §4.3, §5.3)."""

from __future__ import annotations

from pathlib import Path

import typer

from worldagent.commands.console import console, friendly_errors
from worldagent.commands.options import (
    algo_help,
    algorithm,
    check_seed,
    check_training_episodes,
    curricula_help,
    curriculum_set_flag,
    env_argument,
    env_options,
    option_flag,
    set_flag,
)
from worldagent.commands.strategic import check_confirm
from worldagent.errors import WorldagentError
from worldagent.files import check_writable, write_text

BASELINE_WORLDS = 100  # random G(z) worlds (8 episodes each) the agent plays: "harder than average" compares with them
FAVOURED_FILE = "favoured.json"


def interrupted(out: Path) -> str:
    """What an interrupted run left: the driver checkpoints on the way out, and a rerun resumes from it to the same files."""
    from worldagent.agents.training import CHECKPOINT_FILE

    if (out / CHECKPOINT_FILE).is_file():
        return f"interrupted: checkpoint saved in {out / CHECKPOINT_FILE}; run the same command again to resume (it ends where an uninterrupted run would)."
    return f"interrupted before the first checkpoint; run the same command again to start {out} afresh."


def favoured_confirm_flag():
    """``--confirm N``: fresh episodes per favoured world of an adaptive curriculum (``analysis.confirm.REPEATS``; 0 skips)."""
    from worldagent.analysis.confirm import REPEATS

    return typer.Option(
        REPEATS,
        "--confirm",
        help="With an adaptive curriculum: fresh episodes (from keys no search or training draws) to replay each of the worlds its buffer "
        f"favoured most on, against {BASELINE_WORLDS} random G(z) worlds; 0 skips. The buffer's scores are noisy, its favourites partly luck.",
    )


def confirm_favourites(spec, out: Path, curriculum, options: dict, repeats: int, seed: int, progress: bool) -> str:
    """The line on the curriculum's favoured worlds: the last buffer's highest scores replayed with the trained agent
    on ``repeats`` fresh episodes each (``analysis.favoured``), against its failure rate on ``BASELINE_WORLDS`` random
    G(z) worlds; both kept in OUT/store.sqlite (a rerun reads them back), found beside confirmed in OUT/favoured.json.
    "" when the run kept no buffer snapshot or its last buffer was empty."""
    import json

    from worldagent import experiments
    from worldagent.analysis.confirm import random_failure_rate
    from worldagent.analysis.favoured import confirm_favoured, failure_event, favoured_line, favoured_rows, scored_by
    from worldagent.curricula.snapshots import load_snapshots
    from worldagent.influence.statistics import json_safe
    from worldagent.store import RunStore

    snapshots = load_snapshots(out)
    if not snapshots or not len(snapshots[-1]["score"]):
        return ""
    setup = experiments.setup(spec.name, str(out), curriculum.worlds.generator, options=options)
    failure, metric, score = failure_event(spec), spec.metrics.main, scored_by(curriculum)
    with RunStore(out) as store:
        found = confirm_favoured(store, setup, snapshots[-1], curriculum=curriculum.name, score=score, repeats=repeats, seed=seed, progress=progress)
        randoms = (
            experiments.random_evaluation(store, setup, metric, worlds=BASELINE_WORLDS, seed=seed, progress=progress) if found and failure else []
        )
    baseline = random_failure_rate(randoms, failure) if randoms else None
    record = {
        "scored_by": score,
        "random_worlds": len(randoms),
        "random_failure_rate": baseline,
        "favoured": favoured_rows(found, metric, failure, baseline),
    }
    write_text(out / FAVOURED_FILE, json.dumps(json_safe(record), indent=2) + "\n")
    return f"{favoured_line(found, metric, failure, baseline)}; found (the buffer's {score}) beside confirmed: {out / FAVOURED_FILE}"


def register(app: typer.Typer) -> None:
    """Add ``worldagent train``."""

    @app.command()
    @friendly_errors
    def train(
        env: str = env_argument(),
        out: Path = typer.Option(..., "--out", help="Run directory: checkpoint, learning curve (CSV, PNG), the saved agent in OUT/policy."),
        algo: str = typer.Option(None, "--algo", help=algo_help()),
        episodes: int = typer.Option(None, "--episodes", help="Training episodes (default: the algorithm's budget for the env)."),
        worlds: str = typer.Option(
            "generator", "--worlds", help="Training worlds: generator (procedural), vae (G(z), needs --generator), or a dataset .npz."
        ),
        generator: Path = typer.Option(None, "--generator", help="Generator directory for --worlds vae."),
        curriculum: str = typer.Option("dr", "--curriculum", help="Where each episode's world comes from as the agent learns: " + curricula_help()),
        target: str = typer.Option(
            None, "--target", help="Score worlds by this event (e.g. 'crash_rate > 0.5') or, with --maximize/--minimize, this metric."
        ),
        maximize: bool = typer.Option(None, "--maximize/--minimize", help="With --target METRIC: train toward worlds where it is high / low."),
        curriculum_settings: list[str] = curriculum_set_flag(),
        option: list[str] = option_flag(),
        settings: list[str] = set_flag(),
        seed: int = typer.Option(0, "--seed", help="Seed of the run."),
        confirm: int = favoured_confirm_flag(),
        keep_every: int = typer.Option(
            None, "--keep-every", help="Also keep the agent every N episodes in OUT/snapshots/<episodes>/ (an --agent for diff, evaluate, ...)."
        ),
        resume: bool = typer.Option(True, "--resume/--restart", help="Continue from the run directory's checkpoint, or start over."),
        quiet: bool = typer.Option(False, "--quiet", help="No progress bar."),
    ) -> None:
        """Train agents on a distribution of worlds (paper §4.3, §5.3); a killed run resumes."""
        from worldagent.agents.algorithms import parse_settings, training_config
        from worldagent.agents.distributions import world_distribution
        from worldagent.agents.training import train as run_training
        from worldagent.curricula import check_request, label, late_replay_warning, make_curriculum, parse_curriculum_settings
        from worldagent.curricula.scores import requested_target
        from worldagent.envs import registry

        spec = registry.get(env)
        algo = algorithm(env, algo)
        options = env_options(env, option)
        check_training_episodes(episodes)
        check_seed(seed)
        check_confirm(confirm)
        check_writable(out, folder=True)
        if keep_every is not None and keep_every < 1:
            raise WorldagentError(f"--keep-every {keep_every}; pass a positive number of episodes, e.g. half of --episodes.")
        if worlds == "vae" and generator is None:
            raise WorldagentError("--worlds vae draws G(z): pass --generator DIR (from `worldagent generator train`).")
        config = training_config(spec, algo, episodes=episodes, options=options, **parse_settings(settings, [algo])[algo])
        scoring = requested_target(spec, target, maximize)
        settings = parse_curriculum_settings(curriculum_settings)
        check_request(curriculum, settings, worlds == "vae" or (Path(worlds) / "generator.json").is_file())
        distribution = world_distribution(spec, worlds, generator_dir=generator, progress=not quiet)
        schedule = make_curriculum(curriculum, distribution, settings, scoring)
        late = late_replay_warning(schedule, config.episodes)
        if late:
            console.print(f"[yellow]{late}[/yellow]")
        try:
            result = run_training(
                spec, algo, config, schedule, out, seed=seed, options=options, progress=not quiet, resume=resume,
                distribution_spec=worlds if curriculum == "dr" else f"{worlds}; curriculum {label(schedule)}", keep_every=keep_every,
            )  # fmt: skip
        except KeyboardInterrupt:
            console.print(interrupted(out), highlight=False)
            raise typer.Exit(code=130) from None
        console.print(f"trained {algo} for {result.episodes:,} episodes ({result.env_steps:,} steps, {result.wall_seconds:.0f} s) -> {out}")
        kept = sorted((out / "snapshots").glob("*/"), key=lambda p: int(p.name) if p.name.isdigit() else -1) if keep_every else []
        if kept:
            console.print(f"kept the agent at {len(kept)} points of training: {', '.join(str(p) for p in kept)}")
        if (out / "curriculum.png").is_file():
            console.print(f"the curriculum's buffer over training: {out / 'curriculum.png'} (snapshots in {out / 'curriculum'})")
        if getattr(schedule, "adaptive", False) and confirm:
            said = confirm_favourites(spec, out, schedule, options, confirm, seed, not quiet)
            if said:
                console.print(said, highlight=False)
