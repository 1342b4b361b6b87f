"""Harvest's repair step: decoded cell logits -> a valid map (paper §5.2.1).

Walls where the wall logit is positive; the spawn corners always free; exactly K apples on the
K free cells with the highest apple logits (the paper keeps the number of resources the same
across worlds). If fewer than K non-corner cells are free, the walls with the lowest logits are
cleared to make room, so any input yields a valid map.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from worldagent.envs.harvest.world import HarvestMap, spawn_corners
from worldagent.errors import WorldagentError

LOGIT_CLIP = 1e4  # keeps the priorities below apart from the wall offset
WALL_OFFSET = 1e6


def repair_maps(logits: jax.Array, apples: int) -> HarvestMap:
    """Valid maps with exactly ``apples`` apples and free spawn corners from decoded logits.

    Args:
        logits: f32[2, H, W] (or [B, 2, H, W]) wall and apple logits.
        apples: K, the number of apples every map gets.

    Returns:
        ``HarvestMap`` with bool walls and apples of shape [H, W] (or [B, H, W]).
    """
    if logits.ndim == 4:
        return jax.vmap(lambda one: repair_maps(one, apples))(logits)
    wall_logit, apple_logit = jnp.clip(logits[0], -LOGIT_CLIP, LOGIT_CLIP), jnp.clip(logits[1], -LOGIT_CLIP, LOGIT_CLIP)
    height, width = wall_logit.shape
    corners = jnp.zeros((height, width), bool).at[tuple(spawn_corners(height, width).T)].set(True)
    walls = (wall_logit > 0) & ~corners
    # Free cells first, by apple logit; then wall cells, least confident walls first; never corners.
    priority = jnp.where(walls, -WALL_OFFSET - wall_logit, apple_logit)
    priority = jnp.where(corners, -jnp.inf, priority).reshape(-1)
    _, chosen = jax.lax.top_k(priority, apples)
    apple_cells = jnp.zeros(height * width, bool).at[chosen].set(True).reshape(height, width)
    return HarvestMap(walls=walls & ~apple_cells, apples=apple_cells)


def threshold_maps(logits) -> HarvestMap:
    """The unrepaired decode: walls and apples where their logits are positive ([B, 2, H, W])."""
    logits = np.asarray(logits)
    return HarvestMap(walls=logits[:, 0] > 0, apples=logits[:, 1] > 0)


def median_apples(worlds: HarvestMap) -> int:
    """The median apple count of a batch of maps (the default K of the repair)."""
    apples = np.asarray(worlds.apples)
    return int(np.median(apples.reshape(len(apples), -1).sum(axis=1)))


@struct.dataclass
class HarvestRepair:
    """G's repair for harvest: exactly ``apples`` apples, free spawn corners (static fields).

    Attributes:
        apples: K, the apple count of every generated map.
        grid: (H, W) of the maps.
    """

    apples: int = struct.field(pytree_node=False)
    grid: tuple = struct.field(pytree_node=False)

    @classmethod
    def from_dataset(cls, dataset, config=None) -> HarvestRepair:
        """The repair for maps like ``dataset``'s; ``config["apples"]`` K (default: the dataset's median)."""
        config = dict(config or {})
        grid = tuple(int(s) for s in dataset.cell_shape[1:])
        count = config.get("apples") or median_apples(dataset.worlds)
        free = int(np.prod(grid)) - 4
        if not 1 <= int(count) <= free:
            raise WorldagentError(f"apples={count}; pick between 1 and {free} (the non-corner cells of the map).")
        return cls(int(count), grid)

    @property
    def config(self) -> dict:
        return {"apples": self.apples}

    def __call__(self, logits: jax.Array) -> HarvestMap:
        """Valid maps from decoded logits f32[B, 2·H·W]."""
        return repair_maps(logits.reshape(-1, 2, *self.grid), self.apples)
