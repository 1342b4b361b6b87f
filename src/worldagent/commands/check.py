"""``worldagent check ENV [--generator DIR]``: the environment contract's conformance checks, from the installed package.

Prints a table of checks (``worldagent.conformance``) and exits 0 when none failed, 1 when one did, 2 on bad input.
"""

from __future__ import annotations

from pathlib import Path

import typer

from worldagent.commands.console import console, friendly_errors
from worldagent.commands.options import QUIET_HELP, env_argument
from worldagent.errors import WorldagentError

GENERATOR_CHECK_HELP = (
    "Also check worlds G(z) decoded from 512 prior latents (the atlas's sample) with this generator directory "
    "(`worldagent generator train`): they must play, store and describe as generated worlds do."
)


def load_checked_generator(env: str, directory: Path):
    """The generator in ``directory``, refused in one line when it makes another environment's worlds."""
    from worldagent.worlds.generator import load_generator

    generator = load_generator(directory, env=env)[0]
    if generator.env != env:
        raise WorldagentError(f"the generator in {directory} makes {generator.env} worlds; pass a {env} generator (or check {generator.env}).")
    return generator


def register(app: typer.Typer) -> None:
    """Add ``worldagent check``."""

    @app.command("check")
    @friendly_errors
    def check_command(
        env: str = env_argument(),
        generator: Path = typer.Option(None, "--generator", help=GENERATOR_CHECK_HELP),
        quiet: bool = typer.Option(False, "--quiet", help=QUIET_HELP),
    ) -> None:
        """Check that an environment keeps the env contract (docs/adding-an-environment.md §5): a table of checks; exit 1 if one fails."""
        from worldagent import conformance
        from worldagent.envs import registry
        from worldagent.progress import progress_bar

        spec = registry.get(env)
        decoder = load_checked_generator(spec.name, generator) if generator is not None else None
        with progress_bar(f"checking {spec.name}", total=conformance.planned(decoder), enabled=not quiet) as advance:
            rows = conformance.run(spec, decoder, advance)
        for line in conformance.table(rows):
            typer.echo(line)
        failed = [row for row in rows if not row.result.passed]
        if failed:
            console.print(
                f"[red]{spec.name} breaks the env contract in {len(failed)} check(s)[/red]; docs/adding-an-environment.md §6 says why each holds."
            )
            raise typer.Exit(code=1)
