"""The lava gridworld: walk from the top-left cell to the goal without stepping into lava.

It follows ``worldagent.envs.core``'s contract: a frozen ``Environment`` with static
configuration, traced ``params``, a ``state`` that carries its ``world`` and accumulates the
episode's metrics, and pure jittable ``reset``/``step``.

Actions: 0 up, 1 right, 2 down, 3 left; a move off the grid stays put. Reward (on the scale of
±1): ``goal_reward`` on reaching the goal and ``-lava_penalty`` on stepping into lava, each
ending the episode, and ``-step_penalty`` every step; ``max_steps`` steps truncate it.

Observation f32[2·V·V + 2], flat (PPO's networks take a 1-D observation): the lava and the
off-grid cells in the V×V window around the agent, then the goal's offset from the agent
(rows, columns) divided by the grid side. A local view generalises across worlds far better
than the whole grid does.
"""

from __future__ import annotations

from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from worldagent.envs.core import Environment, check_actions, check_shape
from worldagent.errors import WorldagentError

from .world import SIZE, START, LavaGrid

MOVES = np.array([[-1, 0], [0, 1], [1, 0], [0, -1]], np.int32)  # up, right, down, left as (drow, dcol)
VIEW = 7  # side of the window the agent sees, centred on it


@struct.dataclass
class LavaParams:
    """Traced parameters.

    Attributes:
        goal_reward: reward for reaching the goal.
        lava_penalty: reward lost by stepping into lava.
        step_penalty: reward lost every step.
        max_steps: steps after which an episode is truncated (a far goal is 20 moves away).
    """

    goal_reward: float = 1.0
    lava_penalty: float = 1.0
    step_penalty: float = 0.01
    max_steps: int = 60


@struct.dataclass
class LavaState:
    """The agent's cell and the episode's running metrics.

    Attributes:
        world: the grid being played.
        position: i32[2] (row, col).
        time: i32 steps taken.
        episode_return: f32 sum of rewards.
        reached: bool, the agent stands on the goal.
        burned: bool, the agent stepped into lava.
    """

    world: LavaGrid
    position: jax.Array
    time: jax.Array
    episode_return: jax.Array
    reached: jax.Array
    burned: jax.Array


@dataclass(frozen=True)
class LavaGridEnv(Environment):
    """The lava gridworld (static configuration: the side of the agent's view)."""

    view: int = VIEW

    num_agents = 1
    observation_dtype = jnp.float32

    @property
    def default_params(self) -> LavaParams:
        return LavaParams()

    @property
    def num_actions(self) -> int:
        return len(MOVES)

    @property
    def observation_shape(self) -> tuple[int, ...]:
        return (2 * self.view * self.view + 2,)

    def check_world(self, world: LavaGrid) -> None:
        """Raise ``WorldagentError`` if ``world`` is not one lava grid this env can play."""
        if not isinstance(world, LavaGrid):
            raise WorldagentError(f"world is a {type(world).__name__}; expected a LavaGrid (see lavagrid.world.generate).")
        check_shape("lava", world.lava, (SIZE, SIZE))
        check_shape("lava goal", world.goal, (SIZE, SIZE))
        if not any(isinstance(leaf, jax.core.Tracer) for leaf in jax.tree_util.tree_leaves(world)):
            world.validate()

    def reset(self, key: jax.Array, world: LavaGrid, params: LavaParams) -> tuple[jax.Array, LavaState]:
        """The agent on the start cell (deterministic; ``key`` unused)."""
        del key
        world = LavaGrid(lava=jnp.asarray(world.lava, bool), goal=jnp.asarray(world.goal, bool))
        state = LavaState(world, jnp.asarray(START, jnp.int32), jnp.int32(0), jnp.float32(0.0), jnp.bool_(False), jnp.bool_(False))
        return self.observe(state, params), state

    def step(self, key: jax.Array, state: LavaState, action: jax.Array, params: LavaParams):
        """One move (deterministic; ``key`` unused). Returns ``(obs, state, reward, terminated, truncated, info)``."""
        del key
        if not isinstance(action, jax.core.Tracer):
            check_actions(action, self.num_actions)
        target = state.position + jnp.asarray(MOVES)[action]
        inside = jnp.all((target >= 0) & (target < SIZE))
        position = jnp.where(inside, target, state.position)
        reached = state.world.goal[position[0], position[1]]
        burned = state.world.lava[position[0], position[1]]
        reward = jnp.where(reached, params.goal_reward, 0.0) - jnp.where(burned, params.lava_penalty, 0.0) - params.step_penalty
        time = state.time + 1
        terminated = reached | burned
        truncated = (time >= params.max_steps) & ~terminated
        state = state.replace(position=position, time=time, episode_return=state.episode_return + reward, reached=reached, burned=burned)
        return self.observe(state, params), state, reward.astype(jnp.float32), terminated, truncated, {"reached": reached, "burned": burned}

    def observe(self, state: LavaState, params: LavaParams) -> jax.Array:
        """f32[2·V·V + 2]: lava and off-grid cells in the window around the agent, then the goal's offset / S."""
        del params
        radius = self.view // 2
        lava = jnp.pad(state.world.lava.astype(jnp.float32), radius)
        outside = jnp.pad(jnp.zeros((SIZE, SIZE), jnp.float32), radius, constant_values=1.0)
        window = lambda grid: jax.lax.dynamic_slice(grid, (state.position[0], state.position[1]), (self.view, self.view)).ravel()
        offset = (goal_cell(state.world) - state.position).astype(jnp.float32) / SIZE
        return jnp.concatenate([window(lava), window(outside), offset])

    def metrics(self, state: LavaState) -> dict[str, jax.Array]:
        """The episode's return, whether it reached the goal or burned, and its steps."""
        return {"return": state.episode_return, "reached": state.reached, "burned": state.burned, "steps": state.time}


def goal_cell(world: LavaGrid) -> jax.Array:
    """i32[2]: the goal's (row, col) in one world."""
    goal = jnp.argmax(world.goal.ravel())
    return jnp.stack([goal // SIZE, goal % SIZE]).astype(jnp.int32)
