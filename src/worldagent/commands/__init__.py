"""CLI command modules: each module here with a ``register(app)`` adds its commands.

``worldagent.cli`` calls every one of them, so a new command is a new module here and never an
edit to a shared file. ``console`` and ``options`` hold what the commands share.
"""

from __future__ import annotations

import importlib
import pkgutil

import typer


def register_all(app: typer.Typer) -> None:
    """Add the commands of every module in this package to ``app`` (alphabetical order)."""
    for name in sorted(m.name for m in pkgutil.iter_modules(__path__)):
        module = importlib.import_module(f"{__name__}.{name}")
        if hasattr(module, "register"):
            module.register(app)
