"""Independent DQN for multi-agent envs such as Resource Harvest (paper §5.3; §6.2.2 with agent 0 able to TAG).

"Independent learning with each agent separately learning using its own Deep Q-Network ...
the same settings as [Perolat et al. 2017] ... 5,000 episodes" (§5.3). Each of the four agents
has its own Q-network, target network, Adam state and replay buffer; they share no parameters
and no data. All ``N = env.num_agents`` are stacked on a leading agent axis and updated by one
``vmap``; ``E`` envs run in parallel (``vmap``). The trainer contract is ``trainer.py``'s
(``make_train(config, env, env_params, distribution) -> Trainer``); one update is one episode
of every env (a "chunk" of ``env_params.max_steps`` vector steps), after which every env
restarts on a world drawn from the distribution. The env's episodes must end exactly at its
step limit (harvest's do): the chunk is the episode.

Every hyper-parameter of ``DQNConfig`` says where it comes from. Perolat et al. (2017) give
the agents' Q-network as a small MLP and otherwise defer to the DQN of Mnih et al. (2015) and
the settings of Leibo et al. (2017); values marked "ours" are not from those papers. Deviations
forced by the budget (5,000 x 1,000-step episodes = 20M agent-steps in <= 60 min on 2 CPU
cores): ``num_envs`` episodes run side by side, one gradient step per agent per vector step
(``train_every``) with a correspondingly larger minibatch, and a replay buffer of 100,000
transitions per agent (bit-packed, ``replay.py``).

Episode ends: harvest episodes end only by the time limit, which the agents cannot observe;
the last transition of an episode is treated as terminal (no bootstrap), as in PureJaxRL and
``rollouts.py``: one transition in 1,000. Observations are 0/1 planes (uint8, planes last,
at most 8), which the replay buffer stores bit-packed.
"""

from __future__ import annotations

import dataclasses
import functools
from typing import Any, ClassVar

import jax
import jax.numpy as jnp
import optax
from flax import struct

from worldagent.agents import replay as replay_lib
from worldagent.agents.networks import QNetwork
from worldagent.agents.trainer import Trainer, budgeted_trainer, curve_row, raw_key
from worldagent.configs import JsonConfig
from worldagent.curricula import as_curriculum, is_robust
from worldagent.errors import WorldagentError


@dataclasses.dataclass(frozen=True)
class DQNConfig(JsonConfig):
    """Settings of an independent-DQN run (sources in brackets). The env (window, episode length =
    ``env_params.max_steps``, who may TAG) comes from the env and its options, not from here.

    Values marked † are from the cited papers as we recall them; their text was not at hand
    to check when this was written (the one second-hand confirmation: Perolat's agents used an
    MLP, not a CNN).

    Attributes:
        num_episodes: training episodes per agent [paper §5.3: 5,000]; rounded up to a
            multiple of ``num_envs``.
        num_envs: episodes played side by side [ours: parallelism for the time budget].
        hidden_sizes: widths of the Q-network's hidden layers (ReLU, fully connected on the
            flattened window) [Perolat et al. 2017 / Leibo et al. 2017: an MLP, two hidden
            layers of 32 units †].
        gamma: discount [Mnih et al. 2015: 0.99; Perolat et al. 2017 †].
        learning_rate: Adam step size [ours: 5e-4, untuned; Adam (Kingma & Ba 2015) in place
            of the RMSProp of Mnih et al. 2015].
        max_grad_norm: global gradient-norm clip [ours: 10, as Huber loss bounds the error
            gradient in Mnih et al. 2015].
        batch_size: minibatch per agent and update [ours: 128 = Mnih's 32 x 4, since one update
            is taken per vector step of ``num_envs`` transitions instead of one per 4].
        buffer_size: transitions in each agent's replay buffer [ours: 100,000; Mnih et al.
            2015 used 1M frames, a fifth of this run's 5M per agent].
        learning_starts: transitions per agent before the first update [ours: 10,000].
        train_every: vector steps between gradient updates [ours: 1].
        target_update_every: gradient updates between target-network copies [ours: 500,
            i.e. 20,000 env transitions per agent at 40 envs; Mnih et al. 2015: 10,000].
        epsilon_start, epsilon_end: epsilon-greedy exploration, decayed linearly [Leibo et al.
            2017 / Perolat et al. 2017: 1.0 to 0.1 †].
        epsilon_decay_episodes: episodes over which epsilon decays [ours: 1,000, the first 20% of
            the paper's 5,000; Mnih et al. 2015 decay over the first 1M of 50M frames]. None:
            ``epsilon_decay_fraction`` of the budget instead.
        epsilon_decay_fraction: with ``epsilon_decay_episodes=None``, the share of ``num_episodes``
            over which epsilon decays, as Stable-Baselines3's DQN ``exploration_fraction``
            [ours: 0.2]. Not the default: at the quick preset's 1,000 episodes, a 200-episode
            decay left the agents weaker (group reward on random G(z) worlds 71-101 against
            126-132 with the 1,000-episode decay; docs/harvest.md, the quick preset).
        double_q: use double-DQN targets [off: Perolat used DQN].
        act_epsilon: exploration of the trained agents when they act (saved with the agents)
            [ours: 0.1 = ``epsilon_end``, the agents as they acted at the end of training and as
            their learning curve measures them. Memoryless greedy agents under partial
            observation get stuck where no apple is in view; measured at the paper's budget
            with agent 0 tagging (benchmarks/results/train_harvest-tagger0-cpu.json), group
            reward / random: greedy 0.62, epsilon 0.05 (Mnih et al. 2015's evaluation) 2.07, 0.1 2.66].
    """

    budget_field: ClassVar[str] = "num_episodes"
    chunk_updates: ClassVar[int] = 1  # one episode of every env between checkpoints

    num_episodes: int = 5000
    num_envs: int = 40
    hidden_sizes: tuple[int, ...] = (32, 32)
    gamma: float = 0.99
    learning_rate: float = 5e-4
    max_grad_norm: float = 10.0
    batch_size: int = 128
    buffer_size: int = 100_000
    learning_starts: int = 10_000
    train_every: int = 1
    target_update_every: int = 500
    epsilon_start: float = 1.0
    epsilon_end: float = 0.1
    epsilon_decay_episodes: int | None = 1000
    epsilon_decay_fraction: float = 0.2
    double_q: bool = False
    act_epsilon: float = 0.1

    def __post_init__(self):
        object.__setattr__(self, "hidden_sizes", tuple(self.hidden_sizes))
        for name in ("num_episodes", "num_envs", "batch_size", "buffer_size", "train_every", "target_update_every"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise WorldagentError(f"DQNConfig.{name}={value!r}; give a positive integer.")
        if not self.hidden_sizes or any(isinstance(h, bool) or not isinstance(h, int) or h < 1 for h in self.hidden_sizes):
            raise WorldagentError(f"DQNConfig.hidden_sizes={self.hidden_sizes!r}; give positive layer widths, e.g. (32, 32).")
        if not 0.0 <= self.gamma < 1.0:
            raise WorldagentError(f"DQNConfig.gamma={self.gamma}; pick a discount in [0, 1).")
        if not self.learning_rate > 0 or not self.max_grad_norm > 0:
            raise WorldagentError("DQNConfig.learning_rate and max_grad_norm must be positive.")
        if not 0.0 <= self.act_epsilon <= 1.0:
            raise WorldagentError(f"DQNConfig.act_epsilon={self.act_epsilon}; pick a probability in [0, 1].")
        decay = self.epsilon_decay_episodes
        if (
            not 0.0 <= self.epsilon_end <= self.epsilon_start <= 1.0
            or not 0.0 <= self.epsilon_decay_fraction <= 1.0
            or (decay is not None and decay < 0)
        ):
            raise WorldagentError(
                "DQNConfig: exploration needs 0 <= epsilon_end <= epsilon_start <= 1, epsilon_decay_fraction in [0, 1] and epsilon_decay_episodes >= 0."
            )
        if self.learning_starts < 0 or self.buffer_size < 2 * self.num_envs:
            raise WorldagentError(
                f"DQNConfig.buffer_size ({self.buffer_size}) must hold at least two steps of {self.num_envs} envs and learning_starts be >= 0."
            )

    @property
    def num_chunks(self) -> int:
        """Chunks of ``num_envs`` parallel episodes: ceil(num_episodes / num_envs)."""
        return -(-self.num_episodes // self.num_envs)

    @property
    def decay_episodes(self) -> int:
        """Episodes over which epsilon decays: ``epsilon_decay_episodes``, else that share of the budget."""
        if self.epsilon_decay_episodes is not None:
            return self.epsilon_decay_episodes
        return round(self.epsilon_decay_fraction * self.num_episodes)

    @property
    def buffer_slices(self) -> int:
        """Time slices of the ring buffer (each holds ``num_envs`` transitions per agent)."""
        return max(2, self.buffer_size // self.num_envs)


def q_network(config: DQNConfig, env) -> QNetwork:
    """One agent's Q-network: an MLP with ReLUs on its flattened observation -> f32[..., A]."""
    return QNetwork(num_actions=env.num_actions, hidden=config.hidden_sizes, activation="relu", obs_rank=len(env.observation_shape))


def init_params(key: jax.Array, config: DQNConfig, env) -> Any:
    """The N agents' Q-network parameters, stacked on a leading agent axis [N, ...]."""
    dummy = jnp.zeros(env.observation_shape, jnp.uint8)
    return jax.vmap(q_network(config, env).init, in_axes=(0, None))(jax.random.split(key, env.num_agents), dummy)


def q_values(network: QNetwork, params: Any, obs: jax.Array) -> jax.Array:
    """f32[..., N, A]: each agent's Q-values from its own network, for obs [..., N, *O]."""
    lead = obs.ndim - network.obs_rank - 1  # batch axes before the agent axis
    moved = jnp.moveaxis(obs, lead, 0)  # [N, ..., *O]
    return jnp.moveaxis(jax.vmap(network.apply)(params, moved), 0, lead)


def epsilon_greedy(key: jax.Array, q: jax.Array, epsilon: jax.Array) -> jax.Array:
    """i32[...]: argmax of q f32[..., A], replaced by a uniform action with probability epsilon."""
    key_explore, key_action = jax.random.split(key)
    random_action = jax.random.randint(key_action, q.shape[:-1], 0, q.shape[-1], dtype=jnp.int32)
    explore = jax.random.uniform(key_explore, q.shape[:-1]) < epsilon
    return jnp.where(explore, random_action, jnp.argmax(q, axis=-1).astype(jnp.int32))


def epsilon_at(config: DQNConfig, step: jax.Array, episode_length: int) -> jax.Array:
    """f32 exploration rate after ``step`` vector steps (linear decay, then constant)."""
    decay_steps = max(1, config.decay_episodes * episode_length // config.num_envs)
    fraction = jnp.clip(step / decay_steps, 0.0, 1.0)
    return config.epsilon_start + fraction * (config.epsilon_end - config.epsilon_start)


@struct.dataclass
class DQNState:
    """Everything a run carries between chunks (the checkpoint).

    Attributes:
        params, target_params: the agents' Q-network and target parameters, stacked [N, ...].
        opt_state: their Adam states, stacked [N, ...].
        replay: the N replay buffers (``replay.Replay``, agent axis 2).
        env_state: the env state batched [E].
        obs: [E, N, *O] the current observations.
        key: the run's PRNG key as raw u32 key data (a resumed run continues identically).
        update: i32 chunks done (one episode of every env each).
        episodes: i32 episodes ended (per agent); env_steps: i32 env steps taken.
        steps: i32 vector steps taken; gradient_steps: i32 gradient steps taken (per agent).
        curriculum: the curriculum's state (``worldagent.curricula``; ``()`` for ``dr``).
        z, slot: f32[E, D] the latent of each env's world and the buffer slot it was replayed from.
    """

    params: Any
    target_params: Any
    opt_state: Any
    replay: replay_lib.Replay
    env_state: Any
    obs: jax.Array
    key: jax.Array
    update: jax.Array
    episodes: jax.Array
    env_steps: jax.Array
    steps: jax.Array
    gradient_steps: jax.Array
    curriculum: Any = ()
    z: jax.Array | None = None
    slot: jax.Array | None = None


def _optimizer(config: DQNConfig) -> optax.GradientTransformation:
    return optax.chain(optax.clip_by_global_norm(config.max_grad_norm), optax.adam(config.learning_rate))


def _td_loss(config: DQNConfig, network: QNetwork, params, target_params, batch) -> tuple[jax.Array, jax.Array]:
    """Huber TD loss of one agent's minibatch (Mnih et al. 2015), and the mean Q of the actions taken."""
    q = network.apply(params, batch["obs"])
    q_taken = jnp.take_along_axis(q, batch["action"][:, None], axis=-1)[:, 0]
    q_next_target = network.apply(target_params, batch["next_obs"])
    if config.double_q:
        best = jnp.argmax(network.apply(params, batch["next_obs"]), axis=-1)
        q_next = jnp.take_along_axis(q_next_target, best[:, None], axis=-1)[:, 0]
    else:
        q_next = q_next_target.max(axis=-1)
    target = batch["reward"] + config.gamma * (1.0 - batch["ended"].astype(jnp.float32)) * q_next
    loss = optax.huber_loss(q_taken, jax.lax.stop_gradient(target)).mean()
    return loss, q_taken.mean()


def _td_magnitude(config: DQNConfig, network: QNetwork, state: DQNState, q, action, reward, next_obs, ended) -> jax.Array:
    """f32[E]: each env's |TD error| of this step, averaged over agents (DQN's learning potential, PLR)."""
    q_taken = jnp.take_along_axis(q, action[..., None], axis=-1)[..., 0]  # [E, N]
    q_next_target = q_values(network, state.target_params, next_obs)
    if config.double_q:
        best = jnp.argmax(q_values(network, state.params, next_obs), axis=-1)
        q_next = jnp.take_along_axis(q_next_target, best[..., None], axis=-1)[..., 0]
    else:
        q_next = q_next_target.max(axis=-1)
    target = reward + config.gamma * (1.0 - ended.astype(jnp.float32))[:, None] * q_next
    return jnp.abs(q_taken - target).reshape(q_taken.shape[0], -1).mean(axis=-1)


def check_env(env) -> None:
    """Refuse envs independent DQN cannot train (one line naming the fix)."""
    shape = tuple(env.observation_shape)
    if getattr(env, "num_agents", 1) < 2:
        raise WorldagentError("DQN here trains multi-agent envs (a leading agent axis); train single-agent envs with ppo or acktr.")
    if not shape or not 1 <= shape[-1] <= 8:
        raise WorldagentError(f"DQN stores observations as bit planes (at most 8, last axis); this env's are {shape}: use ppo or acktr.")


def episode_row(metrics: dict) -> dict:
    """Means over envs of ``env.metrics`` (f[E] each; per-agent f[E, N] as ``name_i`` columns)."""
    row = {}
    for name, value in metrics.items():
        value = jnp.asarray(value, jnp.float32).reshape(value.shape[0], -1).mean(axis=0)
        row.update({name: value[0]} if value.shape[0] == 1 else {f"{name}_{i}": v for i, v in enumerate(value)})
    return row


def make_train(config: DQNConfig, env, env_params, distribution, training_params=None) -> Trainer:
    """Independent DQN on ``env`` with each episode's world drawn from ``distribution``.

    Args:
        config: ``DQNConfig``.
        env: a multi-agent env (obs [N, *O] of 0/1 planes) whose episodes end at ``max_steps``.
        env_params: its params (episode length ``env_params.max_steps``; e.g. who may TAG).
        distribution: a world distribution (``distributions.py``), passed to the jitted
            functions as an argument.
        training_params: the env's ``EnvSpec.training_params``, ``(params, config, fraction) ->
            params``, applied at the start of every episode (``config``'s budget is the shared
            core's, not the run's); None: ``env_params`` as they are (harvest).

    Returns:
        A ``trainer.Trainer`` whose update is one episode of every env. Curve rows: ``active``,
        ``episodes``, ``env_steps``, the env's per-episode metrics averaged over envs (harvest:
        group_reward, equality, conflict, ..., ``returns_i`` per agent), the mean TD ``loss`` and
        ``q`` over agents and steps, and ``epsilon``. Compilations are shared between trainers
        of the same config (but for its budget) and env.
    """
    if not isinstance(config, DQNConfig):
        raise WorldagentError(f"config is a {type(config).__name__}; pass a DQNConfig.")
    check_env(env)
    if is_robust(distribution):
        raise WorldagentError("robust PLR weighs an actor-critic's steps; DQN learns from its replay buffer: drop robust=true or train ppo/acktr.")
    # the core is shared by every budget, so the budget-dependent decay is fixed here
    core_config = config.replace(num_episodes=1, epsilon_decay_episodes=config.decay_episodes)
    init, update = _core(core_config, env, int(env_params.max_steps), training_params or _unchanged_params)
    consts = (env_params, distribution, jnp.float32(config.num_episodes))
    return budgeted_trainer(init, update, config.num_episodes, config.num_chunks, q_network(config, env), consts)


def _unchanged_params(env_params, config, fraction):
    """The ``training_params`` of an env whose spec declares none: its params as they are."""
    del config, fraction
    return env_params


@functools.lru_cache(maxsize=16)
def _core(config: DQNConfig, env, episode_length: int, training_params):
    """``init(key, consts)`` and ``update(state, consts)`` (one episode of every env); consts =
    (env_params, distribution, f32 episode budget): the budget is an argument, so every budget shares the compilation."""
    network, optimizer = q_network(config, env), _optimizer(config)
    num_envs, num_agents, obs_shape = config.num_envs, env.num_agents, tuple(env.observation_shape)
    min_filled = max(2, -(-config.learning_starts // num_envs))
    reset_all = jax.vmap(env.reset, in_axes=(0, 0, None))

    def init(key: jax.Array, consts) -> DQNState:
        env_params, distribution, _ = consts
        curriculum = as_curriculum(distribution)
        env_params = training_params(env_params, config, jnp.float32(0.0))
        key_params, key_worlds, key_reset, key_run = jax.random.split(key, 4)
        params = init_params(key_params, config, env)
        schedule = curriculum.init(key_worlds)
        draw = curriculum.sample(schedule, key_worlds, num_envs)
        obs, env_state = reset_all(jax.random.split(key_reset, num_envs), draw.worlds, env_params)
        zero = jnp.int32(0)
        replay = replay_lib.create(config.buffer_slices, num_envs, num_agents, obs_shape)
        return DQNState(
            params, params, jax.vmap(optimizer.init)(params), replay, env_state, obs, raw_key(key_run), zero, zero, zero, zero, zero,
            schedule, draw.z, draw.slot,
        )  # fmt: skip

    def learn(key: jax.Array, state: DQNState) -> tuple[DQNState, jax.Array, jax.Array]:
        def one_agent(key, agent, params, target_params, opt_state):
            batch = replay_lib.sample(key, state.replay, agent, config.batch_size, obs_shape[-1])
            (loss, q_mean), grads = jax.value_and_grad(lambda p: _td_loss(config, network, p, target_params, batch), has_aux=True)(params)
            changes, opt_state = optimizer.update(grads, opt_state, params)
            return optax.apply_updates(params, changes), opt_state, loss, q_mean

        keys = jax.random.split(key, num_agents)
        params, opt_state, loss, q_mean = jax.vmap(one_agent)(keys, jnp.arange(num_agents), state.params, state.target_params, state.opt_state)
        gradient_steps = state.gradient_steps + 1
        copy = gradient_steps % config.target_update_every == 0
        target = jax.tree_util.tree_map(lambda new, old: jnp.where(copy, new, old), params, state.target_params)
        return state.replace(params=params, opt_state=opt_state, target_params=target, gradient_steps=gradient_steps), loss, q_mean

    def env_step(state: DQNState, key: jax.Array, env_params, scored: bool):
        key_act, key_env, key_learn = jax.random.split(key, 3)
        epsilon = epsilon_at(config, state.steps, episode_length)
        q = q_values(network, state.params, state.obs)  # [E, N, A]
        action = epsilon_greedy(key_act, q, epsilon)  # [E, N]
        step_all = jax.vmap(env.step, in_axes=(0, 0, 0, None))
        obs, env_state, reward, terminated, truncated, _ = step_all(jax.random.split(key_env, num_envs), state.env_state, action, env_params)
        ended = jnp.logical_or(terminated, truncated).reshape(num_envs, -1).any(axis=-1)
        td = _td_magnitude(config, network, state, q, action, reward, obs, ended) if scored else jnp.zeros(num_envs)
        replay = replay_lib.add(state.replay, state.obs, action, reward, ended)
        state = state.replace(replay=replay, env_state=env_state, obs=obs, steps=state.steps + 1)
        ready = (replay.filled >= min_filled) & (state.steps % config.train_every == 0)
        no_update = lambda k, s: (s, jnp.full(num_agents, jnp.nan), jnp.full(num_agents, jnp.nan))  # noqa: E731
        state, loss, q_mean = jax.lax.cond(ready, learn, no_update, key_learn, state)
        return state, {"loss": loss, "q": q_mean, "epsilon": epsilon, "td": td}

    def update(state: DQNState, consts) -> tuple[DQNState, dict]:
        # One episode of every env, then every env restarts on a world drawn here (one draw per
        # episode, not per step: G(z) is costly). The episode's metrics are read before the reset.
        # A curriculum scores each env's episode (its mean |TD error|, or its target margin) before the draw.
        env_params, distribution, budget = consts
        curriculum = as_curriculum(distribution)
        scored = curriculum.adaptive and curriculum.target is None
        env_params = training_params(env_params, config, jnp.clip(state.episodes / budget, 0.0, 1.0))
        key, key_worlds, key_reset, key_steps = jax.random.split(jax.random.wrap_key_data(state.key), 4)
        state, trace = jax.lax.scan(lambda s, k: env_step(s, k, env_params, scored), state, jax.random.split(key_steps, episode_length))
        metrics = jax.vmap(env.metrics)(state.env_state)
        schedule = state.curriculum
        if curriculum.adaptive:
            score = curriculum.episode_score(trace["td"].mean(axis=0), metrics)
            schedule = curriculum.update(schedule, state.z, state.slot, score, jnp.ones(num_envs, bool))
        draw = curriculum.sample(schedule, key_worlds, num_envs)
        obs, env_state = reset_all(jax.random.split(key_reset, num_envs), draw.worlds, env_params)
        state = state.replace(
            curriculum=schedule, z=draw.z, slot=draw.slot,
            env_state=env_state, obs=obs, key=raw_key(key), update=state.update + 1,
            episodes=state.episodes + num_envs, env_steps=state.env_steps + num_envs * episode_length,
        )  # fmt: skip
        row = {"active": 1.0, "episodes": state.episodes, "env_steps": state.env_steps, **episode_row(metrics)}
        row.update(loss=jnp.nanmean(trace["loss"]), q=jnp.nanmean(trace["q"]), epsilon=trace["epsilon"][-1])
        return state, curve_row(row)

    return init, update
