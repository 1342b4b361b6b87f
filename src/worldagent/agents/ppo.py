"""PPO (Schulman et al. 2017), jitted end to end in the style of PureJaxRL (``trainer.py``'s contract).

The paper trains its racing agent with ACKTR for 10,000 episodes (§5.3); PPO is the modern
default, kept to the same budget: training stops once ``total_episodes`` episodes have ended,
so episodes, not env steps, are what is counted.

    trainer = make_train(config, env, env_params, distribution)
    state, curve = trainer.train(key)                       # the whole run, one jitted call
    states, curves = jax.vmap(trainer.train)(keys)          # several seeds at once

With ``recurrent="lstm"`` (or "gru") the actor-critic carries memory (``networks.ActorCritic``):
the runner holds each env's memory, the rollout resets it where an episode starts, and the learner
replays each env's whole segment through the cell from the memory it began with (minibatches of
envs, as PureJaxRL's recurrent PPO and jaxued's students).

The host driver (``training.train``) calls ``train_chunk(state, n)`` a few updates at a time.
The curve has one row per update: the training statistics and the mean of every per-episode
entry of the env's step ``info`` over the episodes that ended (racing: crashed, lap_completed,
progress), whatever the env reports.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from typing import Any

import jax
import jax.numpy as jnp
import optax
from flax import struct

from worldagent.agents.networks import CELLS, ActorCritic, initial_memory
from worldagent.agents.rollouts import EnvRunner, action_log_prob, collect, entropy, episode_summary, gae, init_runner, score_segment
from worldagent.agents.trainer import Trainer, budgeted_trainer, curve_row, raw_key
from worldagent.configs import JsonConfig
from worldagent.curricula import is_robust
from worldagent.errors import WorldagentError


@dataclass(frozen=True)
class PPOConfig(JsonConfig):
    """PPO settings. The defaults are PPO's usual ones (Schulman et al. 2017, PureJaxRL's), with
    the paper's budget of 10,000 episodes: rewards unscaled, no respawn, no warm-up. An env
    declares its departures in its spec (``EnvSpec.training_settings``; ``--set`` on the CLI
    overrides both). Racing's (``envs/racing/spec.py``) are ``reward_scale=0.01`` and
    ``respawn``, and without the route sensor ``crash_warmup`` and ``quadratic``
    (``docs/racing.md``): without respawn the agent parks before the first bend (a parked
    episode, −60, beats the −300 crashes that learning to corner costs) whatever else was tried
    (entropy 0.03, γ 0.995, centring shaping, a CNN on the window, penalty curricula).

    Attributes:
        total_episodes: training stops once this many episodes have ended (paper §5.3: 10,000).
        total_env_steps: when > 0, training also stops once this many env steps are taken,
            whichever budget is spent first (a step budget compares runs with other code bases,
            e.g. jaxued's; 0: episodes only). Both count toward the learning-rate anneal.
        num_envs: B, envs stepped in parallel, each on its own world.
        num_steps: T, steps per env per update (an update learns from B·T steps).
        update_epochs: passes over each update's B·T steps.
        num_minibatches: minibatches per pass (each of B·T / num_minibatches steps).
        learning_rate: Adam step size at the start.
        anneal_lr: decay the step size linearly to 0 with the fraction of the budget spent.
        gamma: discount factor.
        gae_lambda: GAE's lambda.
        clip_eps: PPO's ratio clip (also clips the value update).
        ent_coef: weight of the entropy bonus.
        vf_coef: weight of the value loss.
        max_grad_norm: global gradient-norm clip.
        reward_scale: rewards are multiplied by this for learning only (racing: 0.01, as its
            returns span −360..100). Logged returns stay raw.
        clip_value: clip the value update to ``clip_eps`` around the old values.
        hidden: hidden layer widths of each actor-critic torso (see ``networks.py``).
        activation: "tanh" or "relu".
        respawn: train with the env's respawn-on-failure, where its spec has one
            (``EnvSpec.training_params``; racing: a crash costs its penalty and the agent carries
            on from the centreline, so every episode teaches up to 300 steps). Evaluation keeps
            the paper's rule: a crash ends the episode.
        crash_warmup: fraction of the episode budget over which the env's training failure
            penalty ramps linearly from 0 to its value, where its spec has one (racing: the crash
            penalty); 0: the full penalty from the start. Evaluation always pays the full penalty.
        quadratic: the networks read the observation and its pairwise products (``networks.py``).
        recurrent: None (an MLP, memoryless), "lstm" or "gru": the actor-critic carries memory
            (``networks.ActorCritic``), for worlds the agent sees only in part. The learner then
            replays whole segments through the cell from the memory each began with, so
            minibatches are sets of envs (``num_minibatches`` must divide ``num_envs``) and
            ``hidden`` is the one torso before the cell.
        memory_size: M, units of the recurrent cell (jaxued's and minimax's student: 256).
    """

    total_episodes: int = 10_000
    total_env_steps: int = 0
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
    reward_scale: float = 1.0
    clip_value: bool = False
    hidden: tuple[int, ...] = (128, 128)
    activation: str = "tanh"
    respawn: bool = False
    crash_warmup: float = 0.0
    quadratic: bool = False
    recurrent: str | None = None
    memory_size: int = 256

    def __post_init__(self):
        for name in ("total_episodes", "num_envs", "num_steps", "update_epochs", "num_minibatches", "memory_size"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise WorldagentError(f"PPOConfig.{name}={value!r}; it must be a positive integer.")
        if isinstance(self.total_env_steps, bool) or not isinstance(self.total_env_steps, int) or self.total_env_steps < 0:
            raise WorldagentError(f"PPOConfig.total_env_steps={self.total_env_steps!r}; it must be a whole number of env steps (0: no step budget).")
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
        if not 0.0 <= self.crash_warmup <= 1.0:
            raise WorldagentError(f"PPOConfig.crash_warmup={self.crash_warmup!r}; it must be a fraction of the budget in [0, 1].")
        if not self.hidden or any(not isinstance(w, int) or w < 1 for w in self.hidden):
            raise WorldagentError(f"PPOConfig.hidden={self.hidden!r}; give one or more positive layer widths.")
        if self.activation not in ("tanh", "relu"):
            raise WorldagentError(f"PPOConfig.activation={self.activation!r}; use 'tanh' or 'relu'.")
        object.__setattr__(self, "hidden", tuple(self.hidden))
        self._check_recurrent()

    def _check_recurrent(self) -> None:
        """``recurrent`` names a cell, and minibatches split the envs (sequences are not cut)."""
        if self.recurrent not in (None, *CELLS):
            raise WorldagentError(f"PPOConfig.recurrent={self.recurrent!r}; use {' or '.join(CELLS)} (or none for a memoryless MLP).")
        if self.recurrent and self.num_envs % self.num_minibatches:
            raise WorldagentError(
                f"recurrent PPO splits its {self.num_envs} envs into {self.num_minibatches} minibatches of whole sequences; "
                "pick num_minibatches dividing num_envs."
            )


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


def unchanged_params(env_params, config, fraction):
    """The ``training_params`` of an env whose spec declares none: its params as they are."""
    del config, fraction
    return env_params


def budget_fraction(state, config) -> jax.Array:
    """f32 in [0, 1]: the share of the run's budget spent (episodes, or env steps where that budget is set and further along)."""
    fraction = state.episodes / config.total_episodes
    steps = getattr(config, "total_env_steps", 0)
    if steps:
        fraction = jnp.maximum(fraction, state.env_steps / steps)
    return jnp.clip(fraction, 0.0, 1.0)


def max_updates(total_episodes: int, num_envs: int, num_steps: int, max_episode_steps: int) -> int:
    """Updates after which ``total_episodes`` have surely ended (each env ends one every ``max_episode_steps``)."""
    return math.ceil(math.ceil(total_episodes / num_envs) * max_episode_steps / num_steps) + 1


def update_row(state: TrainState, summary: dict, **stats) -> dict:
    """One curve row: progress, the episodes' means (``episode_summary`` less its count) and ``stats``."""
    episodes = {name: value for name, value in summary.items() if name != "episodes"}
    return curve_row({"active": 1.0, "episodes": state.episodes, "env_steps": state.env_steps, **episodes, **stats})


def make_train(config: PPOConfig, env, env_params, distribution, training_params=None) -> Trainer:
    """PPO on ``env`` with each episode's world drawn from ``distribution``.

    Args:
        config: ``PPOConfig``.
        env: a single-agent env with flat observations (e.g. Particle Racing).
        env_params: its params.
        distribution: a world distribution (``distributions.py``), passed to the jitted
            functions as an argument.
        training_params: the env's ``EnvSpec.training_params``, ``(params, config, fraction) ->
            params`` applied on every update (where ``respawn`` and ``crash_warmup`` take
            effect); None: ``env_params`` as they are.

    Returns:
        A ``trainer.Trainer``; ``train(key)`` is vmappable over keys (seeds).
    """
    return single_agent_trainer("PPO", PPOConfig, _core, config, env, env_params, distribution, training_params)


def single_agent_trainer(name: str, config_type: type, core, config, env, env_params, distribution, training_params=None) -> Trainer:
    """The ``Trainer`` of an actor-critic (PPO, ACKTR) whose ``core(config, env, training_params)``
    gives ``(init, update, network)``: checks the config and the env and budgets updates."""
    if not isinstance(config, config_type):
        raise WorldagentError(f"config is a {type(config).__name__}; {name} takes its {config_type.__name__}.")
    if getattr(env, "num_agents", 1) != 1:
        raise WorldagentError(f"{name} trains single-agent envs; this env has {env.num_agents} agents: use an algorithm for several (dqn).")
    budget = max_updates(config.total_episodes, config.num_envs, config.num_steps, int(env_params.max_steps))
    steps = getattr(config, "total_env_steps", 0)
    if steps:
        budget = min(budget, math.ceil(steps / (config.num_envs * config.num_steps)))
    init, update, network = core(config, env, training_params or unchanged_params)
    return budgeted_trainer(init, update, config.total_episodes, budget, network, (env_params, distribution), total_env_steps=steps)


@functools.lru_cache(maxsize=16)
def _core(config: PPOConfig, env, training_params):
    """``init(key, consts)``, ``update(state, consts)`` and the network; consts = (env_params, distribution).
    Cached, so trainers of the same config, env and ``training_params`` share their compilation."""
    network = ActorCritic(env.num_actions, config.hidden, config.activation, config.quadratic, config.recurrent, config.memory_size)
    tx = optax.chain(optax.clip_by_global_norm(config.max_grad_norm), optax.scale_by_adam(eps=1e-5))
    batch = config.num_envs * config.num_steps
    # a minibatch: steps of the flattened segment (MLP), or whole sequences of some envs (recurrent)
    rows = config.num_envs if config.recurrent else batch
    forward, learner_data = (_sequence_forward(network), _sequences) if config.recurrent else (network.apply, _steps)

    def init(key: jax.Array, consts) -> TrainState:
        params_env, distribution = consts
        key_net, key_env, key_run = jax.random.split(key, 3)
        params = network.init(key_net, jnp.zeros(env.observation_shape, jnp.float32))
        runner = init_runner(key_env, env, training_params(params_env, config, jnp.float32(0.0)), distribution, config.num_envs)
        if config.recurrent:
            runner = runner.replace(memory=initial_memory(config.recurrent, config.memory_size, (config.num_envs,)))
        zero = jnp.int32(0)
        return TrainState(params, tx.init(params), runner, raw_key(key_run), zero, zero, zero)

    def loss_fn(params, batch_data):
        inputs, action, old_log_prob, old_value, advantage, target, *weight = batch_data  # weight: robust PLR's
        mean = (lambda x: x.mean()) if not weight else (lambda x: jnp.sum(weight[0] * x) / jnp.maximum(weight[0].sum(), 1.0))  # noqa: E731
        logits, value = forward(params, inputs)
        log_prob = action_log_prob(logits, action)
        ratio = jnp.exp(log_prob - old_log_prob)
        centred = advantage - mean(advantage)
        advantage = centred / (jnp.sqrt(mean(centred**2)) + 1e-8) if weight else centred / (advantage.std() + 1e-8)
        clip = config.clip_eps
        policy_loss = -mean(jnp.minimum(ratio * advantage, jnp.clip(ratio, 1 - clip, 1 + clip) * advantage))
        value_loss = (value - target) ** 2
        if config.clip_value:
            value_loss = jnp.maximum(value_loss, (old_value + jnp.clip(value - old_value, -clip, clip) - target) ** 2)
        value_loss = 0.5 * mean(value_loss)
        ent = mean(entropy(logits))
        total = policy_loss + config.vf_coef * value_loss - config.ent_coef * ent
        approx_kl = mean((ratio - 1) - (log_prob - old_log_prob))
        return total, (policy_loss, value_loss, ent, approx_kl)

    def learn(params, opt_state, data, lr, key):
        """``update_epochs`` passes of minibatch Adam steps over one update's data."""

        def epoch(carry, key_epoch):
            order = jax.random.permutation(key_epoch, rows).reshape(config.num_minibatches, rows // config.num_minibatches)

            def minibatch_step(carry, index):
                params, opt_state = carry
                grads, aux = jax.grad(loss_fn, has_aux=True)(params, jax.tree_util.tree_map(lambda x: x[index], data))
                updates, opt_state = tx.update(grads, opt_state, params)
                params = optax.apply_updates(params, jax.tree_util.tree_map(lambda u: -lr * u, updates))
                return (params, opt_state), aux

            return jax.lax.scan(minibatch_step, carry, order)

        return jax.lax.scan(epoch, (params, opt_state), jax.random.split(key, config.update_epochs))

    def update(state: TrainState, consts) -> tuple[TrainState, dict]:
        params_env, distribution = consts
        key, key_roll, key_perm = jax.random.split(jax.random.wrap_key_data(state.key), 3)
        fraction = budget_fraction(state, config)
        params_env = training_params(params_env, config, fraction)
        runner, traj, last_value = collect(key_roll, state.runner, network.apply, state.params, env, params_env, distribution, config.num_steps)
        advantages, targets = gae(traj.reward * config.reward_scale, traj.value, traj.done, last_value, config.gamma, config.gae_lambda)
        runner, weights = score_segment(distribution, runner, traj, targets)
        per_step = (traj.action, traj.log_prob, traj.value, advantages, targets) + ((weights,) if is_robust(distribution) else ())
        data = learner_data(state.runner, traj, per_step)
        lr = config.learning_rate * (1.0 - fraction) if config.anneal_lr else jnp.float32(config.learning_rate)
        (params, opt_state), aux = learn(state.params, state.opt_state, data, lr, key_perm)
        summary = episode_summary(traj)
        new_state = TrainState(
            params, opt_state, runner, raw_key(key), state.update + 1, state.episodes + summary["episodes"], state.env_steps + batch
        )
        policy_loss, value_loss, ent, approx_kl = (x.mean() for x in aux)
        row = update_row(new_state, summary, policy_loss=policy_loss, value_loss=value_loss, entropy=ent, approx_kl=approx_kl, learning_rate=lr)
        return new_state, row

    return init, update, network


def _steps(runner: EnvRunner, traj, per_step: tuple) -> tuple:
    """The MLP learner's data: the segment's B·T steps, flattened (minibatches of steps)."""
    del runner
    flat = lambda x: x.reshape(-1, *x.shape[2:])  # noqa: E731
    return tuple(map(flat, (traj.obs, *per_step)))


def _sequences(runner: EnvRunner, traj, per_step: tuple) -> tuple:
    """The recurrent learner's data, env-major [B, T, ...] (minibatches of envs): the inputs
    (obs, first, the memory each env began the segment with) and the per-step arrays."""
    first = jnp.concatenate([(runner.episode_length == 0)[None], traj.done[:-1]])  # obs t starts an episode
    env_major = lambda x: jnp.swapaxes(x, 0, 1)  # noqa: E731
    return ((env_major(traj.obs), env_major(first), runner.memory), *map(env_major, per_step))


def _sequence_forward(network):
    """``forward(params, (obs [b, T, D], first bool[b, T], memory [b, ...])) -> (logits [b, T, A],
    value [b, T])``: the segment replayed through the cell as the rollout played it."""

    def forward(params, inputs):
        obs, first, memory = inputs

        def one_step(memory, step):
            logits, value, memory = network.apply(params, step[0], memory, step[1])
            return memory, (logits, value)

        _, (logits, value) = jax.lax.scan(one_step, memory, (jnp.swapaxes(obs, 0, 1), jnp.swapaxes(first, 0, 1)))
        return jnp.swapaxes(logits, 0, 1), jnp.swapaxes(value, 0, 1)

    return forward
