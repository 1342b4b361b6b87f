"""The toy gridworld: one agent walks from the top-left cell to the goal (a worked example).

It follows ``worldagent.envs.core``'s contract as racing and harvest do: a frozen ``Environment``
with static configuration, traced ``params``, a ``state`` that carries its ``world`` and
accumulates the episode's metrics, and pure jittable ``reset``/``step``.

Actions: 0 up, 1 right, 2 down, 3 left; a move into a wall or off the grid stays put. Reward:
``-step_penalty`` every step and ``goal_reward`` on reaching the goal, which terminates the
episode; ``max_steps`` steps without reaching it truncate it.

Observation f32[3·S·S]: the wall grid, the goal grid and the agent's cell (one-hot), flattened.
"""

from __future__ import annotations

from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from worldagent.envs.core import Environment, check_actions, check_shape
from worldagent.errors import WorldagentError

from .world import SIZE, START, Grid

MOVES = np.array([[-1, 0], [0, 1], [1, 0], [0, -1]], np.int32)  # up, right, down, left as (drow, dcol)


@struct.dataclass
class ToyParams:
    """Traced parameters.

    Attributes:
        step_penalty: reward lost every step.
        goal_reward: reward for reaching the goal.
        max_steps: steps after which an episode is truncated.
    """

    step_penalty: float = 0.01
    goal_reward: float = 1.0
    max_steps: int = 30


@struct.dataclass
class ToyState:
    """The agent's cell and the episode's running metrics.

    Attributes:
        world: the grid being played.
        position: i32[2] (row, col).
        time: i32 steps taken.
        episode_return: f32 sum of rewards.
        reached: bool, the agent stands on the goal.
    """

    world: Grid
    position: jax.Array
    time: jax.Array
    episode_return: jax.Array
    reached: jax.Array


@dataclass(frozen=True)
class ToyGrid(Environment):
    """The toy gridworld (static configuration: the grid side)."""

    size: int = SIZE

    num_agents = 1

    @property
    def default_params(self) -> ToyParams:
        return ToyParams()

    @property
    def num_actions(self) -> int:
        return len(MOVES)

    @property
    def observation_shape(self) -> tuple[int, ...]:
        return (3 * self.size * self.size,)

    observation_dtype = jnp.float32

    def check_world(self, world: Grid) -> None:
        """Raise ``WorldagentError`` if ``world`` is not one grid this env can play."""
        if not isinstance(world, Grid):
            raise WorldagentError(f"world is a {type(world).__name__}; expected a toy Grid (see toy_env.world.generate).")
        check_shape("toy walls", world.walls, (self.size, self.size))
        check_shape("toy goal", world.goal, (self.size, self.size))
        if not any(isinstance(leaf, jax.core.Tracer) for leaf in jax.tree_util.tree_leaves(world)):
            world.validate()

    def reset(self, key: jax.Array, world: Grid, params: ToyParams) -> tuple[jax.Array, ToyState]:
        """The agent at the start cell (deterministic; ``key`` unused)."""
        del key
        world = Grid(walls=jnp.asarray(world.walls, bool), goal=jnp.asarray(world.goal, bool))
        state = ToyState(world, jnp.asarray(START, jnp.int32), jnp.int32(0), jnp.float32(0.0), jnp.bool_(False))
        return self.observe(state, params), state

    def step(self, key: jax.Array, state: ToyState, action: jax.Array, params: ToyParams):
        """One move (deterministic; ``key`` unused). Returns ``(obs, state, reward, terminated, truncated, info)``."""
        del key
        if not isinstance(action, jax.core.Tracer):
            check_actions(action, self.num_actions)
        target = state.position + jnp.asarray(MOVES)[action]
        inside = jnp.all((target >= 0) & (target < self.size))
        clipped = jnp.clip(target, 0, self.size - 1)
        free = inside & ~state.world.walls[clipped[0], clipped[1]]
        position = jnp.where(free, clipped, state.position)
        reached = state.world.goal[position[0], position[1]]
        reward = jnp.where(reached, params.goal_reward, 0.0) - params.step_penalty
        time = state.time + 1
        terminated = reached
        truncated = jnp.logical_and(time >= params.max_steps, ~terminated)
        state = state.replace(position=position, time=time, episode_return=state.episode_return + reward, reached=reached)
        return self.observe(state, params), state, reward.astype(jnp.float32), terminated, truncated, {"reached": reached}

    def observe(self, state: ToyState, params: ToyParams) -> jax.Array:
        """f32[3·S·S]: walls, goal and the agent's cell, flattened."""
        del params
        agent = jnp.zeros((self.size, self.size), jnp.float32).at[state.position[0], state.position[1]].set(1.0)
        return jnp.concatenate([state.world.walls.astype(jnp.float32).ravel(), state.world.goal.astype(jnp.float32).ravel(), agent.ravel()])

    def metrics(self, state: ToyState) -> dict[str, jax.Array]:
        """The episode's return, whether it reached the goal, and its steps."""
        return {"return": state.episode_return, "reached": state.reached, "steps": state.time}
