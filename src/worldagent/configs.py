"""Frozen dataclass configs written to and read from JSON (run directories, saved agents)."""

from __future__ import annotations

import dataclasses

from worldagent.errors import WorldagentError


class JsonConfig:
    """Mixin for frozen dataclass configs: ``to_dict`` / ``from_dict`` (tuples travel as lists)."""

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
