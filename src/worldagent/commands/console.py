"""The console every command prints to, and the wrapper that turns bad input into one line."""

from __future__ import annotations

import functools

import typer
from rich.console import Console
from rich.markup import escape

from worldagent.errors import WorldagentError

console = Console(stderr=True, soft_wrap=True)  # never break a message across lines


def friendly_errors(command):
    """Decorator: report ``WorldagentError`` as one line on stderr and exit with code 2."""

    @functools.wraps(command)
    def wrapper(*args, **kwargs):
        try:
            return command(*args, **kwargs)
        except WorldagentError as error:
            console.print(f"[red]error:[/red] {escape(str(error))}", soft_wrap=True)  # one line, no markup
            raise typer.Exit(code=2) from None

    return wrapper


def status_line(text: str) -> None:
    """One status line, printed as is (no rich markup: configs hold brackets)."""
    console.print(text, markup=False, highlight=False)
