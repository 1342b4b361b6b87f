"""G(z)'s repair: decoded cell logits to a valid maze that need not be in the dataset (an open repair).

Scattered walls are noise to a VAE: near the mean maze every cell's wall probability is about the
dataset's wall share (~7%), so thresholding at p = 1/2 leaves an empty maze. The default keeps the
decoded wall *count* instead (``round(Σ p)``, the most probable cells), as ``tests/scatter_env.py``
does; ``walls=threshold`` thresholds. Then the goal is the most probable cell off the walls, and
the agent's start the most probable (cell, direction) off the walls and the goal; both cells are
cleared of walls, so the maze is always valid (goal and start free and distinct). The maze may
still have its goal cut off from the start, as jaxued's own generator allows.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from worldagent.errors import WorldagentError

from .world import CELLS, DIRECTIONS, SIZE, MazeWorld

WALL_RULES = ("count", "threshold")
BLOCKED = 1e6  # subtracted from the logits of cells a choice must avoid: any free cell wins over them


def split(logits: jax.Array) -> tuple[jax.Array, jax.Array, jax.Array]:
    """(walls f[B, 169], goal f[B, 169], agent f[B, 4, 169]): the cell channels of ``world.cells``."""
    return logits[:, :CELLS], logits[:, CELLS : 2 * CELLS], logits[:, 2 * CELLS :].reshape(-1, DIRECTIONS, CELLS)


def positions(index: jax.Array) -> jax.Array:
    """i32[B, 2] (x, y) of flat cell indices i32[B]."""
    return jnp.stack([index % SIZE, index // SIZE], axis=-1).astype(jnp.int32)


@struct.dataclass
class MazeRepair:
    """New valid mazes: the decoded wall count's likeliest cells, then the goal and the start on the likeliest free cells.

    Attributes:
        walls: "count" (the decoded wall count's most probable cells) or "threshold" (cells with p > 1/2).
    """

    walls: str = struct.field(pytree_node=False, default="count")

    @classmethod
    def from_dataset(cls, dataset, config=None) -> MazeRepair:
        """The repair with ``config``'s settings (``generator train --repair walls=threshold``); the dataset is not needed."""
        del dataset
        settings = dict(config or {})
        unknown = sorted(set(settings) - {"walls"})
        if unknown:
            raise WorldagentError(f"the ued_maze repair has no setting {unknown[0]!r}; its only setting is walls={'|'.join(WALL_RULES)}.")
        repair = cls(**settings)
        if repair.walls not in WALL_RULES:
            raise WorldagentError(f"walls={repair.walls!r}; pick one of: {', '.join(WALL_RULES)}.")
        return repair

    @property
    def config(self) -> dict:
        return {"walls": self.walls}

    def __call__(self, logits: jax.Array) -> MazeWorld:
        """Valid mazes (batched, leading axis B) from decoded logits f32[B, 6·169]."""
        wall_logits, goal_logits, agent_logits = split(jnp.asarray(logits, jnp.float32))
        if self.walls == "count":
            count = jnp.round(jax.nn.sigmoid(wall_logits).sum(-1, keepdims=True))
            rank = jnp.argsort(jnp.argsort(-wall_logits, axis=-1), axis=-1)
            walls = rank < count
        else:
            walls = wall_logits > 0
        goal = jnp.argmax(goal_logits - BLOCKED * walls, axis=-1)
        goal_cell = jax.nn.one_hot(goal, CELLS, dtype=bool)
        avoid = BLOCKED * walls + 2 * BLOCKED * goal_cell  # the goal's cell loses even to a wall (which is cleared)
        choice = jnp.argmax((agent_logits - avoid[:, None, :]).reshape(len(goal), -1), axis=-1)
        direction, agent = choice // CELLS, choice % CELLS
        cleared = walls & ~goal_cell & ~jax.nn.one_hot(agent, CELLS, dtype=bool)
        return MazeWorld(
            wall_map=cleared.reshape(-1, SIZE, SIZE), goal_pos=positions(goal), agent_pos=positions(agent), agent_dir=direction.astype(jnp.int32)
        )


def raw_decode(logits) -> MazeWorld:
    """Thresholded cells without repair, for the "valid before repair" figure: the walls, and the most probable goal and
    start (which may lie on walls, or on each other)."""
    logits = np.asarray(logits, np.float32)
    walls, goal, agent = (np.asarray(part) for part in split(jnp.asarray(logits)))
    choice = agent.reshape(len(logits), -1).argmax(-1)
    goal_index = goal.argmax(-1)
    return MazeWorld(
        wall_map=(walls > 0).reshape(-1, SIZE, SIZE),
        goal_pos=np.stack([goal_index % SIZE, goal_index // SIZE], -1).astype(np.int32),
        agent_pos=np.stack([choice % CELLS % SIZE, choice % CELLS // SIZE], -1).astype(np.int32),
        agent_dir=(choice // CELLS).astype(np.int32),
    )
