"""Ctrl-C in any command: one line saying what its run directory kept and how to resume (``InterruptedGroup``).

Every long command keeps what it finishes as it goes (the run store commits each evaluation, ``reproduce``'s
manifest each phase, training its checkpoints, files are written atomically), and a rerun of the same command
picks up from there. So the line is the same for all of them, read from the command line and the run
directory: ``worldagent.cli`` builds its app with ``InterruptedGroup``, the one place that catches the interrupt
(a command that says more, as ``train`` does with its checkpoint, says it itself and exits 130 first).
"""

from __future__ import annotations

from pathlib import Path

import typer
from typer.core import TyperCommand, TyperGroup

from worldagent.commands.console import console

INTERRUPTED_EXIT = 130  # 128 + SIGINT, as a shell reports a process Ctrl-C stopped
SHOWN_ENTRIES = 5  # files of a run directory the line names


def given_option(words: list[str], flag: str) -> str | None:
    """The value of ``flag`` on a command line (``--out DIR`` or ``--out=DIR``; the last one given), or None."""
    found = None
    for i, word in enumerate(words):
        if word == flag and i + 1 < len(words):
            found = words[i + 1]
        elif word.startswith(flag + "="):
            found = word.partition("=")[2]
    return found


def leaf_command(group: TyperGroup, ctx: typer.Context, words: list[str]) -> tuple[TyperCommand | None, list[str]]:
    """(the command the words name, its name path), through nested groups (``generator train``)."""
    command, path = group, []
    for word in words:
        if not hasattr(command, "get_command"):  # a command, not a group (typer's click may be its own copy: no isinstance)
            break
        found = command.get_command(ctx, word)
        if found is None:
            break
        command, path = found, [*path, word]
    return (None if command is group else command), path


def option_default(command: TyperCommand, name: str):
    """The default of ``command``'s parameter ``name`` (None when it has none)."""
    return next((param.default for param in command.params if param.name == name), None)


def kept_entries(out: Path) -> str:
    """What ``out`` holds: its store's evaluations and campaigns, and its first files, e.g.
    "store.sqlite (1,234 evaluations in 3 campaigns), diff.json"."""
    from worldagent.errors import WorldagentError
    from worldagent.store import STORE_FILE, RunStore

    names = sorted(
        p.name + ("/" if p.is_dir() else "") for p in out.iterdir() if not p.name.startswith(".") and not p.name.endswith(("-wal", "-shm"))
    )
    said = []
    for name in names[:SHOWN_ENTRIES]:
        if name == STORE_FILE:
            try:
                with RunStore(out / STORE_FILE, create=False) as store:
                    campaigns, evaluations = store.size()
                name += f" ({evaluations:,} evaluation{'s' * (evaluations != 1)} in {campaigns} campaign{'s' * (campaigns != 1)})"
            except WorldagentError:  # a store another process holds, or one interrupted before its schema: named as a file
                pass
        said.append(name)
    more = len(names) - SHOWN_ENTRIES
    return ", ".join(said) + (f" and {more} more" if more > 0 else "")


def interrupted_line(command: TyperCommand | None, path: list[str], words: list[str]) -> str:
    """The line Ctrl-C prints: where the command keeps its work (``--out``, given or default), what is there, and
    the command that resumes it (the same one; with ``--resume`` where a command asks for it)."""
    name = " ".join(path) or "the command"
    out = None if command is None else given_option(words, "--out") or option_default(command, "out")
    if out is None:
        return f"interrupted: {name} keeps no run directory; run it again."
    out = Path(out)
    again = "run the same command again" + (" with --resume" if option_default(command, "resume") is False and "--resume" not in words else "")
    if not out.exists() or (out.is_dir() and not any(out.iterdir())):
        return f"interrupted before {name} kept anything in {out}; {again} to start afresh."
    if out.is_file():
        return f"interrupted: {out} is kept as it was (files are written whole or not at all); {again} to write it."
    return f"interrupted: {out} keeps what {name} finished: {kept_entries(out)}; {again} to resume from there (finished work is not redone)."


class InterruptedGroup(TyperGroup):
    """The CLI's top group: Ctrl-C anywhere below it prints ``interrupted_line`` and exits 130, never a bare exit."""

    def invoke(self, ctx: typer.Context):
        words = [*getattr(ctx, "_protected_args", []), *ctx.args]  # the command line below the group (cleared by invoke)
        try:
            return super().invoke(ctx)
        except KeyboardInterrupt:
            command, path = leaf_command(self, ctx, words)
            console.print(interrupted_line(command, path, words), markup=False, highlight=False)
            raise typer.Exit(code=INTERRUPTED_EXIT) from None
