"""Evaluate agents on many worlds at once (DESIGN.md "Evaluator"; paper §4.4, §5.2.2).

``evaluate(env, policy, worlds[B], repeats, key) -> metrics``: every metric of the env's
episodes as an array ``[B, repeats]`` (or ``[B, repeats, N]`` for per-agent metrics), from a
jitted ``vmap(while_loop)`` over episodes × steps. An episode's loop stops when it ends; under
``vmap`` the batch runs until its last episode ends, the finished ones frozen. Nothing per step
is stored: the metrics accumulate in the env state. With several local devices (a host with 8
GPUs) each call is sharded over all of them.

**Batch invariance.** Every compiled call plays exactly ``episodes_per_call(env)`` episodes per
device, each with its own world and key (the last episode repeated as padding). XLA fuses a
program differently for different shapes, and on CPU a multiply-add fused into an FMA in one
program but not in another changes the last bit of, say, racing's lap fraction; a near-tie in
an agent's action then sends the episode elsewhere. One shape for every call of an env means one
program, so an episode's metrics depend only on its world, key and agent: never on how many
worlds came with it, how a backend split them, or how many devices ran them. The same holds
for external agents, whose own matrix products may also depend on the batch they get.

External agents (``agents.external.HostPolicy``, ``host = True``) go to the batched host
evaluator (``evaluation/host.py``) with the same keys and the same output.
"""

from __future__ import annotations

import functools
import os
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec

from worldagent.envs.core import Environment, initial_memory, policy_step
from worldagent.errors import WorldagentError

# Episodes each compiled call plays per device. On 2 CPU cores 256 is as fast per episode as
# 1,024 and pads a CMA-ES generation (21 worlds x 8) less; accelerators want far more at once.
EPISODES_PER_CALL = {"cpu": 256}
ACCELERATOR_EPISODES_PER_CALL = 4096


def run_episode(env: Environment, policy, key: jax.Array, world: Any, params: Any, num_steps: int) -> dict[str, jax.Array]:
    """One episode of at most ``num_steps`` steps; returns ``env.metrics`` of its last state.

    A policy with memory starts from its ``initial_memory`` and carries it step to step
    (``envs.core.policy_step``); a memoryless policy's memory is None and costs nothing.
    """
    key_reset, key_steps = jax.random.split(key)
    obs, state = env.reset(key_reset, world, params)

    def running(carry):
        t, _, _, done, _, _ = carry
        return jnp.logical_and(t < num_steps, ~done)

    def one_step(carry):
        t, obs, state, _, key, memory = carry
        key, key_act, key_env = jax.random.split(key, 3)
        action, memory = policy_step(policy, obs, key_act, state, memory)
        obs, state, _, terminated, truncated, _ = env.step(key_env, state, action, params)
        done = jnp.any(jnp.logical_or(terminated, truncated))
        return t + 1, obs, state, done, key, memory

    carry = (jnp.int32(0), obs, state, jnp.bool_(False), key_steps, initial_memory(policy))
    _, _, final, _, _, _ = jax.lax.while_loop(running, one_step, carry)
    return env.metrics(final)


@functools.lru_cache(maxsize=32)
def _compiled(env: Environment, num_steps: int):
    """Jitted ``(policy, worlds[E], keys[E], params) -> metrics[E, ...]``: episode e on world e."""
    episode = lambda policy, world, key, params: run_episode(env, policy, key, world, params, num_steps)  # noqa: E731
    return jax.jit(jax.vmap(episode, in_axes=(None, 0, 0, None)))


def episode_keys(key: jax.Array, worlds: int, repeats: int) -> jax.Array:
    """Keys ``[worlds, repeats]``: episode r of world b uses ``keys[b, r]``."""
    return jax.random.split(key, (worlds, repeats))


def episodes_per_call(env: Environment | None = None) -> int:
    """Episodes one compiled call plays on each device: ``WORLDAGENT_EPISODES_PER_CALL`` if set, else on a CPU
    ``env.cpu_episodes_per_call`` where the env declares it, else the device's default."""
    given = os.environ.get("WORLDAGENT_EPISODES_PER_CALL")
    if given:
        if not given.isdigit() or int(given) < 1:
            raise WorldagentError(f"WORLDAGENT_EPISODES_PER_CALL={given!r}; set it to a positive whole number, or unset it.")
        return int(given)
    backend = jax.default_backend()
    if backend == "cpu" and getattr(env, "cpu_episodes_per_call", None):
        return int(env.cpu_episodes_per_call)
    return EPISODES_PER_CALL.get(backend, ACCELERATOR_EPISODES_PER_CALL)


def episode_calls(total: int, env: Environment | None = None) -> list[tuple[int, np.ndarray]]:
    """``(count, episodes)`` per compiled call: ``episodes`` are always ``episodes_per_call(env)`` x devices
    indices into ``range(total)``, the first ``count`` real and the rest repeats of the last."""
    size = episodes_per_call(env) * len(jax.local_devices())
    calls = []
    for start in range(0, total, size):
        real = np.arange(start, min(start + size, total))
        calls.append((len(real), np.concatenate([real, np.full(size - len(real), real[-1])])))
    return calls


def on_all_devices(batch: Any) -> Any:
    """``batch`` (its leading axis a multiple of the local devices' number) sharded over all of them."""
    devices = jax.local_devices()
    if len(devices) == 1:
        return batch
    return jax.device_put(batch, NamedSharding(Mesh(np.array(devices), ("episodes",)), PartitionSpec("episodes")))


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

    An episode's metrics depend only on its world, its key and the policy (see "Batch
    invariance" in the module docstring).

    Args:
        env: the environment.
        policy: a ``Policy`` (a pytree with ``act(params, obs, key, state)``, or with memory and
            ``step``), or an external
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
    metrics = play_episodes(env, policy, worlds, np.repeat(np.arange(count), repeats), keys.reshape(count * repeats), params, num_steps)
    return {name: value.reshape(count, repeats, *value.shape[1:]) for name, value in metrics.items()}


def play_episodes(env: Environment, policy, worlds: Any, world_of: np.ndarray, keys: jax.Array, params: Any, num_steps: int) -> dict[str, np.ndarray]:
    """{metric: [E, ...]} of E episodes, episode e played on ``worlds[world_of[e]]`` with ``keys[e]``."""
    if getattr(policy, "host", False):
        from worldagent.evaluation.host import evaluate_host

        return in_calls(lambda part, part_keys: evaluate_host(env, policy, part, part_keys, params, num_steps), worlds, world_of, keys, env)
    compiled = _compiled(env, num_steps)
    return in_calls(lambda part, part_keys: compiled(policy, *on_all_devices((part, part_keys)), params), worlds, world_of, keys, env)


def in_calls(run: Callable[[Any, jax.Array], Any], worlds: Any, world_of: np.ndarray, keys: jax.Array, env: Environment | None = None) -> Any:
    """``run(worlds[E], keys[E]) -> arrays [E, ...]`` over every episode, in calls of one fixed E
    (``episode_calls(_, env)``); episode e is played on ``worlds[world_of[e]]``, results in episode order."""
    world_of = np.asarray(world_of)
    parts = []
    for count, episodes in episode_calls(len(world_of), env):
        part = jax.tree_util.tree_map(lambda leaf: jnp.asarray(leaf)[world_of[episodes]], worlds)
        parts.append(jax.tree_util.tree_map(lambda value: np.asarray(value)[:count], run(part, keys[episodes])))
    return jax.tree_util.tree_map(lambda *values: np.concatenate(values), *parts)


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
