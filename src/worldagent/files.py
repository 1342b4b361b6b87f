"""Writing files atomically: a temp file beside the target, then a rename.

A reader (or a resumed run) never sees a half-written file, even if the writer is killed.
``check_writable`` refuses, before any work, an output that could not be written.
"""

from __future__ import annotations

import os
import tempfile
from collections.abc import Callable
from pathlib import Path

from worldagent.errors import WorldagentError


def check_writable(path: Path | str, *, folder: bool, option: str = "--out") -> Path:
    """Refuse, in one line naming the fix, an output path this process cannot write.

    ``folder``: the output is a directory (a run directory) rather than a file. Refused: an
    existing path of the other kind, a file among its parents, and a nearest existing folder in
    which no file can be created (permissions, a read-only file system). Creates nothing.
    """
    path = Path(path)
    if visible(path) and path.is_dir() != folder:
        found, wanted = ("a file", "a folder") if folder else ("a folder", "a file name")
        raise WorldagentError(f"{option} {path} is {found}; pass {wanted} there.")
    start = path if folder else path.parent  # a file is written beside itself, then renamed
    existing = next(p for p in (start, *start.parents) if visible(p))
    if not existing.is_dir():
        raise WorldagentError(f"{option} {path}: {existing} is a file, not a folder; choose another {option}.")
    if not can_create_files_in(existing):
        raise WorldagentError(f"{option} {path}: cannot create files in {existing}; choose a writable {option} or change the folder's permissions.")
    return path


def visible(path: Path) -> bool:
    """Whether ``path`` exists as far as this process can see (False inside a folder it may not read)."""
    try:
        return path.exists()
    except OSError:
        return False


def can_create_files_in(folder: Path) -> bool:
    """Whether a file can be created in ``folder``: tried, as permission bits do not tell for root
    or a read-only mount."""
    try:
        with tempfile.TemporaryFile(dir=folder):
            return True
    except OSError:
        return False


def write_atomically(path: Path | str, save: Callable[[Path], None]) -> Path:
    """Call ``save(tmp)`` to write a temp file, then rename it to ``path`` (parents created). A save that
    fails (a full disk, an interrupt) leaves neither ``path`` changed nor its temp file behind."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    try:
        save(tmp)
        tmp.replace(path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    return path


def write_bytes(path: Path | str, blob: bytes) -> Path:
    return write_atomically(path, lambda tmp: tmp.write_bytes(blob))


def write_text(path: Path | str, text: str) -> Path:
    return write_atomically(path, lambda tmp: tmp.write_text(text))


def save_png(image, path: Path | str) -> Path:
    """Write a Pillow image as PNG."""
    return write_atomically(path, lambda tmp: image.save(tmp, format="PNG"))
