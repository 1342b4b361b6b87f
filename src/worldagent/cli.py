"""``worldagent ...``: the command-line tool (typer).

This module only builds the app: every command lives in a module of ``worldagent.commands``
(``register(app)``), and every command turns a ``WorldagentError`` into one red line and exit
code 2, never a traceback.
"""

from __future__ import annotations

import typer

from worldagent.commands import register_all
from worldagent.commands.interrupted import InterruptedGroup

app = typer.Typer(
    help="Find the worlds in which trained RL agents fail or shine, and reshape what they train on.",
    no_args_is_help=True,
    add_completion=False,
    cls=InterruptedGroup,  # Ctrl-C in any command: one line on what its run directory kept and how to resume
)


def _print_version(value: bool) -> None:
    """``--version``: print ``worldagent.__version__`` (the one version source, which the wheel's metadata reads) and exit."""
    if value:
        from worldagent import __version__

        typer.echo(f"worldagent {__version__}")
        raise typer.Exit()


@app.callback()
def root(
    version: bool = typer.Option(False, "--version", callback=_print_version, is_eager=True, help="Print the version and exit."),
) -> None:
    """Find the worlds in which trained RL agents fail or shine, and reshape what they train on."""
    from worldagent.compilation import use_compilation_cache

    use_compilation_cache()  # compiled programs are kept on disk for the next command (worldagent.compilation)


register_all(app)
