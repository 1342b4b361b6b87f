"""Frozen dataclass configs written to and read from JSON (run directories, saved agents)."""

from __future__ import annotations

import dataclasses
import types
import typing
from typing import Any, ClassVar

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


# -- config fields from ``NAME=VALUE`` texts (``--set``, ``--curriculum-set``) ----------------------

_TRUE, _FALSE = ("true", "yes", "on", "1"), ("false", "no", "off", "0")


def describe_field(hint: Any) -> str:
    """How to write a value of type ``hint``, for error messages."""
    args = [a for a in typing.get_args(hint) if a is not type(None)]
    if type(None) in typing.get_args(hint):
        return f"{describe_field(args[0])} or none"
    if typing.get_origin(hint) is tuple:
        return f"comma-separated {describe_field(args[0]).removeprefix('an ').removeprefix('a ')}s, e.g. 64,64"
    return {bool: "true or false", int: "an integer", float: "a number", str: "text"}.get(hint, str(hint))


def parse_field(text: str, hint: Any) -> Any:
    """``text`` as a value of type ``hint`` (bool, int, float, str, tuples of those, optional ones); ValueError if it is not."""
    args = [a for a in typing.get_args(hint) if a is not type(None)]
    if typing.get_origin(hint) in (typing.Union, types.UnionType):
        return None if text.lower() in ("none", "null") else parse_field(text, args[0])
    if typing.get_origin(hint) is tuple:
        parts = [part.strip() for part in text.strip().strip("()[]").split(",")]
        if not all(parts):
            raise ValueError(text)
        return tuple(parse_field(part, args[0]) for part in parts)
    if hint is bool:
        if text.lower() not in _TRUE + _FALSE:
            raise ValueError(text)
        return text.lower() in _TRUE
    if hint in (int, float, str):
        return hint(text)
    raise ValueError(f"no parser for {hint}")
