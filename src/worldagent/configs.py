"""Frozen dataclass configs written to and read from JSON (run directories, saved agents)."""

from __future__ import annotations

import dataclasses
from typing import ClassVar

from worldagent.errors import WorldagentError


class JsonConfig:
    """Mixin for frozen dataclass configs: ``to_dict`` / ``from_dict`` (tuples travel as lists).

    Training configs also say which field is their episode budget (``budget_field``), so every
    layer sets a budget the same way (``with_episodes``), and how many updates the host driver
    runs between checkpoints (``chunk_updates``).
    """

    budget_field: ClassVar[str] = "total_episodes"
    chunk_updates: ClassVar[int] = 10

    def to_dict(self) -> dict:
        """JSON-able fields."""
        return {k: list(v) if isinstance(v, tuple) else v for k, v in dataclasses.asdict(self).items()}

    @classmethod
    def from_dict(cls, fields: dict):
        """Inverse of ``to_dict``; unknown fields are refused."""
        known = {f.name for f in dataclasses.fields(cls)}
        unknown = set(fields) - known
        if unknown:
            raise WorldagentError(f"{cls.__name__} has unknown fields {sorted(unknown)}; remove them (known: {', '.join(sorted(known))}).")
        return cls(**{k: tuple(v) if isinstance(v, list) else v for k, v in fields.items()})

    @property
    def episodes(self) -> int:
        """The episode budget (the value of ``budget_field``)."""
        return getattr(self, self.budget_field)

    def with_episodes(self, episodes: int):
        """This config with the episode budget set to ``episodes``."""
        return self.replace(**{self.budget_field: episodes})

    def replace(self, **changes):
        """This config with ``changes``; unknown fields are refused (one line, listing the known)."""
        known = {f.name for f in dataclasses.fields(self)}
        unknown = sorted(set(changes) - known)
        if unknown:
            raise WorldagentError(f"{type(self).__name__} has no field {unknown[0]!r}; its fields: {', '.join(sorted(known))}.")
        return dataclasses.replace(self, **changes)
