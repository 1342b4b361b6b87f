"""SQLite's failures as one line naming the fix, at the run store's boundary (``store.RunStore``).

SQLite reports a full disk, a read-only directory, a damaged file or a lock held by another process
as exceptions whose text names none of the fixes; ``one_line_sqlite_errors`` turns each into a
``WorldagentError`` a user can act on, and leaves anything else (a bug) with its traceback.
"""

from __future__ import annotations

import functools
import inspect
import sqlite3
import time
from pathlib import Path

from worldagent.errors import WorldagentError


def use_wal(db: sqlite3.Connection, patience: float = 30.0) -> None:
    """Switch to WAL, retrying: SQLite answers "locked" without waiting when two connections
    switch a new file at once (the busy timeout does not cover that step)."""
    deadline = time.monotonic() + patience
    while True:
        try:
            db.execute("PRAGMA journal_mode=WAL")
            return
        except sqlite3.OperationalError as error:
            if "locked" not in str(error) or time.monotonic() > deadline:
                raise
            time.sleep(0.01)


def sqlite_kind(error: sqlite3.Error) -> str:
    """What went wrong, from SQLite's own error code (its message where Python gives none): "locked",
    "full", "read-only", "damaged", "io", or "" (anything else: a bug, whose traceback is wanted)."""
    name = getattr(error, "sqlite_errorname", "") or ""
    text = str(error).lower()
    kinds = (
        ("locked", ("SQLITE_BUSY", "SQLITE_LOCKED"), ("locked", "busy")),
        ("full", ("SQLITE_FULL",), ("disk is full", "database or disk is full")),
        ("read-only", ("SQLITE_READONLY", "SQLITE_CANTOPEN", "SQLITE_PERM", "SQLITE_AUTH"), ("readonly", "read-only", "unable to open")),
        ("damaged", ("SQLITE_CORRUPT", "SQLITE_NOTADB"), ("malformed", "not a database", "corrupt")),
        ("io", ("SQLITE_IOERR",), ("disk i/o error",)),
    )
    for kind, codes, words in kinds:
        if name.startswith(codes) or any(word in text for word in words):
            return kind
    return ""


def sqlite_failure(error: sqlite3.Error, path: Path) -> WorldagentError | None:
    """The one line naming the fix for a SQLite failure on the store at ``path`` (``sqlite_kind``), or None for a bug."""
    fixes = {
        "locked": "stayed locked by another process writing to it (another worldagent command on the same --out?); "
        "wait for it to finish, or pass another --out",
        "full": "cannot be written: the disk is full; free some space (or pass an --out on another disk) and run the same command "
        "again (every evaluation committed before is kept, and the rerun resumes)",
        "read-only": f"cannot be written ({error}): SQLite writes the store and files beside it in {path.parent}; make both writable, "
        "or copy the run directory somewhere writable and pass the copy",
        "damaged": f"is damaged ({error}); restore it from a copy or choose another --out",
        "io": f"could not be read or written ({error}: the disk or its mount failed); check the disk, then run the same command again",
    }
    kind = sqlite_kind(error)
    return WorldagentError(f"the run store {path} {fixes[kind]}.") if kind else None


def one_line_sqlite_errors(cls):
    """Class decorator: a SQLite failure in any public method of ``cls`` (a generator's too) is raised as ``sqlite_failure``'s
    ``WorldagentError``: the store is the one boundary where SQLite's errors become one line naming the fix."""

    def guarded(method):
        if inspect.isgeneratorfunction(method):

            @functools.wraps(method)
            def generator(self, *args, **kwargs):
                try:
                    yield from method(self, *args, **kwargs)
                except sqlite3.Error as error:
                    raise (sqlite_failure(error, self.path) or error) from None

            return generator

        @functools.wraps(method)
        def wrapper(self, *args, **kwargs):
            try:
                return method(self, *args, **kwargs)
            except sqlite3.Error as error:
                raise (sqlite_failure(error, self.path) or error) from None

        return wrapper

    for name, method in list(vars(cls).items()):
        if inspect.isfunction(method) and not name.startswith("_"):
            setattr(cls, name, guarded(method))
    return cls
