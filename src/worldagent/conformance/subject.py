"""What the conformance checks run on: one environment, a small batch of its worlds, and its functions jitted once.

A ``Subject`` holds worlds of one kind: the procedural generator's (``generated_subject``) or G(z)'s decodes of
prior latents (``decoded_subject``), the worlds every search sees. Checks that play episodes share one jitted
batch of random-action episodes (``Subject.played``), so a whole run compiles each program once.
"""

from __future__ import annotations

import dataclasses
import functools
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from worldagent.envs import core
from worldagent.envs.registry import EnvSpec

STEPS = 6  # the step limit every episode check sets (params.max_steps)
BATCH = 4  # worlds per batch
DESCRIBED = 64  # generated worlds each descriptor is measured on
GENERATED = "generated"
DECODED = "decoded"


def short(params: Any, steps: int) -> Any:
    """``params`` with ``max_steps`` set to ``steps``, keeping its type (python int or array)."""
    old = params.max_steps
    return params.replace(max_steps=jnp.asarray(steps, jnp.asarray(old).dtype) if isinstance(old, jax.Array) else steps)


def take(worlds: Any, index: Any) -> Any:
    """World(s) ``index`` of a batched world, as numpy."""
    return jax.tree_util.tree_map(lambda leaf: np.asarray(leaf)[index], worlds)


def episode(env: Any, random_action: Any, key: jax.Array, world: Any, params: Any) -> dict:
    """A random-action episode of ``STEPS`` steps (not frozen at its end: only the first end is checked).

    The keys: ``key -> (steps, reset)``; step t: ``steps[t] -> (act, env)``.
    """
    key_steps, key_reset = jax.random.split(key)
    obs, state = env.reset(key_reset, world, params)

    def one(state, key):
        key_act, key_env = jax.random.split(key)
        action = random_action(key_act)
        obs, state, reward, terminated, truncated, _ = env.step(key_env, state, action, params)
        return state, {"obs": obs, "action": action, "reward": reward, "terminated": terminated, "truncated": truncated}

    final, steps = jax.lax.scan(one, state, jax.random.split(key_steps, STEPS))
    return {"obs0": obs, "final": final, **steps}


@dataclasses.dataclass(frozen=True)
class Jitted:
    """The env's functions jitted once per subject (compiling dominates the checks).

    Attributes:
        episodes: ``(keys[B], worlds[B], params) -> episode`` under jit and vmap.
        reset, step: one world, jitted.
        autoreset: ``core.step_autoreset`` with a ``next_world``, jitted.
    """

    episodes: Any
    reset: Any
    step: Any
    autoreset: Any


class Subject:
    """One environment and ``BATCH`` of its worlds of one kind.

    Args:
        spec: the environment.
        worlds: ``BATCH`` worlds (batched, numpy).
        described: the worlds descriptors are measured on (batched, numpy; more than ``worlds``).
        kind: ``GENERATED`` or ``DECODED``; ``source``: where the worlds came from, in words.
    """

    def __init__(self, spec: EnvSpec, worlds: Any, described: Any, kind: str, source: str):
        self.spec, self.worlds, self.described, self.kind, self.source = spec, worlds, described, kind, source
        env, params = spec.make_env()
        self.env, self.params = env, short(params, STEPS)
        self.keys = jax.random.split(jax.random.key(0), BATCH)

    @property
    def action_shape(self) -> tuple[int, ...]:
        """``()``, or ``(N,)`` for N agents: multi-agent envs put a leading agent axis on actions, rewards, obs."""
        return () if self.env.num_agents == 1 else (self.env.num_agents,)

    def world(self, index: int) -> Any:
        return take(self.worlds, index)

    def random_action(self, key: jax.Array) -> jax.Array:
        return jax.random.randint(key, self.action_shape, 0, self.env.num_actions)

    @functools.cached_property
    def jitted(self) -> Jitted:
        env = self.env
        return Jitted(
            episodes=jax.jit(jax.vmap(lambda key, world, params: episode(env, self.random_action, key, world, params), in_axes=(0, 0, None))),
            reset=jax.jit(env.reset),
            step=jax.jit(env.step),
            autoreset=jax.jit(lambda key, state, action, params, next_world: core.step_autoreset(env, key, state, action, params, next_world)),
        )

    @functools.cached_property
    def played(self) -> dict:
        """``BATCH`` random episodes, one per world, as numpy (keys: ``self.keys``)."""
        return jax.tree_util.tree_map(np.asarray, self.jitted.episodes(self.keys, self.worlds, self.params))


def generated_subject(spec: EnvSpec) -> Subject:
    """The procedural generator's worlds: seeds 0..BATCH-1, and 0..DESCRIBED-1 for the descriptors."""
    worlds, described = (take(spec.generate(np.arange(count)), slice(None)) for count in (BATCH, DESCRIBED))
    return Subject(spec, worlds, described, GENERATED, f"the procedural generator's seeds 0-{DESCRIBED - 1}")


def decoded_subject(spec: EnvSpec, generator: Any, seed: int = 0) -> Subject:
    """G(z) of the prior latents ``worldagent atlas`` sets its grid's ranges with (``RANGE_SAMPLES`` of them, its seed):
    a descriptor constant on these is one the atlas refuses."""
    from worldagent.search.atlas import RANGE_SAMPLES
    from worldagent.search.objectives import generate

    z = np.random.default_rng([seed, 7]).standard_normal((RANGE_SAMPLES, generator.latent_dim))
    described = jax.tree_util.tree_map(np.asarray, generate(generator, z))
    return Subject(spec, take(described, slice(0, BATCH)), described, DECODED, f"G(z) of {RANGE_SAMPLES} prior latents z ~ N(0, I)")
