"""``worldagent ...``: the command-line tool (typer).

Every command turns a ``WorldagentError`` into one red line and exit code 2, never a traceback.
"""

from __future__ import annotations

import functools
from pathlib import Path

import typer
from rich.console import Console

from worldagent.errors import WorldagentError

app = typer.Typer(
    help="Find the worlds in which trained RL agents fail or shine, and reshape what they train on.",
    no_args_is_help=True,
    add_completion=False,
)
console = Console(stderr=True)


def _print_version(value: bool) -> None:
    if value:
        from worldagent import __version__

        typer.echo(f"worldagent {__version__}")
        raise typer.Exit()


@app.callback()
def root(
    version: bool = typer.Option(False, "--version", callback=_print_version, is_eager=True, help="Print the version and exit."),
) -> None:
    """Find the worlds in which trained RL agents fail or shine, and reshape what they train on."""


def friendly_errors(command):
    """Decorator: report ``WorldagentError`` as one line on stderr and exit with code 2."""

    @functools.wraps(command)
    def wrapper(*args, **kwargs):
        try:
            return command(*args, **kwargs)
        except WorldagentError as error:
            console.print(f"[red]error:[/red] {error}")
            raise typer.Exit(code=2) from None

    return wrapper


@app.command()
@friendly_errors
def tracks(
    n: int = typer.Option(16, "--n", help="Number of tracks to draw."),
    seed: int = typer.Option(0, "--seed", help="Track i uses seed SEED + i (CarRacing's own seeding)."),
    out: Path = typer.Option(Path("tracks.png"), "--out", help="PNG file to write."),
) -> None:
    """Generate racing tracks with CarRacing's procedural generator and draw them on one sheet."""
    from worldagent.envs.racing.render import draw_track_sheet
    from worldagent.envs.racing.tracks import generate_tracks, seeds_from

    batch = generate_tracks(seeds_from(seed, n))
    draw_track_sheet(batch, out, seeds=seeds_from(seed, n))
    console.print(f"wrote {n} tracks to {out}")
