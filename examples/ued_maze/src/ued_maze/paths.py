"""Shortest paths in a maze, in JAX: the ``shortest_path`` descriptor and the privileged ``oracle`` policy.

A breadth-first search over the free cells (4-neighbours), written as repeated relaxation of a
distance grid until it stops changing (at most one sweep per cell of the longest path): pure,
jittable and vmappable. jaxued's agent never stands on the goal (walking into it ends the
episode), but the goal's cell counts as the path's last cell.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from worldagent.envs.registry import ScriptedPolicy

from .world import SIZE, MazeWorld

UNREACHABLE = SIZE * SIZE  # larger than any path's length (a path visits each cell at most once)
MOVES = jnp.array([[1, 0], [0, 1], [-1, 0], [0, -1]], jnp.int32)  # jaxued's DIR_TO_VEC as (dx, dy): right, down, left, up
FORWARD, RIGHT, LEFT = 2, 1, 0  # jaxued's Actions


def distances(wall_map: jax.Array, source: jax.Array) -> jax.Array:
    """i32[13, 13]: moves from ``source`` (x, y) to each cell over free cells; ``UNREACHABLE`` on walls and cut-off cells.

    Args:
        wall_map: bool[13, 13] indexed [y, x].
        source: i32[2] (x, y).
    """
    free = ~jnp.asarray(wall_map, bool)
    start = jnp.full((SIZE, SIZE), UNREACHABLE, jnp.int32).at[source[1], source[0]].set(0)

    def relax(carry):
        grid, _ = carry
        padded = jnp.pad(grid, 1, constant_values=UNREACHABLE)
        neighbours = jnp.minimum(jnp.minimum(padded[:-2, 1:-1], padded[2:, 1:-1]), jnp.minimum(padded[1:-1, :-2], padded[1:-1, 2:]))
        relaxed = jnp.where(free, jnp.minimum(grid, neighbours + 1), grid)
        return relaxed, jnp.any(relaxed != grid)

    grid, _ = jax.lax.while_loop(lambda carry: carry[1], relax, (start, jnp.bool_(True)))
    return grid


@jax.jit
def path_length(world: MazeWorld) -> jax.Array:
    """i32: moves from the agent's start to the goal's cell; -1 when walls cut the goal off."""
    goal = jnp.asarray(world.goal_pos, jnp.int32)
    moves = distances(world.wall_map, jnp.asarray(world.agent_pos, jnp.int32))[goal[1], goal[0]]
    return jnp.where(moves >= UNREACHABLE, -1, moves)


def shortest_path(world: MazeWorld) -> float:
    """The descriptor: moves from the start to the goal of one (unbatched) maze, -1 if it cannot be solved."""
    return float(path_length(jax.tree_util.tree_map(np.asarray, world)))


def wall_count(world: MazeWorld) -> float:
    """The descriptor: wall cells of one maze."""
    return float(np.asarray(world.wall_map, bool).sum())


def oracle_action(state) -> jax.Array:
    """i32: the action of a shortest path from jaxued's state: forward when the cell ahead is nearer the goal, else a turn
    toward a nearer neighbour (right if that one is, else left); with the goal cut off, it turns left forever."""
    inner = state.inner
    to_goal = distances(inner.wall_map, inner.goal_pos.astype(jnp.int32))
    position, direction = inner.agent_pos.astype(jnp.int32), inner.agent_dir.astype(jnp.int32)

    def distance_toward(d):
        x, y = position + MOVES[d % 4]
        inside = (x >= 0) & (x < SIZE) & (y >= 0) & (y < SIZE)
        return jnp.where(inside, to_goal[jnp.clip(y, 0, SIZE - 1), jnp.clip(x, 0, SIZE - 1)], UNREACHABLE)

    here = to_goal[position[1], position[0]]
    action = jnp.where(distance_toward(direction + 1) < here, RIGHT, LEFT)
    return jnp.where(distance_toward(direction) < here, FORWARD, action).astype(jnp.int32)


def oracle(env, params) -> ScriptedPolicy:
    """Privileged: walks a shortest path to the goal (reads the walls and the goal from the state), solving every solvable maze."""
    del env, params
    return ScriptedPolicy(None, lambda p, obs, key, state: oracle_action(state), privileged=True)


def uniform(env, params) -> ScriptedPolicy:
    """Uniformly random actions among jaxued's seven: the baseline a trained agent must beat."""
    del params
    return ScriptedPolicy(None, lambda p, obs, key, state: jax.random.randint(key, (), 0, env.num_actions))
