"""The toy gridworld's world: walls and one goal on a small square grid, as a fixed-shape pytree.

Coordinates are ``grid[row, col]`` with row 0 at the top; the agent always starts at ``START``
(the top-left cell), which must be free, and the goal is one free cell other than the start.
"""

from __future__ import annotations

import jax
import numpy as np
from flax import struct

from worldagent.errors import WorldagentError

SIZE = 7  # grid side, cells
START = (0, 0)  # the agent's start cell (row, col)


@struct.dataclass
class Grid:
    """One grid (or a batch, with a leading axis on both fields).

    Attributes:
        walls: bool[S, S] wall cells.
        goal: bool[S, S] one-hot: the goal cell.
    """

    walls: jax.Array
    goal: jax.Array

    def validate(self) -> None:
        """Host-side check of shapes and the start/goal rules; raises ``WorldagentError``."""
        walls, goal = np.asarray(self.walls), np.asarray(self.goal)
        if walls.shape[-2:] != (SIZE, SIZE) or walls.shape != goal.shape:
            raise WorldagentError(f"toy grid has walls {walls.shape} and goal {goal.shape}; expected two ({SIZE}, {SIZE}) grids.")
        for name, grid in (("walls", walls), ("goal", goal)):
            if not np.isin(grid, (0, 1)).all():
                raise WorldagentError(f"toy grid {name} must be 0/1; threshold it first.")
        walls, goal = walls.astype(bool), goal.astype(bool)
        if np.any(goal.sum(axis=(-2, -1)) != 1):
            raise WorldagentError("toy grid needs exactly one goal cell; set one cell of goal to 1.")
        if np.any(walls & goal):
            raise WorldagentError("toy grid has its goal inside a wall; clear the wall on the goal cell.")
        if np.any(walls[..., START[0], START[1]] | goal[..., START[0], START[1]]):
            raise WorldagentError("toy grid blocks the start cell (top-left); keep it free of walls and of the goal.")


def generate(seeds) -> Grid:
    """The toy's procedural generator: ``seeds int64[N] -> Grid`` batch (numpy).

    Each cell is a wall with probability 0.25 (the start and its two neighbours never); the goal is a uniformly chosen
    free cell other than the start. Goals may be walled off: some worlds are unwinnable.
    """
    seeds = np.asarray(seeds, np.int64).reshape(-1)
    walls = np.zeros((len(seeds), SIZE, SIZE), bool)
    goal = np.zeros((len(seeds), SIZE, SIZE), bool)
    for i, seed in enumerate(seeds):
        rng = np.random.default_rng([int(seed), 11])
        walls[i] = rng.random((SIZE, SIZE)) < 0.25
        walls[i][START] = walls[i][START[0], START[1] + 1] = walls[i][START[0] + 1, START[1]] = False  # a way out of the corner
        free = np.flatnonzero(~walls[i].reshape(-1))
        free = free[free != START[0] * SIZE + START[1]]
        goal[i].reshape(-1)[rng.choice(free)] = True
    return Grid(walls=walls, goal=goal)


def cells(worlds: Grid) -> np.ndarray:
    """uint8[N, 2·S·S]: each world's wall grid and goal grid, the VAE's input."""
    grids = np.stack([np.asarray(worlds.walls), np.asarray(worlds.goal)], axis=1)
    return grids.reshape(len(grids), -1).astype(np.uint8)
