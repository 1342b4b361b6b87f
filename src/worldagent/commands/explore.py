"""``worldagent explore RUN_DIR``: a local web app over a ``reproduce`` run (docs/explorer.md)."""

from __future__ import annotations

from pathlib import Path

import typer

from worldagent.commands.console import console, friendly_errors
from worldagent.errors import WorldagentError


def check_port(port: int) -> int:
    if not 1 <= port <= 65535:
        raise WorldagentError(f"--port {port}: pick a port between 1 and 65535 (default 8765).")
    return port


def register(app: typer.Typer) -> None:
    """Add ``worldagent explore``."""

    @app.command()
    @friendly_errors
    def explore(
        run_dir: Path = typer.Argument(..., help="A run directory `worldagent reproduce` wrote (its manifest.json, stores, generator, agents)."),
        host: str = typer.Option("127.0.0.1", "--host", help="Address to listen on. Any other than 127.0.0.1 requires a token."),
        port: int = typer.Option(8765, "--port", help="Port to listen on."),
        token: str = typer.Option("", "--token", help="Token every request must carry (made and printed when --host is not local)."),
        warm: bool = typer.Option(True, "--warm/--no-warm", help="Compile G(z) and the run's agents before serving (first clicks answer at once)."),
    ) -> None:
        """Serve the map of a run's worlds, worlds decoded and played live, the atlas and the failures, on a local page."""
        from worldagent.explore.server import serve
        from worldagent.explore.session import Session

        check_port(port)
        if not run_dir.is_dir():
            raise WorldagentError(f"{run_dir} is not a directory; pass a run directory `worldagent reproduce --out` wrote.")
        session = Session.open(run_dir)
        if warm:
            for env in session.envs.values():
                console.print(f"warming {env.env}: compiling G(z) and the run's agent ...")
                env.warm_up()
        serve(session, host=host, port=port, token=token or None, echo=console.print)
