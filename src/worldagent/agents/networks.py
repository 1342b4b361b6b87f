"""Networks of the agents (Flax linen, pure ``init``/``apply``), and how to rebuild them from a config.

``ActorCritic`` is the racing agent of PPO and ACKTR: two separate MLP torsos (actor, critic)
on the flat observation f32[260] (16×16 road window, position, velocity / top speed).

Sizes and why: two hidden layers of 128 units, tanh. The paper's agent (pytorch-a2c-ppo-acktr's
ACKTR with defaults, §5.3) uses an MLP of two 64-unit tanh layers for flat observations; the
256 road pixels here are a larger input than that default was tuned for, so the torsos are
twice as wide. Separate torsos keep value-loss gradients (returns span −360..100) out of the
policy. Orthogonal initialisation as in PPO's reference implementations: gain √2 in hidden
layers, 0.01 for the policy head (near-uniform initial policy), 1 for the value head.
``window > 0`` puts a small CNN (``WindowEncoder``) on the road window first; it was tried and
is ~5× slower per step on CPU without learning to drive within the budget either (see
``ppo.py``), so the default is the MLP.

``build_network(kind, config)`` rebuilds a module from its saved config (``policy.py``), so a
saved agent names its architecture instead of pickling it.
"""

from __future__ import annotations

import dataclasses
from typing import Sequence

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


class WindowEncoder(nn.Module):
    """Racing's flat observation [..., W·W + 4] -> features: two strided 3×3 convs on the W×W road
    window (16 and 32 channels, relu), flattened, concatenated with the 4 position/velocity values."""

    window: int = 16

    @nn.compact
    def __call__(self, obs: jax.Array) -> jax.Array:
        cells = self.window * self.window
        batch = obs.shape[:-1]
        image = obs[..., :cells].reshape(-1, self.window, self.window, 1)
        for channels in (16, 32):
            image = nn.relu(nn.Conv(channels, (3, 3), strides=(2, 2), kernel_init=nn.initializers.orthogonal(np.sqrt(2.0)))(image))
        features = image.reshape(*batch, -1)
        return jnp.concatenate([features, obs[..., cells:]], axis=-1)


class ActorCritic(nn.Module):
    """Categorical policy logits and a state value from a flat observation.

    Attributes:
        num_actions: A, the number of discrete actions.
        hidden: widths of the hidden layers of each torso.
        activation: "tanh" or "relu".
        window: 0: the torsos read the flat observation; W > 0: each torso first encodes the
            W×W road window of racing's observation with a small CNN (``WindowEncoder``).
    """

    num_actions: int
    hidden: Sequence[int] = (128, 128)
    activation: str = "tanh"
    window: int = 0

    @nn.compact
    def __call__(self, obs: jax.Array) -> tuple[jax.Array, jax.Array]:
        """obs [..., D] (any dtype; cast to f32) -> (logits f32[..., A], value f32[...])."""
        x = obs.astype(jnp.float32)
        if self.window:
            x_actor = WindowEncoder(self.window, name="actor_encoder")(x)
            x_critic = WindowEncoder(self.window, name="critic_encoder")(x)
            logits = MLP(tuple(self.hidden), self.num_actions, 0.01, self.activation, name="actor")(x_actor)
            value = MLP(tuple(self.hidden), 1, 1.0, self.activation, name="critic")(x_critic)
            return logits, value[..., 0]
        logits = MLP(tuple(self.hidden), self.num_actions, 0.01, self.activation, name="actor")(x)
        value = MLP(tuple(self.hidden), 1, 1.0, self.activation, name="critic")(x)
        return logits, value[..., 0]


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


def register_network(kind: str, module: type[nn.Module]) -> None:
    """Make ``module`` (a linen dataclass of JSON-able fields) loadable by ``kind`` (e.g. a DQN's conv net)."""
    NETWORKS[kind] = module


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
