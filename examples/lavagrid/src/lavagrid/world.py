"""A lava grid: lava cells and one goal on an 11×11 grid, the agent starting top-left.

``LavaGrid`` holds one world or a batch (leading axis on both fields). Every world has a
lava-free path from the start to the goal: the generator clears one (``clear_path``: an
L-shaped path, down then across or across then down) and keeps the cells next to the start
free, so an agent always can reach the goal and is never born beside lava.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct
from scipy import ndimage

from worldagent.errors import WorldagentError

SIZE = 11
START = (0, 0)
SAFE_RADIUS = 2  # cells within this Manhattan distance of the start are never lava
MIN_GOAL_DISTANCE = 3  # just outside the safe zone: near goals teach a new agent where goals are, far ones are hard
LAVA_SHARE = (0.05, 0.3)  # the generator's lava density, drawn per world


@struct.dataclass
class LavaGrid:
    """Lava and goal cells.

    Attributes:
        lava: bool[..., S, S], True where stepping ends the episode with the lava penalty.
        goal: bool[..., S, S], exactly one True cell per world.
    """

    lava: np.ndarray
    goal: np.ndarray

    def validate(self) -> None:
        """Raise ``WorldagentError`` unless every world is well formed and its goal reachable."""
        lava, goal = np.asarray(self.lava), np.asarray(self.goal)
        if lava.shape[-2:] != (SIZE, SIZE) or goal.shape != lava.shape:
            raise WorldagentError(f"lava grid fields have shapes {lava.shape} and {goal.shape}; both must be [..., {SIZE}, {SIZE}].")
        lava, goal = lava.reshape(-1, SIZE, SIZE).astype(bool), goal.reshape(-1, SIZE, SIZE).astype(bool)
        for index, (hot, target) in enumerate(zip(lava, goal)):
            if target.sum() != 1:
                raise WorldagentError(f"lava grid {index} has {int(target.sum())} goal cells; a world has exactly one.")
            if hot[START] or (hot & target).any():
                raise WorldagentError(f"lava grid {index} has lava on its start or goal; clear them (lavagrid.world.clear_path).")
            components, _ = ndimage.label(~hot)
            if components[START] != components[np.unravel_index(np.argmax(target), target.shape)]:
                raise WorldagentError(f"lava grid {index}'s goal cannot be reached without lava; clear a path (lavagrid.world.clear_path).")


def safe_zone() -> jax.Array:
    """bool[S, S]: the cells near the start that are never lava."""
    rows, cols = jnp.meshgrid(jnp.arange(SIZE), jnp.arange(SIZE), indexing="ij")
    return jnp.abs(rows - START[0]) + jnp.abs(cols - START[1]) <= SAFE_RADIUS


def l_path(goal_index: jax.Array, rows_first: jax.Array) -> jax.Array:
    """bool[S, S]: the L-shaped path from the start (0, 0) to the goal cell ``goal_index`` (flat), down first or across first."""
    goal_row, goal_col = goal_index // SIZE, goal_index % SIZE
    rows, cols = jnp.meshgrid(jnp.arange(SIZE), jnp.arange(SIZE), indexing="ij")
    down_then_across = ((cols == 0) & (rows <= goal_row)) | ((rows == goal_row) & (cols <= goal_col))
    across_then_down = ((rows == 0) & (cols <= goal_col)) | ((cols == goal_col) & (rows <= goal_row))
    return jnp.where(rows_first, down_then_across, across_then_down)


def clear_path(lava: jax.Array, goal_index: jax.Array, rows_first: jax.Array) -> LavaGrid:
    """One world: ``lava`` bool[S, S] with the start's safe zone and an L path to the goal cleared, and the goal."""
    lava = lava & ~safe_zone() & ~l_path(goal_index, rows_first)
    goal = jax.nn.one_hot(goal_index, SIZE * SIZE, dtype=bool).reshape(SIZE, SIZE)
    return LavaGrid(lava=lava, goal=goal)


def _far_cells() -> np.ndarray:
    """int[K]: the flat cells at least ``MIN_GOAL_DISTANCE`` from the start (where generated goals go)."""
    rows, cols = np.indices((SIZE, SIZE))
    return np.flatnonzero((rows - START[0]) + (cols - START[1]) >= MIN_GOAL_DISTANCE)


def generate(seeds) -> LavaGrid:
    """The procedural generator: one world per seed (numpy ``default_rng(seed)``), deterministic.

    Lava falls on each cell with a probability drawn from ``LAVA_SHARE``; the goal is a cell at
    least ``MIN_GOAL_DISTANCE`` from the start; then ``clear_path`` makes it reachable.
    """
    lava, goals, rows_first = [], [], []
    far = _far_cells()
    for seed in np.asarray(seeds, np.int64).reshape(-1):
        rng = np.random.default_rng(int(seed))
        lava.append(rng.random((SIZE, SIZE)) < rng.uniform(*LAVA_SHARE))
        goals.append(rng.choice(far))
        rows_first.append(rng.random() < 0.5)
    worlds = jax.vmap(clear_path)(jnp.asarray(np.stack(lava)), jnp.asarray(goals, jnp.int32), jnp.asarray(rows_first))
    return LavaGrid(lava=np.asarray(worlds.lava), goal=np.asarray(worlds.goal))


def cells(worlds: LavaGrid) -> np.ndarray:
    """uint8[N, 2·S·S]: the lava cells then the goal cell, flattened (the VAE's input)."""
    lava, goal = np.asarray(worlds.lava, np.uint8), np.asarray(worlds.goal, np.uint8)
    return np.concatenate([lava.reshape(len(lava), -1), goal.reshape(len(goal), -1)], axis=1)
