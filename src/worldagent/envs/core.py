"""The functional environment contract (DESIGN.md, "Environment") and one place for autoreset.

An environment is a frozen object holding *static* configuration (shapes, number of agents);
everything traced lives in ``params`` (a pytree) and ``state`` (a pytree that carries its
``world``). Both methods are pure and jittable::

    obs, state = env.reset(key, world, params)
    obs, state, reward, terminated, truncated, info = env.step(key, state, action, params)

Multi-agent environments put a leading agent axis on ``obs``, ``action`` and ``reward``.
Per-episode metrics are accumulated in ``state`` so that evaluation never stores trajectories.
"""

from __future__ import annotations

from typing import Any, ClassVar

import jax
import jax.numpy as jnp
import numpy as np

from worldagent.errors import WorldagentError


class Environment:
    """Base class of the pure-JAX environments; subclasses are frozen dataclasses.

    ``cpu_episodes_per_call``: episodes one compiled evaluation call plays on a CPU (None: the
    evaluator's default, ``evaluation.local.EPISODES_PER_CALL``). An env whose episodes all run the same
    number of steps plays them as fast in smaller calls, which pad a search's small batches less.
    """

    num_agents: int = 1
    cpu_episodes_per_call: ClassVar[int | None] = None

    @property
    def default_params(self) -> Any:
        raise NotImplementedError

    @property
    def num_actions(self) -> int:
        raise NotImplementedError

    @property
    def observation_shape(self) -> tuple[int, ...]:
        raise NotImplementedError

    def reset(self, key: jax.Array, world: Any, params: Any) -> tuple[jax.Array, Any]:
        raise NotImplementedError

    def step(self, key: jax.Array, state: Any, action: jax.Array, params: Any):
        raise NotImplementedError

    def metrics(self, state: Any) -> dict[str, jax.Array]:
        """The per-episode metrics accumulated in ``state`` (scalars, or ``[N]`` per agent)."""
        raise NotImplementedError


def step_autoreset(env: Environment, key: jax.Array, state: Any, action: jax.Array, params: Any, next_world: Any = None, ended_metrics: bool = False):
    """``env.step``, then, where the episode ended, a fresh episode on the same world.

    Training on a distribution of worlds passes ``next_world``, a world drawn by the caller
    (e.g. ``distribution.sample(key)``): an episode that ends restarts on it instead.

    The returned ``obs`` and ``state`` are those of the new episode where it ended; ``reward``,
    ``terminated``, ``truncated`` and ``info`` are those of the step that ended it (gymnax's
    convention). With ``ended_metrics`` a seventh value follows: ``env.metrics`` of the episode
    as of this step, before any reset (what a curriculum scores an ended episode by). The world is never copied: only the dynamic fields are selected. Envs with an
    ``observe(state, params)`` method are observed once, after the selection, so that the
    observations of the step and of the reset are never both computed.
    """
    key_step, key_reset = jax.random.split(key)
    obs, next_state, reward, terminated, truncated, info = env.step(key_step, state, action, params)
    reset_obs, reset_state = env.reset(key_reset, state.world if next_world is None else next_world, params)
    done = jnp.logical_or(terminated, truncated)
    if done.ndim:  # multi-agent envs end an episode for everybody at once
        done = done.any()
    pick = lambda fresh, old: jax.lax.select(done, fresh, old)  # noqa: E731
    new_state = jax.tree_util.tree_map(pick, reset_state.replace(world=None), next_state.replace(world=None))
    if next_world is None:
        new_state = new_state.replace(world=state.world)
    else:
        new_state = new_state.replace(world=jax.tree_util.tree_map(pick, reset_state.world, state.world))
    observe = getattr(env, "observe", None)
    new_obs = observe(new_state, params) if observe is not None else pick(reset_obs, obs)
    if ended_metrics:
        return new_obs, new_state, reward, terminated, truncated, info, env.metrics(next_state)
    return new_obs, new_state, reward, terminated, truncated, info


def check_finite(name: str, value: Any) -> np.ndarray:
    """Host-side check that ``value`` is a finite float array; returns it as numpy."""
    array = np.asarray(value, dtype=np.float64)
    if not np.all(np.isfinite(array)):
        raise WorldagentError(f"{name} contains NaN or infinite values; pass finite numbers.")
    return array


def check_shape(name: str, value: Any, shape: tuple[int | None, ...]) -> None:
    """Check an array's shape (static, so this works on tracers too); ``None`` matches any size."""
    actual = np.shape(value)
    ok = len(actual) == len(shape) and all(w is None or w == s for s, w in zip(actual, shape))
    if not ok:
        want = "(" + ", ".join("any" if w is None else str(w) for w in shape) + ")"
        raise WorldagentError(f"{name} has shape {tuple(actual)}; expected {want}.")


def check_actions(value: Any, num_actions: int, shape: tuple[int, ...] = ()) -> np.ndarray:
    """Host-side check that actions are integers in ``[0, num_actions)`` of the given shape."""
    array = np.asarray(value)
    if array.shape != shape:
        raise WorldagentError(f"action has shape {array.shape}; expected {shape}.")
    if not np.issubdtype(array.dtype, np.integer) or array.min(initial=0) < 0 or array.max(initial=0) >= num_actions:
        raise WorldagentError(f"action {array.tolist()} is not an integer in [0, {num_actions}); pick a valid action index.")
    return array


def initial_memory(policy) -> Any:
    """The memory an episode of ``policy`` starts with: its ``initial_memory``, None if memoryless."""
    return getattr(policy, "initial_memory", None)


def policy_step(policy, obs: Any, key: jax.Array, state: Any, memory: Any) -> tuple[Any, Any]:
    """``(action, memory)``: one step of ``policy``, the one adapter every rollout loop acts through.

    A policy with memory (``step`` set, e.g. a recurrent PPO agent) steps with it; a memoryless
    one (``agents.policy.Policy`` of an MLP, ``registry.ScriptedPolicy``) acts with
    ``act(params, obs, key, state)`` and hands ``memory`` (None) back unchanged, so its loops
    compute exactly what they did before policies had memory.
    """
    step = getattr(policy, "step", None)
    if step is None:
        return policy.act(policy.params, obs, key, state), memory
    return step(policy.params, obs, key, state, memory)


def rollout(env: Environment, policy, key: jax.Array, world: Any, params: Any, num_steps: int):
    """One episode of at most ``num_steps`` steps as a ``lax.scan``; frozen once it ends.

    Args:
        policy: a policy value with ``params`` and ``act(params, obs, key, state) -> action``
            (pure JAX): ``agents.policy.Policy`` (with memory or not) or ``registry.ScriptedPolicy``.

    Returns:
        (final_state, trajectory): ``trajectory`` holds per-step pytrees with a leading time axis
        ``[T, ...]``: ``state`` (the state after each step, without its world), ``action``,
        ``reward`` and ``alive`` (True for the steps taken before the episode ended).
    """
    key_reset, key_steps = jax.random.split(key)
    obs, state = env.reset(key_reset, world, params)

    def one_step(carry, step_key):
        obs, state, done, memory = carry
        key_act, key_env = jax.random.split(step_key)
        action, next_memory = policy_step(policy, obs, key_act, state, memory)
        next_obs, next_state, reward, terminated, truncated, _ = env.step(key_env, state, action, params)
        keep = lambda new, old: jax.lax.select(done, old, new)  # noqa: E731
        next_obs = keep(next_obs, obs)
        next_state = jax.tree_util.tree_map(keep, next_state, state)
        next_memory = jax.tree_util.tree_map(keep, next_memory, memory)
        reward = jnp.where(done, jnp.zeros_like(reward), reward)
        ended = jnp.logical_or(terminated, truncated)
        next_done = jnp.logical_or(done, ended.any() if ended.ndim else ended)
        record = {"state": next_state.replace(world=None), "action": action, "reward": reward, "alive": ~done}
        return (next_obs, next_state, next_done, next_memory), record

    start = (obs, state, jnp.bool_(False), initial_memory(policy))
    (_, final_state, _, _), trajectory = jax.lax.scan(one_step, start, jax.random.split(key_steps, num_steps))
    return final_state, trajectory
