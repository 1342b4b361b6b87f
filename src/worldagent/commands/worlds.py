"""``worldagent worlds ENV``: draw a sheet of procedurally generated worlds of any environment."""

from __future__ import annotations

from pathlib import Path

import typer

from worldagent.commands.console import console, friendly_errors
from worldagent.commands.options import PICTURE_CAP, check_counts, check_seed, env_argument
from worldagent.errors import WorldagentError
from worldagent.files import check_writable


def draw_worlds(env: str, n: int, seed: int, out: Path) -> Path:
    """Generate worlds ``seed .. seed + n - 1`` with the env's generator and draw them on one PNG."""
    import numpy as np

    from worldagent.envs import registry

    spec = registry.get(env)
    if n < 1:
        raise WorldagentError(f"--n is {n}; ask for at least one world.")
    check_counts(caps={"n": PICTURE_CAP}, n=n)
    check_seed(seed)
    check_writable(out, folder=False)
    if out.suffix.lower() != ".png":
        raise WorldagentError(f"--out {out}: the worlds are drawn as a PNG picture; pass a .png file name, e.g. --out {out.with_suffix('.png')}.")
    if spec.pictures.sheet is None:
        raise WorldagentError(f"{spec.name} registers no picture sheet (pictures.sheet); it cannot be drawn here.")
    return spec.pictures.sheet(spec.generate(np.arange(seed, seed + n, dtype=np.int64)), out)


def register(app: typer.Typer) -> None:
    """Add ``worldagent worlds``."""

    @app.command()
    @friendly_errors
    def worlds(
        env: str = env_argument(),
        n: int = typer.Option(16, "--n", help=f"Number of worlds to draw (at most {PICTURE_CAP})."),
        seed: int = typer.Option(0, "--seed", help="World i uses generator seed SEED + i."),
        out: Path = typer.Option(Path("worlds.png"), "--out", help="PNG file to write."),
    ) -> None:
        """Generate worlds with the environment's procedural generator and draw them on one sheet."""
        path = draw_worlds(env, n, seed, out)
        console.print(f"wrote {n} {env} worlds to {path}")
