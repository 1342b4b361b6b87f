"""The batched host evaluator: external agents on many worlds at once (DESIGN.md "Evaluator").

An external agent (``agents.external.HostPolicy``: a Python callable, ONNX or Stable-Baselines3
model) cannot run inside ``jit``. Here the jitted env steps E episodes in lockstep (each on its
own world; ``local.play_episodes`` always passes the same E, so the agent always sees batches
of one size), and the agent is called from Python once per step on the whole batch of
observations ``[E, ...]``. Keys follow ``local.run_episode`` split for split (reset and steps from each
episode key, then ``(next, act, env)`` at every step), and a finished episode is frozen as under
``vmap(while_loop)``, so a jitted policy computing the same function gives the same metrics.

``evaluate_host(env, policy, worlds[E], keys[E], params, num_steps) -> {metric: [E, ...]}``;
``host_rollouts`` with a ``trace`` keeps the agents' positions, as ``trajectories.replay`` does
for jitted policies.
"""

from __future__ import annotations

import functools
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from worldagent.envs.core import Environment


@functools.lru_cache(maxsize=16)
def _compiled(env: Environment, trace: Any = None):
    """Jitted ``start(worlds[E], keys[E], params)``, ``step(state, obs, keys3, actions, done, params)``,
    ``metrics(states[E])`` and (with ``trace``) ``where(states[E])``."""

    def start_one(world, key, params):
        key_reset, key_steps = jax.random.split(key)
        obs, state = env.reset(key_reset, world, params)
        return obs, state, jax.random.split(key_steps, 3)

    def step_one(state, obs, keys3, action, done, params):
        obs_next, state_next, _, terminated, truncated, _ = env.step(keys3[2], state, action, params)
        keep = lambda new, old: jax.lax.select(done, old, new)  # frozen once ended, as under vmap(while_loop)
        obs_next = jax.tree_util.tree_map(keep, obs_next, obs)
        state_next = jax.tree_util.tree_map(keep, state_next, state)
        ended = jnp.any(jnp.logical_or(terminated, truncated))
        keys_next = keep(jax.random.split(keys3[0], 3), keys3)
        return obs_next, state_next, keys_next, jnp.logical_or(done, ended)

    start = jax.jit(jax.vmap(start_one, in_axes=(0, 0, None)))
    step = jax.jit(jax.vmap(step_one, in_axes=(0, 0, 0, 0, 0, None)))
    metrics = jax.jit(jax.vmap(env.metrics))
    where = jax.jit(jax.vmap(trace)) if trace is not None else None
    return start, step, metrics, where


def host_rollouts(env: Environment, policy, worlds: Any, keys: jax.Array, params: Any, num_steps: int, trace: Any = None):
    """Play episodes ``keys[E]`` on ``worlds[E]`` (episode e on world e) with a host policy, in lockstep.

    Returns:
        ({metric: [E, ...]} of the episodes' ends, steps taken i32[E], and with ``trace`` the
        agents' positions and presence at the start and after every step, ``[E, num_steps + 1, ...]``,
        else None).
    """
    start, step, metrics, where = _compiled(env, trace)
    obs, state, keys3 = start(worlds, keys, params)
    done = jnp.zeros(len(keys), bool)
    steps = np.zeros(len(keys), np.int32)
    trail = [where(state)] if where is not None else None
    for _ in range(num_steps):
        actions = policy(np.asarray(obs), keys3[:, 1])
        was_done = np.asarray(done)
        obs, state, keys3, done = step(state, obs, keys3, jnp.asarray(actions), done, params)
        steps += ~was_done
        if trail is not None:
            trail.append(where(state))
        if bool(np.all(np.asarray(done))):
            break
    ends = {name: np.asarray(value) for name, value in metrics(state).items()}
    if trail is None:
        return ends, steps, None
    # episodes that all ended early: positions after the end repeat the last ones, as in a replay
    trail += [trail[-1]] * (num_steps + 1 - len(trail))
    positions = jax.tree_util.tree_map(lambda *frames: np.stack([np.asarray(f) for f in frames], axis=1), *trail)
    return ends, steps, positions


def evaluate_host(env: Environment, policy, worlds: Any, keys: jax.Array, params: Any, num_steps: int) -> dict[str, np.ndarray]:
    """{metric: [E, ...]} of a host policy's episodes ``keys[E]`` on ``worlds[E]`` (``local.play_episodes``'s output)."""
    return host_rollouts(env, policy, worlds, keys, params, num_steps)[0]
