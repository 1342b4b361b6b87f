"""Progress bars (rich) for long work; silent when disabled (``--quiet``) or not a terminal."""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Iterator

from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn


@contextlib.contextmanager
def progress_bar(description: str, total: int, enabled: bool = True) -> Iterator[Callable[..., None]]:
    """Yield ``advance(steps=1, **fields)``; draws a bar on stderr while the block runs.

    Extra ``fields`` (e.g. ``loss=0.31``) are shown after the bar.
    """
    if not enabled:
        yield lambda steps=1, **fields: None
        return
    columns = (
        TextColumn("{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TimeElapsedColumn(),
        TimeRemainingColumn(),
        TextColumn("{task.fields[status]}"),
    )
    with Progress(*columns, transient=False, console=Console(stderr=True)) as progress:  # stdout may be a command's JSON
        task = progress.add_task(description, total=total, status="")

        def advance(steps: int = 1, **fields) -> None:
            status = "  ".join(f"{k} {v:.4g}" if isinstance(v, float) else f"{k} {v}" for k, v in fields.items())
            progress.update(task, advance=steps, status=status)

        yield advance
