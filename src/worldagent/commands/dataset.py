"""``worldagent dataset ENV``: a dataset of procedurally generated worlds (paper §5.2.1)."""

from __future__ import annotations

from pathlib import Path

import typer

from worldagent.commands.console import console, friendly_errors
from worldagent.commands.options import DATASET_CAP, check_counts, check_seed, env_argument
from worldagent.files import check_writable


def register(app: typer.Typer) -> None:
    """Add ``worldagent dataset``."""

    @app.command()
    @friendly_errors
    def dataset(
        env: str = env_argument(),
        n: int = typer.Option(10_000, "--n", help=f"Number of worlds (the paper: 10,000; at most {DATASET_CAP:,})."),
        seed: int = typer.Option(0, "--seed", help="World i uses generator seed SEED + i."),
        out: Path = typer.Option(..., "--out", help="Dataset file to write (.npz)."),
        quiet: bool = typer.Option(False, "--quiet", help="No progress bar."),
    ) -> None:
        """Generate a dataset of worlds with the environment's procedural generator (paper §5.2.1)."""
        from worldagent.envs import registry
        from worldagent.worlds.dataset import make_dataset

        registry.get(env)
        check_counts(caps={"n": DATASET_CAP}, n=n)
        check_seed(seed)
        check_writable(out, folder=False)
        data = make_dataset(env, n, seed, progress=not quiet)
        data.save(out)
        console.print(f"wrote {len(data):,} {env} worlds to {out} (fingerprint {data.fingerprint})")
