"""A curriculum over latents that replays and edits the worlds it scores highest (PLR, ACCEL, target).

One engine, three settings (``plr.py``, ``accel.py``, ``target.py``): each env's next world is
- replayed from the buffer with probability ρ (``replay_prob``), once the buffer is
  ``min_fill`` full, drawn by rank and staleness (``buffer.replay_probabilities``);
- otherwise an *edit* with probability ``edit_prob`` (ACCEL, Parker-Holder et al. 2022): a latent
  drawn from the buffer the same way, moved by a Gaussian step of ``mutation_scale`` per dimension;
- otherwise new, z ~ N(0, I).
Every world is G(z). When an episode ends, its score (``scores.py``) goes to the buffer: a
replayed latent's score is updated, a new or edited one enters if it beats the lowest there.

With ``robust`` (robust PLR, Jiang et al. 2021b) the actor-critics' gradient sees only steps
on replayed worlds; new and edited worlds are played to be scored.
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from typing import Any

import jax
import jax.numpy as jnp
from flax import struct

from worldagent.curricula import buffer as buffer_lib
from worldagent.curricula.scores import TargetScore
from worldagent.errors import WorldagentError


@dataclass(frozen=True)
class Settings:
    """A replay curriculum's settings (defaults: robust PLR's and ACCEL's, Jiang et al. 2021b, Parker-Holder et al. 2022).

    Attributes:
        buffer_size: latents kept (4000 in both papers).
        replay_prob: ρ, the chance an env's next world is replayed (0.5 in robust PLR).
        temperature: β of the rank prioritisation (0.3).
        staleness: p, the staleness share of the replay distribution (0.3).
        min_fill: share of the buffer filled before replay starts (0.5, as jaxued's ``minimum_fill_ratio``).
        edit_prob: chance a non-replayed world is an edit of a buffer latent once replay has
            begun (ACCEL alternates fresh worlds with edits of the replayed ones: 0.5; PLR: 0).
        mutation_scale: standard deviation of an edit's Gaussian step per latent dimension (0.2:
            a latent edit has no published default; 0.2 keeps an edit close to its parent under N(0, I)).
        window: a replayed latent's score averages its last ``window`` episodes (1: the latest
            score, as PLR; a target averages 8, the episodes the paper rolls out per world).
        robust: learn only from steps on replayed worlds (robust PLR; PPO and ACKTR).
    """

    buffer_size: int = 4000
    replay_prob: float = 0.5
    temperature: float = 0.3
    staleness: float = 0.3
    min_fill: float = 0.5
    edit_prob: float = 0.0
    mutation_scale: float = 0.2
    window: int = 1
    robust: bool = False

    def __post_init__(self) -> None:
        for name in ("replay_prob", "staleness", "min_fill", "edit_prob"):
            value = getattr(self, name)
            if not 0.0 <= value <= 1.0:
                raise WorldagentError(f"curriculum {name}={value!r} is outside [0, 1]; set it between 0 and 1.")
        for name in ("buffer_size", "window"):
            if getattr(self, name) < 1:
                raise WorldagentError(f"curriculum {name}={getattr(self, name)!r}; it must be at least 1.")
        for name in ("temperature", "mutation_scale"):
            if not getattr(self, name) > 0:
                raise WorldagentError(f"curriculum {name}={getattr(self, name)!r}; it must be positive.")


def settings_fields() -> tuple[str, ...]:
    return tuple(f.name for f in fields(Settings))


@struct.dataclass
class State:
    """What a replay curriculum carries through training (part of the trainer state, so checkpointed).

    Attributes:
        buffer: the scored latents (``buffer.Buffer``).
    """

    buffer: buffer_lib.Buffer


@struct.dataclass
class Draw:
    """The next worlds of n envs.

    Attributes:
        z: f32[n, D] their latents.
        slot: i32[n] the buffer slot each was replayed from, or -1 (new or edited).
        worlds: the decoded worlds, leading axis n.
    """

    z: jax.Array
    slot: jax.Array
    worlds: Any


@struct.dataclass
class ReplayCurriculum:
    """PLR / ACCEL / target over the latents of a generator (``distributions.LatentWorlds``).

    Attributes:
        worlds: the ``LatentWorlds`` (a pytree: the decoder's weights are arguments, not constants).
        settings: ``Settings`` (static).
        target: a ``TargetScore`` (static), or None to score by learning potential.
        name: the curriculum's name (static), for records.
    """

    worlds: Any
    settings: Settings = struct.field(pytree_node=False)
    target: TargetScore | None = struct.field(pytree_node=False, default=None)
    name: str = struct.field(pytree_node=False, default="plr")

    adaptive = True

    @property
    def latent_dim(self) -> int:
        return self.worlds.latent_dim

    def init(self, key: jax.Array) -> State:
        del key
        return State(buffer_lib.empty(self.settings.buffer_size, self.latent_dim))

    def sample(self, state: State, key: jax.Array, n: int) -> Draw:
        """The next worlds of ``n`` envs (pure: the state changes only when scores arrive)."""
        s = self.settings
        key_choice, key_pick, key_new, key_edit = jax.random.split(key, 4)
        buffer = state.buffer
        ready = buffer_lib.fill_fraction(buffer) >= jnp.maximum(s.min_fill, 1.0 / s.buffer_size)
        u = jax.random.uniform(key_choice, (2, n))
        replay = ready & (u[0] < s.replay_prob)
        edit = ready & ~replay & (u[1] < s.edit_prob)
        parent = buffer_lib.draw(buffer, key_pick, n, s.temperature, s.staleness)
        fresh = jax.random.normal(key_new, (n, self.latent_dim), jnp.float32)
        step = s.mutation_scale * jax.random.normal(key_edit, (n, self.latent_dim), jnp.float32)
        z = jnp.where(replay[:, None], buffer.z[parent], jnp.where(edit[:, None], buffer.z[parent] + step, fresh))
        return Draw(z, jnp.where(replay, parent, -1), self.worlds.generator(z))

    def update(self, state: State, z: jax.Array, slot: jax.Array, score: jax.Array, valid: jax.Array) -> State:
        """The state after ended episodes (f32[M, D] latents, i32[M] slots, f32[M] scores, bool[M] valid)."""
        return State(buffer_lib.record(state.buffer, z, slot, score, valid, self.settings.window))

    def slot_of(self, state: State, z: jax.Array, slot: jax.Array) -> jax.Array:
        """i32[B]: the buffer slot of each world in play (``buffer.locate``)."""
        return buffer_lib.locate(state.buffer, z, slot)

    def learns_from(self, replayed: jax.Array) -> jax.Array:
        """f32[...]: 1 where the learner's gradient may use a step (robust PLR: only on worlds drawn by replay), else 0."""
        return replayed.astype(jnp.float32) if self.settings.robust else jnp.ones(replayed.shape, jnp.float32)

    def episode_score(self, potential: jax.Array, metrics: dict) -> jax.Array:
        """An ended episode's score: its target margin, or its mean learning potential."""
        return potential if self.target is None else self.target(metrics)


def check_latent_worlds(worlds: Any, name: str) -> None:
    """Replay curricula need latents: refuse a fixed pool with the fix."""
    if not hasattr(worlds, "generator"):
        raise WorldagentError(f"curriculum {name!r} draws latents of a generator; train on --worlds vae --generator DIR (or use --curriculum dr).")


def build_replay(name: str, worlds: Any, settings: dict, target: TargetScore | None) -> ReplayCurriculum:
    """A ``ReplayCurriculum`` named ``name`` over a generator's latents, with ``settings`` (field: value)."""
    check_latent_worlds(worlds, name)
    unknown = sorted(set(settings) - set(settings_fields()))
    if unknown:
        raise WorldagentError(f"unknown curriculum setting {', '.join(unknown)}; known: {', '.join(settings_fields())}.")
    return ReplayCurriculum(worlds, Settings(**settings), target, name)
