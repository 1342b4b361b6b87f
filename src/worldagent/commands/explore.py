"""``worldagent explore RUN_DIR``: a local web app over a run (docs/explorer.md)."""

from __future__ import annotations

import threading
from pathlib import Path

import typer

from worldagent.commands.console import console, friendly_errors
from worldagent.errors import WorldagentError
from worldagent.runs import MANIFEST_FILE

DIFF_FILE = "diff.json"  # what `worldagent diff` writes into its --out


def check_port(port: int) -> int:
    if not 1 <= port <= 65535:
        raise WorldagentError(f"--port {port}: pick a port between 1 and 65535 (default 8765).")
    return port


def diff_run(run_dir: Path):
    """The run of a ``worldagent diff --out`` directory: its store, with the generator its diff.json names."""
    import json

    from worldagent.runs import Run

    recorded = json.loads((run_dir / DIFF_FILE).read_text())
    if not recorded.get("generator"):
        raise WorldagentError(f"{run_dir} compared worlds without a generator; pass --store {run_dir / 'store.sqlite'} and --generator DIR.")
    return Run.of_parts(run_dir / "store.sqlite", Path(recorded["generator"]), None, recorded.get("env"))


def open_run(run_dir: Path | None, store: Path | None, generator: Path | None, agent: str, env: str):
    """The ``runs.Run`` to explore: a reproduce directory, or a store with its generator (and agent)."""
    from worldagent.runs import Run

    if run_dir is not None:
        if store or generator or agent:
            raise WorldagentError("give either RUN_DIR or --store with --generator (and --agent), not both.")
        if not run_dir.is_dir():
            raise WorldagentError(f"{run_dir} is not a directory; pass a run directory `worldagent reproduce --out` wrote.")
        if (run_dir / DIFF_FILE).is_file() and not (run_dir / MANIFEST_FILE).is_file():
            return diff_run(run_dir)
        return Run.open(run_dir)
    if store is None or generator is None:
        raise WorldagentError("pass a run directory (worldagent explore runs/quick), or --store and --generator (and --agent).")
    return Run.of_parts(store, generator, agent or None, env or None)


def register(app: typer.Typer) -> None:
    """Add ``worldagent explore``."""

    @app.command()
    @friendly_errors
    def explore(
        run_dir: Path = typer.Argument(
            None, help="A run directory `worldagent reproduce` wrote (its manifest.json, stores, generator, agents), or a `worldagent diff --out`."
        ),
        store: Path = typer.Option(None, "--store", help="Instead of RUN_DIR: a run store (store.sqlite) of campaigns."),
        generator: Path = typer.Option(None, "--generator", help="With --store: the generator its campaigns searched."),
        agent: str = typer.Option("", "--agent", help="With --store: the agent to play (a train run, a scripted policy's name, ...)."),
        env: str = typer.Option("", "--env", help="With --store: the environment (default: the generator's)."),
        host: str = typer.Option("127.0.0.1", "--host", help="Address to listen on. Any other than 127.0.0.1 requires a token."),
        port: int = typer.Option(8765, "--port", help="Port to listen on."),
        token: str = typer.Option("", "--token", help="Token every request must carry (made and printed when --host is not local)."),
        warm: bool = typer.Option(
            True,
            "--warm/--no-warm",
            help="Compile G(z) and every agent in the background while serving, the run's agent first (first plays answer at once).",
        ),
    ) -> None:
        """Serve the map of a run's worlds, worlds decoded and played live, the atlas and the failures, on a local page."""
        from worldagent.explore.server import serve
        from worldagent.explore.session import Session

        check_port(port)
        session = Session.of(open_run(run_dir, store, generator, agent, env))
        if warm:
            warm_in_background(session)
        serve(session, host=host, port=port, token=token or None, echo=console.print)


def warm_in_background(session) -> threading.Thread:
    """Compile G(z) and the agents while the page is already served: each env's first agent (the run's) first,
    then the others; the page says "compiling AGENT" for a play that waits on it."""
    import time

    def warm() -> None:
        started = time.perf_counter()
        envs = list(session.envs.values())
        for found in envs:
            found.warm_up(list(found.agents)[:1], echo=console.print)
        for found in envs:
            found.warm_up(echo=console.print)
        console.print(f"warm: G(z) and {sum(len(e.agents) for e in envs)} agents compiled in {time.perf_counter() - started:.0f} s", highlight=False)

    thread = threading.Thread(target=warm, name="explorer-warm-up", daemon=True)
    thread.start()
    return thread
