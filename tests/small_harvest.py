"""A harvest small enough to train in a test: a 9x9 window and 20-step episodes, registered under
a name of the test's own (so it never replaces the real ``harvest``)."""

from __future__ import annotations

import contextlib
import dataclasses
from collections.abc import Iterator

from worldagent.envs import registry
from worldagent.envs.harvest.env import Harvest, make_params
from worldagent.envs.registry import EnvSpec


@contextlib.contextmanager
def small_harvest(name: str) -> Iterator[EnvSpec]:
    """The small harvest spec, registered as ``name`` for the duration of the ``with`` block."""
    spec = dataclasses.replace(
        registry.get("harvest"),
        name=name,
        make=lambda options: (Harvest(view_size=9, view_behind=2), make_params(max_steps=20)),
        options=(),
    )
    registry.register(spec)
    try:
        yield spec
    finally:
        registry.unregister(name)
