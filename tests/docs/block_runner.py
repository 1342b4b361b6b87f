"""Running a page's code blocks: shell lines (``worldagent`` in-process, the rest in ``bash``) and Python blocks.

A failing line raises ``BlockFailed`` naming the line and what it printed, so a broken example (an unknown
option, a renamed function, a missing file) fails its test with the reason.
"""

from __future__ import annotations

import contextlib
import io
import os
import subprocess
import sys
from pathlib import Path

from doc_blocks import cut_budgets, logical_lines, worldagent_argv

SHELL_TIMEOUT_S = 120  # one non-worldagent line (a `python -c`, a heredoc)


class BlockFailed(AssertionError):
    """A line of a documentation block failed."""


def worldagent_command():
    import typer

    from worldagent.cli import app

    return app, typer.main.get_command(app)


def parse_worldagent(argv: list[str]) -> None:
    """Parse ``worldagent ARGV`` as the command line would, down to its leaf command, without running it."""
    _, command = worldagent_command()
    name, args, parent = "worldagent", list(argv), None
    while True:
        try:
            context = command.make_context(name, args, parent=parent)
        except Exception as error:  # click's UsageError / BadParameter, under typer's copy of click
            raise BlockFailed(f"worldagent {' '.join(argv)}: {error.format_message() if hasattr(error, 'format_message') else error}") from None
        if not hasattr(command, "commands"):
            return
        rest = [*getattr(context, "_protected_args", getattr(context, "protected_args", [])), *context.args]
        if not rest:
            raise BlockFailed(f"worldagent {' '.join(argv)}: names no command")
        try:
            name, command, args = command.resolve_command(context, rest)
        except Exception as error:
            raise BlockFailed(f"worldagent {' '.join(argv)}: {error.format_message() if hasattr(error, 'format_message') else error}") from None
        parent = context


def run_worldagent(argv: list[str]) -> str:
    """Run ``worldagent ARGV`` in this process (JAX's compiled programs are shared between blocks); its output."""
    from typer.testing import CliRunner

    app, _ = worldagent_command()
    result = CliRunner().invoke(app, argv)
    if result.exit_code != 0:
        reason = (
            "" if result.exception is None or isinstance(result.exception, SystemExit) else f"{type(result.exception).__name__}: {result.exception}"
        )
        raise BlockFailed(f"worldagent {' '.join(argv)} exited {result.exit_code}: {reason}\n{result.output[-3000:]}")
    return result.output


def run_bash(line: str, cwd: Path) -> str:
    """One shell line (or heredoc) in bash, with this Python's environment first on the PATH."""
    env = dict(os.environ, PATH=f"{Path(sys.executable).parent}{os.pathsep}{os.environ.get('PATH', '')}")
    done = subprocess.run(["bash", "-euo", "pipefail", "-c", line], cwd=cwd, env=env, capture_output=True, text=True, timeout=SHELL_TIMEOUT_S)
    if done.returncode != 0:
        raise BlockFailed(f"{line.splitlines()[0]} exited {done.returncode}:\n{(done.stdout + done.stderr)[-3000:]}")
    return done.stdout


def run_shell_block(code: str, cwd: Path, parse_only: bool = False) -> str:
    """Each line of a shell block in order, in ``cwd``: ``worldagent`` lines in-process with budgets cut (only
    parsed with ``parse_only``), the others in bash (skipped with ``parse_only``). What they printed."""
    printed = []
    with working_directory(cwd):
        for line in logical_lines(code):
            argv = worldagent_argv(line)
            if parse_only:
                if argv is not None:
                    parse_worldagent(argv)
                continue
            printed.append(run_worldagent(cut_budgets(argv)) if argv is not None else run_bash(line, cwd))
    return "".join(printed)


def run_python_block(code: str, namespace: dict, cwd: Path, origin: str) -> str:
    """A Python block in ``namespace`` (shared by the blocks of one page), in ``cwd``; what it printed."""
    printed = io.StringIO()
    with working_directory(cwd), contextlib.redirect_stdout(printed):
        exec(compile(code, origin, "exec"), namespace)
    return printed.getvalue()


@contextlib.contextmanager
def working_directory(path: Path):
    """``path`` as the working directory and first on ``sys.path`` (``--agent mymodule:act`` imports from it)."""
    before, modules = Path.cwd(), set(sys.modules)
    os.chdir(path)
    sys.path.insert(0, str(path))
    try:
        yield
    finally:
        os.chdir(before)
        sys.path.remove(str(path))
        for name in set(sys.modules) - modules:  # a page's own modules (mymodule) do not outlive it
            if getattr(sys.modules[name], "__file__", None) and str(path) in str(sys.modules[name].__file__):
                del sys.modules[name]
