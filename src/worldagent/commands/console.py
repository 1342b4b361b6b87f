"""The console every command prints to, and the wrapper that turns bad input and warnings into one line."""

from __future__ import annotations

import functools
import warnings

import typer
from rich.console import Console
from rich.markup import escape

from worldagent.errors import WorldagentError

console = Console(stderr=True, soft_wrap=True)  # never break a message across lines


def one_line_warning(message, category, filename, lineno, file=None, line=None) -> None:
    """``warnings.showwarning`` for the command line: the message on one line, without the file
    path and source line Python adds (library users keep Python's own format)."""
    kind = "" if category is UserWarning else f" ({category.__name__})"
    console.print(f"[yellow]warning{kind}:[/yellow] {escape(' '.join(str(message).split()))}", soft_wrap=True)


def friendly_errors(command):
    """Decorator: report ``WorldagentError`` as one line on stderr and exit with code 2; warnings
    raised while the command runs are shown as one line each (``one_line_warning``)."""

    @functools.wraps(command)
    def wrapper(*args, **kwargs):
        with warnings.catch_warnings():  # restores Python's showwarning afterwards
            warnings.showwarning = one_line_warning
            try:
                return command(*args, **kwargs)
            except WorldagentError as error:
                console.print(f"[red]error:[/red] {escape(str(error))}", soft_wrap=True)  # one line, no markup
                raise typer.Exit(code=2) from None

    return wrapper


def status_line(text: str) -> None:
    """One status line, printed as is (no rich markup: configs hold brackets)."""
    console.print(text, markup=False, highlight=False)
