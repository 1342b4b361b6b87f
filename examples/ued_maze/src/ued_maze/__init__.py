"""ued_maze: jaxued's UED maze (minimax / jaxued's 13×13 scattered-wall maze) for worldagent.

Registered only through the ``worldagent.envs`` entry point (``pyproject.toml``); nothing in
worldagent knows it. jaxued is a dependency, called and never copied; the patches it needs on
jax 0.10 live in ``ued_maze.shims``, imported here first so every module of the package sees them.
"""

from . import shims  # noqa: F401  (first: jaxued must not be imported before its jax 0.10 patches)
from .world import PREFAB_NAMES  # noqa: E402  (the names of the ``prefabs`` world set, in its order)

__all__ = ["PREFAB_NAMES"]
