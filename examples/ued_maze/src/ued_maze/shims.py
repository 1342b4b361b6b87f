"""Every patch jaxued 0.0.1 (and the gymnax and chex it brings) needs on jax 0.10, in one place.

``ued_maze/__init__.py`` imports this module before anything imports jaxued, so each patch is in
place whichever of the package's modules is imported first. Each patch is applied only where it is
missing, so on an older jax (or a fixed jaxued) this module changes nothing.

Found by importing and running what this package calls (the env's ``reset_env_to_level`` and
``step_env``, ``make_level_generator``, ``Level.from_str`` / ``pad_to_shape`` / ``load_prefabs``)
on jax 0.10.2 with gymnax 0.0.9 (and 1.0.1) and chex 0.1.92:

1. ``jax.tree_map``: jax 0.6 removed this alias of ``jax.tree_util.tree_map`` (its module
   ``__getattr__`` now raises ``AttributeError``). jaxued 0.0.1 still calls it in ``Level.stack``,
   which ``Level.load_prefabs`` uses to build the held-out prefab set (and in its mutators,
   wrappers and level sampler, which this package does not call). jaxued's GitHub head has moved
   to ``jax.tree_util.tree_map``, but the wheel on the package index predates that.

Nothing else was needed: gymnax and chex import and run on jax 0.10.2 as they are (gymnax does
import ``six`` without declaring it: a missing dependency, not a jax change, so ``pyproject.toml``
declares ``six`` instead of patching it here; it also says why gymnax is held below 1.0).
"""

from __future__ import annotations

import jax
import jax.tree_util

PATCHED: tuple[str, ...] = ()  # the names patched in this process, for tests and bug reports

if not hasattr(jax, "tree_map"):  # patch 1
    jax.tree_map = jax.tree_util.tree_map
    PATCHED += ("jax.tree_map",)
