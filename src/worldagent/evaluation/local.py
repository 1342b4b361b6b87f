"""Evaluate agents on many worlds at once (DESIGN.md "Evaluator"; paper §4.4, §5.2.2).

``evaluate(env, policy, worlds[B], repeats, key) -> metrics``: every metric of the env's
episodes as an array ``[B, repeats]`` (or ``[B, repeats, N]`` for per-agent metrics), from one
jitted ``vmap(vmap(while_loop))`` over worlds × repeats × steps. An episode's loop stops when
it ends; under ``vmap`` the batch runs until its last episode ends, the finished ones frozen.
Nothing per step is stored: the metrics accumulate in the env state. With several local
devices (a host with 8 GPUs) each batch of worlds is sharded over all of them.

External agents (``agents.external.HostPolicy``, ``host = True``) go to the batched host
evaluator (``evaluation/host.py``) with the same keys and the same output.
"""

from __future__ import annotations

import functools
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec

from worldagent.envs.core import Environment
from worldagent.errors import WorldagentError

MAX_BATCH = 1024  # worlds per compiled call (bounds device memory; results are concatenated)


def run_episode(env: Environment, policy, key: jax.Array, world: Any, params: Any, num_steps: int) -> dict[str, jax.Array]:
    """One episode of at most ``num_steps`` steps; returns ``env.metrics`` of its last state."""
    key_reset, key_steps = jax.random.split(key)
    obs, state = env.reset(key_reset, world, params)

    def running(carry):
        t, _, _, done, _ = carry
        return jnp.logical_and(t < num_steps, ~done)

    def one_step(carry):
        t, obs, state, _, key = carry
        key, key_act, key_env = jax.random.split(key, 3)
        action = policy.act(policy.params, obs, key_act, state)
        obs, state, _, terminated, truncated, _ = env.step(key_env, state, action, params)
        done = jnp.any(jnp.logical_or(terminated, truncated))
        return t + 1, obs, state, done, key

    carry = (jnp.int32(0), obs, state, jnp.bool_(False), key_steps)
    _, _, final, _, _ = jax.lax.while_loop(running, one_step, carry)
    return env.metrics(final)


@functools.lru_cache(maxsize=32)
def _compiled(env: Environment, num_steps: int):
    """Jitted ``(policy, worlds, keys[B, R], params) -> metrics[B, R, ...]`` for one env."""

    def per_world(policy, world, keys, params):
        return jax.vmap(lambda key: run_episode(env, policy, key, world, params, num_steps))(keys)

    return jax.jit(jax.vmap(per_world, in_axes=(None, 0, 0, None)))


def episode_keys(key: jax.Array, worlds: int, repeats: int) -> jax.Array:
    """Keys ``[worlds, repeats]``: episode r of world b uses ``keys[b, r]``."""
    return jax.random.split(key, (worlds, repeats))


def on_all_devices(batch: Any) -> Any:
    """``batch`` (leading axis B) sharded over every local device, padded to a multiple of their
    number with copies of its last entry (drop the padding from the results: ``[:B]``)."""
    devices = jax.local_devices()
    if len(devices) == 1:
        return batch
    size = len(jax.tree_util.tree_leaves(batch)[0])
    pad = -size % len(devices)
    padded = jax.tree_util.tree_map(lambda leaf: jnp.concatenate([leaf, jnp.repeat(leaf[-1:], pad, axis=0)]) if pad else leaf, batch)
    sharding = NamedSharding(Mesh(np.array(devices), ("worlds",)), PartitionSpec("worlds"))
    return jax.device_put(padded, sharding)


def evaluate(
    env: Environment,
    policy,
    worlds: Any,
    repeats: int,
    key: jax.Array,
    params: Any = None,
    num_steps: int | None = None,
    keys: jax.Array | None = None,
) -> dict[str, np.ndarray]:
    """Roll ``policy`` out ``repeats`` times on each of the B ``worlds`` (a batched world pytree).

    Args:
        env: the environment.
        policy: a ``Policy`` (a pytree with ``act(params, obs, key, state)``), or an external
            ``HostPolicy`` (stepped by the batched host evaluator).
        worlds: B worlds with a leading batch axis.
        repeats: episodes per world (the paper: 8).
        key: randomness of all the episodes (ignored if ``keys`` is given).
        params: env parameters (default: ``env.default_params``).
        num_steps: step limit (default: ``params.max_steps``).
        keys: optional ``[B, repeats]`` episode keys (campaigns derive them per world).

    Returns:
        {metric: np.ndarray [B, repeats, ...]}.
    """
    params = env.default_params if params is None else params
    num_steps = int(params.max_steps) if num_steps is None else int(num_steps)
    count = _batch_size(worlds)
    if repeats < 1 or num_steps < 1:
        raise WorldagentError(f"repeats={repeats}, num_steps={num_steps}; both must be at least 1.")
    env.check_world(jax.tree_util.tree_map(lambda leaf: leaf[0], worlds))
    keys = episode_keys(key, count, repeats) if keys is None else keys
    if keys.shape[:2] != (count, repeats):
        raise WorldagentError(f"episode keys have shape {keys.shape}; expected ({count}, {repeats}).")
    host = getattr(policy, "host", False)
    chunks = []
    for start in range(0, count, MAX_BATCH):
        part = jax.tree_util.tree_map(lambda leaf: jnp.asarray(leaf[start : start + MAX_BATCH]), worlds)
        part_keys = keys[start : start + MAX_BATCH]
        if host:
            from worldagent.evaluation.host import evaluate_host

            chunks.append(evaluate_host(env, policy, part, part_keys, params, num_steps))
        else:
            sharded = on_all_devices((part, part_keys))
            metrics = _compiled(env, num_steps)(policy, *sharded, params)
            chunks.append(jax.tree_util.tree_map(lambda leaf: np.asarray(leaf)[: len(part_keys)], metrics))
    return {name: np.concatenate([chunk[name] for chunk in chunks]) for name in chunks[0]}


def summarise(metrics: dict[str, np.ndarray]) -> dict[str, dict[str, np.ndarray]]:
    """Per world: the mean over repeats and its standard error, for each metric."""
    summary = {}
    for name, values in metrics.items():
        values = np.asarray(values, np.float64)
        repeats = values.shape[1]
        sem = values.std(axis=1, ddof=1) / np.sqrt(repeats) if repeats > 1 else np.full(values.mean(axis=1).shape, np.nan)
        summary[name] = {"mean": values.mean(axis=1), "sem": sem}
    return summary


def _batch_size(worlds: Any) -> int:
    leaves = jax.tree_util.tree_leaves(worlds)
    if not leaves or np.ndim(leaves[0]) < 1:
        raise WorldagentError("worlds must be a batch (a world pytree with a leading axis); index one world as world[None].")
    return int(np.shape(leaves[0])[0])
