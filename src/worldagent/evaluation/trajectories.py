"""Replay a world's episodes and keep where the agents went (paper §4.4, Figures 1 and 6b).

The evaluator (``local.evaluate``) never stores trajectories: it keeps only per-episode metrics.
To *draw* the worlds a campaign found, we replay some of their episodes here and record the
agents' positions at every step. The replay mirrors ``local.run_episode`` key for key (the same
reset/step split of each episode key), so with the keys the campaign used (``scored_keys``) the
drawn episodes are exactly the scored ones: same return, same crash, same step count.

``replay(spec, env, policy, world, keys[E]) -> Episodes``: one jitted ``vmap(scan)`` over the E
episodes; a finished episode is frozen, so positions after its end repeat its last one. Where
the agents are is the env's own business (``EnvSpec.trace``); how episodes ended, in words, too
(``EnvSpec.episode_note``).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from worldagent.envs import registry
from worldagent.envs.core import Environment, initial_memory, policy_step
from worldagent.errors import WorldagentError


@dataclass(frozen=True)
class Episodes:
    """E replayed episodes of one world.

    Attributes:
        positions: where the agents were at the start and after every step, as ``spec.trace``
            says: [E, T+1, ...] (racing f32[E, T+1, 2] (x, y); harvest i32[E, T+1, N, 2] cells).
        present: bool[E, T+1, ...]: the agent is on the map (harvest agents are removed while
            tagged out; racing's particle always is).
        steps: i32[E] steps each episode took (its positions are ``positions[e, :steps[e] + 1]``).
        metrics: ``env.metrics`` of each episode's end, {name: [E] or [E, N]} — the evaluator's.
    """

    positions: np.ndarray
    present: np.ndarray
    steps: np.ndarray
    metrics: dict[str, np.ndarray]

    def __len__(self) -> int:
        return len(self.steps)

    def path(self, episode: int) -> np.ndarray:
        """Positions of episode ``episode``'s steps taken: [steps + 1, 2] (or [steps + 1, N, 2])."""
        return self.positions[episode, : int(self.steps[episode]) + 1]


def scored_keys(seed: int, repeats: int) -> jax.Array:
    """The ``[repeats]`` episode keys ``LatentObjective`` gives a world evaluated with ``seed``.

    A campaign evaluates world (generation, slot) with ``campaign.stored_seed(...)``; these
    are that world's episode keys, so ``replay`` with them replays the scored episodes.
    """
    return jax.random.split(jax.random.key(int(seed)), int(repeats))


def replay_episode(env: Environment, trace, policy, key: jax.Array, world: Any, params: Any, num_steps: int):
    """One episode as ``local.run_episode`` plays it (memory threaded the same way), recording
    ``trace(state)`` (where the agents are).

    Returns:
        (positions [T+1, ...], present [T+1, ...], steps i32, metrics of the last state).
    """
    key_reset, key_steps = jax.random.split(key)
    obs, state = env.reset(key_reset, world, params)

    def one_step(carry, _):
        obs, state, done, steps, key, memory = carry
        next_key, key_act, key_env = jax.random.split(key, 3)  # the evaluator's split, step for step
        action, next_memory = policy_step(policy, obs, key_act, state, memory)
        next_obs, next_state, _, terminated, truncated, _ = env.step(key_env, state, action, params)
        ended = jnp.any(jnp.logical_or(terminated, truncated))
        keep = lambda new, old: jax.lax.select(done, old, new)  # noqa: E731  frozen once ended
        obs = jax.tree_util.tree_map(keep, next_obs, obs)
        state = jax.tree_util.tree_map(keep, next_state, state)
        memory = jax.tree_util.tree_map(keep, next_memory, memory)
        carry = (obs, state, jnp.logical_or(done, ended), steps + (~done).astype(jnp.int32), keep(next_key, key), memory)
        return carry, trace(state)

    carry = (obs, state, jnp.bool_(False), jnp.int32(0), key_steps, initial_memory(policy))
    (_, final, _, steps, _, _), (positions, present) = jax.lax.scan(one_step, carry, None, length=num_steps)
    start, start_present = trace(state)
    positions = jnp.concatenate([start[None], positions])
    present = jnp.concatenate([jnp.broadcast_to(start_present, present.shape[1:])[None], present])
    return positions, present, steps, env.metrics(final)


@functools.lru_cache(maxsize=16)
def _compiled(env: Environment, trace, num_steps: int):
    """Jitted ``(policy, world, keys[E], params) -> replay_episode`` over E episodes, for one env."""
    episodes = lambda policy, world, keys, params: jax.vmap(  # noqa: E731
        lambda key: replay_episode(env, trace, policy, key, world, params, num_steps)
    )(keys)
    return jax.jit(episodes)


def _replay_host(env: Environment, trace, policy, world: Any, keys: jax.Array, params: Any, num_steps: int):
    """``replay_episode``'s outputs for an external (host) policy, from the batched host evaluator
    in the evaluator's own calls (``local.in_calls``), so the agent sees the batches it was scored in."""
    from worldagent.evaluation.host import host_rollouts
    from worldagent.evaluation.local import in_calls

    worlds = jax.tree_util.tree_map(lambda leaf: jnp.asarray(leaf)[None], world)
    run = lambda part, part_keys: host_rollouts(env, policy, part, part_keys, params, num_steps, trace)  # noqa: E731
    metrics, steps, (positions, present) = in_calls(run, worlds, np.zeros(len(keys), int), keys, env)
    return positions, present, steps, metrics


def replay(spec, env: Environment, policy, world: Any, keys: jax.Array, params: Any = None, num_steps: int | None = None) -> Episodes:
    """Replay E episodes of ``policy`` on one (unbatched) ``world``, keeping positions.

    Args:
        spec: the env's ``EnvSpec`` (or its name): ``spec.trace`` says where the agents are.
        env: the environment.
        policy: a ``Policy``, or an external ``HostPolicy`` (played by the host evaluator).
        world: one world (no batch axis).
        keys: ``[E]`` episode keys (``scored_keys`` for the episodes a campaign scored).
        params: env parameters (default: ``env.default_params``).
        num_steps: step limit (default: ``params.max_steps``, as the evaluator).

    Returns:
        ``Episodes`` (see its attributes for shapes).
    """
    params = env.default_params if params is None else params
    num_steps = int(params.max_steps) if num_steps is None else int(num_steps)
    if num_steps < 1:
        raise WorldagentError(f"num_steps={num_steps}; replay at least one step.")
    env.check_world(world)
    keys = jnp.asarray(keys)
    if keys.ndim != 1 or len(keys) < 1:
        raise WorldagentError(f"episode keys have shape {keys.shape}; pass a 1-d array of at least one key.")
    trace = registry.get(spec).trace
    if getattr(policy, "host", False):
        positions, present, steps, metrics = _replay_host(env, trace, policy, world, keys, params, num_steps)
    else:
        positions, present, steps, metrics = _compiled(env, trace, num_steps)(policy, world, keys, params)
    return Episodes(
        np.asarray(positions),
        np.asarray(present, bool),
        np.asarray(steps),
        {name: np.asarray(value) for name, value in metrics.items()},
    )
