"""On-policy rollouts for actor-critic agents over a batch of envs on a world distribution.

Shared by PPO and ACKTR (paper §5.3). One call of ``collect`` is one ``lax.scan`` of
``num_steps`` steps over ``B`` envs at once (``vmap``), pure and jittable::

    runner = init_runner(key, env, env_params, distribution, num_envs)
    runner, traj, last_value = collect(key, runner, apply_fn, net_params, env, env_params, distribution, num_steps)
    advantages, targets = gae(traj.reward, traj.value, traj.done, last_value, gamma, lam)

Worlds (issue 5, "every env in a training batch can be on a different world"): every env
holds a *pending* world; an episode that ends restarts on it (``core.step_autoreset(...,
next_world=...)``). At the start of each ``collect`` pending worlds are drawn from the
curriculum, never per step. From a pool (cheap) every env gets a fresh one each segment. From
G(z), which decodes and searches 10,000 rasters per world, only ``draws_per_segment`` are
decoded (one per 64 env-steps), and they go to the envs whose pending world was started since
their last draw: an env keeps an unused pending world, and an env that ends more episodes than
it is given worlds replays its pending world.

Curricula (``worldagent.curricula``): the ``distribution`` argument is a curriculum, or a fixed
distribution taken as ``dr``. The runner carries the curriculum's state and each env's latent;
after the trainer has its value targets, ``score_segment`` scores every episode that ended in
the segment (mean positive value loss over its steps, or its target margin) and updates the
curriculum, inside the jitted update.

Memory: a recurrent policy's memory rides in the runner (``EnvRunner.memory``, None for an MLP);
the network zeroes it where an env's observation starts an episode (``episode_length == 0``),
as PureJaxRL's ``ScannedRNN`` resets on done, so segments may cross episodes.

Ends of episodes: ``done = terminated | truncated``, both cut the bootstrap (PureJaxRL's
convention; the racing observation has no clock, so a time-limit value would be guessed).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
from flax import struct

from worldagent.curricula import as_curriculum
from worldagent.curricula.scores import positive_value_loss
from worldagent.envs.core import step_autoreset

# apply_fn(net_params, obs[B, ...]) -> (logits f32[B, A], value f32[B]); with memory (runner.memory
# set): apply_fn(net_params, obs[B, ...], memory, first bool[B]) -> (logits, value, memory)
ApplyFn = Callable[..., tuple]


def with_memory(apply_fn: ApplyFn, memory: Any) -> Callable:
    """``apply_fn`` as ``(params, obs, memory, first) -> (logits, value, memory)``: a memoryless
    one ignores ``first`` and hands ``memory`` (None) back, so ``collect`` has one code path."""
    if memory is not None:
        return apply_fn
    return lambda params, obs, memory, first: (*apply_fn(params, obs), memory)


@struct.dataclass
class EnvRunner:
    """The carry of a rollout: a batch of B envs mid-episode.

    Attributes:
        obs: [B, *obs_shape] current observations.
        state: the batched env state (leading axis B).
        episode_return: f32[B] return of each env's episode so far.
        episode_length: i32[B] steps of each env's episode so far.
        curriculum: the curriculum's state (``()`` for ``dr``).
        z, slot: f32[B, D] the latent of each env's world (D = 0 without latents) and the
            buffer slot it was replayed from (-1: new); ``pending_z``, ``pending_slot``: the
            same of each env's pending world.
        potential, potential_steps: f32[B] the learning potential summed over each env's
            episode so far (the steps already scored), and how many steps that sum holds.
        pending: each env's pending world (a batched world pytree, leading axis B).
        used: bool[B] the pending world was started since it was drawn (it needs a new one).
        replayed, pending_replayed: bool[B] the world in play / pending was drawn by replay
            from the buffer (robust PLR learns only there), not merely found in it later.
        memory: a recurrent policy's memory of each env's episode (a pytree, leading axis B),
            as of before ``obs``; None for memoryless policies. An env whose ``episode_length``
            is 0 starts an episode at ``obs``, and the network forgets there.
    """

    obs: jax.Array
    state: Any
    episode_return: jax.Array
    episode_length: jax.Array
    curriculum: Any
    z: jax.Array
    slot: jax.Array
    pending_z: jax.Array
    pending_slot: jax.Array
    potential: jax.Array
    potential_steps: jax.Array
    pending: Any
    used: jax.Array
    replayed: jax.Array
    pending_replayed: jax.Array
    memory: Any = None


@struct.dataclass
class Trajectory:
    """A segment of ``T`` steps of ``B`` envs (every field has leading axes ``[T, B]``).

    Attributes:
        obs: the observation each action was chosen from.
        action: i32 actions taken.
        log_prob: f32 log pi(action | obs) under the policy that acted.
        value: f32 V(obs) of the critic that acted.
        reward: f32 rewards.
        done: bool, the episode ended at this step (terminated or truncated).
        terminated: bool, it ended by the env's rules (crash, lap), not the time limit.
        episode: dict of per-episode metrics, meaningful where ``done``: "return" (f32),
            "length" (i32) and the env step's per-env ``info`` entries at that step (racing:
            "crashed", "lap_completed", "progress"), whatever the env reports.
        metrics: ``env.metrics`` of each env's episode as of each step (before any reset).
    """

    obs: jax.Array
    action: jax.Array
    log_prob: jax.Array
    value: jax.Array
    reward: jax.Array
    done: jax.Array
    terminated: jax.Array
    episode: dict
    metrics: dict


def init_runner(key: jax.Array, env, env_params, distribution, num_envs: int) -> EnvRunner:
    """B envs reset onto B worlds drawn from ``distribution`` (a curriculum or a fixed distribution)."""
    curriculum = as_curriculum(distribution)
    key_worlds, key_reset = jax.random.split(key)
    state = curriculum.init(jax.random.fold_in(key_worlds, 1))  # its own stream; sample keeps key_worlds (dr as before)
    draw = curriculum.sample(state, key_worlds, num_envs)
    obs, env_state = jax.vmap(env.reset, in_axes=(0, 0, None))(jax.random.split(key_reset, num_envs), draw.worlds, env_params)
    zeros = jnp.zeros(num_envs, jnp.float32)
    used, replayed = jnp.ones(num_envs, bool), draw.slot >= 0
    return EnvRunner(
        obs, env_state, zeros, jnp.zeros(num_envs, jnp.int32), state, draw.z, draw.slot, draw.z, draw.slot, zeros, zeros, draw.worlds, used,
        replayed, replayed,
    )  # fmt: skip


def draws_per_segment(distribution, num_envs: int, num_steps: int) -> int:
    """Pending worlds drawn per segment: every env's from a pool; from G(z), one per 64 env-steps.

    64 steps is shorter than the episodes training plays where G(z) is costly (racing with its
    training respawn: 150-300 steps), so envs rarely wait for a world.
    """
    if not hasattr(getattr(as_curriculum(distribution), "worlds", None), "generator"):
        return num_envs
    return int(min(num_envs, max(1, -(-num_envs * num_steps // 64))))


def refill(runner: EnvRunner, draw) -> EnvRunner:
    """The runner with the drawn worlds given, in env order, to envs whose pending world was used."""
    count = draw.slot.shape[0]
    if count == runner.used.shape[0]:  # one per env: all replaced (what training always did)
        return runner.replace(
            pending=draw.worlds, pending_z=draw.z, pending_slot=draw.slot, used=jnp.zeros_like(runner.used), pending_replayed=draw.slot >= 0
        )
    rank = jnp.cumsum(runner.used) - 1
    take = runner.used & (rank < count)
    index = jnp.clip(rank, 0, count - 1)
    pick = lambda new, old: jnp.where(take.reshape(-1, *[1] * (old.ndim - 1)), new[index], old)  # noqa: E731
    return runner.replace(
        pending=jax.tree_util.tree_map(pick, draw.worlds, runner.pending), pending_z=pick(draw.z, runner.pending_z),
        pending_slot=pick(draw.slot, runner.pending_slot), used=runner.used & ~take,
        pending_replayed=pick(draw.slot >= 0, runner.pending_replayed),
    )  # fmt: skip


def sample_action(key: jax.Array, logits: jax.Array) -> tuple[jax.Array, jax.Array]:
    """(i32[B] actions drawn from the categorical ``logits`` f32[B, A], f32[B] their log-probs)."""
    action = jax.random.categorical(key, logits).astype(jnp.int32)
    return action, action_log_prob(logits, action)


def action_log_prob(logits: jax.Array, action: jax.Array) -> jax.Array:
    """f32[...] log-softmax(logits)[action]."""
    return jnp.take_along_axis(jax.nn.log_softmax(logits), action[..., None], axis=-1)[..., 0]


def entropy(logits: jax.Array) -> jax.Array:
    """f32[...] entropy of the categorical ``logits``."""
    log_p = jax.nn.log_softmax(logits)
    return -jnp.sum(jnp.exp(log_p) * log_p, axis=-1)


def collect(
    key: jax.Array,
    runner: EnvRunner,
    apply_fn: ApplyFn,
    net_params: Any,
    env,
    env_params,
    distribution,
    num_steps: int,
) -> tuple[EnvRunner, Trajectory, jax.Array]:
    """Run the policy for ``num_steps`` steps in every env (see module docstring).

    Args:
        key: PRNG key.
        runner: the envs' carry (``init_runner``).
        apply_fn: ``apply_fn(net_params, obs[B, ...]) -> (logits f32[B, A], value f32[B])``;
            where ``runner.memory`` is set, ``apply_fn(net_params, obs, memory, first bool[B]) ->
            (logits, value, memory)`` (a recurrent actor-critic; ``first``: obs starts an episode).
        net_params: the actor-critic's parameters.
        env, env_params: the environment and its params.
        distribution: a curriculum, or a world distribution with ``sample(key) -> world``.
        num_steps: T, steps per env (static).

    Returns:
        ``(runner, trajectory [T, B], last_value f32[B])``: the carry to continue from, the
        segment, and the value of the state after its last step (for bootstrapping).
    """
    num_envs = runner.episode_return.shape[0]
    curriculum = as_curriculum(distribution)
    key_worlds, key_steps = jax.random.split(key)
    draw = curriculum.sample(runner.curriculum, key_worlds, draws_per_segment(curriculum, num_envs, num_steps))
    runner = refill(runner, draw)
    step_env = jax.vmap(lambda k, s, a, w: step_autoreset(env, k, s, a, env_params, next_world=w, ended_metrics=True))
    forward = with_memory(apply_fn, runner.memory)

    def one_step(runner: EnvRunner, step_key):
        key_act, key_env = jax.random.split(step_key)
        logits, value, memory = forward(net_params, runner.obs, runner.memory, runner.episode_length == 0)
        action, log_prob = sample_action(key_act, logits)
        obs, state, reward, terminated, truncated, info, metrics = step_env(jax.random.split(key_env, num_envs), runner.state, action, runner.pending)
        done = jnp.logical_or(terminated, truncated)
        episode_return = runner.episode_return + reward
        episode_length = runner.episode_length + 1
        per_env = {name: value for name, value in info.items() if jnp.ndim(value) == 1}  # per-agent entries do not summarise
        episode = {"return": episode_return, "length": episode_length, **per_env}
        record = Trajectory(runner.obs, action, log_prob, value, reward, done, terminated, episode, metrics)
        runner = runner.replace(
            obs=obs, state=state, episode_return=jnp.where(done, 0.0, episode_return), episode_length=jnp.where(done, 0, episode_length),
            used=runner.used | done, memory=memory,
        )  # fmt: skip
        return runner, record

    runner, trajectory = jax.lax.scan(one_step, runner, jax.random.split(key_steps, num_steps))
    _, last_value, _ = forward(net_params, runner.obs, runner.memory, runner.episode_length == 0)
    return runner, trajectory, last_value


def score_segment(distribution, runner: EnvRunner, trajectory: Trajectory, targets: jax.Array) -> tuple[EnvRunner, jax.Array]:
    """The runner after the curriculum has scored the episodes that ended in ``trajectory``, and
    f32[T, B] weights of the steps the learner may use (all 1 but for robust PLR).

    Each episode's learning potential is the mean positive value loss over its steps,
    max(target - V, 0) with the trainer's value ``targets`` f32[T, B] (an episode that began in
    an earlier segment carries its sum in ``runner.potential``). Its score is that, or its
    target margin (``curriculum.episode_score``). A fixed distribution (``dr``) is left alone.
    """
    curriculum = as_curriculum(distribution)
    if not curriculum.adaptive:
        return runner, jnp.ones(trajectory.done.shape, jnp.float32)
    potential = positive_value_loss(targets, trajectory.value)

    def one_step(carry, step):
        z, slot, replayed, total, steps, on_pending, pending_sum, pending_count = carry
        step_potential, done, metrics = step
        total, steps = total + step_potential, steps + 1.0
        score = curriculum.episode_score(total / steps, metrics)
        ended = (z, slot, score, done & ~on_pending, curriculum.learns_from(replayed))  # ended: the segment's first world
        again = done & on_pending  # the pending world's episodes are pooled into one entry below
        carry = (
            jnp.where(done[:, None], runner.pending_z, z), jnp.where(done, runner.pending_slot, slot),
            jnp.where(done, runner.pending_replayed, replayed), jnp.where(done, 0.0, total), jnp.where(done, 0.0, steps),
            on_pending | done, pending_sum + jnp.where(again, score, 0.0), pending_count + again,
        )  # fmt: skip
        return carry, ended

    zero = jnp.zeros(runner.slot.shape, jnp.float32)
    already = jnp.all(runner.z == runner.pending_z, axis=-1)  # an env given no new world plays its pending one now
    start = (runner.z, runner.slot, runner.replayed, runner.potential, runner.potential_steps, already, zero, zero)
    carry, (zs, slots, scores, valid, weights) = jax.lax.scan(one_step, start, (potential, trajectory.done, trajectory.metrics))
    z, slot, replayed, total, steps, _, pending_sum, pending_count = carry
    # one entry per env for the episodes its pending world ended within the segment (their mean score),
    # so that a world replayed several times in a segment (short episodes) never enters the buffer twice
    flat = lambda x, last: jnp.concatenate([x.reshape(-1, *x.shape[2:]), last])  # noqa: E731
    state = curriculum.update(
        runner.curriculum, flat(zs, runner.pending_z), flat(slots, runner.pending_slot),
        flat(scores, pending_sum / jnp.maximum(pending_count, 1.0)), flat(valid, pending_count > 0),
    )  # fmt: skip
    slot = curriculum.slot_of(state, z, slot)
    pending_slot = curriculum.slot_of(state, runner.pending_z, runner.pending_slot)  # a pending world kept for later segments too
    return runner.replace(
        curriculum=state, z=z, slot=slot, replayed=replayed, pending_slot=pending_slot, potential=total, potential_steps=steps
    ), weights


def gae(rewards, values, dones, last_value, gamma: float, lam: float) -> tuple[jax.Array, jax.Array]:
    """Generalised advantage estimation (Schulman et al. 2016) over a ``[T, B]`` segment.

    Returns:
        ``(advantages f32[T, B], value targets f32[T, B] = advantages + values)``.
    """

    def backward(carry, step):
        advantage, next_value = carry
        reward, value, done = step
        not_done = 1.0 - done.astype(jnp.float32)
        delta = reward + gamma * next_value * not_done - value
        advantage = delta + gamma * lam * not_done * advantage
        return (advantage, value), advantage

    _, advantages = jax.lax.scan(backward, (jnp.zeros_like(last_value), last_value), (rewards, values, dones), reverse=True)
    return advantages, advantages + values


def nstep_returns(rewards, dones, last_value, gamma: float) -> jax.Array:
    """f32[T, B] discounted n-step returns bootstrapped from ``last_value`` (A2C / ACKTR targets)."""

    def backward(next_return, step):
        reward, done = step
        ret = reward + gamma * next_return * (1.0 - done.astype(jnp.float32))
        return ret, ret

    _, returns = jax.lax.scan(backward, last_value, (rewards, dones), reverse=True)
    return returns


def episode_summary(trajectory: Trajectory) -> dict[str, jax.Array]:
    """Means over the episodes that ended in a segment, and their count.

    Returns:
        ``{"episodes": i32 count, "return": mean raw return, "length": mean steps, and the mean
        of every other per-episode entry (racing: crash rate, lap rate, progress)}``; NaN means
        when no episode ended.
    """
    done = trajectory.done
    count = done.sum()
    mean = lambda x: jnp.where(count > 0, jnp.sum(jnp.where(done, x.astype(jnp.float32), 0.0)) / jnp.maximum(count, 1), jnp.nan)  # noqa: E731
    return {"episodes": count.astype(jnp.int32), **{name: mean(value) for name, value in trajectory.episode.items()}}
