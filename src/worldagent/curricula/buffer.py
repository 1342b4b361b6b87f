"""The level buffer of Prioritized Level Replay (Jiang et al. 2021), over latents: pure, jittable.

A buffer holds up to N latents with a score each (higher: train on it more), how many episodes
that score averages, and when it was last scored. Replay draws latents by rank of score mixed
with staleness (the paper's P_replay = (1 - p) P_S + p P_C), so that old scores get refreshed::

    buffer = empty(size, dim)
    index = draw(buffer, key, n, temperature, staleness)          # i32[n]
    buffer = record(buffer, z, slot, score, valid, window)         # after episodes end

A latent whose episode ended enters the buffer if there is room or if its score beats the
lowest one there (which it replaces); a replayed latent (``slot`` >= 0) has its score
updated in place. ``record`` takes a whole segment's episodes at once.
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


def record(buffer: Buffer, z: jax.Array, slot: jax.Array, score: jax.Array, valid: jax.Array, window: int) -> Buffer:
    """The buffer after M ended episodes, all at once (vectorised: no loop over episodes).

    A replayed latent still in its slot has its score moved toward the mean of this batch's
    episodes on it, by k / min(count + k, window) (``window`` 1: replaced, as PLR; larger: a
    running mean of about its last ``window`` episodes). The other episodes' latents compete
    for slots: the best of them replace empty slots, then the lowest-scoring ones, wherever
    they score higher, so the buffer ends holding the top scores of both (existing latents
    keep their slots, so the slots of worlds in play stay valid).

    Args:
        z: f32[M, D] each episode's latent.
        slot: i32[M] the slot it was replayed from, or -1 (a new or edited latent).
        score: f32[M] the episode's score.
        valid: bool[M] which entries are episodes (the rest are padding).
        window: see above.
    """
    n = buffer.size
    safe = jnp.clip(slot, 0, n - 1)
    held = valid & (slot >= 0) & jnp.all(buffer.z[safe] == z, axis=-1) & (buffer.count[safe] > 0)
    clock = buffer.clock + valid.sum(dtype=jnp.int32)

    # replayed latents: their scores updated in place
    k = jnp.zeros(n, jnp.float32).at[safe].add(held.astype(jnp.float32))
    total = jnp.zeros(n, jnp.float32).at[safe].add(jnp.where(held, score, 0.0))
    replayed = k > 0
    weight = jnp.minimum(k / jnp.maximum(jnp.minimum(buffer.count + k, window), 1.0), 1.0)
    scores = jnp.where(replayed, buffer.score + weight * (total / jnp.maximum(k, 1.0) - buffer.score), buffer.score)
    counts = jnp.where(replayed, jnp.minimum(buffer.count + k.astype(jnp.int32), window), buffer.count)
    last = jnp.where(replayed, clock, buffer.last)

    # new latents: the i-th best candidate against the i-th weakest slot (empty slots weakest)
    candidate = jnp.where(valid & ~held, score, -jnp.inf)
    best = jnp.argsort(-candidate, stable=True)[: min(n, candidate.shape[0])]
    weakest = jnp.argsort(jnp.where(counts > 0, scores, -jnp.inf), stable=True)[: best.shape[0]]
    enters = (candidate[best] > jnp.where(counts[weakest] > 0, scores[weakest], -jnp.inf)) & jnp.isfinite(candidate[best])
    target = jnp.where(enters, weakest, n)  # n: out of range, dropped by the scatter
    put = lambda array, value: array.at[target].set(value, mode="drop")  # noqa: E731
    return Buffer(put(buffer.z, z[best]), put(scores, score[best]), put(counts, 1), put(last, clock), clock)


def locate(buffer: Buffer, z: jax.Array, slot: jax.Array) -> jax.Array:
    """i32[B]: ``slot``, with each -1 whose latent ``z`` f32[B, D] now sits in the buffer replaced by its slot.

    A world still in play when its latent entered the buffer is then scored as a replay of that
    entry, not entered a second time.
    """
    same = jnp.all(buffer.z[None, :, :] == z[:, None, :], axis=-1) & filled(buffer)[None, :]  # [B, N]
    return jnp.where((slot < 0) & same.any(axis=1), jnp.argmax(same, axis=1), slot).astype(jnp.int32)
