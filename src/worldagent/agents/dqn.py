"""Independent DQN for Resource Harvest (paper §5.3; §6.2.2 with agent 0 able to TAG).

"Independent learning with each agent separately learning using its own Deep Q-Network ...
the same settings as [Perolat et al. 2017] ... 5,000 episodes" (§5.3). Each of the four agents
has its own Q-network, target network, Adam state and replay buffer; they share no parameters
and no data. All four are stacked on a leading agent axis and updated by one ``vmap``; ``E``
envs run in parallel (``vmap``), each drawing a new world from the training distribution when
its episode ends (``core.step_autoreset(next_world=...)``). Training is jitted end to end in
the PureJaxRL style: ``make_train(config, distribution)(key)``; the host loop in
``worldagent.agents.dqn_run`` (``train_harvest``) runs the same code one episode of every env
(a "chunk") at a time to draw progress, write the learning curve and checkpoint.

Every hyper-parameter of ``DQNConfig`` says where it comes from. Perolat et al. (2017) give
the agents' Q-network as a small MLP and otherwise defer to the DQN of Mnih et al. (2015) and
the settings of Leibo et al. (2017); values marked "ours" are not from those papers. Deviations
forced by the budget (5,000 x 1,000-step episodes = 20M agent-steps in <= 60 min on 2 CPU
cores): ``num_envs`` episodes run side by side, one gradient step per agent per vector step
(``train_every``) with a correspondingly larger minibatch, and a replay buffer of 100,000
transitions per agent (bit-packed, ``replay.py``).

Episode ends: harvest episodes end only by the time limit, which the agents cannot observe;
the last transition of an episode is treated as terminal (no bootstrap), as in PureJaxRL and
``rollouts.py``: one transition in 1,000.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import optax
from flax import struct

from worldagent.agents import replay as replay_lib
from worldagent.agents.networks import QNetwork
from worldagent.envs.core import step_autoreset
from worldagent.envs.harvest.env import NUM_ACTIONS, NUM_AGENTS, NUM_CHANNELS, Harvest, make_params
from worldagent.envs.harvest.metrics import conflict, equality
from worldagent.errors import WorldagentError

ALGORITHMS = ("dqn",)


@dataclasses.dataclass(frozen=True)
class DQNConfig:
    """Settings of an independent-DQN run on Resource Harvest (sources in brackets).

    Values marked † are from the cited papers as we recall them; their text was not at hand
    to check when this was written (the one second-hand confirmation: Perolat's agents used an
    MLP, not a CNN).

    Attributes:
        num_episodes: training episodes per agent [paper §5.3: 5,000]; rounded up to a
            multiple of ``num_envs``.
        episode_length: steps per episode [Perolat et al. 2017: 1,000].
        num_envs: episodes played side by side [ours: parallelism for the time budget].
        tagger: index of the one agent allowed to TAG, or None [paper §6.2.2: agent 0].
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
        epsilon_decay_episodes: episodes over which epsilon decays [ours: the first 20%].
        double_q: use double-DQN targets [off: Perolat used DQN].
        act_epsilon: exploration of the trained agents when they act (``make_act``'s default)
            [ours: 0.1 = ``epsilon_end``, the agents as they acted at the end of training and as
            their learning curve measures them. Memoryless greedy agents under partial
            observation get stuck where no apple is in view; measured at the paper's budget
            with agent 0 tagging (benchmarks/results/train_harvest-tagger0-cpu.json), group
            reward / random: greedy 0.62, epsilon 0.05 (Mnih et al. 2015's evaluation) 2.07, 0.1 2.66].
        view_size, view_behind: the observation window (the env's defaults, see ``Harvest``).
        seed: the run's seed; it becomes the key at the API boundary (``train_harvest``).
        checkpoint_every: chunks (of ``num_envs`` episodes) between checkpoints of the host loop.
    """

    num_episodes: int = 5000
    episode_length: int = 1000
    num_envs: int = 40
    tagger: int | None = None
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
    epsilon_decay_episodes: int = 1000
    double_q: bool = False
    act_epsilon: float = 0.1
    view_size: int = 15
    view_behind: int = 2
    seed: int = 0
    checkpoint_every: int = 10

    def validate(self) -> None:
        """Raise ``WorldagentError`` (one line, naming the fix) for impossible settings."""
        positive = (
            "num_episodes",
            "episode_length",
            "num_envs",
            "batch_size",
            "buffer_size",
            "train_every",
            "target_update_every",
            "checkpoint_every",
        )
        for name in positive:
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise WorldagentError(f"DQNConfig.{name}={value!r}; give a positive integer.")
        if self.tagger is not None and (isinstance(self.tagger, bool) or self.tagger not in range(NUM_AGENTS)):
            raise WorldagentError(f"DQNConfig.tagger={self.tagger!r}; pick an agent index 0-3, or None for no tagging.")
        if not self.hidden_sizes or any(not isinstance(h, int) or h < 1 for h in self.hidden_sizes):
            raise WorldagentError(f"DQNConfig.hidden_sizes={self.hidden_sizes!r}; give positive layer widths, e.g. (32, 32).")
        if not 0.0 <= self.gamma < 1.0:
            raise WorldagentError(f"DQNConfig.gamma={self.gamma}; pick a discount in [0, 1).")
        if not self.learning_rate > 0 or not self.max_grad_norm > 0:
            raise WorldagentError("DQNConfig.learning_rate and max_grad_norm must be positive.")
        if not 0.0 <= self.act_epsilon <= 1.0:
            raise WorldagentError(f"DQNConfig.act_epsilon={self.act_epsilon}; pick a probability in [0, 1].")
        if not 0.0 <= self.epsilon_end <= self.epsilon_start <= 1.0 or self.epsilon_decay_episodes < 0:
            raise WorldagentError("exploration needs 0 <= epsilon_end <= epsilon_start <= 1 and epsilon_decay_episodes >= 0.")
        if self.learning_starts < 0 or self.buffer_size < 2 * self.num_envs:
            raise WorldagentError(
                f"buffer_size ({self.buffer_size}) must hold at least two steps of {self.num_envs} envs and learning_starts be >= 0."
            )
        Harvest(view_size=self.view_size, view_behind=self.view_behind)  # checks the window

    @property
    def num_chunks(self) -> int:
        """Chunks of ``num_envs`` parallel episodes: ceil(num_episodes / num_envs)."""
        return -(-self.num_episodes // self.num_envs)

    @property
    def buffer_slices(self) -> int:
        """Time slices of the ring buffer (each holds ``num_envs`` transitions per agent)."""
        return max(2, self.buffer_size // self.num_envs)

    @property
    def can_tag(self) -> tuple[bool, ...]:
        """bool[4]: which agents may TAG."""
        return tuple(i == self.tagger for i in range(NUM_AGENTS))

    def env(self) -> Harvest:
        return Harvest(view_size=self.view_size, view_behind=self.view_behind)

    def env_params(self):
        return make_params(can_tag=self.can_tag, max_steps=self.episode_length)


def q_network(config: DQNConfig) -> QNetwork:
    """One agent's Q-network: an MLP with ReLUs on its flattened window uint8[..., V, V, 4] -> f32[..., 8]."""
    return QNetwork(num_actions=NUM_ACTIONS, hidden=tuple(config.hidden_sizes), activation="relu", obs_rank=3)


def init_params(key: jax.Array, config: DQNConfig) -> Any:
    """The four agents' Q-network parameters, stacked on a leading agent axis [4, ...]."""
    network = q_network(config)
    dummy = jnp.zeros((config.view_size, config.view_size, NUM_CHANNELS), jnp.uint8)
    return jax.vmap(network.init, in_axes=(0, None))(jax.random.split(key, NUM_AGENTS), dummy)


def q_values(config: DQNConfig, params: Any, obs: jax.Array) -> jax.Array:
    """f32[..., 4, 8]: each agent's Q-values from its own network, for obs uint8[..., 4, V, V, 4]."""
    network = q_network(config)
    lead = obs.ndim - 4  # batch axes before the agent axis
    moved = jnp.moveaxis(obs, lead, 0)  # [4, ..., V, V, 4]
    return jnp.moveaxis(jax.vmap(network.apply)(params, moved), 0, lead)


def epsilon_greedy(key: jax.Array, q: jax.Array, epsilon: jax.Array) -> jax.Array:
    """i32[...]: argmax of q f32[..., 8], replaced by a uniform action with probability epsilon."""
    key_explore, key_action = jax.random.split(key)
    random_action = jax.random.randint(key_action, q.shape[:-1], 0, q.shape[-1], dtype=jnp.int32)
    explore = jax.random.uniform(key_explore, q.shape[:-1]) < epsilon
    return jnp.where(explore, random_action, jnp.argmax(q, axis=-1).astype(jnp.int32))


def make_act(config: DQNConfig, epsilon: float | None = None) -> Callable:
    """The trained agents as one policy: ``act(params, obs uint8[4, V, V, 4], key) -> int32[4]``.

    Epsilon-greedy with ``epsilon`` (default ``config.act_epsilon``); ``epsilon=0`` is greedy.
    Also accepts a batch of obs [..., 4, V, V, 4].
    """
    return _make_act(config, float(config.act_epsilon if epsilon is None else epsilon))


@functools.lru_cache(maxsize=64)
def _make_act(config: DQNConfig, epsilon: float) -> Callable:
    """Cached, so that evaluators jitted per policy compile once."""

    def act(policy_params: Any, obs: jax.Array, key: jax.Array) -> jax.Array:
        return epsilon_greedy(key, q_values(config, policy_params, obs), jnp.float32(epsilon))

    return act


def epsilon_at(config: DQNConfig, step: jax.Array) -> jax.Array:
    """f32 exploration rate after ``step`` vector steps (linear decay, then constant)."""
    decay_steps = max(1, config.epsilon_decay_episodes * config.episode_length // config.num_envs)
    fraction = jnp.clip(step / decay_steps, 0.0, 1.0)
    return config.epsilon_start + fraction * (config.epsilon_end - config.epsilon_start)


@struct.dataclass
class DQNState:
    """Everything a run carries between steps (no keys: each chunk takes its own).

    Attributes:
        params, target_params: the agents' Q-network and target parameters, stacked [4, ...].
        opt_state: their Adam states, stacked [4, ...].
        replay: the four replay buffers (``replay.Replay``, agent axis 2).
        env_state: ``HarvestState`` batched [E].
        obs: uint8[E, 4, V, V, 4] the current observations.
        steps: i32 vector steps taken; updates: i32 gradient steps taken (per agent).
    """

    params: Any
    target_params: Any
    opt_state: Any
    replay: replay_lib.Replay
    env_state: Any
    obs: jax.Array
    steps: jax.Array
    updates: jax.Array


class Trainer(NamedTuple):
    """The jitted pieces of a run: ``init(key, dist)``, ``chunk(key, state, dist)`` (one episode
    of every env, returning per-episode stats), and ``train(key)`` = init + all chunks."""

    init: Callable
    chunk: Callable
    train: Callable


def _optimizer(config: DQNConfig) -> optax.GradientTransformation:
    return optax.chain(optax.clip_by_global_norm(config.max_grad_norm), optax.adam(config.learning_rate))


def _td_loss(config: DQNConfig, params, target_params, batch) -> tuple[jax.Array, jax.Array]:
    """Huber TD loss of one agent's minibatch (Mnih et al. 2015), and the mean Q of the actions taken."""
    network = q_network(config)
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


def make_trainer(config: DQNConfig) -> Trainer:
    """Build the jitted ``init``, ``chunk`` and ``train`` of independent DQN for ``config``.

    The distribution (a ``WorldPool`` or any pytree with ``sample(key) -> world``) is an
    argument of ``init``/``chunk``, so its arrays are not baked into the compiled program.
    Trainers are cached by config, so a resumed or repeated run does not compile again.
    """
    config.validate()
    # The compiled step does not depend on the run's length, seed or checkpointing.
    init, chunk, jit_init, jit_chunk = _make_trainer(dataclasses.replace(config, num_episodes=1, seed=0, checkpoint_every=1))

    def train(key: jax.Array, distribution: Any) -> tuple[DQNState, dict[str, jax.Array]]:
        key_init, key_chunks = jax.random.split(key)
        state = init(key_init, distribution)
        keys = jax.vmap(lambda i: chunk_key(key_chunks, i))(jnp.arange(config.num_chunks))
        return jax.lax.scan(lambda s, k: chunk(k, s, distribution), state, keys)

    return Trainer(init=jit_init, chunk=jit_chunk, train=jax.jit(train))


@functools.lru_cache(maxsize=16)
def _make_trainer(config: DQNConfig) -> tuple[Callable, Callable, Callable, Callable]:
    env, env_params = config.env(), config.env_params()
    optimizer = _optimizer(config)
    num_envs, num_agents = config.num_envs, NUM_AGENTS
    obs_shape = env.observation_shape
    min_filled = max(2, -(-config.learning_starts // num_envs))

    def init(key: jax.Array, distribution: Any) -> DQNState:
        key_params, key_worlds, key_reset = jax.random.split(key, 3)
        params = init_params(key_params, config)
        worlds = jax.vmap(distribution.sample)(jax.random.split(key_worlds, num_envs))
        obs, env_state = jax.vmap(env.reset, in_axes=(0, 0, None))(jax.random.split(key_reset, num_envs), worlds, env_params)
        return DQNState(
            params=params,
            target_params=params,
            opt_state=jax.vmap(optimizer.init)(params),
            replay=replay_lib.create(config.buffer_slices, num_envs, num_agents, obs_shape),
            env_state=env_state,
            obs=obs,
            steps=jnp.int32(0),
            updates=jnp.int32(0),
        )

    def update(key: jax.Array, state: DQNState) -> tuple[DQNState, jax.Array, jax.Array]:
        def one_agent(key, agent, params, target_params, opt_state):
            batch = replay_lib.sample(key, state.replay, agent, config.batch_size, obs_shape[-1])
            (loss, q_mean), grads = jax.value_and_grad(lambda p: _td_loss(config, p, target_params, batch), has_aux=True)(params)
            changes, opt_state = optimizer.update(grads, opt_state, params)
            return optax.apply_updates(params, changes), opt_state, loss, q_mean

        keys = jax.random.split(key, num_agents)
        params, opt_state, loss, q_mean = jax.vmap(one_agent)(keys, jnp.arange(num_agents), state.params, state.target_params, state.opt_state)
        updates = state.updates + 1
        copy = updates % config.target_update_every == 0
        target = jax.tree_util.tree_map(lambda new, old: jnp.where(copy, new, old), params, state.target_params)
        return state.replace(params=params, opt_state=opt_state, target_params=target, updates=updates), loss, q_mean

    def env_step(state, key, next_worlds):
        key_act, key_env, key_update = jax.random.split(key, 3)
        epsilon = epsilon_at(config, state.steps)
        action = epsilon_greedy(key_act, q_values(config, state.params, state.obs), epsilon)  # [E, 4]
        step_all = jax.vmap(lambda k, s, a, w: step_autoreset(env, k, s, a, env_params, next_world=w))
        obs, env_state, reward, terminated, truncated, info = step_all(jax.random.split(key_env, num_envs), state.env_state, action, next_worlds)
        ended = jnp.logical_or(terminated, truncated).any(axis=-1)
        replay = replay_lib.add(state.replay, state.obs, action, reward, ended)
        state = state.replace(replay=replay, env_state=env_state, obs=obs, steps=state.steps + 1)
        ready = (replay.filled >= min_filled) & (state.steps % config.train_every == 0)
        no_update = lambda k, s: (s, jnp.full(num_agents, jnp.nan), jnp.full(num_agents, jnp.nan))  # noqa: E731
        state, loss, q_mean = jax.lax.cond(ready, update, no_update, key_update, state)
        record = {"reward": reward, "tagged_out": info["tagged_out"].any(axis=-1), "loss": loss, "q": q_mean, "epsilon": epsilon}
        return state, record

    def chunk(key: jax.Array, state: DQNState, distribution: Any) -> tuple[DQNState, dict[str, jax.Array]]:
        # A chunk is exactly one episode of every env: each ends at the chunk's last step and
        # restarts on the world drawn here (one draw per episode, not per step: G(z) is costly).
        key_worlds, key_steps = jax.random.split(key)
        next_worlds = jax.vmap(distribution.sample)(jax.random.split(key_worlds, num_envs))
        state, trace = jax.lax.scan(lambda s, k: env_step(s, k, next_worlds), state, jax.random.split(key_steps, config.episode_length))
        returns = trace["reward"].sum(axis=0)  # [E, 4]: every env played exactly one whole episode
        stats = {
            "returns": returns,
            "group_reward": returns.sum(axis=-1),
            "equality": equality(returns),
            "conflict": conflict(trace["tagged_out"].sum(axis=0), jnp.int32(config.episode_length)),
            "loss": jnp.nanmean(trace["loss"], axis=0),
            "q": jnp.nanmean(trace["q"], axis=0),
            "epsilon": trace["epsilon"][-1],
        }
        return state, stats

    jit_init = jax.jit(init)
    jit_chunk = jax.jit(chunk, donate_argnums=1)

    return init, chunk, jit_init, jit_chunk


def chunk_key(key: jax.Array, index) -> jax.Array:
    """The key of chunk ``index`` of a run with chunk key ``key`` (so a resumed run replays the same keys)."""
    return jax.random.fold_in(key, index)


def make_train(config: DQNConfig, distribution: Any) -> Callable:
    """PureJaxRL-style entry: ``train(key) -> (DQNState, stats)``, one jitted call for the whole run.

    ``stats`` holds, per chunk (leading axis ``num_chunks``) and env, each episode's
    ``returns`` f32[..., E, 4], ``group_reward``, ``equality`` and ``conflict`` f32[..., E], and the
    per-agent mean ``loss`` and ``q`` f32[..., 4] and the final ``epsilon``. The same keys as
    the chunked host loop, so both give the same agents. vmappable over keys (seeds).
    """
    trainer = make_trainer(config)
    return lambda key: trainer.train(key, distribution)


def check_algorithm(algo: str) -> str:
    """The algorithm name, or ``WorldagentError`` listing the known ones."""
    if algo not in ALGORITHMS:
        raise WorldagentError(f"unknown harvest algorithm {algo!r}; use one of: {', '.join(ALGORITHMS)}.")
    return algo
