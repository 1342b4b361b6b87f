"""A stranger's environment for the generator's quality tests (issue 39): jaxued's maze with scattered walls.

A 13x13 grid whose wall count is uniform in [0, 25], the walls scattered uniformly (no corridors,
no structure), and one goal; the agent starts in the top-left cell. It has no dynamics (``make``
refuses): it exists to train generators on, through the public API only::

    from scatter_env import registered

    with registered() as spec:
        make_dataset(spec.name, 512, 0)

The default repair keeps the decoded wall count: the ``round(sum p)`` most probable wall cells
(p = sigmoid of the wall logits), as the issue's stranger did; ``{"walls": "threshold"}`` keeps the
cells with p > 1/2 instead, which gives a wall-free maze from any decoder near the mean maze (mean
wall share 12.5/169 ≈ 7%).
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from toy_env import pictures
from toy_env.spec import trace
from worldagent.envs import registry
from worldagent.envs.registry import EnvSpec, Metrics, Pictures
from worldagent.errors import WorldagentError

NAME = "scatter"
SIZE = 13
CELLS = SIZE * SIZE
MAX_WALLS = 25
START_INDEX = 0  # the top-left cell, always free


@struct.dataclass
class Maze:
    """One maze (or a batch, with a leading axis on both fields).

    Attributes:
        walls: bool[13, 13] wall cells.
        goal: bool[13, 13] one-hot: the goal cell.
    """

    walls: jax.Array
    goal: jax.Array

    def validate(self) -> None:
        """Shapes, 0/1 cells, one goal off the walls, a free start; raises ``WorldagentError``."""
        walls, goal = np.asarray(self.walls), np.asarray(self.goal)
        if walls.shape[-2:] != (SIZE, SIZE) or walls.shape != goal.shape:
            raise WorldagentError(f"maze has walls {walls.shape} and goal {goal.shape}; expected two ({SIZE}, {SIZE}) grids.")
        if not (np.isin(walls, (0, 1)).all() and np.isin(goal, (0, 1)).all()):
            raise WorldagentError("maze cells must be 0/1; threshold them first.")
        walls, goal = walls.astype(bool), goal.astype(bool)
        if np.any(goal.sum(axis=(-2, -1)) != 1) or np.any(walls & goal):
            raise WorldagentError("maze needs exactly one goal cell, off the walls.")
        if np.any(walls[..., 0, 0] | goal[..., 0, 0]):
            raise WorldagentError("maze blocks the start cell (top-left); keep it free.")


def generate(seeds) -> Maze:
    """``seeds int64[N] -> Maze`` batch: ``n ~ U{0..25}`` walls on distinct cells other than the start, a goal on a free cell."""
    seeds = np.asarray(seeds, np.int64).reshape(-1)
    walls = np.zeros((len(seeds), CELLS), bool)
    goal = np.zeros((len(seeds), CELLS), bool)
    for i, seed in enumerate(seeds):
        rng = np.random.default_rng([int(seed), 39])
        walls[i, 1 + rng.choice(CELLS - 1, rng.integers(0, MAX_WALLS + 1), replace=False)] = True
        free = np.flatnonzero(~walls[i])
        goal[i, rng.choice(free[free != START_INDEX])] = True
    return Maze(walls=walls.reshape(-1, SIZE, SIZE), goal=goal.reshape(-1, SIZE, SIZE))


def cells(worlds: Maze) -> np.ndarray:
    """uint8[N, 2·169]: each maze's wall grid and goal grid."""
    grids = np.stack([np.asarray(worlds.walls), np.asarray(worlds.goal)], axis=1)
    return grids.reshape(len(grids), -1).astype(np.uint8)


@struct.dataclass
class ScatterRepair:
    """Walls: the decoded count's most probable cells (``count``) or those above p = 1/2 (``threshold``);
    the start kept free; the goal the most probable free cell.

    Attributes:
        walls: "count" or "threshold".
    """

    walls: str = struct.field(pytree_node=False, default="count")

    @classmethod
    def from_dataset(cls, dataset, config=None) -> ScatterRepair:
        del dataset
        repair = cls(**dict(config or {}))
        if repair.walls not in ("count", "threshold"):
            raise WorldagentError(f"walls={repair.walls!r}; pick count or threshold.")
        return repair

    @property
    def config(self) -> dict:
        return {"walls": self.walls}

    def __call__(self, logits: jax.Array) -> Maze:
        """A batch of valid mazes from decoded logits f32[B, 2·169]."""
        logits = jnp.asarray(logits, jnp.float32)
        start = jnp.arange(CELLS) == START_INDEX
        wall_logits = jnp.where(start, -jnp.inf, logits[:, :CELLS])
        if self.walls == "count":
            count = jnp.round(jax.nn.sigmoid(wall_logits).sum(-1, keepdims=True))
            rank = jnp.argsort(jnp.argsort(-wall_logits, axis=-1), axis=-1)
            walls = rank < count
        else:
            walls = wall_logits > 0
        goal_logits = jnp.where(start, -jnp.inf, logits[:, CELLS:] - 1e6 * walls)  # a free cell wins over any wall
        goal = jax.nn.one_hot(jnp.argmax(goal_logits, axis=-1), CELLS, dtype=bool)
        walls = walls & ~goal
        return Maze(walls=walls.reshape(-1, SIZE, SIZE), goal=goal.reshape(-1, SIZE, SIZE))


def make(options):
    raise WorldagentError("the scatter maze has no dynamics; it is a dataset for generator tests.")


def wall_count(world) -> float:
    return float(np.asarray(world.walls, bool).sum())


def goal_distance(world) -> float:
    row, col = np.unravel_index(int(np.argmax(np.asarray(world.goal))), (SIZE, SIZE))
    return float(row + col)


SPEC = EnvSpec(
    name=NAME,
    description="13x13 maze with 0-25 scattered walls (tests/scatter_env): a stranger's dataset for generator quality.",
    make=make,
    world_type=Maze,
    generate=generate,
    cells=cells,
    cell_shape=(2, SIZE, SIZE),
    repair=ScatterRepair.from_dataset,
    metrics=Metrics(
        main="return",
        names=("return",),
        descriptors={"wall_count": wall_count, "goal_distance": goal_distance},
        default_descriptors=("wall_count", "goal_distance"),
    ),
    trace=trace,
    pictures=Pictures(world=pictures.world_picture, episodes=pictures.draw_episodes, sheet=pictures.sheet),
)


@contextlib.contextmanager
def registered() -> Iterator[EnvSpec]:
    """The scatter spec, registered for the duration of the ``with`` block (removed after, if we added it)."""
    added = NAME not in registry.names()
    if added:
        registry.register(SPEC)
    try:
        yield registry.get(NAME)
    finally:
        if added:
            registry.unregister(NAME)
