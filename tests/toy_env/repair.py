"""The toy's repair step (paper §4.2: G(z) = repair(decoder(z))): decoded cells -> a valid grid.

Walls are the wall logits above ``threshold`` (the start cell always free); the goal is the most
probable cell of the goal channel, free cells first, and its wall (if any) is cleared. Pure JAX,
so ``G(z)`` stays one jitted function.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from .world import SIZE, START, Grid

CELLS = SIZE * SIZE
START_INDEX = START[0] * SIZE + START[1]


@struct.dataclass
class ToyRepair:
    """Threshold the walls, keep the start free, goal = argmax of the goal channel.

    Attributes:
        threshold: wall logit above which a cell is a wall (0: probability one half).
    """

    threshold: float = struct.field(pytree_node=False, default=0.0)

    @classmethod
    def from_dataset(cls, dataset, config=None) -> ToyRepair:
        """The repair with ``config`` (``{"threshold": float}``); the dataset is not needed."""
        del dataset
        return cls(**dict(config or {}))

    @property
    def config(self) -> dict:
        return {"threshold": float(self.threshold)}

    def __call__(self, logits: jax.Array) -> Grid:
        """A batch of valid grids from decoded logits f32[B, 2·S·S]."""
        logits = jnp.asarray(logits, jnp.float32)
        start = jnp.arange(CELLS) == START_INDEX
        walls = (logits[:, :CELLS] > self.threshold) & ~start
        goal_logits = jnp.where(start, -jnp.inf, logits[:, CELLS:] - 1e6 * walls)  # a free cell wins over any wall
        goal = jax.nn.one_hot(jnp.argmax(goal_logits, axis=-1), CELLS, dtype=bool)
        walls = walls & ~goal
        return Grid(walls=walls.reshape(-1, SIZE, SIZE), goal=goal.reshape(-1, SIZE, SIZE))


def raw_decode(logits) -> Grid:
    """Thresholded cells without repair (may hold no goal, several, or a blocked start)."""
    cells = np.asarray(logits) > 0
    return Grid(walls=cells[:, :CELLS].reshape(-1, SIZE, SIZE), goal=cells[:, CELLS:].reshape(-1, SIZE, SIZE))
