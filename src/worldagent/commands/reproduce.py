"""``worldagent reproduce`` (the paper end to end) and ``worldagent report`` (its HTML report)."""

from __future__ import annotations

from pathlib import Path

import typer

from worldagent.commands.console import console, friendly_errors, status_line
from worldagent.commands.options import check_store, curricula_help, curriculum_set_flag, set_flag
from worldagent.files import check_writable

REPRODUCE_SET_HELP = (
    "A training setting NAME=VALUE (repeatable): sets that field of the config of every env's algorithm that has it; "
    "ALGO.NAME=VALUE only for agents trained with ALGO, e.g. --set ppo.learning_rate=1e-3. Over the algorithm's defaults and the env's own "
    "settings; the agent and influence phases record it, and changing it redoes them."
)


def check_reproduce_dir(out: Path, envs: list[str], redo: list[str]) -> None:
    """A ``reproduce`` run directory, before any phase runs: it and each env's folder can be written,
    and each env's store is intact unless ``redo`` (the phases to redo) replaces it."""
    from worldagent.reproduce.layout import RunLayout

    check_writable(out, folder=True)
    for env in envs:
        layout = RunLayout(out, env)
        check_writable(layout.dir, folder=True)
        if "random" not in redo:  # redoing "random" deletes the store
            check_store(layout.store_path)


def check_report_dir(run_dir: Path) -> None:
    """``report RUN_DIR``: a folder the report can be written in, whose stores are intact."""
    from worldagent.reports.html import REPORT_FILE
    from worldagent.store import STORE_FILE

    check_writable(run_dir, folder=True, option="RUN_DIR")
    check_writable(run_dir / REPORT_FILE, folder=False, option="RUN_DIR")
    for store in sorted(run_dir.glob(f"*/{STORE_FILE}")):  # one an environment
        check_store(store)


def register(app: typer.Typer) -> None:
    """Add ``reproduce`` and ``report`` to the CLI."""
    from worldagent.envs import registry
    from worldagent.reproduce.presets import PHASES

    @app.command()
    @friendly_errors
    def reproduce(
        preset: str = typer.Option("quick", "--preset", help="quick (under 10 min on 2 CPU cores), paper (the paper's budgets; a GPU) or tiny (CI)."),
        env: str = typer.Option("all", "--env", help=f"all, or one or more (comma-separated) of: {', '.join(registry.names())}."),
        out: Path = typer.Option(None, "--out", help="Run directory (default runs/PRESET); a rerun skips finished phases, a killed run resumes."),
        algo: str = typer.Option(
            None,
            "--algo",
            help="Training algorithm for every env that has it (default: each env's own, `worldagent envs`; racing ppo learnt to lap for 3 seeds of 3, the paper's acktr for 1).",
        ),
        restart: list[str] = typer.Option(
            [],
            "--restart",
            help=f"Redo this phase (and what depends on it): {', '.join(PHASES)}. Repeatable.",
        ),
        settings: list[str] = set_flag(REPRODUCE_SET_HELP),
        curriculum: str = typer.Option(
            "dr",
            "--curriculum",
            help="Where each training episode's world comes from as every env's agent learns: dr trains on the dataset's worlds (the paper's way); "
            "an adaptive curriculum draws latents of the run's G(z). " + curricula_help(),
        ),
        target: str = typer.Option(
            None,
            "--target",
            help="Score worlds by this event (e.g. 'crash_rate > 0.5') or, with --maximize/--minimize, this metric; "
            "--curriculum target without it: each env's failure event (`worldagent envs`).",
        ),
        maximize: bool = typer.Option(None, "--maximize/--minimize", help="With --target METRIC: train toward worlds where it is high / low."),
        curriculum_settings: list[str] = curriculum_set_flag(),
        repair: str = typer.Option(
            None,
            "--repair",
            help="Every env's G(z) repair by name, e.g. open (new valid worlds beyond the dataset); default: the paper's (nearest). "
            "`worldagent envs` lists them.",
        ),
        accept_generator: bool = typer.Option(
            False,
            "--accept-generator",
            help="Use a generator its quality gate rejects (docs/generator.md) instead of stopping; the verdict and its warnings "
            "are recorded in the manifest and the report.",
        ),
        show: bool = typer.Option(False, "--show", help="Print the preset's config and exit."),
        quiet: bool = typer.Option(False, "--quiet", help="No progress bars (status lines only)."),
        sequential: bool = typer.Option(
            False,
            "--sequential",
            help="Run the environments one after another in this process (default on a CPU: each in a process of its own, "
            "as many at once as there are cores; also WORLDAGENT_SEQUENTIAL_ENVS=1).",
        ),
    ) -> None:
        """Run the paper end to end: datasets, generators, agents, random and strategic evaluation, ES vs BO, influencing; then the HTML report."""
        from worldagent.agents.algorithms import parse_settings
        from worldagent.curricula import parse_curriculum_settings
        from worldagent.reproduce.pipeline import adaptive, resolve_envs, restart_closure
        from worldagent.reproduce.pipeline import reproduce as run
        from worldagent.reproduce.presets import get_preset

        chosen = get_preset(preset).with_algo(algo).with_repair(repair).with_generator_accepted("--accept-generator" if accept_generator else None)
        envs = resolve_envs(env, chosen)
        chosen = chosen.with_settings(parse_settings(settings, [chosen.algo_of(name) for name in envs]))
        chosen = chosen.with_curriculum(curriculum, target, maximize, parse_curriculum_settings(curriculum_settings))
        for name in envs:
            chosen.check_curriculum(name)
            chosen.check_repair(name)
        if show:
            typer.echo(chosen.show())
            return
        out = out or Path("runs") / chosen.name
        check_reproduce_dir(out, envs, restart_closure(restart, adaptive(chosen, envs)))
        manifest = run(chosen, out, envs, restart=restart, progress=not quiet, echo=status_line, sequential=sequential)
        failed = [key for key, entry in manifest.data["phases"].items() if entry.get("status") == "failed"]
        if failed:
            console.print(f"[yellow]finished with failed phase(s): {', '.join(failed)} (see the report)[/yellow]")
        console.print(f"report: {out / 'report.html'}")

    @app.command()
    @friendly_errors
    def report(run_dir: Path = typer.Argument(..., help="A `worldagent reproduce` run directory.")) -> None:
        """Rebuild RUN_DIR/report.html from the run's manifest, stores and phase outputs."""
        from worldagent.reports.html import build_report

        check_report_dir(run_dir)
        console.print(f"wrote {build_report(run_dir)}")
