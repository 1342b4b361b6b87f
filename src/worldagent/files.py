"""Writing files atomically: a temp file beside the target, then a rename.

A reader (or a resumed run) never sees a half-written file, even if the writer is killed.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from pathlib import Path


def write_atomically(path: Path | str, save: Callable[[Path], None]) -> Path:
    """Call ``save(tmp)`` to write a temp file, then rename it to ``path`` (parents created)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    save(tmp)
    tmp.replace(path)
    return path


def write_bytes(path: Path | str, blob: bytes) -> Path:
    return write_atomically(path, lambda tmp: tmp.write_bytes(blob))


def write_text(path: Path | str, text: str) -> Path:
    return write_atomically(path, lambda tmp: tmp.write_text(text))


def save_png(image, path: Path | str) -> Path:
    """Write a Pillow image as PNG."""
    return write_atomically(path, lambda tmp: image.save(tmp, format="PNG"))
