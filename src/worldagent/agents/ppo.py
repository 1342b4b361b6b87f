"""PPO (Schulman et al. 2017) for the racing agent, jitted end to end in the style of PureJaxRL.

The paper trains its racing agent with ACKTR for 10,000 episodes (§5.3); PPO is the modern
default, kept to the same budget: training stops once ``total_episodes`` episodes have ended,
so episodes, not env steps, are what is counted.

    trainer = make_train(config, env, env_params, distribution)
    state, curve = trainer.train(key)                       # the whole run, one jitted call
    states, curves = jax.vmap(trainer.train)(keys)          # several seeds at once

``train`` is ``init`` followed by ``train_chunk(state, max_updates)``; the host loop of
``training.train_racing`` calls ``train_chunk(state, n)`` instead, a few updates at a time, and
saves a checkpoint, the learning curve and the progress bar between chunks. Updates after the
budget is spent are skipped (``lax.cond``), so chunks may overshoot the budget harmlessly: the
result is the same however the run is chunked. The curve has one row per update, NaN on
updates that did not run (``curve["active"]`` is False there).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import optax
from flax import struct

from worldagent.agents.networks import ActorCritic
from worldagent.agents.rollouts import (
    EnvRunner,
    action_log_prob,
    collect,
    entropy,
    episode_summary,
    gae,
    init_runner,
)
from worldagent.configs import JsonConfig
from worldagent.errors import WorldagentError


@dataclass(frozen=True)
class PPOConfig(JsonConfig):
    """PPO settings; the defaults are the paper's racing budget (10,000 episodes).

    What the defaults reach (``benchmarks/train_racing.py``, 2 CPU cores): see the README's
    measured figures. Two choices make racing learnable at this budget (both in the env, see
    ``envs/racing/env.py``): the route sensor in the observation, and respawn-on-crash while
    training (``respawn``). Without them the agent parks before the first bend (a parked
    episode, −60, beats the −300 crashes that learning to corner costs) whatever else was tried
    (entropy 0.03, γ 0.995, centring shaping, a CNN on the window, penalty curricula).

    Attributes:
        total_episodes: training stops once this many episodes have ended (paper §5.3: 10,000).
        num_envs: B, envs stepped in parallel, each on its own world.
        num_steps: T, steps per env per update (an update learns from B·T steps).
        update_epochs: passes over each update's B·T steps.
        num_minibatches: minibatches per pass (each of B·T / num_minibatches steps).
        learning_rate: Adam step size at the start.
        anneal_lr: decay the step size linearly to 0 with the fraction of episodes done.
        gamma: discount factor.
        gae_lambda: GAE's lambda.
        clip_eps: PPO's ratio clip (also clips the value update).
        ent_coef: weight of the entropy bonus.
        vf_coef: weight of the value loss.
        max_grad_norm: global gradient-norm clip.
        reward_scale: rewards are multiplied by this for learning only (racing's returns span
            −360..100; 0.01 brings value targets near unit scale). Logged returns stay raw.
        clip_value: clip the value update to ``clip_eps`` around the old values.
        hidden: hidden layer widths of each actor-critic torso (see ``networks.py``).
        activation: "tanh" or "relu".
        respawn: train with ``RacingParams.respawn``: a crash costs its penalty and the agent
            carries on from the centreline, so every episode teaches up to 300 steps
            (evaluation keeps the paper's rule: a crash ends the episode).
    """

    total_episodes: int = 10_000
    num_envs: int = 16
    num_steps: int = 128
    update_epochs: int = 4
    num_minibatches: int = 4
    learning_rate: float = 3e-4
    anneal_lr: bool = True
    gamma: float = 0.99
    gae_lambda: float = 0.95
    clip_eps: float = 0.2
    ent_coef: float = 0.01
    vf_coef: float = 0.5
    max_grad_norm: float = 0.5
    reward_scale: float = 0.01
    clip_value: bool = False
    hidden: tuple[int, ...] = (128, 128)
    activation: str = "tanh"
    respawn: bool = True

    def __post_init__(self):
        for name in ("total_episodes", "num_envs", "num_steps", "update_epochs", "num_minibatches"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise WorldagentError(f"PPOConfig.{name}={value!r}; it must be a positive integer.")
        if (self.num_envs * self.num_steps) % self.num_minibatches:
            raise WorldagentError(
                f"num_envs·num_steps = {self.num_envs * self.num_steps} does not split into {self.num_minibatches} minibatches; "
                "pick num_minibatches dividing it."
            )
        for name in ("learning_rate", "clip_eps", "max_grad_norm", "reward_scale"):
            if not getattr(self, name) > 0:
                raise WorldagentError(f"PPOConfig.{name}={getattr(self, name)!r}; it must be positive.")
        for name in ("gamma", "gae_lambda"):
            if not 0.0 <= getattr(self, name) <= 1.0:
                raise WorldagentError(f"PPOConfig.{name}={getattr(self, name)!r}; it must be in [0, 1].")
        if self.ent_coef < 0 or self.vf_coef < 0:
            raise WorldagentError("PPOConfig.ent_coef and vf_coef must be non-negative.")
        if not self.hidden or any(not isinstance(w, int) or w < 1 for w in self.hidden):
            raise WorldagentError(f"PPOConfig.hidden={self.hidden!r}; give one or more positive layer widths.")
        if self.activation not in ("tanh", "relu"):
            raise WorldagentError(f"PPOConfig.activation={self.activation!r}; use 'tanh' or 'relu'.")
        object.__setattr__(self, "hidden", tuple(self.hidden))


@struct.dataclass
class TrainState:
    """Everything a run carries between updates (the checkpoint).

    Attributes:
        params: the actor-critic's parameters.
        opt_state: the optimiser's state (Adam for PPO, K-FAC for ACKTR).
        runner: the envs mid-episode (``rollouts.EnvRunner``).
        key: the run's PRNG key as raw u32 key data (kept so that a resumed run continues
            identically; raw so that msgpack can write it).
        update: i32 updates done.
        episodes: i32 episodes ended so far.
        env_steps: i32 env steps taken so far.
    """

    params: Any
    opt_state: Any
    runner: EnvRunner
    key: jax.Array
    update: jax.Array
    episodes: jax.Array
    env_steps: jax.Array


class Trainer(NamedTuple):
    """What ``make_train`` returns (all pure; ``train_chunk`` and ``train`` are jitted).

    Attributes:
        init: ``init(key) -> TrainState``.
        train_chunk: ``train_chunk(state, n) -> (state, curve)``, ``n`` updates (static); each
            ``curve`` entry is f32[n] (see ``CURVE_FIELDS``).
        train: ``train(key) -> (state, curve)``, the whole budget (``max_updates`` rows).
        network: the ``ActorCritic`` module.
        max_updates: updates that surely spend the budget (every env ends an episode at
            least every ``max_steps`` steps).
        done: ``done(state) -> bool``, the budget is spent.
    """

    init: Callable
    train_chunk: Callable
    train: Callable
    network: ActorCritic
    max_updates: int
    done: Callable


CURVE_FIELDS = (
    "active",
    "episodes",
    "env_steps",
    "return",
    "length",
    "crashed",
    "lap_completed",
    "progress",
    "policy_loss",
    "value_loss",
    "entropy",
    "approx_kl",
    "learning_rate",
)


def raw_key(key: jax.Array) -> jax.Array:
    """u32 key data (serialisable with msgpack) of a typed or raw PRNG key."""
    return jax.random.key_data(key) if jnp.issubdtype(key.dtype, jax.dtypes.prng_key) else key


def training_params(env_params, respawn: bool):
    """The env params a learner trains under: racing's respawn-on-crash set as configured."""
    return env_params.replace(respawn=respawn) if hasattr(env_params, "respawn") else env_params


def max_updates(total_episodes: int, num_envs: int, num_steps: int, max_episode_steps: int) -> int:
    """Updates after which ``total_episodes`` have surely ended (each env ends one every ``max_episode_steps``)."""
    return math.ceil(math.ceil(total_episodes / num_envs) * max_episode_steps / num_steps) + 1


def budgeted_trainer(init: Callable, update: Callable, total_episodes: int, budget: int, network: Any) -> Trainer:
    """A ``Trainer`` from ``init(key) -> state`` and ``update(state) -> (state, curve row)``.

    Updates run in jitted chunks (``lax.scan``); once ``total_episodes`` episodes have ended the
    remaining ones are skipped (their curve rows NaN, ``active`` 0), so a chunk may overshoot
    the budget harmlessly. ``budget`` is the number of updates ``train(key)`` scans.
    """

    def done(state) -> jax.Array:
        return state.episodes >= total_episodes

    def skip(state):
        return state, {k: jnp.float32(0.0 if k == "active" else jnp.nan) for k in CURVE_FIELDS}

    def guarded(state, _):
        return jax.lax.cond(done(state), skip, update, state)

    train_chunk = jax.jit(lambda state, n: jax.lax.scan(guarded, state, None, length=n), static_argnums=1)

    @jax.jit
    def train(key: jax.Array):
        return train_chunk(init(key), budget)

    return Trainer(init, train_chunk, train, network, budget, done)


def make_train(config: PPOConfig, env, env_params, distribution) -> Trainer:
    """PPO on ``env`` with each episode's world drawn from ``distribution``.

    Args:
        config: ``PPOConfig``.
        env: a single-agent env with flat observations (Particle Racing).
        env_params: its params (``env.default_params``); ``config.respawn`` overrides racing's respawn.
        distribution: a world distribution (``distributions.py``); it is closed over as a
            constant of the compiled program, so keep pools at dataset size (10,000 worlds).

    Returns:
        A ``Trainer``; ``train(key)`` is vmappable over keys (seeds).
    """
    if not isinstance(config, PPOConfig):
        raise WorldagentError(f"config is a {type(config).__name__}; pass a PPOConfig.")
    if getattr(env, "num_agents", 1) != 1:
        raise WorldagentError("PPO here trains single-agent envs (racing); use the independent DQN for harvest.")
    env_params = training_params(env_params, config.respawn)
    network = ActorCritic(
        env.num_actions,
        config.hidden,
        config.activation,
    )
    tx = optax.chain(optax.clip_by_global_norm(config.max_grad_norm), optax.scale_by_adam(eps=1e-5))
    batch = config.num_envs * config.num_steps
    minibatch = batch // config.num_minibatches
    horizon = int(env_params.max_steps)
    budget = max_updates(config.total_episodes, config.num_envs, config.num_steps, horizon)

    def init(key: jax.Array) -> TrainState:
        key_net, key_env, key_run = jax.random.split(key, 3)
        params = network.init(key_net, jnp.zeros(env.observation_shape, jnp.float32))
        runner = init_runner(key_env, env, env_params, distribution, config.num_envs)
        zero = jnp.int32(0)
        return TrainState(params, tx.init(params), runner, raw_key(key_run), zero, zero, zero)

    def loss_fn(params, batch_data, clip_eps):
        obs, action, old_log_prob, old_value, advantage, target = batch_data
        logits, value = network.apply(params, obs)
        log_prob = action_log_prob(logits, action)
        ratio = jnp.exp(log_prob - old_log_prob)
        advantage = (advantage - advantage.mean()) / (advantage.std() + 1e-8)
        policy_loss = -jnp.minimum(ratio * advantage, jnp.clip(ratio, 1 - clip_eps, 1 + clip_eps) * advantage).mean()
        value_clipped = old_value + jnp.clip(value - old_value, -clip_eps, clip_eps)
        value_loss = (value - target) ** 2
        if config.clip_value:
            value_loss = jnp.maximum(value_loss, (value_clipped - target) ** 2)
        value_loss = 0.5 * value_loss.mean()
        ent = entropy(logits).mean()
        total = policy_loss + config.vf_coef * value_loss - config.ent_coef * ent
        approx_kl = ((ratio - 1) - (log_prob - old_log_prob)).mean()
        return total, (policy_loss, value_loss, ent, approx_kl)

    def update(state: TrainState) -> tuple[TrainState, dict]:
        key, key_roll, key_perm = jax.random.split(jax.random.wrap_key_data(state.key), 3)
        runner, traj, (last_value, _) = collect(key_roll, state.runner, network.apply, state.params, env, env_params, distribution, config.num_steps)
        rewards = traj.reward * config.reward_scale
        advantages, targets = gae(rewards, traj.value, traj.done, last_value, config.gamma, config.gae_lambda)
        flat = lambda x: x.reshape(batch, *x.shape[2:])  # noqa: E731
        data = tuple(map(flat, (traj.obs, traj.action, traj.log_prob, traj.value, advantages, targets)))
        fraction = jnp.clip(state.episodes / config.total_episodes, 0.0, 1.0)
        lr = config.learning_rate * (1.0 - fraction) if config.anneal_lr else jnp.float32(config.learning_rate)

        def epoch(carry, key_epoch):
            params, opt_state = carry
            order = jax.random.permutation(key_epoch, batch).reshape(config.num_minibatches, minibatch)

            def minibatch_step(carry, index):
                params, opt_state = carry
                grads, aux = jax.grad(loss_fn, has_aux=True)(params, tuple(x[index] for x in data), config.clip_eps)
                updates, opt_state = tx.update(grads, opt_state, params)
                params = optax.apply_updates(params, jax.tree_util.tree_map(lambda u: -lr * u, updates))
                return (params, opt_state), aux

            return jax.lax.scan(minibatch_step, (params, opt_state), order)

        (params, opt_state), aux = jax.lax.scan(epoch, (state.params, state.opt_state), jax.random.split(key_perm, config.update_epochs))
        summary = episode_summary(traj)
        new_state = TrainState(
            params, opt_state, runner, raw_key(key), state.update + 1, state.episodes + summary["episodes"], state.env_steps + batch
        )
        policy_loss, value_loss, ent, approx_kl = (x.mean() for x in aux)
        row = {
            "active": jnp.float32(1.0),
            "episodes": new_state.episodes.astype(jnp.float32),
            "env_steps": new_state.env_steps.astype(jnp.float32),
            "return": summary["return"],
            "length": summary["length"],
            "crashed": summary.get("crashed", jnp.nan),
            "lap_completed": summary.get("lap_completed", jnp.nan),
            "progress": summary.get("progress", jnp.nan),
            "policy_loss": policy_loss,
            "value_loss": value_loss,
            "entropy": ent,
            "approx_kl": approx_kl,
            "learning_rate": jnp.float32(lr),
        }
        return new_state, {k: jnp.asarray(row[k], jnp.float32) for k in CURVE_FIELDS}

    return budgeted_trainer(init, update, config.total_episodes, budget, network)
