"""A third, toy environment defined entirely in the test suite (issue 11: proof of extensibility).

A 7x7 gridworld with random walls and one goal, registered through the public API only::

    from toy_env import registered

    with registered() as spec:          # registry.register(SPEC) ... registry.unregister("toy")
        make_dataset(spec.name, 256, 0)

``docs/adding-an-environment.md`` walks through it.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator

from worldagent.envs import registry
from worldagent.envs.registry import EnvSpec

from .spec import NAME, SPEC

__all__ = ["NAME", "SPEC", "registered"]


@contextlib.contextmanager
def registered() -> Iterator[EnvSpec]:
    """The toy spec, registered for the duration of the ``with`` block (removed after, if we added it)."""
    added = NAME not in registry.names()
    if added:
        registry.register(SPEC)
    try:
        yield registry.get(NAME)
    finally:
        if added:
            registry.unregister(NAME)
