"""Networks of the agents (Flax linen, pure ``init``/``apply``), and how to rebuild them from a config.

``ActorCritic`` is the agent of PPO and ACKTR (racing's): two separate MLP torsos (actor, critic)
on the flat observation (position, velocity / top speed, route ahead; see ``envs/racing/env.py``).

Sizes and why: two hidden layers of 128 units, tanh. The paper's agent (pytorch-a2c-ppo-acktr's
ACKTR with defaults, §5.3) uses an MLP of two 64-unit tanh layers for flat observations; the
torsos here are twice as wide (chosen when the observation held 256 road pixels; kept, as the
agents reach the targets with it). Separate torsos keep value-loss gradients (returns span
−360..100) out of the policy. Orthogonal initialisation as in PPO's reference implementations:
gain √2 in hidden layers, 0.01 for the policy head (near-uniform initial policy), 1 for the
value head. (A small CNN on the road window was tried: ~5× slower per step on CPU and it did
not learn to drive within the budget either.)

With ``recurrent`` ("lstm" or "gru") the actor-critic carries memory: a shared torso, a cell of
``memory_size`` units, linear actor and critic heads (the UED papers' student for partially
observed worlds: jaxued and minimax put a 256-unit LSTM after a small torso). Its call is
``(obs, memory, first) -> (logits, value, memory)``; memory is zeroed where ``first`` (the
observation starts an episode), so one scan over a segment that crosses episodes is exact.

``build_network(kind, config)`` rebuilds a module from its saved config (``policy.py``), so a
saved agent names its architecture instead of pickling it.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np

from worldagent.errors import WorldagentError

ACTIVATIONS = {"tanh": nn.tanh, "relu": nn.relu}


class MLP(nn.Module):
    """Hidden layers of ``features`` units with orthogonal(√2) init, then a linear head of ``out`` units."""

    features: Sequence[int]
    out: int
    head_scale: float = 1.0
    activation: str = "tanh"

    @nn.compact
    def __call__(self, x: jax.Array) -> jax.Array:
        act = ACTIVATIONS[self.activation]
        for width in self.features:
            x = act(nn.Dense(width, kernel_init=nn.initializers.orthogonal(np.sqrt(2.0)), bias_init=nn.initializers.zeros)(x))
        return nn.Dense(self.out, kernel_init=nn.initializers.orthogonal(self.head_scale), bias_init=nn.initializers.zeros)(x)


def quadratic_features(x: jax.Array) -> jax.Array:
    """f32[..., D + D(D+1)/2]: ``x`` and the products ``x_i x_j`` (i <= j) of its entries.

    Why: a policy that must choose among directions by how well each agrees with another input
    (racing's road rays against the position or the velocity) needs products of inputs. With
    them PPO on racing's rays went 0.33 → 0.49 of a lap per episode at 10,000 episodes
    (``docs/racing.md``).
    """
    i, j = np.triu_indices(x.shape[-1])
    return jnp.concatenate([x, x[..., i] * x[..., j]], axis=-1)


def check_flat_observation(shape: Sequence[int]) -> None:
    """PPO and ACKTR's actor-critic reads a flat observation f32[D]; refuse any other shape in one line."""
    if len(shape) != 1:
        raise WorldagentError(
            f"PPO and ACKTR need a flat observation (observation_shape (D,)); this env's is {tuple(shape)}: "
            "flatten it in the env's observe, or train with an algorithm that reads any shape (dqn)."
        )


CELLS = ("lstm", "gru")


def initial_memory(cell: str, size: int, batch: tuple[int, ...] = ()) -> jax.Array | tuple[jax.Array, jax.Array]:
    """Zero memory of a ``cell`` ("lstm": (c, h), each f32[*batch, size]; "gru": h f32[*batch, size])."""
    zeros = jnp.zeros((*batch, size), jnp.float32)
    return (zeros, zeros) if cell == "lstm" else zeros


class ActorCritic(nn.Module):
    """Categorical policy logits and a state value from a flat observation, with or without memory.

    Attributes:
        num_actions: A, the number of discrete actions.
        hidden: widths of the hidden layers of each torso (recurrent: of the one shared torso).
        activation: "tanh" or "relu".
        quadratic: the torsos read ``quadratic_features(obs)`` instead of ``obs`` (for short
            observations only: D inputs become D + D(D+1)/2).
        recurrent: None (memoryless: two MLPs), "lstm" or "gru" (see the module docstring).
        memory_size: M, units of the recurrent cell (ignored without ``recurrent``).
    """

    num_actions: int
    hidden: Sequence[int] = (128, 128)
    activation: str = "tanh"
    quadratic: bool = False
    recurrent: str | None = None
    memory_size: int = 256

    @nn.compact
    def __call__(self, obs: jax.Array, memory=None, first=None):
        """Memoryless: obs [..., D] (any dtype; cast to f32) -> (logits f32[..., A], value f32[...]).

        Recurrent: ``(obs [..., D], memory, first bool[...]) -> (logits, value, memory)`` with
        memory f32[..., M] (LSTM: a pair); ``memory=None`` is a fresh episode's.

        Initialise with one observation f32[D] (as PPO and ACKTR do): an observation of another
        shape is refused there, in one line, instead of failing later inside a trainer.
        """
        if self.is_initializing():
            check_flat_observation(obs.shape)
        x = obs.astype(jnp.float32)
        x = quadratic_features(x) if self.quadratic else x
        if self.recurrent is not None:
            return self._recurrent(x, memory, first)
        logits = MLP(tuple(self.hidden), self.num_actions, 0.01, self.activation, name="actor")(x)
        value = MLP(tuple(self.hidden), 1, 1.0, self.activation, name="critic")(x)
        return logits, value[..., 0]

    def _recurrent(self, x: jax.Array, memory, first):
        """Shared torso -> cell (memory zeroed where ``first``) -> linear heads."""
        if self.recurrent not in CELLS:
            raise WorldagentError(f"ActorCritic.recurrent={self.recurrent!r}; use one of {', '.join(CELLS)} (or None for no memory).")
        fresh = initial_memory(self.recurrent, self.memory_size, x.shape[:-1])
        if memory is None:
            memory = fresh
        elif first is not None:  # an episode starts here: forget the last one
            memory = jax.tree_util.tree_map(lambda zero, old: jnp.where(first[..., None], zero, old), fresh, memory)
        act = ACTIVATIONS[self.activation]
        for i, width in enumerate(self.hidden):
            x = act(nn.Dense(width, kernel_init=nn.initializers.orthogonal(np.sqrt(2.0)), name=f"torso_{i}")(x))
        cell = nn.OptimizedLSTMCell if self.recurrent == "lstm" else nn.GRUCell
        memory, y = cell(self.memory_size, name="cell")(memory, x)
        logits = nn.Dense(self.num_actions, kernel_init=nn.initializers.orthogonal(0.01), name="actor")(y)
        value = nn.Dense(1, kernel_init=nn.initializers.orthogonal(1.0), name="critic")(y)
        return logits, value[..., 0], memory


class QNetwork(nn.Module):
    """Action values from an observation of any shape (flattened): an MLP with a linear head.

    Attributes:
        num_actions: A.
        hidden: widths of the hidden layers.
        activation: "tanh" or "relu".
        obs_rank: number of trailing observation axes (flattened into one).
    """

    num_actions: int
    hidden: Sequence[int] = (128, 128)
    activation: str = "relu"
    obs_rank: int = 1

    @nn.compact
    def __call__(self, obs: jax.Array) -> jax.Array:
        """obs [..., *obs_shape] (``obs_rank`` trailing axes, flattened) -> q f32[..., A]."""
        x = obs.reshape(*obs.shape[: obs.ndim - self.obs_rank], -1).astype(jnp.float32)
        return MLP(tuple(self.hidden), self.num_actions, 1.0, self.activation)(x)


NETWORKS: dict[str, type[nn.Module]] = {"actor_critic": ActorCritic, "q_network": QNetwork}


def network_config(module: nn.Module) -> dict:
    """The JSON-able fields of ``module`` (what ``build_network`` needs to rebuild it)."""
    config = {}
    for field in dataclasses.fields(module):
        if field.name in ("parent", "name"):
            continue
        value = getattr(module, field.name)
        config[field.name] = list(value) if isinstance(value, (tuple, list)) else value
    return config


def build_network(kind: str, config: dict) -> nn.Module:
    """The module of architecture ``kind`` with the saved ``config``; unknown kinds or fields are refused."""
    if kind not in NETWORKS:
        raise WorldagentError(f"unknown network architecture {kind!r}; this worldagent knows: {', '.join(sorted(NETWORKS))}.")
    module = NETWORKS[kind]
    known = {f.name for f in dataclasses.fields(module)} - {"parent", "name"}
    unknown = set(config) - known
    if unknown:
        raise WorldagentError(f"network config for {kind!r} has unknown fields {sorted(unknown)}; it was saved by another version of worldagent.")
    return module(**{k: tuple(v) if isinstance(v, list) else v for k, v in config.items()})
