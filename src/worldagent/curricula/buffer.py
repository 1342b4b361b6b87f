"""The level buffer of Prioritized Level Replay (Jiang et al. 2021), over latents: pure, jittable.

A buffer holds up to N latents with a score each (higher: train on it more), how many episodes
that score averages, and when it was last scored. Replay draws latents by rank of score mixed
with staleness (the paper's P_replay = (1 - p) P_S + p P_C), so that old scores get refreshed::

    buffer = empty(size, dim)
    index = draw(buffer, key, n, temperature, staleness)          # i32[n]
    buffer = record(buffer, z, slot, score, valid, window)         # after episodes end

A latent whose episode ended enters the buffer if there is room or if its score beats the
lowest one there (which it replaces); a replayed latent (``slot`` >= 0) has its score
updated in place.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from flax import struct


@struct.dataclass
class Buffer:
    """Latents and their scores.

    Attributes:
        z: f32[N, D] the latents.
        score: f32[N] each latent's score (meaningful where ``count`` > 0).
        count: i32[N] episodes its score averages (0: the slot is empty), capped at the window.
        last: i32[N] the clock when it was last scored.
        clock: i32 episodes scored so far (staleness is measured in them).
    """

    z: jax.Array
    score: jax.Array
    count: jax.Array
    last: jax.Array
    clock: jax.Array

    @property
    def size(self) -> int:
        return self.score.shape[-1]


def empty(size: int, dim: int) -> Buffer:
    """A buffer of ``size`` empty slots for latents of ``dim`` dimensions."""
    zeros = jnp.zeros(size, jnp.int32)
    return Buffer(jnp.zeros((size, dim), jnp.float32), jnp.zeros(size, jnp.float32), zeros, zeros, jnp.int32(0))


def filled(buffer: Buffer) -> jax.Array:
    """bool[N]: the slots that hold a scored latent."""
    return buffer.count > 0


def fill_fraction(buffer: Buffer) -> jax.Array:
    """f32: the share of slots in use."""
    return filled(buffer).mean(dtype=jnp.float32)


def replay_probabilities(buffer: Buffer, temperature: float, staleness: float) -> jax.Array:
    """f32[N]: P_replay over the slots; zero on empty ones (Jiang et al. 2021, §3).

    P_S is rank prioritisation, h(S_i) = 1 / rank(S_i), raised to 1 / temperature; P_C is each
    latent's age (episodes since it was last scored) over the sum of ages.
    """
    used = filled(buffer)
    order = jnp.argsort(jnp.where(used, -buffer.score, jnp.inf), stable=True)  # best first, empty slots last
    rank = jnp.zeros(buffer.size, jnp.float32).at[order].set(jnp.arange(1, buffer.size + 1, dtype=jnp.float32))
    weight = jnp.where(used, rank ** (-1.0 / temperature), 0.0)
    by_score = weight / jnp.maximum(weight.sum(), 1e-30)
    age = jnp.where(used, buffer.clock - buffer.last, 0).astype(jnp.float32)
    uniform = used / jnp.maximum(used.sum(), 1)
    by_age = jnp.where(age.sum() > 0, age / jnp.maximum(age.sum(), 1e-30), uniform)  # all fresh: no preference
    return (1.0 - staleness) * by_score + staleness * by_age


def draw(buffer: Buffer, key: jax.Array, n: int, temperature: float, staleness: float) -> jax.Array:
    """i32[n] slots drawn with replacement by ``replay_probabilities`` (the buffer must hold a latent)."""
    probabilities = replay_probabilities(buffer, temperature, staleness)
    return jax.random.choice(key, buffer.size, (n,), p=probabilities).astype(jnp.int32)


def _record_one(buffer: Buffer, episode, window: int) -> Buffer:
    """One ended episode: update its slot if it was replayed from there, else insert if it earns a slot."""
    z, slot, score, valid = episode
    held = (slot >= 0) & jnp.all(buffer.z[jnp.maximum(slot, 0)] == z)  # still there (not evicted since drawn)
    used = filled(buffer)
    worst = jnp.argmin(jnp.where(used, buffer.score, jnp.inf))
    free = jnp.argmin(used)  # first empty slot (0 when full: then ``room`` is False)
    room = ~jnp.all(used)
    target = jnp.where(held, slot, jnp.where(room, free, worst))
    enters = held | room | (score > buffer.score[worst])
    write = valid & enters
    count = jnp.where(held, jnp.minimum(buffer.count[target] + 1, window), 1)
    previous = jnp.where(held, buffer.score[target], score)
    new_score = previous + (score - previous) / count  # a running mean over the last ``window`` episodes
    clock = buffer.clock + valid.astype(jnp.int32)
    put = lambda array, value: jnp.where(write, array.at[target].set(value), array)  # noqa: E731
    return Buffer(put(buffer.z, z), put(buffer.score, new_score), put(buffer.count, count), put(buffer.last, clock), clock)


def record(buffer: Buffer, z: jax.Array, slot: jax.Array, score: jax.Array, valid: jax.Array, window: int) -> Buffer:
    """The buffer after M ended episodes, in order.

    Args:
        z: f32[M, D] each episode's latent.
        slot: i32[M] the slot it was replayed from, or -1 (a new or edited latent).
        score: f32[M] the episode's score.
        valid: bool[M] which entries are episodes (the rest are padding).
        window: a replayed latent's score is the mean of its last ``window`` episodes (1: the latest).
    """
    buffer, _ = jax.lax.scan(lambda b, e: (_record_one(b, e, window), None), buffer, (z, slot, score, valid))
    return buffer
