"""The repair step (paper §4.2: G(z) = repair(decoder(z))): decoded cells -> a valid lava grid.

Lava is the lava logits above ``threshold``; the goal is the most probable cell of the goal
channel outside the start's safe zone; then the L path to it that crosses the less likely lava
is cleared (``world.clear_path``), so every repaired world is reachable. Pure JAX, so ``G(z)``
stays one jitted function.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from .world import SIZE, LavaGrid, clear_path, l_path, safe_zone

CELLS = SIZE * SIZE


@struct.dataclass
class LavaRepair:
    """Threshold the lava, goal = argmax of the goal channel, clear the cheaper L path.

    Attributes:
        threshold: lava logit above which a cell is lava (0: probability one half).
    """

    threshold: float = struct.field(pytree_node=False, default=0.0)

    @classmethod
    def from_dataset(cls, dataset, config=None) -> LavaRepair:
        """The repair with ``config`` (``{"threshold": float}``); the dataset is not needed."""
        del dataset
        return cls(**dict(config or {}))

    @property
    def config(self) -> dict:
        return {"threshold": float(self.threshold)}

    def __call__(self, logits: jax.Array) -> LavaGrid:
        """A batch of valid worlds from decoded logits f32[B, 2·S·S]."""
        return jax.vmap(self.one)(jnp.asarray(logits, jnp.float32))

    def one(self, logits: jax.Array) -> LavaGrid:
        lava_logits = logits[:CELLS].reshape(SIZE, SIZE)
        goal = jnp.argmax(jnp.where(safe_zone().ravel(), -jnp.inf, logits[CELLS:]))
        lava_cost = lambda rows_first: jnp.sum(jnp.where(l_path(goal, rows_first), jax.nn.sigmoid(lava_logits), 0.0))
        return clear_path(lava_logits > self.threshold, goal, lava_cost(True) <= lava_cost(False))


def raw_decode(logits) -> LavaGrid:
    """Thresholded cells without repair (may hold no goal, several, or no safe path)."""
    cells = np.asarray(logits) > 0
    return LavaGrid(lava=cells[:, :CELLS].reshape(-1, SIZE, SIZE), goal=cells[:, CELLS:].reshape(-1, SIZE, SIZE))
