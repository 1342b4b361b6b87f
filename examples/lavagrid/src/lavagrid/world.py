"""A lava grid: pools of lava and one goal on an 11×11 grid, the agent starting top-left.

``LavaGrid`` holds one world or a batch (leading axis on both fields). Lava lies in a few
rectangular pools, not scattered cell by cell: a VAE learns where pools are, while i.i.d. lava
cells are noise it cannot encode (its decoder gave every cell p < 0.5: G(z) worlds had 0.01% lava
against the dataset's 16%). Every world keeps the cells next to the start free and has a lava-free path to the goal.
"""

from __future__ import annotations

import numpy as np
from flax import struct
from scipy import ndimage

from worldagent.errors import WorldagentError

SIZE = 11
START = (0, 0)
SAFE_RADIUS = 2  # cells within this Manhattan distance of the start are never lava
MIN_GOAL_DISTANCE = 3  # just outside the safe zone: near goals teach a new agent where goals are, far ones are hard
POOLS = (2, 5)  # lava pools per world, drawn in [low, high)
POOL_SIDE = (2, 5)  # each pool's height and width, drawn in [low, high)


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
        for index, (hot, target) in enumerate(zip(lava.reshape(-1, SIZE, SIZE).astype(bool), goal.reshape(-1, SIZE, SIZE).astype(bool))):
            if target.sum() != 1:
                raise WorldagentError(f"lava grid {index} has {int(target.sum())} goal cells; a world has exactly one.")
            if not reachable(hot, target):
                raise WorldagentError(f"lava grid {index}'s goal cannot be reached from the start without lava; clear a path to it.")


def reachable(lava: np.ndarray, goal: np.ndarray) -> bool:
    """Whether a lava-free 4-connected path joins the start and the goal of one world (bool[S, S] each)."""
    if lava[START] or (lava & goal).any():
        return False
    components, _ = ndimage.label(~lava)
    return bool(components[START] == components[np.unravel_index(np.argmax(goal), goal.shape)])


def distances() -> np.ndarray:
    """int[S, S]: each cell's Manhattan distance from the start."""
    rows, cols = np.indices((SIZE, SIZE))
    return np.abs(rows - START[0]) + np.abs(cols - START[1])


def draw(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """(lava, goal) bool[S, S] each: a few rectangular pools off the start's safe zone, a goal off the lava."""
    lava = np.zeros((SIZE, SIZE), bool)
    for _ in range(rng.integers(*POOLS)):
        height, width = rng.integers(*POOL_SIDE, size=2)
        row, col = rng.integers(0, SIZE - height + 1), rng.integers(0, SIZE - width + 1)
        lava[row : row + height, col : col + width] = True
    lava &= distances() > SAFE_RADIUS
    goal = np.zeros((SIZE, SIZE), bool)
    goal.flat[rng.choice(np.flatnonzero((distances() >= MIN_GOAL_DISTANCE) & ~lava))] = True
    return lava, goal


def generate(seeds) -> LavaGrid:
    """The procedural generator: one world per seed (numpy ``default_rng(seed)``), deterministic.

    Draws pools and a goal until the goal is reachable (a few draws at most: pools rarely wall it off).
    """
    lava, goals = [], []
    for seed in np.asarray(seeds, np.int64).reshape(-1):
        rng = np.random.default_rng(int(seed))
        while not reachable(*(world := draw(rng))):
            pass
        lava.append(world[0])
        goals.append(world[1])
    return LavaGrid(lava=np.stack(lava), goal=np.stack(goals))


def cells(worlds: LavaGrid) -> np.ndarray:
    """uint8[N, 2·S·S]: the lava cells then the goal cell, flattened (the VAE's input)."""
    lava, goal = np.asarray(worlds.lava, np.uint8), np.asarray(worlds.goal, np.uint8)
    return np.concatenate([lava.reshape(len(lava), -1), goal.reshape(len(goal), -1)], axis=1)
