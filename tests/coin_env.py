"""A world whose failure probability is known exactly: the ground truth of confirmation (issue 50, item 5).

A world is a coin: ``p`` in [0, 1] and a ``tag`` that tells worlds of equal ``p`` apart. An episode is one
step; it fails (``failed`` 1, return -1) with probability ``p``, by a draw from the episode's key alone, so
every episode is an independent coin whatever the agent does::

    from coin_env import registered, coins

    with registered() as spec:
        setup = experiments.setup(spec.name, "idle", None)
        worlds = coins(np.array([0.1, 0.5]))
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from worldagent.envs import registry
from worldagent.envs.core import Environment
from worldagent.envs.registry import EnvSpec, Metrics, Pictures, ScriptedPolicy
from worldagent.errors import WorldagentError

NAME = "coin"


@struct.dataclass
class Coin:
    """One world (or a batch): its failure probability ``p`` f32 and a ``tag`` i32 naming it."""

    p: jax.Array
    tag: jax.Array


@struct.dataclass
class CoinParams:
    max_steps: int = 1


@struct.dataclass
class CoinState:
    world: Coin
    failed: jax.Array
    done: jax.Array


@dataclass(frozen=True)
class CoinEnv(Environment):
    """One step per episode; the coin is drawn at reset from the episode's key."""

    num_agents = 1

    @property
    def default_params(self) -> CoinParams:
        return CoinParams()

    @property
    def num_actions(self) -> int:
        return 1

    @property
    def observation_shape(self) -> tuple[int, ...]:
        return (1,)

    def check_world(self, world: Coin) -> None:
        if not isinstance(world, Coin):
            raise WorldagentError(f"world is a {type(world).__name__}; expected a Coin.")
        if not isinstance(world.p, jax.core.Tracer) and not 0.0 <= float(np.asarray(world.p)) <= 1.0:
            raise WorldagentError(f"coin p={float(np.asarray(world.p))}; it must be in [0, 1].")

    def reset(self, key, world: Coin, params):
        failed = jax.random.uniform(key) < world.p
        state = CoinState(Coin(jnp.asarray(world.p, jnp.float32), jnp.asarray(world.tag, jnp.int32)), failed, jnp.bool_(False))
        return jnp.zeros(1, jnp.float32), state

    def step(self, key, state: CoinState, action, params):
        del key, action
        reward = -state.failed.astype(jnp.float32)
        state = state.replace(done=jnp.bool_(True))
        return jnp.zeros(1, jnp.float32), state, reward, jnp.bool_(True), jnp.bool_(False), {}

    def metrics(self, state: CoinState) -> dict[str, jax.Array]:
        return {"return": -state.failed.astype(jnp.float32), "failed": state.failed.astype(jnp.float32)}


def coins(p: np.ndarray, first_tag: int = 0) -> Coin:
    """A batch of coins with failure probabilities ``p`` and tags ``first_tag, first_tag + 1, ...``."""
    p = np.asarray(p, np.float32).reshape(-1)
    return Coin(p=p, tag=np.arange(first_tag, first_tag + len(p), dtype=np.int32))


def idle(env, params) -> ScriptedPolicy:
    """The one action: the coin decides."""
    return ScriptedPolicy(None, lambda p, obs, key, state: jnp.int32(0))


def _make(options):
    del options
    env = CoinEnv()
    return env, env.default_params


def _no_repair(dataset, config=None):
    raise WorldagentError("the coin env has no generator; play given coins.")


SPEC = EnvSpec(
    name=NAME,
    description="A coin per world (tests/coin_env): each episode fails with the world's probability p.",
    make=_make,
    world_type=Coin,
    generate=lambda seeds: coins(np.random.default_rng(np.asarray(seeds, np.int64)).random(len(np.atleast_1d(seeds)))),
    cells=lambda worlds: (np.asarray(worlds.p)[:, None] * 255).astype(np.uint8),
    cell_shape=(1,),
    repair=_no_repair,
    metrics=Metrics(main="return", names=("return", "failed")),
    trace=lambda state: (jnp.zeros(2), jnp.bool_(True)),
    pictures=Pictures(world=lambda world, size: None),
    scripted={"idle": idle},
    failure="failed > 0.5",
)


@contextlib.contextmanager
def registered() -> Iterator[EnvSpec]:
    """The coin spec, registered for the duration of the ``with`` block (removed after, if we added it)."""
    added = NAME not in registry.names()
    if added:
        registry.register(SPEC)
    try:
        yield registry.get(NAME)
    finally:
        if added:
            registry.unregister(NAME)
