"""ACKTR (Wu et al. 2017, the paper's [21]) for the racing agent, jitted end to end (PureJaxRL style).

The paper trains its racing agent with "an existing PyTorch implementation of the ACKTR
algorithm with its default settings, training for 10,000 episodes" (§5.3): ikostrikov's
pytorch-a2c-ppo-acktr. ACKTR is A2C whose actor and critic are updated together by K-FAC
(``kfac.py``) with a KL trust-region step size. As there:

- loss = ``-mean(A·log π(a)) + vf_coef · mean(A²) - ent_coef · mean(H(π))`` with advantages
  ``A = R - V`` from n-step returns ``R`` (no GAE, no advantage normalisation);
- the Fisher is sampled: actions drawn from the policy itself and a value target ``V + ε``,
  ``ε ~ N(0, 1)``, as ``log π(ã) - (V - sg(V + ε))²`` (baselines' ``vf_fisher_coef`` = 1);
- no gradient clipping (ikostrikov clips only for A2C).

The trainer contract of ``trainer.py`` (``make_train(config, env, env_params, distribution) ->
Trainer``; the budget is counted in episodes), so the host driver ``training.train`` runs it.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import jax
import jax.numpy as jnp

from worldagent.agents.kfac import KFAC, KFACConfig
from worldagent.agents.networks import ActorCritic
from worldagent.agents.ppo import TrainState, single_agent_trainer, update_row
from worldagent.agents.rollouts import action_log_prob, collect, entropy, episode_summary, gae, init_runner, nstep_returns, score_segment
from worldagent.agents.trainer import Trainer, raw_key
from worldagent.configs import JsonConfig
from worldagent.curricula import is_robust
from worldagent.errors import WorldagentError


@dataclass(frozen=True)
class ACKTRConfig(JsonConfig):
    """ACKTR settings. Sources: ikostrikov = pytorch-a2c-ppo-acktr (the paper's implementation),
    baselines = OpenAI baselines ``acktr``. The defaults are theirs; an env declares its
    departures in its spec (``EnvSpec.training_settings``; ``--set`` on the CLI overrides both).
    Racing's ("racing" below; ``envs/racing/spec.py``) were changed from them to learn within the
    paper's budget on 2 CPU cores.

    Attributes:
        total_episodes: training stops once this many episodes have ended (paper §5.3: 10,000).
        num_envs: B, envs stepped in parallel, each on its own world [ikostrikov 16; racing 32].
        num_steps: T, steps per env per update, the n of the n-step returns [ikostrikov 5; racing 16].
        gamma: discount [ikostrikov, baselines 0.99].
        gae_lambda: 1.0 = plain n-step returns [ikostrikov use_gae=False]; below 1, GAE targets.
        ent_coef: entropy bonus weight [ikostrikov, baselines 0.01; racing 0.001: with its 0.01
            reward scale the bonus outweighed the rewards, entropy rose from 0.85 to 1.0 and the
            agent that lapped at 1,000 episodes had slowed to 0.8 laps in 300 steps by 10,000].
        vf_coef: value loss weight [ikostrikov value_loss_coef 0.5; baselines vf_coef 0.5].
        reward_scale: rewards are multiplied by this for learning only [1; ikostrikov normalises
            rewards of non-image envs by a running return std (VecNormalize); racing 0.01, as its
            returns span −360..100, puts value targets near unit scale].
        learning_rate: K-FAC's η_max [ikostrikov, baselines 0.25].
        anneal_lr: decay η_max linearly to 0 with the fraction of episodes done [baselines'
            lrschedule="linear"; ikostrikov: off by default].
        kl_clip: the trust-region radius δ [ikostrikov, baselines 0.001; racing 0.01: with 0.001
            the step was clipped on most updates and learning to stay on the road took ~4,000 of
            the 10,000 episodes at B·T = 512].
        momentum: K-FAC momentum [0.9].
        stat_decay: running-average decay of the Kronecker factors [ikostrikov 0.99].
        damping: K-FAC damping λ [ikostrikov 0.01].
        inverse_every: T_inv, updates between eigendecompositions of the factors [ikostrikov 10].
        hidden: hidden widths of each actor-critic torso (``networks.py``) [ours, as PPO's; ikostrikov 64, 64].
        activation: "tanh" [ikostrikov] or "relu".
        respawn: train with the env's respawn-on-failure, where its spec has one
            (``EnvSpec.training_params``) [off; racing on: without it early crashes end episodes
            after ~15 steps, the 10,000-episode budget buys ~150,000 steps and the agent parks].
        crash_warmup: fraction of the budget over which the env's training failure penalty ramps
            up from 0, where its spec has one (racing: the crash penalty) [0: off].
        quadratic: the networks read the observation and its pairwise products (``networks.py``).
    """

    total_episodes: int = 10_000
    num_envs: int = 16
    num_steps: int = 5
    gamma: float = 0.99
    gae_lambda: float = 1.0
    ent_coef: float = 0.01
    vf_coef: float = 0.5
    reward_scale: float = 1.0
    learning_rate: float = 0.25
    anneal_lr: bool = False
    kl_clip: float = 0.001
    momentum: float = 0.9
    stat_decay: float = 0.99
    damping: float = 0.01
    inverse_every: int = 10
    hidden: tuple[int, ...] = (128, 128)
    activation: str = "tanh"
    respawn: bool = False
    crash_warmup: float = 0.0
    quadratic: bool = False

    def __post_init__(self):
        for name in ("total_episodes", "num_envs", "num_steps", "inverse_every"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise WorldagentError(f"ACKTRConfig.{name}={value!r}; it must be a positive integer.")
        for name in ("reward_scale", "learning_rate", "kl_clip", "damping"):
            if not getattr(self, name) > 0:
                raise WorldagentError(f"ACKTRConfig.{name}={getattr(self, name)!r}; it must be positive.")
        for name in ("gamma", "gae_lambda"):
            if not 0.0 <= getattr(self, name) <= 1.0:
                raise WorldagentError(f"ACKTRConfig.{name}={getattr(self, name)!r}; it must be in [0, 1].")
        for name in ("momentum", "stat_decay"):
            if not 0.0 <= getattr(self, name) < 1.0:
                raise WorldagentError(f"ACKTRConfig.{name}={getattr(self, name)!r}; it must be in [0, 1).")
        if self.ent_coef < 0 or self.vf_coef < 0:
            raise WorldagentError("ACKTRConfig.ent_coef and vf_coef must be non-negative.")
        if not 0.0 <= self.crash_warmup <= 1.0:
            raise WorldagentError(f"ACKTRConfig.crash_warmup={self.crash_warmup!r}; it must be a fraction of the budget in [0, 1].")
        if not self.hidden or any(isinstance(w, bool) or not isinstance(w, int) or w < 1 for w in self.hidden):
            raise WorldagentError(f"ACKTRConfig.hidden={self.hidden!r}; give one or more positive layer widths.")
        if self.activation not in ("tanh", "relu"):
            raise WorldagentError(f"ACKTRConfig.activation={self.activation!r}; use 'tanh' or 'relu'.")
        object.__setattr__(self, "hidden", tuple(self.hidden))

    def kfac_config(self) -> KFACConfig:
        """The K-FAC optimiser's settings (exact damping, as ikostrikov)."""
        return KFACConfig(
            learning_rate=self.learning_rate, kl_clip=self.kl_clip, momentum=self.momentum,
            stat_decay=self.stat_decay, damping=self.damping, inverse_every=self.inverse_every,
        )  # fmt: skip


def make_train(config: ACKTRConfig, env, env_params, distribution, training_params=None) -> Trainer:
    """ACKTR on ``env`` with each episode's world drawn from ``distribution``.

    Args:
        config: ``ACKTRConfig``.
        env: a single-agent env with flat observations (e.g. Particle Racing).
        env_params: its params.
        distribution: a world distribution (``distributions.py``).
        training_params: the env's ``EnvSpec.training_params`` (see ``ppo.make_train``).

    Returns:
        A ``trainer.Trainer``. Curve rows are PPO's (``ppo.update_row``); for ACKTR
        ``learning_rate`` is the step size η the trust region allowed and ``approx_kl`` the KL it
        predicts, ``½ η² Δᵀ F̂ Δ``.
    """
    return single_agent_trainer("ACKTR", ACKTRConfig, _core, config, env, env_params, distribution, training_params)


@functools.lru_cache(maxsize=16)
def _core(config: ACKTRConfig, env, training_params):
    """``init(key, consts)``, ``update(state, consts)`` and the network; consts = (env_params, distribution).
    Cached, so trainers of the same config, env and ``training_params`` share their compilation."""
    network = ActorCritic(env.num_actions, config.hidden, config.activation, config.quadratic)
    kfac = KFAC(config.kfac_config(), network.apply)
    batch = config.num_envs * config.num_steps
    example_obs = jnp.zeros((batch, *env.observation_shape), jnp.float32)

    def init(key: jax.Array, consts) -> TrainState:
        params_env, distribution = consts
        key_net, key_env, key_run = jax.random.split(key, 3)
        params = network.init(key_net, jnp.zeros(env.observation_shape, jnp.float32))
        runner = init_runner(key_env, env, training_params(params_env, config, jnp.float32(0.0)), distribution, config.num_envs)
        zero = jnp.int32(0)
        return TrainState(params, kfac.init(params, example_obs), runner, raw_key(key_run), zero, zero, zero)

    def targets(traj, last_value):
        """f32[B·T] value targets: n-step returns, or GAE targets when ``gae_lambda < 1``."""
        rewards = traj.reward * config.reward_scale
        if config.gae_lambda < 1.0:
            return gae(rewards, traj.value, traj.done, last_value, config.gamma, config.gae_lambda)[1].reshape(batch)
        return nstep_returns(rewards, traj.done, last_value, config.gamma).reshape(batch)

    def update(state: TrainState, consts) -> tuple[TrainState, dict]:
        params_env, distribution = consts
        key, key_roll, key_fisher = jax.random.split(jax.random.wrap_key_data(state.key), 3)
        fraction = jnp.clip(state.episodes / config.total_episodes, 0.0, 1.0)
        params_env = training_params(params_env, config, fraction)
        runner, traj, last_value = collect(key_roll, state.runner, network.apply, state.params, env, params_env, distribution, config.num_steps)
        returns = targets(traj, last_value)
        runner, weights = score_segment(distribution, runner, traj, returns.reshape(traj.value.shape))
        weight = weights.reshape(batch) if is_robust(distribution) else None  # robust PLR: only replayed worlds' steps
        obs = traj.obs.reshape(batch, *traj.obs.shape[2:])
        action = traj.action.reshape(batch)

        mean = jnp.mean if weight is None else (lambda x: jnp.sum(weight * x) / jnp.maximum(weight.sum(), 1.0))  # noqa: E731

        def loss_fn(outputs):
            logits, value = outputs
            advantage = returns - value
            policy_loss = -mean(jax.lax.stop_gradient(advantage) * action_log_prob(logits, action))
            value_loss = mean(advantage**2)
            ent = mean(entropy(logits))
            return policy_loss + config.vf_coef * value_loss - config.ent_coef * ent, (policy_loss, value_loss, ent)

        def fisher_fn(outputs, key):
            logits, value = outputs
            key_action, key_value = jax.random.split(key)
            sampled = jax.random.categorical(key_action, jax.lax.stop_gradient(logits))
            target = jax.lax.stop_gradient(value + jax.random.normal(key_value, value.shape))
            return jnp.sum(action_log_prob(logits, sampled)) - jnp.sum((value - target) ** 2)

        _, (policy_loss, value_loss, ent), grads, stats = kfac.gradients(key_fisher, state.params, (obs,), loss_fn, fisher_fn)
        scale = (1.0 - fraction) if config.anneal_lr else jnp.float32(1.0)
        params, opt_state, info = kfac.update(
            jax.tree_util.tree_map(lambda g: scale * g, grads), stats, state.opt_state, state.params["params"]
        )  # annealing η_max ≡ scaling the gradient, as the trust region bounds the product
        summary = episode_summary(traj)
        new_state = TrainState(
            {**state.params, "params": params}, opt_state, runner, raw_key(key), state.update + 1,
            state.episodes + summary["episodes"], state.env_steps + batch,
        )  # fmt: skip
        kl = 0.5 * info["step_size"] ** 2 * info["fisher_quadratic"]
        row = update_row(
            new_state, summary, policy_loss=policy_loss, value_loss=value_loss, entropy=ent, approx_kl=kl, learning_rate=info["step_size"]
        )
        return new_state, row

    return init, update, network
