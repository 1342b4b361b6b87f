"""The console every command prints to, and the wrapper that turns bad input and warnings into one line."""

from __future__ import annotations

import contextlib
import errno
import functools
import sqlite3
import warnings

import typer
from rich.console import Console
from rich.markup import escape

from worldagent.errors import WorldagentError

console = Console(stderr=True, soft_wrap=True)  # never break a message across lines


def one_line_warning(message, category, filename, lineno, line=None) -> str:
    """``warnings.formatwarning`` for the command line: the message on one line, without the file
    path and source line Python adds (library users keep Python's own format)."""
    kind = "" if category is UserWarning else f" ({category.__name__})"
    return f"warning{kind}: {' '.join(str(message).split())}\n"


@contextlib.contextmanager
def one_line_warnings():
    """Warnings shown while the block runs are one line each. Only their format changes (not
    ``showwarning``), so whoever records warnings (``pytest.warns``) still sees them."""
    previous, warnings.formatwarning = warnings.formatwarning, one_line_warning
    try:
        yield
    finally:
        warnings.formatwarning = previous


FULL_DISK = (errno.ENOSPC, errno.EDQUOT)


def machine_failure(error: BaseException) -> str | None:
    """One line naming the fix for a failure of the machine rather than of the input (a run store another
    process is writing, a full disk), or None for any other error (a bug: its traceback is wanted)."""
    if isinstance(error, sqlite3.OperationalError) and "locked" in str(error):
        return (
            "the run store stayed locked by another process writing to it (another worldagent command on the same --out?); "
            "wait for it to finish, or pass another --out."
        )
    if isinstance(error, OSError) and error.errno in FULL_DISK:
        where = f" while writing {error.filename}" if error.filename else ""
        return f"no space left on the device{where}; free some space (or pass an --out on another disk) and run the same command again."
    return None


def friendly_errors(command):
    """Decorator: report ``WorldagentError`` (and ``machine_failure``s: a locked store, a full disk) as one
    line on stderr and exit with code 2; warnings raised while the command runs are shown as one line each
    (``one_line_warning``)."""

    @functools.wraps(command)
    def wrapper(*args, **kwargs):
        with one_line_warnings():
            try:
                return command(*args, **kwargs)
            except WorldagentError as error:
                console.print(f"[red]error:[/red] {escape(str(error))}", soft_wrap=True)  # one line, no markup
                raise typer.Exit(code=2) from None
            except (sqlite3.OperationalError, OSError) as error:
                message = machine_failure(error)
                if message is None:
                    raise
                console.print(f"[red]error:[/red] {escape(message)}", soft_wrap=True)
                raise typer.Exit(code=2) from None

    return wrapper


def status_line(text: str) -> None:
    """One status line, printed as is (no rich markup: configs hold brackets)."""
    console.print(text, markup=False, highlight=False)
