"""jaxued's maze behind worldagent's environment contract (``worldagent.envs.core``).

Every transition is jaxued's: ``reset`` calls ``Maze.reset_env_to_level`` on the world's ``Level``
and ``step`` calls ``Maze.step_env`` (the pure functions under jaxued's jitted ``reset_to_level``
and ``step``), with jaxued's defaults: a 5×5 egocentric view, observations divided by 10 (as its
``maze_plr.py`` makes the env), a goal reward of ``1 - 0.9·t / max_steps`` that ends the episode,
and 250 steps. This module only adapts the faces:

- observation f32[5·5·3 + 4]: jaxued's view image flattened, then its direction one-hot
  (worldagent's PPO and ACKTR read a flat vector);
- actions: jaxued's seven (0 left, 1 right, 2 forward, 3 pickup, 4 drop, 5 toggle, 6 done; the
  last four do nothing in the maze);
- ``terminated`` when the agent walks into the goal (jaxued's reward is positive exactly then),
  ``truncated`` at ``params.max_steps`` otherwise (jaxued folds both into one ``done``);
- the state carries the world and the episode's metrics: ``return``, ``solved``, ``episode_length``.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import jax
import jax.numpy as jnp
from flax import struct
from jaxued.environments.maze import Maze
from jaxued.environments.maze.env import Actions, EnvParams, EnvState

from worldagent.envs.core import Environment, check_actions, check_shape
from worldagent.errors import WorldagentError

from .world import DIRECTIONS, SIZE, MazeWorld, to_level

VIEW = 5  # jaxued's default agent_view_size
CHANNELS = 3  # jaxued's image channels: object, colour, state
MAX_STEPS = 250  # jaxued's EnvParams.max_steps_in_episode


@struct.dataclass
class MazeParams:
    """Traced parameters.

    Attributes:
        max_steps: steps after which an episode is truncated (jaxued's ``max_steps_in_episode``; its
            goal reward also shrinks over them).
    """

    max_steps: int = MAX_STEPS


@struct.dataclass
class MazeState:
    """jaxued's state of the episode, its world and the metrics so far.

    Attributes:
        world: the maze being played.
        inner: jaxued's ``EnvState`` (agent_pos u32[2] (x, y), agent_dir u8, goal_pos, wall_map,
            maze_map u8[21, 21, 3] padded, time i32, terminal bool), with fixed dtypes.
        episode_return: f32 sum of rewards.
        solved: bool, the agent has reached the goal.
    """

    world: MazeWorld
    inner: EnvState
    episode_return: jax.Array
    solved: jax.Array


@functools.cache
def jaxued_maze(view: int = VIEW) -> Maze:
    """jaxued's ``Maze`` as ``maze_plr.py`` makes it (13×13, normalised observations), one per view size."""
    return Maze(max_height=SIZE, max_width=SIZE, agent_view_size=view, normalize_obs=True)


def canonical(inner: EnvState) -> EnvState:
    """jaxued's state with the same dtypes after reset and step (its step turns ``agent_dir`` u8 into i32, ``time`` int into i32)."""
    return inner.replace(
        agent_pos=jnp.asarray(inner.agent_pos, jnp.uint32),
        agent_dir=jnp.asarray(inner.agent_dir, jnp.uint8),
        goal_pos=jnp.asarray(inner.goal_pos, jnp.uint32),
        wall_map=jnp.asarray(inner.wall_map, jnp.bool_),
        maze_map=jnp.asarray(inner.maze_map, jnp.uint8),
        time=jnp.asarray(inner.time, jnp.int32),
        terminal=jnp.asarray(inner.terminal, jnp.bool_),
    )


@dataclass(frozen=True)
class UedMazeEnv(Environment):
    """jaxued's maze (static configuration: the side of the agent's view, jaxued's ``agent_view_size``)."""

    view: int = VIEW

    num_agents = 1
    observation_dtype = jnp.float32

    @property
    def maze(self) -> Maze:
        return jaxued_maze(self.view)

    @property
    def default_params(self) -> MazeParams:
        return MazeParams()

    @property
    def num_actions(self) -> int:
        return len(Actions)

    @property
    def observation_shape(self) -> tuple[int, ...]:
        return (self.view * self.view * CHANNELS + DIRECTIONS,)

    def check_world(self, world: MazeWorld) -> None:
        """Raise ``WorldagentError`` if ``world`` is not one maze this env can play."""
        if not isinstance(world, MazeWorld):
            raise WorldagentError(f"world is a {type(world).__name__}; expected a MazeWorld (see ued_maze.world.generate or from_level).")
        check_shape("maze wall_map", world.wall_map, (SIZE, SIZE))
        check_shape("maze goal_pos", world.goal_pos, (2,))
        check_shape("maze agent_pos", world.agent_pos, (2,))
        check_shape("maze agent_dir", world.agent_dir, ())
        if not any(isinstance(leaf, jax.core.Tracer) for leaf in jax.tree_util.tree_leaves(world)):
            world.validate()

    def jaxued_params(self, params: MazeParams) -> EnvParams:
        """jaxued's ``EnvParams`` for ``params``."""
        return EnvParams(max_steps_in_episode=params.max_steps)

    def reset(self, key: jax.Array, world: MazeWorld, params: MazeParams) -> tuple[jax.Array, MazeState]:
        """jaxued's reset onto ``world``'s level. Returns ``(obs f32[D], state)``."""
        world = MazeWorld(
            wall_map=jnp.asarray(world.wall_map, jnp.bool_),
            goal_pos=jnp.asarray(world.goal_pos, jnp.int32),
            agent_pos=jnp.asarray(world.agent_pos, jnp.int32),
            agent_dir=jnp.asarray(world.agent_dir, jnp.int32),
        )
        obs, inner = self.maze.reset_env_to_level(key, to_level(world), self.jaxued_params(params))
        return flat_observation(obs), MazeState(world, canonical(inner), jnp.float32(0.0), jnp.bool_(False))

    def step(self, key: jax.Array, state: MazeState, action: jax.Array, params: MazeParams):
        """jaxued's step. Returns ``(obs f32[D], state, reward f32, terminated, truncated, info)``."""
        if not isinstance(action, jax.core.Tracer):
            check_actions(action, self.num_actions)
        obs, inner, reward, _, _ = self.maze.step_env(key, state.inner, action, self.jaxued_params(params))
        inner = canonical(inner)
        reward = jnp.asarray(reward, jnp.float32)
        solved = reward > 0  # jaxued rewards only the step into the goal, and that reward is at least 0.1
        truncated = (inner.time >= params.max_steps) & ~solved
        state = state.replace(inner=inner, episode_return=state.episode_return + reward, solved=state.solved | solved)
        return flat_observation(obs), state, reward, solved, truncated, {"solved": solved}

    def observe(self, state: MazeState, params: MazeParams) -> jax.Array:
        """f32[D]: jaxued's observation of ``state``."""
        del params
        return flat_observation(self.maze.get_obs(state.inner))

    def metrics(self, state: MazeState) -> dict[str, jax.Array]:
        """The episode's return, whether it reached the goal, and its steps."""
        return {"return": state.episode_return, "solved": state.solved, "episode_length": state.inner.time}


def flat_observation(obs) -> jax.Array:
    """f32[V·V·3 + 4]: jaxued's ``Observation`` (image f32[V, V, 3], agent_dir) as one vector."""
    direction = jax.nn.one_hot(obs.agent_dir, DIRECTIONS, dtype=jnp.float32)
    return jnp.concatenate([jnp.asarray(obs.image, jnp.float32).ravel(), direction])
