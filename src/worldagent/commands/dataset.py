"""``worldagent dataset ENV``: a dataset of procedurally generated worlds (paper §5.2.1)."""

from __future__ import annotations

from pathlib import Path

import typer

from worldagent.commands.console import console, friendly_errors
from worldagent.commands.options import env_argument


def register(app: typer.Typer) -> None:
    """Add ``worldagent dataset``."""

    @app.command()
    @friendly_errors
    def dataset(
        env: str = env_argument(),
        n: int = typer.Option(10_000, "--n", help="Number of worlds (the paper: 10,000)."),
        seed: int = typer.Option(0, "--seed", help="World i uses generator seed SEED + i."),
        out: Path = typer.Option(..., "--out", help="Dataset file to write (.npz)."),
        quiet: bool = typer.Option(False, "--quiet", help="No progress bar."),
    ) -> None:
        """Generate a dataset of worlds with the environment's procedural generator (paper §5.2.1)."""
        from worldagent.worlds.dataset import make_dataset

        data = make_dataset(env, n, seed, progress=not quiet)
        data.save(out)
        console.print(f"wrote {len(data):,} {env} worlds to {out} (fingerprint {data.fingerprint})")
