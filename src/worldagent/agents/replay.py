"""Replay buffers of independent DQN learners as fixed-size JAX arrays (paper §5.3).

One buffer holds the transitions of ``E`` parallel envs for ``A`` agents, time-major:
slice ``t`` holds what every env and agent saw and did at one vector step. Each agent samples
only its own column, so the agents share no data (independent learners); storing them side by
side just lets one ``vmap`` over agents do all four updates.

The next observation of slice ``t`` is the observation of slice ``t + 1`` (no copy is kept),
unless the episode ended at ``t``: then the transition is terminal for the target (the harvest
episode is truncated at its time limit; the agents do not observe time, see ``dqn.py``). The
newest slice has no successor yet and is never sampled.

Observations are 0/1 planes (harvest: uint8[V, V, 4]); they are stored bit-packed, one uint8
per cell, so a 100,000-transition buffer of one agent's 15x15x4 windows takes 22 MB.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from flax import struct


def pack_planes(obs: jax.Array) -> jax.Array:
    """uint8[..., K] of 0/1 planes (K <= 8) -> uint8[...]: plane k in bit k."""
    shifts = jnp.arange(obs.shape[-1], dtype=jnp.uint8)
    return (obs.astype(jnp.uint8) << shifts).sum(axis=-1, dtype=jnp.uint8)


def unpack_planes(codes: jax.Array, num_planes: int) -> jax.Array:
    """uint8[...] -> uint8[..., K] of 0/1 planes (inverse of ``pack_planes``)."""
    return (codes[..., None] >> jnp.arange(num_planes, dtype=jnp.uint8)) & jnp.uint8(1)


@struct.dataclass
class Replay:
    """A ring buffer of ``C`` time slices.

    Attributes:
        codes: uint8[C, E, A, *P] bit-packed observations (``P`` the observation shape less its planes).
        action: uint8[C, E, A] actions taken.
        reward: f32[C, E, A] rewards received.
        ended: bool[C, E] the episode ended at this step (no bootstrap from the next slice).
        position: i32 the slice written next.
        filled: i32 slices holding data (at most C).
    """

    codes: jax.Array
    action: jax.Array
    reward: jax.Array
    ended: jax.Array
    position: jax.Array
    filled: jax.Array

    @property
    def capacity(self) -> int:
        """C, slices in the ring."""
        return self.codes.shape[0]


def create(capacity: int, num_envs: int, num_agents: int, obs_shape: tuple[int, ...]) -> Replay:
    """An empty buffer of ``capacity`` slices for observations of shape ``obs_shape`` (planes last)."""
    return Replay(
        codes=jnp.zeros((capacity, num_envs, num_agents, *obs_shape[:-1]), jnp.uint8),
        action=jnp.zeros((capacity, num_envs, num_agents), jnp.uint8),
        reward=jnp.zeros((capacity, num_envs, num_agents), jnp.float32),
        ended=jnp.zeros((capacity, num_envs), bool),
        position=jnp.int32(0),
        filled=jnp.int32(0),
    )


def add(replay: Replay, obs: jax.Array, action: jax.Array, reward: jax.Array, ended: jax.Array) -> Replay:
    """Write one vector step: obs uint8[E, A, *O] seen, action int[E, A], reward f32[E, A], ended bool[E]."""
    at = replay.position
    return replay.replace(
        codes=replay.codes.at[at].set(pack_planes(obs)),
        action=replay.action.at[at].set(action.astype(jnp.uint8)),
        reward=replay.reward.at[at].set(reward),
        ended=replay.ended.at[at].set(ended),
        position=(at + 1) % replay.capacity,
        filled=jnp.minimum(replay.filled + 1, replay.capacity),
    )


def sample(key: jax.Array, replay: Replay, agent: jax.Array, batch_size: int, num_planes: int) -> dict[str, jax.Array]:
    """A uniform minibatch of one agent's transitions (needs ``filled >= 2``).

    Returns:
        dict of ``obs`` and ``next_obs`` uint8[B, *O], ``action`` i32[B], ``reward`` f32[B],
        ``ended`` bool[B].
    """
    key_time, key_env = jax.random.split(key)
    capacity, num_envs = replay.capacity, replay.codes.shape[1]
    oldest = (replay.position - replay.filled) % capacity
    offset = jax.random.randint(key_time, (batch_size,), 0, jnp.maximum(replay.filled - 1, 1))
    time = (oldest + offset) % capacity
    env = jax.random.randint(key_env, (batch_size,), 0, num_envs)
    return {
        "obs": unpack_planes(replay.codes[time, env, agent], num_planes),
        "next_obs": unpack_planes(replay.codes[(time + 1) % capacity, env, agent], num_planes),
        "action": replay.action[time, env, agent].astype(jnp.int32),
        "reward": replay.reward[time, env, agent],
        "ended": replay.ended[time, env],
    }
